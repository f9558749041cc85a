//! Replicas on one PostgreSQL database (#37): each keeps its own catalogue in memory and
//! follows the others' writes through the store's change log, in commit order.

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Duration;

use axum::http::StatusCode;
use salient_core::mesh::write::Export;
use salient_server::api::{follow, App, Config};
use salient_server::store::{Change, Changes, Derived, PostgresStore, Store};
use serde_json::Value;
use tokio::sync::watch;

use crate::app::{TestApp, TestResponse};
use crate::duplicates::{file, model, remeshed, rescaled};
use crate::own_postgres::OwnServer;
use crate::server::obj;
use crate::shapes;
use crate::stores::fresh_database_url;

/// A replica, in process, on the database `url`, following the others' writes; `set_up`
/// may change it before it serves.
fn replica(url: &str, set_up: impl FnOnce(&mut App)) -> TestApp {
    let store = PostgresStore::open(url).expect("the test database opens");
    let mut app = App::new(Config::default(), Arc::new(store)).expect("the service starts");
    set_up(&mut app);
    let app = TestApp::serving(app);
    follow::start(&app.app);
    app
}

/// Two replicas on one new database.
fn two_replicas() -> (TestApp, TestApp) {
    let url = fresh_database_url();
    (replica(&url, |_| {}), replica(&url, |_| {}))
}

/// The change position a write's response carries.
fn position(response: &TestResponse) -> String {
    response
        .headers()
        .get("salient-position")
        .expect("a write's response carries its position")
        .to_str()
        .unwrap()
        .to_string()
}

/// Distinct small shapes, by id.
fn meshes(prefix: &str, radii: &[f64]) -> Vec<(String, Vec<u8>)> {
    radii
        .iter()
        .enumerate()
        .map(|(i, &r)| (format!("{prefix}{i}"), obj(&shapes::tube(r, 20, 16))))
        .collect()
}

/// Adds each mesh in turn; returns each id with the position of its write.
async fn add_all(app: &TestApp, meshes: &[(String, Vec<u8>)]) -> Vec<(String, String)> {
    let mut written = Vec::new();
    for (id, bytes) in meshes {
        let response = app
            .add(&format!("id={id}"), "model/obj", bytes.clone())
            .await;
        assert_eq!(response.status(), StatusCode::CREATED, "{id}");
        written.push((id.clone(), position(&response)));
    }
    written
}

async fn read_at(app: &TestApp, path: &str, at: &str) -> TestResponse {
    app.get(path).header("salient-position", at).send().await
}

postgres_only! {
    /// Writers on two replicas at once: each replica answers a read that carries another's
    /// write position with that write, and both end with the same catalogue and rankings.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn replicas_on_one_database_serve_each_others_writes() {
        let (a, b) = two_replicas();
        let (on_a, on_b) = (
            meshes("a", &[0.2, 0.3, 0.4]),
            meshes("b", &[0.25, 0.35, 0.45]),
        );
        let (written_a, written_b) = tokio::join!(add_all(&a, &on_a), add_all(&b, &on_b));
        for ((id, at), other) in written_a
            .iter()
            .map(|w| (w, &b))
            .chain(written_b.iter().map(|w| (w, &a)))
        {
            let response = read_at(other, &format!("/v1/models/{id}"), at).await;
            assert_eq!(response.status(), StatusCode::OK, "{id} at {at}");
        }
        let expected: BTreeSet<String> = on_a.iter().chain(&on_b).map(|(id, _)| id.clone()).collect();
        assert_eq!(a.listed_ids().await, expected);
        assert_eq!(b.listed_ids().await, expected);
        let last = written_a.iter().chain(&written_b).map(|(_, at)| at.parse::<u64>().unwrap()).max().unwrap().to_string();
        let mut ranked = Vec::new();
        for app in [&a, &b] {
            let response = read_at(app, "/v1/models/a0/similar?k=5", &last).await;
            assert_eq!(response.status(), StatusCode::OK);
            ranked.push(response.json()["results"].clone());
        }
        let [ranked_a, ranked_b] = <[Value; 2]>::try_from(ranked).unwrap();
        assert_eq!(ranked_a.as_array().unwrap().len(), 5, "{ranked_a}");
        assert_eq!(ranked_a, ranked_b);

        // An edit and a delete on one replica are seen by the other.
        let edited = a
            .request_with_method("PATCH", "/v1/models/b1")
            .header("content-type", "application/json")
            .body(r#"{"tags": ["edited"]}"#)
            .send()
            .await;
        assert_eq!(edited.status(), StatusCode::OK);
        let record = read_at(&b, "/v1/models/b1", &position(&edited)).await.json();
        assert_eq!(record["tags"], serde_json::json!(["edited"]));
        let deleted = b.delete("/v1/models/a2").send().await;
        assert_eq!(deleted.status(), StatusCode::NO_CONTENT);
        let gone = read_at(&a, "/v1/models/a2", &position(&deleted)).await;
        assert_eq!(gone.status(), StatusCode::NOT_FOUND);
        let tagged = read_at(&a, "/v1/models/a0/similar?k=5&tag=edited", &position(&deleted)).await.json();
        let ids: Vec<&Value> = tagged["results"].as_array().unwrap().iter().map(|r| &r["id"]).collect();
        assert_eq!(ids, [&serde_json::json!("b1")], "{tagged}");
    }
}

postgres_only! {
    /// Two disguised copies of one model sent to two replicas at once with
    /// `on_duplicate=reject`: one is stored, the other refused as its duplicate.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_duplicate_is_rejected_across_replicas_even_when_sent_at_once() {
        // Both uploads extracted before either checks: without a lock across replicas,
        // both checks would find nothing.
        let both = Arc::new(std::sync::Barrier::new(2));
        let url = fresh_database_url();
        let [a, b] = [(); 2].map(|()| {
            let both = both.clone();
            replica(&url, |app| app.set_duplicate_hook(Arc::new(move || {
                both.wait();
            })))
        });
        let (inches, _) = file(&rescaled(&model()), Export::Glb);
        let (remeshed, _) = file(&remeshed(&model()), Export::BinaryStl);
        let (on_a, on_b) = tokio::join!(
            a.add("id=inches&on_duplicate=reject", "model/gltf-binary", inches),
            b.add("id=remeshed&on_duplicate=reject", "model/stl", remeshed),
        );
        let mut statuses = [on_a.status(), on_b.status()];
        statuses.sort();
        assert_eq!(statuses, [StatusCode::CREATED, StatusCode::CONFLICT]);
        let refused = if on_a.status() == StatusCode::CONFLICT { &on_a } else { &on_b };
        assert_eq!(refused.json()["error"]["code"], "duplicate");
        let kept = if on_a.status() == StatusCode::CREATED { "inches" } else { "remeshed" };
        assert_eq!(refused.json()["error"]["duplicate"]["id"], kept);
    }
}

postgres_only! {
    /// Two processes' writers racing: a reader of the log never sees a later change before
    /// an earlier one (a gap would read as a trimmed log), and every position is there once.
    #[test]
    fn the_change_log_is_read_in_commit_order_while_writers_race() {
        let url = fresh_database_url();
        let (one, two, reader) = (
            PostgresStore::open(&url).unwrap(),
            PostgresStore::open(&url).unwrap(),
            PostgresStore::open(&url).unwrap(),
        );
        const EACH: u64 = 60;
        let shared = reader.shared().unwrap();
        let read = std::thread::scope(|scope| {
            for (n, store) in [&one, &two].into_iter().enumerate() {
                scope.spawn(move || {
                    for i in 0..EACH {
                        store.set_state(&format!("writer{n}"), &i.to_le_bytes()).unwrap();
                    }
                });
            }
            let mut read = Vec::new();
            while (read.len() as u64) < 2 * EACH {
                match shared.changes_after(read.len() as u64, 7).unwrap() {
                    Changes::Next(changes) => read.extend(changes),
                    Changes::Trimmed => panic!("a gap after position {}", read.len()),
                }
            }
            read
        });
        let positions: Vec<u64> = read.iter().map(|(p, _)| *p).collect();
        assert_eq!(positions, (1..=2 * EACH).collect::<Vec<_>>());
        let by_two = read.iter().filter(|(_, c)| *c == Change::State("writer1".into())).count();
        assert_eq!(by_two as u64, EACH);
        assert_eq!(shared.head().unwrap(), 2 * EACH);
    }
}

postgres_only! {
    /// A replica away for longer than the log keeps (trimmed) loads the store again.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_replica_behind_the_trimmed_log_loads_the_store_again() {
        let url = fresh_database_url();
        let a = replica(&url, |_| {});
        // Not following: it stays where it started until told to catch up.
        let b = TestApp::build(Config::default(), Arc::new(PostgresStore::open(&url).unwrap()), None);
        add_all(&a, &meshes("m", &[0.2, 0.3])).await;
        assert_eq!(a.delete("/v1/models/m0").send().await.status(), StatusCode::NO_CONTENT);
        add_all(&a, &meshes("n", &[0.4])).await;
        let store = PostgresStore::open(&url).unwrap();
        assert!(store.shared().unwrap().trim(Duration::ZERO).unwrap() >= 3);
        assert!(matches!(store.shared().unwrap().changes_after(0, 10).unwrap(), Changes::Trimmed));
        follow::catch_up(&b.app).await.unwrap();
        let expected: BTreeSet<String> = ["m1", "n0"].map(String::from).into();
        assert_eq!(b.listed_ids().await, expected);
    }
}

postgres_only! {
    /// A replica that has not applied the position a request carries in time answers 503
    /// with `Retry-After`, not a stale answer.
    #[tokio::test]
    async fn a_request_for_a_position_not_yet_applied_is_answered_503() {
        let app = replica(&fresh_database_url(), |app| app.config.position_wait_ms = 20);
        let response = read_at(&app, "/v1/models", "1000").await;
        assert_eq!(response.status(), StatusCode::SERVICE_UNAVAILABLE);
        assert_eq!(response.json()["error"]["code"], "behind");
        assert_eq!(response.headers()["retry-after"], "1");
    }
}

/// On a store of its own everything written is applied: the position is accepted and not
/// waited for; one that is not a position is refused.
#[tokio::test]
async fn a_position_on_a_store_of_its_own_is_checked_and_not_waited_for() {
    let app = TestApp::new();
    let response = read_at(&app, "/v1/models", "1000").await;
    assert_eq!(response.status(), StatusCode::OK);
    let response = read_at(&app, "/v1/models", "soon").await;
    assert_eq!(response.status(), StatusCode::BAD_REQUEST);
    assert_eq!(response.json()["error"]["code"], "invalid_position");
}

postgres_only! {
    /// PostgreSQL stopped under two replicas: they still list, read records, and rank
    /// uploads and stored models (from their own copies of the signatures), refuse a write
    /// with 503 and `Retry-After`, and say so on `/readyz`, which stays 200 (a balancer keeps
    /// them). Once it is back they reconnect, and a write on one is served by the other.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn replicas_rank_while_postgres_is_down_and_follow_again_when_it_is_back() {
        let mut server = OwnServer::start();
        let stores =
            [(); 2].map(|()| Arc::new(PostgresStore::open(server.url()).expect("it opens")));
        let [a, b] = stores.clone().map(|store| {
            let app = TestApp::serving(App::new(Config::default(), store).unwrap());
            follow::start(&app.app);
            app
        });
        let written = add_all(&a, &meshes("m", &[0.2, 0.3])).await;
        let seen = read_at(&b, "/v1/models/m1", &written[1].1).await;
        assert_eq!(seen.status(), StatusCode::OK);

        server.stop();
        for store in &stores {
            let mut up = store.shared().unwrap().connected();
            up.wait_for(|up| !up).await.unwrap();
        }
        for app in [&a, &b] {
            assert_eq!(app.get_json("/readyz").await["store"], "unavailable");
            let ranked = app
                .post("/v1/search?k=2")
                .header("content-type", "model/obj")
                .body(obj(&shapes::tube(0.21, 20, 16)))
                .send()
                .await;
            assert_eq!(ranked.status(), StatusCode::OK);
            assert_eq!(ranked.json()["results"][0]["id"], "m0");
            assert_eq!(app.listed_ids().await.len(), 2);
            assert_eq!(app.get_json("/v1/models/m1").await["id"], "m1");
            let similar = app.get_json("/v1/models/m0/similar?k=2").await;
            assert_eq!(similar["results"][0]["id"], "m1", "{similar}");
            let file = app.get("/v1/models/m0/file").send().await;
            assert_eq!(file.status(), StatusCode::SERVICE_UNAVAILABLE);
            assert_eq!(file.json()["error"]["code"], "store_unavailable");
        }
        let refused = b.add("id=n0", "model/obj", obj(&shapes::tube(0.4, 20, 16))).await;
        assert_eq!(refused.status(), StatusCode::SERVICE_UNAVAILABLE);
        assert_eq!(refused.json()["error"]["code"], "store_unavailable");
        assert!(refused.headers().contains_key("retry-after"));

        server.restart();
        for store in &stores {
            let mut up = store.shared().unwrap().connected();
            tokio::time::timeout(Duration::from_secs(30), up.wait_for(|up| *up))
                .await
                .expect("the replica reconnects")
                .unwrap();
        }
        let written = add_all(&b, &meshes("n", &[0.4])).await;
        let seen = read_at(&a, "/v1/models/n0", &written[0].1).await;
        assert_eq!(seen.status(), StatusCode::OK);
        assert_eq!(a.get_json("/readyz").await["store"], "ok");
    }
}

postgres_only! {
    /// A replica that extracts otherwise than the store's others is refused; one told to
    /// adopt its parameters starts, and the others see that it did.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_replica_with_other_extraction_parameters_is_refused_unless_it_adopts_them() {
        let url = fresh_database_url();
        let first = replica(&url, |_| {});
        let other = |adopt: bool| {
            let mut config = Config::default();
            config.params.d2.samples += 1;
            config.adopt_extraction = adopt;
            App::new(config, Arc::new(PostgresStore::open(&url).unwrap()))
        };
        let refused = other(false).err().expect("refused");
        assert!(refused.to_string().contains("--adopt-extraction"), "{refused}");
        let adopted = other(true).expect("it adopts");
        drop(adopted);
        follow::catch_up(&first.app).await.unwrap();
        let metrics = first.get("/metrics").send().await.text();
        assert!(metrics.contains("salient_replica_other_extraction 1"), "{metrics}");
        // And the first, started again with its old parameters, is now the one refused.
        let again = App::new(Config::default(), Arc::new(PostgresStore::open(&url).unwrap()));
        assert!(again.is_err());
    }
}

postgres_only! {
    /// Two replicas start on a store whose signatures are stale for them: one claims the
    /// re-extraction and the other leaves it, so each model is re-extracted once.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn stale_signatures_are_re_extracted_once_by_one_of_the_replicas() {
        let url = fresh_database_url();
        {
            let old = replica(&url, |_| {});
            add_all(&old, &meshes("m", &[0.2, 0.3, 0.4])).await;
        }
        let store = PostgresStore::open(&url).unwrap();
        let shared = store.shared().unwrap();
        let before = shared.head().unwrap();
        let [b, c] = [true, false].map(|adopt| {
            let mut config = Config::default();
            config.params.d2.samples += 1;
            config.adopt_extraction = adopt;
            let app = App::new(config, Arc::new(PostgresStore::open(&url).unwrap()));
            TestApp::serving(app.expect("it starts"))
        });
        assert_eq!((b.app.stale_count(), c.app.stale_count()), (3, 3));
        let mut changed = shared.subscribe();
        b.app.start_background();
        c.app.start_background();
        tokio::time::timeout(Duration::from_secs(120), async {
            loop {
                follow::catch_up(&b.app).await.unwrap();
                follow::catch_up(&c.app).await.unwrap();
                if b.app.stale_count() + c.app.stale_count() == 0 {
                    break;
                }
                changed.changed().await.unwrap();
            }
        })
        .await
        .expect("the signatures are re-extracted");
        let Changes::Next(changes) = shared.changes_after(before, 100).unwrap() else {
            panic!("the log was trimmed");
        };
        let updates = changes
            .iter()
            .filter(|(_, change)| matches!(change, Change::Model(_)))
            .count();
        assert_eq!(updates, 3, "{changes:?}");
    }
}

/// A replica that stores `ids` and is killed before it makes their patches (its background
/// work never started); waits for `survivor` to have applied the writes.
async fn stored_by_a_killed_replica(url: &str, survivor: &TestApp, ids: &str) {
    let killed = replica(url, |_| {});
    let written = add_all(&killed, &meshes(ids, &[0.2, 0.3])).await;
    drop(killed);
    let (id, at) = written.last().unwrap();
    let applied = read_at(survivor, &format!("/v1/models/{id}"), at).await;
    assert_eq!(applied.status(), StatusCode::OK);
}

/// A survivor replica that counts the models lacking patches every second, leaving those
/// stored in the last `grace_secs`; its background work started and its first count done.
async fn counting_every_second(
    url: &str,
    grace_secs: u64,
) -> (TestApp, watch::Receiver<Option<usize>>) {
    let survivor = replica(url, |app| {
        app.config.patch_recount_secs = 1;
        app.config.patch_grace_secs = grace_secs;
    });
    let mut pending = survivor.app.patches_pending();
    survivor.app.start_background();
    pending.wait_for(|p| *p == Some(0)).await.unwrap();
    (survivor, pending)
}

fn patches_made(url: &str, ids: &[&str]) -> Vec<bool> {
    let store = PostgresStore::open(url).unwrap();
    ids.iter()
        .map(|id| store.derived(Derived::Patches, id).unwrap().is_some())
        .collect()
}

postgres_only! {
    /// A replica killed before it made its writes' patches leaves them to another replica's
    /// next count.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn patches_a_killed_replica_left_are_made_by_the_next_count() {
        let url = fresh_database_url();
        let (survivor, mut pending) = counting_every_second(&url, 0).await;
        stored_by_a_killed_replica(&url, &survivor, "k").await;
        tokio::time::timeout(Duration::from_secs(60), async {
            while patches_made(&url, &["k0", "k1"]) != [true, true] {
                pending.changed().await.unwrap();
            }
        })
        .await
        .expect("the survivor makes them");
    }
}

postgres_only! {
    /// A count leaves models stored within the grace to the replica that stored them: a
    /// living one is making them (a killed one's wait for the first count after it).
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_count_leaves_models_stored_within_the_grace() {
        let url = fresh_database_url();
        let (survivor, mut pending) = counting_every_second(&url, 3600).await;
        stored_by_a_killed_replica(&url, &survivor, "k").await;
        // Two counts announced after the survivor applied the writes: the second began after.
        pending.borrow_and_update();
        for _ in 0..2 {
            pending.changed().await.unwrap();
        }
        assert_eq!(*pending.borrow(), Some(0));
        assert_eq!(patches_made(&url, &["k0", "k1"]), [false, false]);
    }
}

/// Waits, bounded, for `store` to hold the lock `name` (a lock let go is freed in the
/// background; a closed session's, once the server has ended it).
fn lock_within(store: &Arc<PostgresStore>, name: &'static str) -> Box<dyn Send> {
    let (taken, told) = std::sync::mpsc::channel();
    let store = store.clone();
    std::thread::spawn(move || {
        let _ = taken.send(store.shared().unwrap().lock(name).unwrap());
    });
    told.recv_timeout(Duration::from_secs(30))
        .expect("the lock is free within 30 s")
}

postgres_only! {
    /// A claim is held by one process at a time, and freed when its holder lets it go or
    /// goes away (its session ends, as when a replica is killed), so another takes it over.
    #[test]
    fn a_claim_is_held_once_and_taken_over_when_its_holder_goes() {
        let url = fresh_database_url();
        let [one, two] = [(); 2].map(|()| Arc::new(PostgresStore::open(&url).unwrap()));
        let held = one.shared().unwrap().try_lock("work").unwrap().expect("free at first");
        assert!(two.shared().unwrap().try_lock("work").unwrap().is_none());
        assert!(two.shared().unwrap().try_lock("other work").unwrap().is_some());
        drop(held);
        let taken = lock_within(&two, "work");
        assert!(one.shared().unwrap().try_lock("work").unwrap().is_none());
        drop(taken);
        // Never let go: its session ends with the store, as a killed replica's does.
        std::mem::forget(lock_within(&one, "work"));
        drop(one);
        lock_within(&two, "work");
    }
}

postgres_only! {
    /// The rolling upgrade: a newer release migrates the schema with additions only, which a
    /// replica of this one, already running, keeps reading and writing; this release started
    /// anew on that schema is refused, so an old replica never comes back after the upgrade.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_running_replica_keeps_serving_after_a_newer_release_adds_to_the_schema() {
        let url = fresh_database_url();
        let old = replica(&url, |_| {});
        add_all(&old, &meshes("m", &[0.2])).await;
        // What a next release's migration may do: add tables and columns with defaults.
        let (client, connection) = tokio_postgres::connect(&url, tokio_postgres::NoTls)
            .await
            .unwrap();
        tokio::spawn(connection);
        client
            .batch_execute(
                "ALTER TABLE models ADD COLUMN added_later text NOT NULL DEFAULT ''; \
                 CREATE TABLE added_later (id text PRIMARY KEY); \
                 INSERT INTO refinery_schema_history (version, name, applied_on, checksum) \
                 SELECT max(version) + 1, 'added_later', now()::text, '0' FROM refinery_schema_history;",
            )
            .await
            .unwrap();
        let written = add_all(&old, &meshes("n", &[0.3])).await;
        assert_eq!(read_at(&old, "/v1/models/n0", &written[0].1).await.status(), StatusCode::OK);
        let deleted = old.delete("/v1/models/m0").send().await;
        assert_eq!(deleted.status(), StatusCode::NO_CONTENT);
        let refused = PostgresStore::open(&url).expect_err("a newer schema is refused");
        assert!(refused.to_string().contains("upgrade salient"), "{refused}");
    }
}

//! The service under concurrent load: what is acknowledged is stored, the server stays
//! responsive while extraction saturates the pool, and overload is a 503, not a hang.

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use reqwest::{Client, StatusCode};
use salient_server::api::{Config, Hook};
use salient_server::store::InMemoryStore;

use crate::app::TestApp;
use crate::server::{obj, Server};
use crate::shapes;

/// Eight clients, 200 requests mixing adds and searches: every acknowledged model is listed
/// afterwards, and nothing else.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn concurrent_adds_and_searches_keep_exactly_the_acknowledged_models() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("store"), &["--queue-depth", "64"]);
    let base = server.url.clone();
    let meshes: Vec<Vec<u8>> = (0..4)
        .map(|s| obj(&shapes::star(2, &shapes::five_tips()[..s + 2])))
        .collect();
    let mut clients = Vec::new();
    for c in 0..8 {
        let (base, meshes) = (base.clone(), meshes.clone());
        clients.push(tokio::spawn(async move {
            let client = Client::new();
            let mut acknowledged = Vec::new();
            for r in 0..25 {
                let mesh = meshes[(c + r) % meshes.len()].clone();
                if r % 3 == 2 {
                    let response = client
                        .post(format!("{base}/v1/search?k=3"))
                        .header("content-type", "model/obj")
                        .body(mesh)
                        .send()
                        .await
                        .unwrap();
                    assert_eq!(response.status(), StatusCode::OK);
                } else {
                    let id = format!("c{c}-r{r}");
                    let response = client
                        .post(format!("{base}/v1/models?id={id}"))
                        .header("content-type", "model/obj")
                        .body(mesh)
                        .send()
                        .await
                        .unwrap();
                    assert!(response.status().is_success(), "{}", response.status());
                    acknowledged.push(id);
                }
            }
            acknowledged
        }));
    }
    let mut expected = BTreeSet::new();
    for client in clients {
        expected.extend(client.await.unwrap());
    }
    assert_eq!(server.listed_ids().await, expected);
    assert_eq!(expected.len(), 8 * 17);
}

/// With one worker and a queue of one, concurrent extractions beyond those get 503 with
/// `Retry-After`; meanwhile `/healthz` answers. (That a full queue is refused at once,
/// without waiting for the worker, is `api::pool`'s unit test.)
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn overload_is_refused_and_health_answers_meanwhile() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(
        &dir.path().join("store"),
        &["--workers", "1", "--queue-depth", "1"],
    );
    let heavy = obj(&shapes::icosphere(5)); // ~0.3 s of extraction each
    let client = Client::new();
    let uploads: Vec<_> = (0..8)
        .map(|i| {
            let (client, url, body) = (
                client.clone(),
                server.at(&format!("/v1/models?id=heavy{i}")),
                heavy.clone(),
            );
            tokio::spawn(async move {
                let response = client
                    .post(url)
                    .header("content-type", "model/obj")
                    .body(body)
                    .send()
                    .await
                    .unwrap();
                let retry = response
                    .headers()
                    .get("retry-after")
                    .map(|v| v.to_str().unwrap().to_string());
                if response.status().is_success() {
                    Ok(())
                } else {
                    Err(retry)
                }
            })
        })
        .collect();
    // While an extraction runs, liveness answers and says so.
    let health = || async {
        let response = client.get(server.at("/healthz")).send().await.unwrap();
        assert_eq!(response.status(), StatusCode::OK);
        response.json::<serde_json::Value>().await.unwrap()
    };
    let mut busy = false;
    for _ in 0..100_000 {
        if health().await["extractions_in_flight"].as_u64().unwrap() >= 1 {
            busy = true;
            break;
        }
    }
    assert!(busy, "no extraction was ever seen in flight");
    let (mut accepted, mut refused) = (0, 0);
    for upload in uploads {
        match upload.await.unwrap() {
            Ok(()) => accepted += 1,
            Err(retry) => {
                refused += 1;
                assert_eq!(retry.as_deref(), Some("1"));
            }
        }
    }
    assert!(
        accepted >= 1 && refused >= 1,
        "accepted {accepted}, refused {refused}"
    );
    assert_eq!(accepted + refused, 8);
}

/// A ranking held in the middle: the test learns when it is there (`wait_entered`) and lets
/// it go on (`release`); `started` counts the rankings that reached that point.
struct Held {
    wait_entered: std::sync::mpsc::Receiver<()>,
    release: std::sync::mpsc::Sender<()>,
    started: Arc<AtomicUsize>,
}

/// An app running `rankings` rankings at once whose first ranking is held (a hook on its
/// thread).
fn holding_the_first_ranking(rankings: usize) -> (Arc<TestApp>, Held) {
    let (entered, wait_entered) = std::sync::mpsc::channel();
    let (release, wait_release) = std::sync::mpsc::channel::<()>();
    let wait_release = Mutex::new(wait_release);
    let started = Arc::new(AtomicUsize::new(0));
    let counted = started.clone();
    let hook: Hook = Arc::new(move || {
        if counted.fetch_add(1, Ordering::SeqCst) == 0 {
            entered.send(()).unwrap();
            wait_release.lock().unwrap().recv().unwrap();
        }
    });
    let config = Config {
        rankings,
        ..Config::default()
    };
    let app = TestApp::build(config, Arc::new(InMemoryStore::new()), Some(hook));
    (
        Arc::new(app),
        Held {
            wait_entered,
            release,
            started,
        },
    )
}

/// The catalogue never blocks: with a ranking held in the middle (a hook on its thread,
/// released by the test), an add completes, and reads and another ranking (two may run at
/// once here) answer. The held ranking then finishes on the snapshot it started with.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_ranking_held_midway_blocks_neither_writes_nor_reads() {
    let (
        app,
        Held {
            wait_entered,
            release,
            ..
        },
    ) = holding_the_first_ranking(2);
    let cone = obj(&shapes::cone(0.5, 20, 24));
    assert_eq!(
        app.add("id=a", "model/obj", cone.clone()).await.status,
        StatusCode::CREATED
    );

    let held = {
        let app = app.clone();
        tokio::spawn(async move { app.get("/v1/models/a/similar").send().await })
    };
    tokio::task::spawn_blocking(move || wait_entered.recv().unwrap())
        .await
        .unwrap();
    // The ranking holds its snapshot on its thread; everything else goes on.
    let star = obj(&shapes::star(2, &shapes::five_tips()));
    assert_eq!(
        app.add("id=b", "model/obj", star).await.status,
        StatusCode::CREATED
    );
    assert_eq!(app.get_json("/v1/models/b").await["id"], "b");
    assert_eq!(app.listed_ids().await.len(), 2);
    let other = app.get_json("/v1/models/b/similar").await;
    assert_eq!(other["results"][0]["id"], "a");
    assert!(app.delete("/v1/models/b").send().await.status.is_success());
    assert!(!held.is_finished());

    release.send(()).unwrap();
    let held = held.await.unwrap();
    assert_eq!(held.status, StatusCode::OK);
    // Its snapshot held only `a`, which a similar search leaves out.
    assert_eq!(held.json()["results"].as_array().unwrap().len(), 0);
}

/// Rankings take turns (`rankings = 1` here): while one is held in the middle, a
/// second waits for its turn — counted on `/metrics` — without starting, and runs when the
/// first ends.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rankings_take_turns() {
    let (
        app,
        Held {
            wait_entered,
            release,
            started,
        },
    ) = holding_the_first_ranking(1);
    for (id, mesh) in [
        ("id=a", obj(&shapes::cone(0.5, 20, 24))),
        ("id=b", obj(&shapes::star(2, &shapes::five_tips()))),
    ] {
        assert_eq!(
            app.add(id, "model/obj", mesh).await.status,
            StatusCode::CREATED
        );
    }
    let similar = |id: &'static str| {
        let app = app.clone();
        tokio::spawn(async move { app.get(format!("/v1/models/{id}/similar")).send().await })
    };
    let first = similar("a");
    tokio::task::spawn_blocking(move || wait_entered.recv().unwrap())
        .await
        .unwrap();
    let second = similar("b");
    // Until the second is counted as waiting, or (were turns not kept) has started.
    while started.load(Ordering::SeqCst) == 1
        && !app
            .get("/metrics")
            .send()
            .await
            .text()
            .contains("salient_rankings_waiting 1")
    {
        tokio::task::yield_now().await;
    }
    assert_eq!(
        started.load(Ordering::SeqCst),
        1,
        "the second ranking started beside the first"
    );
    release.send(()).unwrap();
    for (ranking, other) in [(first, "b"), (second, "a")] {
        let response = ranking.await.unwrap();
        assert_eq!(response.status, StatusCode::OK);
        assert_eq!(response.json()["results"][0]["id"], other);
    }
    assert_eq!(started.load(Ordering::SeqCst), 2);
    assert!(app
        .get("/metrics")
        .send()
        .await
        .text()
        .contains("salient_rankings_waiting 0"));
}

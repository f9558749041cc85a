//! Backups and moving a catalogue between stores (#37): `POST /v1/admin/backup` while models
//! change, `salient restore`, and `salient migrate-store` from sled to PostgreSQL and back.

use std::collections::BTreeSet;
use std::process::Command;
use std::sync::{mpsc, Arc, Mutex};

use axum::http::StatusCode;
use salient_server::api::{App, Config};
use salient_server::store::copy::differences;
use salient_server::store::{Derived, SledStore, Store};
use serde_json::Value;

use crate::app::TestApp;
use crate::golden::golden_store;
use crate::server::obj;
use crate::shapes;
use crate::stores::fresh_database_url;

/// Runs `salient ARGS` with `env`; asserts success and returns what it printed.
fn salient(args: &[&str], env: &[(&str, &str)]) -> String {
    let output = Command::new(env!("CARGO_BIN_EXE_salient"))
        .args(args)
        .envs(env.iter().copied())
        .output()
        .expect("the binary runs");
    assert!(
        output.status.success(),
        "salient {args:?}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout).unwrap()
}

fn tube(radius: f64) -> Vec<u8> {
    obj(&shapes::tube(radius, 20, 16))
}

/// Every model's ranking of the others: ids and distances.
async fn rankings(app: &TestApp) -> Vec<Value> {
    let mut all = Vec::new();
    for id in app.listed_ids().await {
        let ranked = app.get_json(&format!("/v1/models/{id}/similar?k=10")).await;
        all.push(serde_json::json!([id, ranked["results"]]));
    }
    all
}

/// A backup taken while a model is added and another deleted holds the catalogue as it
/// stood when the backup ended; restored elsewhere, it lists the same models and ranks
/// them with the same ids and distances.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_backup_taken_while_models_change_restores_the_catalogue_it_ended_with() {
    let (data, backups, restored) = (
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
    );
    let config = Config {
        backup_dir: Some(backups.path().to_path_buf()),
        ..Config::default()
    };
    let store = Arc::new(SledStore::open(data.path()).unwrap());
    let mut app = App::new(config, store).unwrap();
    // The backup stops between its copy and its catching up until the test says go.
    let (copied, told) = mpsc::channel::<()>();
    let (go, wait) = mpsc::channel::<()>();
    let (copied, wait) = (Mutex::new(copied), Mutex::new(wait));
    app.set_backup_hook(Arc::new(move || {
        copied.lock().unwrap().send(()).unwrap();
        wait.lock().unwrap().recv().unwrap();
    }));
    let app = TestApp::serving(app);
    for (id, radius) in [("m0", 0.2), ("m1", 0.3), ("m2", 0.4)] {
        let added = app
            .add(&format!("id={id}"), "model/obj", tube(radius))
            .await;
        assert_eq!(added.status(), StatusCode::CREATED);
    }

    let meanwhile = async {
        let told = Mutex::new(told);
        tokio::task::spawn_blocking(move || told.lock().unwrap().recv().unwrap())
            .await
            .unwrap();
        let added = app.add("id=m3", "model/obj", tube(0.5)).await;
        assert_eq!(added.status(), StatusCode::CREATED);
        let deleted = app.delete("/v1/models/m0").send().await;
        assert_eq!(deleted.status(), StatusCode::NO_CONTENT);
        go.send(()).unwrap();
    };
    let (backup, ()) = tokio::join!(app.post("/v1/admin/backup").send(), meanwhile);
    assert_eq!(backup.status(), StatusCode::CREATED, "{}", backup.text());
    let backup = backup.json();
    assert_eq!(backup["copied"]["models"], 3);
    let folder = backups.path().join(backup["name"].as_str().unwrap());

    let printed = salient(
        &[
            "restore",
            "--from",
            folder.to_str().unwrap(),
            "--to",
            restored.path().to_str().unwrap(),
        ],
        &[],
    );
    assert!(printed.contains("copied 3 models"), "{printed}");
    let again = TestApp::build(
        Config::default(),
        Arc::new(SledStore::open(restored.path()).unwrap()),
        None,
    );
    let expected: BTreeSet<String> = ["m1", "m2", "m3"].map(String::from).into();
    assert_eq!(again.listed_ids().await, expected);
    assert_eq!(rankings(&again).await, rankings(&app).await);
    let file = again.get("/v1/models/m3/file").send().await;
    assert_eq!(file.status(), StatusCode::OK);
}

/// Backups need a folder, and are not how a PostgreSQL store is backed up.
#[tokio::test]
async fn a_backup_without_a_backup_folder_says_how_to_get_one() {
    let app = TestApp::new();
    let response = app.post("/v1/admin/backup").send().await;
    crate::app::expect_error(&response, StatusCode::CONFLICT, "not_configured");
    assert!(response.text().contains("--backup-dir"));
}

/// Every model, file, signature, derived entry and state value of `a` is in `b` as it is in `a`.
fn same_catalogue(a: &dyn Store, b: &dyn Store) {
    assert!(!a.is_empty());
    assert_eq!(
        differences(a, b, 10).unwrap(),
        Vec::<salient_server::model::ModelId>::new()
    );
    for record in a.list(None, usize::MAX).unwrap() {
        let id = record.id.as_str();
        let (x, y) = (
            a.upload(id).unwrap().unwrap(),
            b.upload(id).unwrap().unwrap(),
        );
        assert_eq!((x.mesh, x.resources), (y.mesh, y.resources), "{id}");
        for cache in Derived::ALL {
            assert_eq!(
                a.derived(cache, id).unwrap(),
                b.derived(cache, id).unwrap(),
                "{id}"
            );
        }
    }
    assert_eq!(a.states().unwrap(), b.states().unwrap());
}

postgres_only! {
    /// A library moved from sled to PostgreSQL and back keeps every model, file and
    /// signature; a store that already holds models is not copied into.
    #[test]
    fn migrate_store_moves_a_library_to_postgres_and_back_whole() {
        let (golden, back) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
        let original = golden_store(golden.path());
        let name = golden.path().to_str().unwrap().to_string();
        drop(original);
        let url = fresh_database_url();
        let printed = salient(&["migrate-store"], &[("SALIENT_FROM", &name), ("SALIENT_TO", &url)]);
        assert!(printed.contains("every model's record and signature checked"), "{printed}");
        let back_name = back.path().to_str().unwrap();
        salient(&["migrate-store", "--to", back_name], &[("SALIENT_FROM", &url)]);
        let (original, postgres, back) = (
            SledStore::open(golden.path()).unwrap(),
            salient_server::store::PostgresStore::open(&url).unwrap(),
            SledStore::open(back.path()).unwrap(),
        );
        same_catalogue(&original, &postgres);
        same_catalogue(&original, &back);
        drop((original, back));
        let refused = Command::new(env!("CARGO_BIN_EXE_salient"))
            .args(["migrate-store", "--from", &name, "--to", back_name])
            .output()
            .unwrap();
        assert!(!refused.status.success());
        let said = String::from_utf8_lossy(&refused.stderr);
        assert!(said.contains("already holds models"), "{said}");
    }
}

postgres_only! {
    /// The PostgreSQL backup the README gives: `pg_dump` of a served database while an upload
    /// goes on, `pg_restore` into an empty one, and a replica there lists the models the dump
    /// holds and ranks them with the same ids and distances.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn pg_dump_and_pg_restore_move_a_served_database_whole() {
        let url = fresh_database_url();
        let store = Arc::new(salient_server::store::PostgresStore::open(&url).unwrap());
        let app = TestApp::build(Config::default(), store, None);
        for (id, radius) in [("m0", 0.2), ("m1", 0.3), ("m2", 0.4)] {
            let added = app.add(&format!("id={id}"), "model/obj", tube(radius)).await;
            assert_eq!(added.status(), StatusCode::CREATED);
        }
        let dump = tempfile::tempdir().unwrap();
        let file = dump.path().join("salient.dump");
        let dumping = {
            let (url, file) = (url.clone(), file.clone());
            tokio::task::spawn_blocking(move || {
                Command::new(crate::own_postgres::program("pg_dump"))
                    .args(["--format=custom", "--file"])
                    .arg(&file)
                    .arg(&url)
                    .status()
                    .expect("pg_dump runs")
            })
        };
        let (dumped, added) = tokio::join!(dumping, app.add("id=m3", "model/obj", tube(0.5)));
        assert!(dumped.unwrap().success());
        assert_eq!(added.status(), StatusCode::CREATED);

        let restored_url = fresh_database_url();
        let restored = Command::new(crate::own_postgres::program("pg_restore"))
            .args(["--no-owner", "--dbname", &restored_url])
            .arg(&file)
            .status()
            .expect("pg_restore runs");
        assert!(restored.success());
        let store = Arc::new(salient_server::store::PostgresStore::open(&restored_url).unwrap());
        let again = TestApp::build(Config::default(), store, None);
        let listed = again.listed_ids().await;
        // The dump is one snapshot: before the upload, or after it.
        let before: BTreeSet<String> = ["m0", "m1", "m2"].map(String::from).into();
        assert!(listed == before || listed == app.listed_ids().await, "{listed:?}");
        for id in &listed {
            let path = format!("/v1/models/{id}/similar?k=10");
            let (ours, theirs) = (again.get_json(&path).await, app.get_json(&path).await);
            // Ids and distances of the models both hold (ranks move with a model the dump
            // left out).
            let kept = |ranked: &Value| -> Vec<(Value, Value)> {
                ranked["results"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .filter(|r| listed.contains(r["id"].as_str().unwrap()))
                    .map(|r| (r["id"].clone(), r["distance"].clone()))
                    .collect()
            };
            assert_eq!(kept(&ours), kept(&theirs), "{id}");
        }
    }
}

//! Online re-extraction (`/v1/admin/reindex`): stale signatures serve until they are renewed
//! in the background, searches say how many models they left out meanwhile, and a run cut
//! by a restart resumes after its last model.

use std::sync::Arc;
use std::time::Duration;

use axum::http::StatusCode;
use salient_core::pipeline::compute;
use salient_core::signature::Signature;
use salient_core::Params;
use salient_server::api::{Config, ReindexProgress, ReindexState};
use salient_server::model::ModelId;
use salient_server::store::{InMemoryStore, Store};

use crate::app::{expect_error, TestApp};
use crate::server::obj;
use crate::shapes;

fn quiet() -> Config {
    Config {
        reindex_on_start: false,
        ..Config::default()
    }
}

/// Waits (bounded) until the run has finished, and returns its progress.
async fn finished(app: &TestApp) -> ReindexProgress {
    let mut progress = app.app.reindex_progress();
    let done = progress.wait_for(|p| p.state == ReindexState::Finished);
    let last = tokio::time::timeout(Duration::from_secs(300), done)
        .await
        .expect("re-extraction finishes")
        .unwrap()
        .clone();
    last
}

async fn add_shapes(app: &TestApp) {
    for (id, mesh) in [
        ("cone", shapes::cone(0.5, 20, 24)),
        ("star", shapes::star(3, &shapes::five_tips())),
        ("tube", shapes::tube(0.2, 30, 16)),
    ] {
        let added = app.add(&format!("id={id}"), "model/obj", obj(&mesh)).await;
        assert_eq!(added.status, StatusCode::CREATED, "{}", added.text());
    }
}

/// Rewrites a stored signature without its light field descriptor, as format 1 had it.
fn strip_descriptor(store: &dyn Store, id: &str) {
    let record = store.get(id).unwrap().unwrap();
    let mut signature = Signature::from_bytes(&store.signature(id).unwrap().unwrap()).unwrap();
    signature.lfd = None;
    assert!(store.update_model(&record, &signature.to_bytes()).unwrap());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_model_without_a_descriptor_is_left_out_then_re_extracted_online() {
    let store = Arc::new(InMemoryStore::new());
    add_shapes(&TestApp::build(quiet(), store.clone(), None)).await;
    strip_descriptor(store.as_ref(), "star");

    let app = TestApp::build(quiet(), store.clone(), None);
    assert_eq!(app.app.stale_count(), 1);
    let ranked = app.get_json("/v1/models/cone/similar?method=lfd").await;
    assert_eq!(ranked["left_out"], 1, "{ranked}");
    assert_eq!(ranked["results"].as_array().unwrap().len(), 1, "{ranked}");
    // The other methods still rank it, with its old signature.
    let ranked = app.get_json("/v1/models/cone/similar?method=ecc").await;
    assert_eq!(ranked["left_out"], 0);
    assert_eq!(ranked["results"].as_array().unwrap().len(), 2);
    // The default ranks it on the parts it has, and says so.
    let ranked = app.get_json("/v1/models/cone/similar").await;
    assert_eq!(ranked["method"], "hybrid");
    assert_eq!(
        (ranked["left_out"].as_u64(), ranked["partial"].as_u64()),
        (Some(0), Some(1))
    );
    assert_eq!(ranked["results"].as_array().unwrap().len(), 2, "{ranked}");
    expect_error(
        &app.get("/v1/models/star/similar?method=lfd").send().await,
        StatusCode::CONFLICT,
        "missing_descriptor",
    );

    let started = app.post("/v1/admin/reindex").send().await;
    assert_eq!(started.status, StatusCode::ACCEPTED, "{}", started.text());
    assert_eq!(started.json()["total"], 1);
    let progress = finished(&app).await;
    assert_eq!((progress.done, progress.failed), (1, 0), "{progress:?}");
    let report = app.get_json("/v1/admin/reindex").await;
    assert_eq!(report["state"], "finished");
    assert_eq!(report["remaining"], 0);

    let ranked = app.get_json("/v1/models/cone/similar?method=lfd").await;
    assert_eq!(ranked["left_out"], 0);
    assert_eq!(ranked["results"].as_array().unwrap().len(), 2);
    assert_eq!(app.get_json("/v1/models/cone/similar").await["partial"], 0);
    let renewed = Signature::from_bytes(&store.signature("star").unwrap().unwrap()).unwrap();
    assert_eq!(renewed.staleness(&Params::default()), None);
    assert!(app.get_json("/v1/models/star/similar?method=lfd").await["results"][0].is_object());
}

/// A run that a restart interrupted goes on after its last model, with its counts; a new
/// run would have counted only what is stale now.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_interrupted_run_resumes_after_its_last_model() {
    let store = Arc::new(InMemoryStore::new());
    add_shapes(&TestApp::build(quiet(), store.clone(), None)).await;
    // New extraction parameters make all three stale; the first was done before the stop.
    let mut params = Params::default();
    params.d2.samples = 500;
    let config = Config {
        params: params.clone(),
        ..quiet()
    };
    let mut record = store.get("cone").unwrap().unwrap();
    let signature = compute(&shapes::cone(0.5, 20, 24), &params).unwrap();
    record.describe(&signature);
    assert!(store.update_model(&record, &signature.to_bytes()).unwrap());
    let interrupted = serde_json::json!({
        "state": "running", "total": 3, "done": 1, "last_id": "cone", "started_unix": 1234
    });
    store
        .set_state("reindex", &serde_json::to_vec(&interrupted).unwrap())
        .unwrap();

    let app = TestApp::build(config, store.clone(), None);
    assert_eq!(app.app.stale_count(), 2);
    app.app.start_background();
    let progress = finished(&app).await;
    assert_eq!(
        (progress.total, progress.done, progress.failed),
        (3, 3, 0),
        "{progress:?}"
    );
    assert_eq!(progress.started_unix, Some(1234));
    assert_eq!(progress.last_id.as_deref(), Some("tube"));
    assert_eq!(app.app.stale_count(), 0);
    for id in ["cone", "star", "tube"] {
        let signature = Signature::from_bytes(&store.signature(id).unwrap().unwrap()).unwrap();
        assert_eq!(signature.params.d2.samples, 500, "{id}");
    }
    // Kept in the store for the next start.
    let kept: ReindexProgress =
        serde_json::from_slice(&store.state("reindex").unwrap().unwrap()).unwrap();
    assert_eq!(kept.state, ReindexState::Finished);
}

/// The release-0.1.0 store is stale as a whole under this release's extraction; a server
/// started on it renews every model by itself, and answers the same neighbours after.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_release_0_1_0_store_is_re_extracted_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let store = crate::golden::golden_store(&dir.path().join("store"));
    let app = TestApp::build(Config::default(), Arc::new(store), None);
    assert_eq!(app.app.stale_count(), 3);
    app.app.start_background();
    let progress = finished(&app).await;
    assert_eq!((progress.done, progress.failed), (3, 0), "{progress:?}");
    assert_eq!(app.app.stale_count(), 0);
    let ranked = app.get_json("/v1/models/horse/similar?method=ecc").await;
    assert_eq!(ranked["results"][0]["id"], "horse-split");
    assert_eq!(ranked["results"][0]["distance"], 0.0);
    let record = app.get_json("/v1/models/horse").await;
    assert_eq!(
        record["params_version"],
        salient_core::params::PARAMS_VERSION
    );
    assert_eq!(record["name"], "Horse");
    assert!(ModelId::parse(record["id"].as_str().unwrap()).is_ok());
}

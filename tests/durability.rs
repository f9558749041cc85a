//! Crash safety of the store: kill -9 the server in the middle of an ingest, restart it, and
//! every acknowledged model is there and whole; nothing half-written appears.

mod server;
mod shapes;

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use reqwest::{Client, StatusCode};
use serde_json::Value;
use server::{obj, Server};

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn acknowledged_models_survive_a_kill_and_nothing_is_half_written() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("store");
    let acknowledged = Arc::new(Mutex::new(BTreeSet::new()));
    let attempted = Arc::new(Mutex::new(BTreeSet::new()));
    let meshes: Vec<Vec<u8>> = (2..6)
        .map(|s| obj(&shapes::star(2, &shapes::five_tips()[..s])))
        .collect();

    for round in 0..3 {
        let mut server = Server::start(&store, &[]);
        let writers: Vec<_> = (0..4)
            .map(|w| {
                let (url, meshes) = (server.url.clone(), meshes.clone());
                let (acknowledged, attempted) = (acknowledged.clone(), attempted.clone());
                tokio::spawn(async move {
                    let client = Client::new();
                    for i in 0.. {
                        let id = format!("r{round}-w{w}-{i}");
                        attempted.lock().unwrap().insert(id.clone());
                        let sent = client
                            .post(format!("{url}/v1/models?id={id}&tags=round{round}"))
                            .header("content-type", "model/obj")
                            .body(meshes[i % meshes.len()].clone())
                            .send()
                            .await;
                        match sent {
                            Ok(r) if r.status() == StatusCode::CREATED => {
                                acknowledged.lock().unwrap().insert(id);
                            }
                            _ => break, // the server is gone
                        }
                    }
                })
            })
            .collect();
        // Let writes pile up, then crash in the middle of them.
        tokio::time::sleep(Duration::from_millis(700 + 300 * round)).await;
        server.kill();
        for w in writers {
            w.await.unwrap();
        }
    }

    let server = Server::start(&store, &[]);
    let client = Client::new();
    let listed = server.listed_ids().await;
    let acknowledged = acknowledged.lock().unwrap().clone();
    assert!(
        acknowledged.len() >= 6,
        "too few writes to test: {}",
        acknowledged.len()
    );
    let missing: Vec<_> = acknowledged.difference(&listed).collect();
    assert!(missing.is_empty(), "acknowledged but lost: {missing:?}");
    assert!(listed.is_subset(&attempted.lock().unwrap()));
    // Whole: record, signature and original file, for every listed model.
    for id in &listed {
        let record: Value = client
            .get(server.at(&format!("/v1/models/{id}")))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        let signature = client
            .get(server.at(&format!("/v1/models/{id}/signature")))
            .send()
            .await
            .unwrap();
        assert_eq!(signature.status(), StatusCode::OK, "{id}");
        let signature: Value = signature.json().await.unwrap();
        assert_eq!(
            signature["features"].as_array().unwrap().len() as u64,
            record["features"].as_u64().unwrap()
        );
    }
    let similar = client
        .get(server.at(&format!("/v1/models/{}/similar", listed.first().unwrap())))
        .send()
        .await
        .unwrap();
    assert_eq!(similar.status(), StatusCode::OK);
    eprintln!(
        "{} acknowledged, {} stored after 3 kills",
        acknowledged.len(),
        listed.len()
    );
}

//! Crash safety of the store: kill -9 the server in the middle of an ingest, restart it, and
//! every acknowledged model is there and whole; nothing half-written appears. Over
//! PostgreSQL a second replica runs throughout, never killed: it lists and ranks every
//! acknowledged model, having learnt of each from the database's change log.

use crate::server;
use crate::shapes;

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use reqwest::{Client, StatusCode};
use rstest_reuse::apply;
use salient_server::store::{PostgresStore, SledStore, Store};
use serde_json::Value;
use server::{obj, Server};

use crate::stores::{fresh_database_url, stores, Stores};

#[apply(stores)]
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn acknowledged_models_survive_a_kill_and_nothing_is_half_written(#[case] kind: Stores) {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("store");
    // Over PostgreSQL, `--data` holds only the process's caches.
    let database = (kind == Stores::Postgres).then(fresh_database_url);
    let flags: Vec<&str> = database
        .iter()
        .flat_map(|url| ["--store", url.as_str()])
        .collect();
    let survivor = database
        .as_ref()
        .map(|url| Server::start(&dir.path().join("survivor"), &["--store", url]));
    let acknowledged = Arc::new(Mutex::new(BTreeSet::new()));
    let attempted = Arc::new(Mutex::new(BTreeSet::new()));
    let meshes: Vec<Vec<u8>> = (2..6)
        .map(|s| obj(&shapes::star(2, &shapes::five_tips()[..s])))
        .collect();

    for round in 0..3 {
        let mut server = Server::start(&store, &flags);
        // Writers count their acknowledged writes here; the server is killed once a few
        // went through in this round, while the others are in flight.
        let (acked, mut progress) = tokio::sync::watch::channel(0usize);
        let writers: Vec<_> = (0..4)
            .map(|w| {
                let (url, meshes) = (server.url.clone(), meshes.clone());
                let (acknowledged, attempted) = (acknowledged.clone(), attempted.clone());
                let acked = acked.clone();
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
                                acked.send_modify(|n| *n += 1);
                            }
                            _ => break, // the server is gone
                        }
                    }
                })
            })
            .collect();
        let enough = progress.wait_for(|n| *n >= 2 + round);
        tokio::time::timeout(Duration::from_secs(120), enough)
            .await
            .expect("writes are acknowledged")
            .unwrap();
        server.kill();
        for w in writers {
            w.await.unwrap();
        }
    }

    let server = Server::start(&store, &flags);
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
    if let Some(survivor) = &survivor {
        // Where the restarted replica's load stood: the survivor answers once it is there.
        let ready: Value = reqwest::get(server.at("/readyz"))
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        let at = ready["position"].as_u64().expect("a position").to_string();
        let page: Value = client
            .get(survivor.at("/v1/models?limit=1000"))
            .header("salient-position", &at)
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        let seen: BTreeSet<String> = page["models"]
            .as_array()
            .unwrap()
            .iter()
            .map(|m| m["id"].as_str().unwrap().to_string())
            .collect();
        assert_eq!(seen, listed, "the replica that ran throughout is in step");
        for id in [listed.first().unwrap(), listed.last().unwrap()] {
            let similar = client
                .get(survivor.at(&format!("/v1/models/{id}/similar")))
                .send()
                .await
                .unwrap();
            assert_eq!(similar.status(), StatusCode::OK, "{id}");
        }
    }
    // And the original file of each, byte for byte, read from the store itself.
    drop(server);
    let store: Box<dyn Store> = match &database {
        Some(url) => Box::new(PostgresStore::open(url).unwrap()),
        None => Box::new(SledStore::open(&store).unwrap()),
    };
    for id in &listed {
        let i: usize = id.rsplit('-').next().unwrap().parse().unwrap();
        let upload = store.upload(id).unwrap().unwrap();
        assert_eq!(upload.mesh, meshes[i % meshes.len()], "{id}");
    }
    eprintln!(
        "{} acknowledged, {} stored after 3 kills",
        acknowledged.len(),
        listed.len()
    );
}

//! The service under concurrent load: what is acknowledged is stored, the server stays
//! responsive while extraction saturates the pool, and overload is a 503, not a hang.

mod server;
mod shapes;

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use reqwest::{Client, StatusCode};
use server::{obj, Server};

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

/// With one worker and no queue, concurrent extractions beyond the first get 503 with
/// `Retry-After` at once; meanwhile `/healthz` answers within 100 ms.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn overload_is_refused_at_once_and_health_stays_fast() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(
        &dir.path().join("store"),
        &["--workers", "1", "--queue-depth", "1"],
    );
    let heavy = obj(&shapes::icosphere(5)); // ~0.3 s of extraction each
    let client = Client::new();
    let started = Instant::now();
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
                (response.status(), retry, Instant::now())
            })
        })
        .collect();
    // While the worker is busy, liveness answers quickly.
    tokio::time::sleep(Duration::from_millis(50)).await;
    let mut slowest = Duration::ZERO;
    for _ in 0..10 {
        let t = Instant::now();
        let health = client.get(server.at("/healthz")).send().await.unwrap();
        assert_eq!(health.status(), StatusCode::OK);
        slowest = slowest.max(t.elapsed());
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(
        slowest < Duration::from_millis(100),
        "healthz took {slowest:?}"
    );
    let mut accepted = 0;
    let mut refused = 0;
    for upload in uploads {
        let (status, retry, finished) = upload.await.unwrap();
        match status {
            StatusCode::CREATED => accepted += 1,
            StatusCode::SERVICE_UNAVAILABLE => {
                refused += 1;
                assert_eq!(retry.as_deref(), Some("1"));
                // Refused at once, not after waiting for the busy worker.
                assert!(
                    finished.duration_since(started) < Duration::from_millis(250),
                    "{:?}",
                    finished.duration_since(started)
                );
            }
            other => panic!("unexpected {other}"),
        }
    }
    assert!(
        accepted >= 1 && refused >= 1,
        "accepted {accepted}, refused {refused}"
    );
    assert_eq!(accepted + refused, 8);
}

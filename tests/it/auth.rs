//! API keys: each route's scope, 401 and 403 in the JSON shape, a rate per key, keys that never show, safe
//! defaults on a network address, key files made by `salient keys new` and read again on
//! SIGHUP, and the ingest client with a key.

use std::process::Command;
use std::sync::Arc;

use axum::http::StatusCode;
use salient_server::api::config::Secret;
use salient_server::api::{App, Config, StartError};
use salient_server::store::InMemoryStore;

use crate::app::{expect_error, TestApp};
use crate::server::{fixture, Server};
use crate::stores::{stores, Stores};
use rstest_reuse::apply;

const READ: &str = "read-key-0123456789";
const WRITE: &str = "write-key-0123456789";
const ADMIN: &str = "admin-key-0123456789";

fn keyed() -> TestApp {
    TestApp::with_config(|config| {
        config.inline_keys = Some(Secret(format!("read:{READ},write:{WRITE},admin:{ADMIN}")));
    })
}

#[apply(stores)]
#[tokio::test]
async fn each_key_has_its_own_rate_and_is_told_when_to_come_back(#[case] store: Stores) {
    let app = TestApp::on_with_config(store, |config| {
        config.inline_keys = Some(Secret(format!("read:{READ},write:{WRITE}")));
        config.requests_per_minute = 3;
    });
    for _ in 0..3 {
        let allowed = app.get("/v1/models").bearer(READ).send().await;
        assert_eq!(allowed.status, StatusCode::OK);
    }
    let limited = app.get("/v1/models").bearer(READ).send().await;
    expect_error(&limited, StatusCode::TOO_MANY_REQUESTS, "rate_limited");
    let wait: u64 = limited.headers["retry-after"]
        .to_str()
        .unwrap()
        .parse()
        .unwrap();
    assert!(
        (1..=21).contains(&wait),
        "one request in 20 s comes back: {wait}"
    );
    // Another key, and the open routes, are not held back by it.
    assert_eq!(
        app.get("/v1/models").bearer(WRITE).send().await.status,
        StatusCode::OK
    );
    assert_eq!(app.get("/healthz").send().await.status, StatusCode::OK);
}

#[tokio::test]
async fn each_route_needs_its_scope() {
    let app = keyed();
    let horse = fixture("capod_horse_m155.obj");
    for open in ["/healthz", "/readyz", "/openapi.yaml"] {
        assert_eq!(app.get(open).send().await.status, StatusCode::OK, "{open}");
    }

    let anonymous = app.get("/v1/models").send().await;
    expect_error(&anonymous, StatusCode::UNAUTHORIZED, "unauthorized");
    assert!(anonymous.headers["www-authenticate"]
        .to_str()
        .unwrap()
        .starts_with("Bearer"));
    let wrong = app
        .get("/v1/models")
        .header("authorization", "Bearer not-a-key-at-all")
        .send()
        .await;
    expect_error(&wrong, StatusCode::UNAUTHORIZED, "unauthorized");
    assert!(!wrong.text().contains("not-a-key-at-all"));
    assert_eq!(
        app.get("/v1/models").bearer(READ).send().await.status,
        StatusCode::OK
    );
    let refused = app
        .post("/v1/models?id=horse")
        .bearer(READ)
        .header("content-type", "model/obj")
        .body(horse.clone())
        .send()
        .await;
    expect_error(&refused, StatusCode::FORBIDDEN, "forbidden");
    assert!(!refused.text().contains(READ));

    let added = app
        .post("/v1/models?id=horse")
        .header("authorization", &format!("bearer {WRITE}"))
        .header("content-type", "model/obj")
        .body(horse.clone())
        .send()
        .await;
    assert_eq!(added.status, StatusCode::CREATED, "{}", added.text());
    // Searching changes nothing: a reader may.
    let searched = app
        .post("/v1/search")
        .bearer(READ)
        .header("content-type", "model/obj")
        .body(horse)
        .send()
        .await;
    assert_eq!(searched.status, StatusCode::OK);
    assert_eq!(searched.json()["results"][0]["id"], "horse");
    expect_error(
        &app.post("/v1/admin/reindex").bearer(WRITE).send().await,
        StatusCode::FORBIDDEN,
        "forbidden",
    );
    expect_error(
        &app.get("/metrics").bearer(WRITE).send().await,
        StatusCode::FORBIDDEN,
        "forbidden",
    );
    assert!(app
        .post("/v1/admin/reindex")
        .bearer(ADMIN)
        .send()
        .await
        .status
        .is_success());
    assert_eq!(
        app.get("/metrics").bearer(ADMIN).send().await.status,
        StatusCode::OK
    );
    let patch = |key: &'static str| {
        app.request_with_method("PATCH", "/v1/models/horse")
            .bearer(key)
            .header("content-type", "application/json")
            .body(r#"{"class": "horse"}"#)
            .send()
    };
    expect_error(&patch(READ).await, StatusCode::FORBIDDEN, "forbidden");
    assert_eq!(patch(WRITE).await.status, StatusCode::OK);
    assert_eq!(
        app.delete("/v1/models/horse")
            .bearer(WRITE)
            .send()
            .await
            .status,
        StatusCode::NO_CONTENT
    );
}

#[apply(stores)]
#[tokio::test]
async fn browsers_may_send_the_key_from_allowed_origins(#[case] store: Stores) {
    let app = TestApp::on_with_config(store, |config| {
        config.inline_keys = Some(Secret(format!("read:{READ}")));
        config.cors_origins = vec!["https://assets.example".into()];
    });
    let preflight = app
        .request_with_method("OPTIONS", "/v1/models")
        .header("origin", "https://assets.example")
        .header("access-control-request-method", "GET")
        .header("access-control-request-headers", "authorization")
        .send()
        .await;
    assert!(preflight.status.is_success(), "{}", preflight.status);
    let allowed = preflight.headers["access-control-allow-headers"]
        .to_str()
        .unwrap()
        .to_ascii_lowercase();
    assert!(allowed.contains("authorization"), "{allowed}");
}

#[test]
fn without_keys_only_loopback_is_served() {
    let on = |addr: &str, configure: fn(&mut Config)| {
        let mut config = Config {
            addr: addr.parse().unwrap(),
            ..Config::default()
        };
        configure(&mut config);
        App::new(config, Arc::new(InMemoryStore::new())).map(|_| ())
    };
    match on("0.0.0.0:8080", |_| {}) {
        Err(error @ StartError::Anonymous(_)) => {
            let message = error.to_string();
            assert!(message.contains("SALIENT_API_KEYS") && message.contains("--allow-anonymous"));
        }
        other => panic!("expected a refusal, got {:?}", other.err()),
    }
    assert!(on("0.0.0.0:8080", |c| c.allow_anonymous = true).is_ok());
    assert!(on("0.0.0.0:8080", |c| c.inline_keys =
        Some(Secret(format!("write:{WRITE}"))))
    .is_ok());
    assert!(on("127.0.0.1:8080", |_| {}).is_ok());
    assert!(on("[::1]:8080", |_| {}).is_ok());
    // Keys that cannot be used stop the start, without showing the key.
    let error = on("127.0.0.1:8080", |c| {
        c.inline_keys = Some(Secret("owner:secret-0123456789".into()))
    })
    .unwrap_err()
    .to_string();
    assert!(
        error.contains("owner") && !error.contains("secret-0123456789"),
        "{error}"
    );
}

fn salient(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_salient"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn the_binary_refuses_a_network_address_without_keys() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("store");
    let out = salient(&[
        "serve",
        "--addr",
        "0.0.0.0:0",
        "--data",
        data.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("--allow-anonymous"), "{stderr}");
}

/// A key made by `salient keys new` into a file works; replaced in the file and announced
/// with SIGHUP, the old key stops working and the new one starts, without a restart. The
/// ingest client sends its key; neither key appears in the server's log.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn key_files_are_read_again_on_sighup() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("keys");
    let make = |scope: &str, label: &str, into: &std::path::Path| {
        let out = salient(&[
            "keys",
            "new",
            "--scope",
            scope,
            "--label",
            label,
            "--file",
            into.to_str().unwrap(),
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap().trim().to_string()
    };
    let first = make("write", "first client", &file);
    let line = std::fs::read_to_string(&file).unwrap();
    assert!(line.starts_with("write ") && line.trim_end().ends_with(" first client"));
    assert!(
        !line.contains(&first),
        "the file holds the hash, not the key"
    );

    let server = Server::start(
        &dir.path().join("store"),
        &["--keys", file.to_str().unwrap()],
    );
    let client = reqwest::Client::new();
    let status = |key: String| {
        let (client, url) = (client.clone(), server.at("/v1/models"));
        async move {
            client
                .get(url)
                .bearer_auth(key)
                .send()
                .await
                .unwrap()
                .status()
        }
    };
    assert_eq!(status(first.clone()).await, StatusCode::OK);
    assert_eq!(
        status("wrong-key-0123456789".into()).await,
        StatusCode::UNAUTHORIZED
    );

    // The ingest client, with and without the key.
    let meshes = dir.path().join("meshes");
    std::fs::create_dir_all(&meshes).unwrap();
    std::fs::write(meshes.join("horse.obj"), fixture("capod_horse_m155.obj")).unwrap();
    let ingest = |key: Option<&str>| {
        let mut command = Command::new(env!("CARGO_BIN_EXE_salient"));
        command.args([
            "ingest",
            meshes.to_str().unwrap(),
            "--server",
            &server.url,
            "--attempts",
            "1",
        ]);
        if let Some(key) = key {
            command.args(["--api-key", key]);
        }
        command.output().unwrap()
    };
    let refused = ingest(None);
    assert!(!refused.status.success());
    assert!(
        String::from_utf8_lossy(&refused.stdout).contains("401")
            || String::from_utf8_lossy(&refused.stderr).contains("401")
    );
    let ingested = ingest(Some(&first));
    assert!(
        ingested.status.success(),
        "{}",
        String::from_utf8_lossy(&ingested.stderr)
    );

    let other = dir.path().join("other");
    let second = make("read", "second client", &other);
    std::fs::rename(&other, &file).unwrap();
    server.signal("HUP");
    let mut renewed = false;
    for _ in 0..10_000 {
        if status(first.clone()).await == StatusCode::UNAUTHORIZED {
            renewed = true;
            break;
        }
    }
    assert!(renewed, "the old key still works after SIGHUP");
    assert_eq!(status(second.clone()).await, StatusCode::OK);
    let log = server.log();
    for key in [&first, &second] {
        assert!(!log.contains(key.as_str()), "a key in the log");
    }
}

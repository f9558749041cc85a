//! `openapi.yaml` is the service's contract: it must be exactly what the code's route
//! annotations generate, and every path and method in it must reach a handler.
//!
//! After an intended API change: `SALIENT_UPDATE_OPENAPI=1 cargo test --test it openapi`.

use std::path::Path;

use axum::body::Body;
use axum::http::{Method, Request, StatusCode};
use salient_server::api::{app, openapi_yaml, App, AppState, Config};
use salient_server::store::SledStore;
use tower::ServiceExt;

fn committed() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("openapi.yaml")
}

#[test]
fn committed_document_matches_the_code() {
    let generated = openapi_yaml();
    if std::env::var_os("SALIENT_UPDATE_OPENAPI").is_some() {
        std::fs::write(committed(), &generated).unwrap();
    }
    let on_disk = std::fs::read_to_string(committed()).unwrap();
    assert!(
        on_disk == generated,
        "openapi.yaml is stale: run `SALIENT_UPDATE_OPENAPI=1 cargo test --test it openapi` and review the diff"
    );
}

/// Every documented operation is routed: a request never falls through to the router's
/// fallback (`no such route`) or gets 405.
#[tokio::test]
async fn every_documented_operation_is_routed() {
    let dir = tempfile::tempdir().unwrap();
    let store = SledStore::open(dir.path()).unwrap();
    let router = app(AppState(std::sync::Arc::new(
        App::new(Config::default(), std::sync::Arc::new(store)).unwrap(),
    )));
    let spec: serde_json::Value = serde_yaml_ng::from_str(&openapi_yaml()).unwrap();
    let paths = spec["paths"].as_object().unwrap();
    let mut operations = 0;
    for (path, item) in paths {
        for method in item.as_object().unwrap().keys() {
            let uri = path
                .replace("{id}", "some-id")
                .replace("{a}", "one")
                .replace("{b}", "other");
            let request = Request::builder()
                .method(Method::from_bytes(method.to_uppercase().as_bytes()).unwrap())
                .uri(&uri)
                .body(Body::empty())
                .unwrap();
            let response = router.clone().oneshot(request).await.unwrap();
            let status = response.status();
            let body = axum::body::to_bytes(response.into_body(), 1 << 20)
                .await
                .unwrap();
            assert_ne!(status, StatusCode::METHOD_NOT_ALLOWED, "{method} {path}");
            assert!(
                !String::from_utf8_lossy(&body).contains("no such route"),
                "{method} {path}"
            );
            operations += 1;
        }
    }
    assert_eq!(operations, 27, "documented operations");
}

/// Every operation names the scope its route declares, with the 401 and 403 a key check may
/// answer; only liveness, readiness and the description itself are open.
#[test]
fn every_operation_has_its_security() {
    let spec: serde_json::Value = serde_yaml_ng::from_str(&openapi_yaml()).unwrap();
    let open = [
        ("get", "/healthz"),
        ("get", "/readyz"),
        ("get", "/openapi.yaml"),
    ];
    let mut scoped = 0;
    for (path, item) in spec["paths"].as_object().unwrap() {
        for (method, operation) in item.as_object().unwrap() {
            if open.contains(&(method.as_str(), path.as_str())) {
                assert!(operation.get("security").is_none(), "{method} {path}");
                continue;
            }
            let scopes = &operation["security"][0]["api_key"];
            assert!(
                matches!(scopes[0].as_str(), Some("read" | "write" | "admin")),
                "{method} {path} names no scope"
            );
            for status in ["401", "403", "429"] {
                assert!(
                    operation["responses"].get(status).is_some(),
                    "{method} {path} lacks {status}"
                );
            }
            scoped += 1;
        }
    }
    assert_eq!(scoped, 24);
    assert_eq!(
        spec["paths"]["/v1/models/{id}"]["patch"]["security"][0]["api_key"][0],
        "write"
    );
    let dismissed = &spec["paths"]["/v1/duplicates/dismissed/{a}/{b}"];
    for method in ["put", "delete"] {
        assert_eq!(dismissed[method]["security"][0]["api_key"][0], "write");
    }
}

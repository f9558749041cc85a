//! The service in process: `api::app` over an in-memory store (or a given one), driven with
//! `tower::ServiceExt::oneshot` as axum's `examples/testing` and crates.io's `TestApp` do.
//! The request builder reads like reqwest's, so a test reads the same in process and
//! against the real binary ([`crate::server`]).

use std::sync::Arc;

use axum::body::{Body, Bytes};
use axum::http::{HeaderMap, Method, Request, StatusCode};
use axum::Router;
use http_body_util::BodyExt;
use salient_server::api::{self, App, AppState, Config, Hook};
use salient_server::store::{InMemoryStore, Store};
use serde_json::Value;
use tower::ServiceExt;

/// The service, in process.
pub struct TestApp {
    pub app: Arc<App>,
    router: Router,
}

impl TestApp {
    /// Default configuration, empty in-memory store.
    pub fn new() -> Self {
        Self::build(Config::default(), Arc::new(InMemoryStore::new()), None)
    }

    /// The default configuration changed by `configure`, empty in-memory store.
    pub fn with_config(configure: impl FnOnce(&mut Config)) -> Self {
        let mut config = Config::default();
        configure(&mut config);
        Self::build(config, Arc::new(InMemoryStore::new()), None)
    }

    /// The default configuration over an empty store of kind `store` ([`crate::stores`]).
    pub fn on(store: crate::stores::Stores) -> Self {
        Self::build(Config::default(), store.open(), None)
    }

    /// The default configuration changed by `configure`, over an empty store of kind `store`.
    pub fn on_with_config(
        store: crate::stores::Stores,
        configure: impl FnOnce(&mut Config),
    ) -> Self {
        let mut config = Config::default();
        configure(&mut config);
        Self::build(config, store.open(), None)
    }

    /// Any configuration, store and ranking hook.
    pub fn build(config: Config, store: Arc<dyn Store>, ranking_hook: Option<Hook>) -> Self {
        let mut app = App::new(config, store).expect("the service starts");
        if let Some(hook) = ranking_hook {
            app.set_ranking_hook(hook);
        }
        Self::serving(app)
    }

    /// `app`, made and set up by the test.
    pub fn serving(app: App) -> Self {
        let app = Arc::new(app);
        let router = api::app(AppState(app.clone()));
        Self { app, router }
    }

    pub fn get(&self, path: impl Into<String>) -> TestRequest<'_> {
        self.request(Method::GET, path)
    }

    pub fn post(&self, path: impl Into<String>) -> TestRequest<'_> {
        self.request(Method::POST, path)
    }

    pub fn delete(&self, path: impl Into<String>) -> TestRequest<'_> {
        self.request(Method::DELETE, path)
    }

    /// A request with any method (`OPTIONS` for a CORS preflight).
    pub fn request_with_method(&self, method: &str, path: impl Into<String>) -> TestRequest<'_> {
        self.request(Method::from_bytes(method.as_bytes()).unwrap(), path)
    }

    fn request(&self, method: Method, path: impl Into<String>) -> TestRequest<'_> {
        TestRequest {
            router: &self.router,
            method,
            path: path.into(),
            headers: Vec::new(),
            body: Vec::new(),
        }
    }

    /// `POST /v1/models?{query}` with a raw body.
    pub async fn add(&self, query: &str, content_type: &str, body: Vec<u8>) -> TestResponse {
        self.post(format!("/v1/models?{query}"))
            .header("content-type", content_type)
            .body(body)
            .send()
            .await
    }

    /// `GET path` as JSON, asserting success.
    pub async fn get_json(&self, path: &str) -> Value {
        let response = self.get(path).send().await;
        assert!(response.status.is_success(), "{path}: {}", response.text());
        response.json()
    }

    /// The ids of every stored model (one page of up to 1 000).
    pub async fn listed_ids(&self) -> std::collections::BTreeSet<String> {
        self.get_json("/v1/models?limit=1000").await["models"]
            .as_array()
            .unwrap()
            .iter()
            .map(|m| m["id"].as_str().unwrap().to_string())
            .collect()
    }
}

/// A request being built.
pub struct TestRequest<'a> {
    router: &'a Router,
    method: Method,
    path: String,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl TestRequest<'_> {
    pub fn header(mut self, name: &str, value: &str) -> Self {
        self.headers.push((name.to_string(), value.to_string()));
        self
    }

    /// `Authorization: Bearer KEY`.
    pub fn bearer(self, key: &str) -> Self {
        self.header("authorization", &format!("Bearer {key}"))
    }

    pub fn body(mut self, body: impl Into<Vec<u8>>) -> Self {
        self.body = body.into();
        self
    }

    /// A `multipart/form-data` body.
    pub fn multipart(self, form: Form) -> Self {
        let content_type = format!("multipart/form-data; boundary={}", Form::BOUNDARY);
        self.header("content-type", &content_type)
            .body(form.bytes())
    }

    /// Sends the request through the router.
    pub async fn send(self) -> TestResponse {
        let mut request = Request::builder().method(self.method).uri(&self.path);
        for (name, value) in &self.headers {
            request = request.header(name, value);
        }
        let request = request
            .body(Body::from(self.body))
            .expect("a valid request");
        let response = self
            .router
            .clone()
            .oneshot(request)
            .await
            .expect("the router is infallible");
        let status = response.status();
        let headers = response.headers().clone();
        let body = response
            .into_body()
            .collect()
            .await
            .expect("the body is readable")
            .to_bytes();
        TestResponse {
            path: self.path,
            status,
            headers,
            body,
        }
    }
}

/// A response, read whole.
#[derive(Clone)]
pub struct TestResponse {
    pub path: String,
    pub status: StatusCode,
    pub headers: HeaderMap,
    pub body: Bytes,
}

impl TestResponse {
    pub fn status(&self) -> StatusCode {
        self.status
    }

    pub fn headers(&self) -> &HeaderMap {
        &self.headers
    }

    pub fn json(&self) -> Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("{}: not JSON ({e}): {}", self.path, self.text()))
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
}

/// Asserts an error response: status, the JSON error shape, and its code.
pub fn expect_error(response: &TestResponse, status: StatusCode, code: &str) {
    assert_eq!(
        response.status,
        status,
        "{}: {}",
        response.path,
        response.text()
    );
    let body = response.json();
    assert_eq!(body["error"]["code"], code, "{body}");
    assert!(body["error"]["message"]
        .as_str()
        .is_some_and(|m| !m.is_empty()));
}

/// A `multipart/form-data` body: files and text fields.
#[derive(Default)]
pub struct Form {
    parts: Vec<(String, Option<String>, Vec<u8>)>,
}

impl Form {
    const BOUNDARY: &'static str = "salient-test-boundary-7d1f";

    pub fn new() -> Self {
        Self::default()
    }

    pub fn file(mut self, field: &str, file_name: &str, bytes: Vec<u8>) -> Self {
        self.parts
            .push((field.to_string(), Some(file_name.to_string()), bytes));
        self
    }

    pub fn text(mut self, field: &str, value: &str) -> Self {
        self.parts
            .push((field.to_string(), None, value.as_bytes().to_vec()));
        self
    }

    fn bytes(&self) -> Vec<u8> {
        let mut body = Vec::new();
        for (field, file_name, bytes) in &self.parts {
            body.extend(format!("--{}\r\n", Self::BOUNDARY).as_bytes());
            let disposition = match file_name {
                Some(file) => format!("form-data; name=\"{field}\"; filename=\"{file}\""),
                None => format!("form-data; name=\"{field}\""),
            };
            body.extend(format!("Content-Disposition: {disposition}\r\n\r\n").as_bytes());
            body.extend(bytes);
            body.extend(b"\r\n");
        }
        body.extend(format!("--{}--\r\n", Self::BOUNDARY).as_bytes());
        body
    }
}

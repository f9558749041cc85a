//! Operations: liveness, readiness, metrics and the API description.

use axum::extract::State;
use axum::http::header::CONTENT_TYPE;
use axum::response::IntoResponse;
use axum::Json;
use serde::{Deserialize, Serialize};

use super::AppState;

/// Health and readiness.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Status {
    pub status: String,
    /// Models in the index.
    pub models: usize,
    /// Extractions running or queued.
    pub extractions_in_flight: usize,
    /// `ok`, or `unavailable` while a shared store cannot be reached: this replica still
    /// answers what needs only its memory (ranking, records, lists) and refuses writes with
    /// 503, so a balancer should keep it.
    pub store: String,
    /// On a store shared by replicas, the last change position this one applied.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<u64>,
}

fn status(state: &AppState) -> Status {
    let shared = state.store.shared();
    Status {
        status: "ok".into(),
        // The gauge, not the catalog: a catalog reader queues behind a pending write, which
        // waits for running searches; liveness must not.
        models: state.metrics.models.get().max(0) as usize,
        extractions_in_flight: state.pool.in_flight(),
        store: if shared.is_none_or(|s| *s.connected().borrow()) {
            "ok".into()
        } else {
            "unavailable".into()
        },
        position: state.follower.as_ref().map(|f| f.applied()),
    }
}

/// Liveness: the process answers. Never waits for extraction.
#[utoipa::path(get, path = "/healthz", tag = "operations", responses((status = 200, description = "Alive", body = Status)))]
pub async fn healthz(State(state): State<AppState>) -> Json<Status> {
    Json(status(&state))
}

/// Readiness: the store is open and every signature is in the index (the server binds its
/// port only after loading, so a listening server is ready). A shared store that cannot be
/// reached now is reported in `store`, and the replica stays ready: it still ranks.
#[utoipa::path(get, path = "/readyz", tag = "operations", responses((status = 200, description = "Ready", body = Status)))]
pub async fn readyz(State(state): State<AppState>) -> Json<Status> {
    Json(status(&state))
}

/// Prometheus metrics in the text exposition format.
#[utoipa::path(get, path = "/metrics", tag = "operations", responses((status = 200, description = "Metrics", body = String, content_type = "text/plain")))]
pub async fn metrics(State(state): State<AppState>) -> impl IntoResponse {
    let app = &state;
    app.metrics
        .extraction_in_flight
        .set(app.pool.in_flight() as i64);
    if let (Some(shared), Some(follower)) = (app.store.shared(), &app.follower) {
        let (applied, heard) = (follower.applied(), *shared.subscribe().borrow());
        let metrics = &app.metrics.replica;
        metrics.position.set(applied as i64);
        metrics.lag.set(heard.saturating_sub(applied) as i64);
        metrics
            .store_up
            .set(i64::from(*shared.connected().borrow()));
        metrics.reconnections.set(shared.reconnections() as i64);
    }
    (
        [(CONTENT_TYPE, "text/plain; version=0.0.4; charset=utf-8")],
        app.metrics.render(),
    )
}

/// This API's OpenAPI 3.1 description (the committed `openapi.yaml`). Its schema is an
/// object: YAML clients (schemathesis among them) parse the body into a mapping.
#[utoipa::path(get, path = "/openapi.yaml", tag = "operations", responses((status = 200, description = "OpenAPI document", body = Object, content_type = "application/yaml")))]
pub async fn openapi_yaml() -> impl IntoResponse {
    ([(CONTENT_TYPE, "application/yaml")], super::openapi_yaml())
}

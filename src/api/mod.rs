//! The HTTP retrieval service (SPEC §8; `openapi.yaml` is the contract): an axum router over
//! a [`Store`], an in-memory [`Index`] of every stored signature, and the bounded extraction
//! [`pool::Pool`]. Handlers only translate between HTTP and the library.

pub mod config;
pub mod error;
mod metrics;
mod models;
mod ops;
pub mod pool;
mod search;
pub mod upload;

use std::collections::BTreeMap;
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

use axum::extract::{DefaultBodyLimit, MatchedPath, Request, State};
use axum::http::{HeaderName, HeaderValue, Method};
use axum::middleware::{self, Next};
use axum::response::Response;
use axum::Router;
use tower_http::compression::CompressionLayer;
use tower_http::cors::{AllowOrigin, CorsLayer};
use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
use tower_http::trace::TraceLayer;
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;

use crate::mesh::load_bytes;
use crate::rank::Index;
use crate::signature::{compute, Signature};
use crate::store::{Store, StoreError, Upload};
pub use config::Config;
use error::AppError;
use metrics::{Metrics, RequestLabels};
use pool::Pool;

/// Shared state of the service (`AppState(Arc<App>)`, as crates.io does it).
#[derive(Clone)]
pub struct AppState(pub Arc<App>);

/// The service: configuration, store, index and pool.
pub struct App {
    pub config: Config,
    store: Arc<dyn Store>,
    catalog: RwLock<Catalog>,
    pool: Pool,
    /// Ranking's own rayon pool. On the global pool, which extraction's parallel loops fill,
    /// a search waited for the extractions in progress: during an ingest, the p99 latency of
    /// `similar` over 1 000 models went from 33 ms to 2.2 s (`benches/load.rs`).
    ranker: rayon::ThreadPool,
    metrics: Metrics,
    /// Serialises writes so that the store and the index change in the same order.
    writes: tokio::sync::Mutex<()>,
}

/// The in-memory view of the store: records by id (ordered, for listing) and the index.
struct Catalog {
    records: BTreeMap<String, crate::store::ModelRecord>,
    index: Index,
}

/// Starting the service failed.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("cannot start the ranking threads: {0}")]
    Threads(String),
    #[error("stored signature of {id} cannot be read: {source}; run `salient reindex`")]
    Signature {
        id: String,
        #[source]
        source: crate::Error,
    },
}

impl App {
    /// Loads every stored signature into the index.
    pub fn new(config: Config, store: Arc<dyn Store>) -> Result<Self, StartError> {
        let mut records = BTreeMap::new();
        let mut index = Index::new(config.params.similarity.clone());
        let (mut stale, mut without_lfd) = (0, 0);
        for loaded in store.load_all() {
            let loaded = loaded?;
            let id = loaded.record.id.clone();
            let signature = Signature::from_bytes(&loaded.signature).map_err(|source| {
                StartError::Signature {
                    id: id.clone(),
                    source,
                }
            })?;
            let (p, c) = (&signature.params, &config.params);
            if (&p.mesh, &p.ecc, &p.salient, &p.d2) != (&c.mesh, &c.ecc, &c.salient, &c.d2) {
                stale += 1;
            }
            if signature.lfd.is_none() {
                without_lfd += 1;
            }
            index.insert(id.clone(), signature);
            records.insert(id, loaded.record);
        }
        if stale > 0 {
            tracing::warn!(stale, "models were extracted with other parameters than configured; run `salient reindex`");
        }
        if without_lfd > 0 {
            tracing::warn!(without_lfd, "models were stored before the light field descriptor and are left out of `lfd` searches; run `salient reindex`");
        }
        let pool = Pool::new(
            config.workers,
            config.queue_depth,
            Duration::from_secs(config.request_timeout_secs),
        );
        let ranker = rayon::ThreadPoolBuilder::new()
            .thread_name(|i| format!("salient-rank-{i}"))
            .build()
            .map_err(|e| StartError::Threads(e.to_string()))?;
        let metrics = Metrics::default();
        metrics.models.set(records.len() as i64);
        Ok(Self {
            config,
            store,
            catalog: RwLock::new(Catalog { records, index }),
            pool,
            ranker,
            metrics,
            writes: tokio::sync::Mutex::new(()),
        })
    }

    /// Models in the index.
    pub fn catalog_len(&self) -> usize {
        self.catalog
            .read()
            .expect("catalog lock poisoned")
            .records
            .len()
    }

    /// Extracts the signature of an upload on the pool, in its stored (binary round-tripped)
    /// form, so that a query ranks exactly as the same model stored or searched offline.
    async fn extract(&self, upload: Arc<Upload>) -> Result<Signature, AppError> {
        let params = self.config.params.clone();
        let limits = self.config.limits;
        let clock = Instant::now();
        let signature = self
            .pool
            .run(move || {
                let raw = load_bytes(&upload.mesh, upload.format, &upload.resources, &limits)?;
                Signature::from_bytes(&compute(&raw, &params)?.to_bytes())
            })
            .await??;
        self.metrics
            .extraction_seconds
            .observe(clock.elapsed().as_secs_f64());
        Ok(signature)
    }

    /// Runs `f` on the catalog off the async threads, on the ranking pool (ranking is CPU
    /// work). The lock is taken before entering the pool: a pool thread waiting for it (behind
    /// a queued writer) could be one whose stack holds another ranking's unfinished half, which
    /// keeps the read lock the writer waits for — a deadlock.
    async fn read_catalog<T: Send + 'static>(
        self: &Arc<Self>,
        f: impl FnOnce(&Catalog) -> T + Send + 'static,
    ) -> Result<T, AppError> {
        let app = self.clone();
        tokio::task::spawn_blocking(move || {
            let catalog = app.catalog.read().expect("catalog lock poisoned");
            app.ranker.install(|| f(&catalog))
        })
        .await
        .map_err(|e| AppError::Internal(e.to_string()))
    }
}

#[derive(OpenApi)]
#[openapi(
    info(
        title = "salient",
        description = "Content-based 3D model retrieval: upload a triangle mesh, get the most similar stored models, ranked by extended cone-curvature salient features under a penalised Earth Mover's Distance.",
        license(name = "MIT OR Apache-2.0")
    ),
    tags(
        (name = "models", description = "Stored models"),
        (name = "search", description = "Similarity search and extraction"),
        (name = "operations", description = "Health, readiness, metrics")
    )
)]
struct ApiDoc;

/// The routes and their OpenAPI description, from the same handler annotations.
fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .routes(utoipa_axum::routes!(models::add_model, models::list_models))
        .routes(utoipa_axum::routes!(
            models::get_model,
            models::delete_model
        ))
        .routes(utoipa_axum::routes!(models::get_signature))
        .routes(utoipa_axum::routes!(search::similar))
        .routes(utoipa_axum::routes!(search::search))
        .routes(utoipa_axum::routes!(search::extract))
        .routes(utoipa_axum::routes!(ops::healthz))
        .routes(utoipa_axum::routes!(ops::readyz))
        .routes(utoipa_axum::routes!(ops::metrics))
        .routes(utoipa_axum::routes!(ops::openapi_yaml))
}

/// The OpenAPI document of the service, as committed in `openapi.yaml`.
pub fn openapi_yaml() -> String {
    let (_, api) = routes().split_for_parts();
    api.to_yaml().expect("the OpenAPI document serialises")
}

/// The service as a router, ready to serve or to drive from tests.
pub fn app(state: AppState) -> Router {
    let config = &state.0.config;
    let (router, _) = routes().split_for_parts();
    let cors = match config.cors_origins.as_slice() {
        [] => CorsLayer::new(),
        [any] if any == "*" => CorsLayer::new().allow_origin(AllowOrigin::any()),
        origins => CorsLayer::new().allow_origin(
            origins
                .iter()
                .filter_map(|o| HeaderValue::from_str(o).ok())
                .collect::<Vec<_>>(),
        ),
    }
    .allow_methods([Method::GET, Method::POST, Method::DELETE]);
    let request_id = HeaderName::from_static("x-request-id");
    router
        .layer(DefaultBodyLimit::max(config.max_body_bytes))
        .layer(middleware::from_fn_with_state(
            state.clone(),
            count_requests,
        ))
        .layer(CompressionLayer::new())
        .layer(cors)
        .layer(PropagateRequestIdLayer::new(request_id.clone()))
        .layer(TraceLayer::new_for_http())
        .layer(SetRequestIdLayer::new(request_id, MakeRequestUuid))
        .fallback(|| async { AppError::NotFound("no such route".into()) })
        .with_state(state)
}

/// Counts every request by route pattern and status for `/metrics`.
async fn count_requests(State(state): State<AppState>, request: Request, next: Next) -> Response {
    let method = request.method().to_string();
    let route = request
        .extensions()
        .get::<MatchedPath>()
        .map_or("unmatched", |p| p.as_str())
        .to_string();
    let response = next.run(request).await;
    state
        .0
        .metrics
        .requests
        .get_or_create(&RequestLabels {
            method,
            route,
            status: response.status().as_u16(),
        })
        .inc();
    response
}

//! The HTTP retrieval service (SPEC §8; `openapi.yaml` is the contract): an axum router over
//! a [`Store`], a ranking [`salient_core::rank::Index`] of every stored model, and the bounded extraction
//! [`pool::Pool`]. Handlers only translate between HTTP and the library.

pub mod auth;
mod backup;
mod catalog;
pub mod config;
mod copies;
pub mod dismissed;
pub mod duplicates;
pub mod error;
pub mod evidence;
mod files;
pub mod first_stage;
pub mod follow;
mod metrics;
mod models;
mod ops;
mod page;
mod patches;
pub mod pool;
mod previews;
mod rankers;
mod reindex;
pub mod request;
mod search;
pub mod upload;

use std::ops::Deref;
use std::sync::Arc;
use std::time::{Duration, Instant};

use arc_swap::ArcSwap;
use axum::extract::{DefaultBodyLimit, MatchedPath, Request, State};
use axum::http::{header, HeaderName, HeaderValue, Method};
use axum::middleware::{self, Next};
use axum::response::IntoResponse;
use axum::response::Response;
use axum::Router;
use tower_http::compression::CompressionLayer;
use tower_http::cors::{AllowOrigin, CorsLayer};
use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
use tower_http::trace::TraceLayer;
use utoipa::OpenApi;
use utoipa_axum::router::{OpenApiRouter, UtoipaMethodRouter};

use crate::model::{ModelId, Upload};
use crate::store::{Store, StoreError};
use auth::{Access, AccessTable, KeyError, KeySet};
use catalog::{Catalog, Snapshot};
pub use config::Config;
use error::AppError;
use metrics::{Metrics, RequestLabels};
use pool::Pool;
pub use reindex::{ReindexProgress, ReindexState};
use salient_core::mesh::load_bytes;
use salient_core::mesh::Format;
use salient_core::pipeline::{signature_of_mesh, Extent};
use salient_core::signature::{Signature, Staleness};

/// Shared state of the service (`AppState(Arc<App>)`, as crates.io does it).
#[derive(Clone)]
pub struct AppState(pub Arc<App>);

impl Deref for AppState {
    type Target = Arc<App>;
    fn deref(&self) -> &Arc<App> {
        &self.0
    }
}

/// A function the service calls at a fixed point of its work, for tests that need to hold
/// it there (with a barrier or a channel) while something else happens.
pub type Hook = Arc<dyn Fn() + Send + Sync>;

/// How many query signatures [`App::extract_query`] remembers (≈ 8 KB each).
const RECENT_QUERIES: std::num::NonZeroUsize = std::num::NonZeroUsize::new(64).expect("not zero");

/// The service: configuration, store, catalogue, pools and background work.
pub struct App {
    pub config: Config,
    store: Arc<dyn Store>,
    catalog: Catalog,
    pool: Pool,
    /// Ranking's own pools, one per ranking running (`config.rankings`).
    rankers: Arc<rankers::Rankers>,
    metrics: Metrics,
    /// Serialises writes so that the store and the catalogue change in the same order.
    writes: tokio::sync::Mutex<()>,
    reindex: reindex::Reindexer,
    /// The API keys accepted now (replaced whole when the key file is read again).
    keys: ArcSwap<KeySet>,
    /// Requests each key label may still make (`requests_per_minute`), if limited.
    rates: Option<governor::DefaultKeyedRateLimiter<String>>,
    /// Signatures of recent queries by content hash, and how much of each was computed (see
    /// [`App::extract_query`]).
    queries: std::sync::Mutex<lru::LruCache<String, (Extent, Arc<Signature>)>>,
    /// Called on the ranking thread while it holds its catalogue snapshot (tests).
    ranking_hook: Option<Hook>,
    /// Called, on a blocking thread, before an upload that rejects duplicates takes the locks
    /// its check runs under (tests).
    duplicate_hook: Option<Hook>,
    /// Called, on a blocking thread, when a backup has copied the store and before it copies
    /// what changed meanwhile (tests).
    backup_hook: Option<Hook>,
    /// Held by the backup running, if any.
    backup_gate: tokio::sync::Mutex<()>,
    /// Meshes and verdicts of the near-duplicate check.
    verifier: duplicates::Verifier,
    /// Pairs an operator said are not duplicates.
    dismissed: dismissed::Dismissed,
    /// Held from the duplicate check of an upload that rejects duplicates until it is stored,
    /// so that two copies uploaded at once cannot both pass.
    duplicate_gate: tokio::sync::Mutex<()>,
    /// The models whose patches are still to be made.
    patcher: patches::Patcher,
    /// How far the catalogue follows a store shared with other replicas (none for a store
    /// of its own).
    follower: Option<follow::Follower>,
}

/// A lock every replica of a shared store takes around a check-then-write
/// ([`App::hold_shared`]).
#[derive(Debug, Clone, Copy)]
enum Across {
    /// An upload that rejects duplicates.
    Duplicates,
    /// An edit of a model's fields, or the re-extraction's write of one.
    Edits,
    /// A change of the dismissed pairs.
    Dismissed,
}

impl Across {
    fn name(self) -> &'static str {
        match self {
            Across::Duplicates => "on_duplicate",
            Across::Edits => "model_edits",
            Across::Dismissed => "dismissed",
        }
    }
}

/// Starting the service failed.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("cannot start the ranking threads: {0}")]
    Threads(String),
    #[error("stored signature of {id} cannot be read: {source}")]
    Signature {
        id: String,
        #[source]
        source: salient_core::Error,
    },
    #[error("API keys: {0}")]
    Keys(#[from] KeyError),
    #[error("cannot write the ranking index's shelf (see `shelf_dir`): {0}")]
    Shelf(std::io::Error),
    #[error("the shared store's models were extracted with other parameters than this replica's: run every replica with the same configuration, or, to change them, stop the others and start one with --adopt-extraction (SALIENT_ADOPT_EXTRACTION=1), which re-extracts every model")]
    OtherExtraction,
    #[error("index = \"pgvector\" needs a PostgreSQL store keeping the first stage (salient serve --store postgres://… --index pgvector)")]
    NoFirstStage,
    #[error("refusing to serve {0} without API keys: anyone who can reach it could add and delete models. Set SALIENT_API_KEYS=write:KEY (or admin:KEY), or pass --keys FILE (make a key with `salient keys new --scope write --label NAME --file FILE`); or, on a network you trust, --allow-anonymous")]
    Anonymous(std::net::SocketAddr),
}

/// Stored models are read from the store by one thread, in batches, while the batch before is
/// decoded and made into index rows in parallel: reading (sled's pages), decoding a signature
/// and making its row (the LFD's summaries, the shelf's write) are each a large part of a start.
const LOAD_BATCH: usize = 1024;

/// The catalogue of every stored model, and how many signatures are stale for their
/// parameters and for a missing descriptor.
fn load(
    config: &Config,
    store: &dyn Store,
    copies: Option<Arc<copies::Copies>>,
) -> Result<(Snapshot, usize, usize), StartError> {
    use rayon::prelude::*;
    let mut snapshot = Snapshot::empty(
        &config.params,
        config.index == config::FirstStageKind::Memory,
        config.shelf_dir.clone(),
        copies,
    );
    let (mut stale_parameters, mut missing_descriptor) = (0, 0);
    std::thread::scope(|scope| {
        let (batches, received) = std::sync::mpsc::sync_channel(1);
        scope.spawn(move || {
            let mut stored = store.load_all();
            loop {
                let batch = stored
                    .by_ref()
                    .take(LOAD_BATCH)
                    .collect::<Result<Vec<_>, _>>();
                let last = batch.as_ref().map_or(true, Vec::is_empty);
                // A closed channel means the loader stopped at an error: so does the reader.
                if batches.send(batch).is_err() || last {
                    break;
                }
            }
        });
        for batch in received {
            let batch = batch?;
            let held = &snapshot;
            let rows = batch
                .into_par_iter()
                .map(|loaded| {
                    let signature = Signature::from_bytes(&loaded.signature).map_err(|source| {
                        StartError::Signature {
                            id: loaded.record.id.to_string(),
                            source,
                        }
                    })?;
                    let row = held
                        .hold(&loaded.record.id, &signature, &loaded.signature)
                        .map_err(StartError::Shelf)?;
                    Ok((loaded.record, row, signature.staleness(&config.params)))
                })
                .collect::<Result<Vec<_>, StartError>>()?;
            for (record, row, staleness) in rows {
                match staleness {
                    Some(Staleness::Parameters) => stale_parameters += 1,
                    Some(Staleness::MissingDescriptor) => missing_descriptor += 1,
                    None => {}
                }
                snapshot.put(record, row);
            }
        }
        Ok::<_, StartError>(())
    })?;
    // Loaded by id: near models put together, for the rankings' block bounds.
    snapshot.index.arrange();
    Ok((snapshot, stale_parameters, missing_descriptor))
}

impl App {
    /// Loads every stored signature into the catalogue. Stale ones keep serving until they
    /// are re-extracted ([`App::start_background`]).
    pub fn new(config: Config, store: Arc<dyn Store>) -> Result<Self, StartError> {
        let keys = config.load_keys()?;
        // Safe by default: without keys, only this machine may reach the service.
        if keys.is_empty() && !config.addr.ip().is_loopback() && !config.allow_anonymous {
            return Err(StartError::Anonymous(config.addr));
        }
        if config.index == config::FirstStageKind::Pgvector && store.first_stage().is_none() {
            return Err(StartError::NoFirstStage);
        }
        // Read before loading: what is committed meanwhile is applied again after.
        let follower = match store.shared() {
            Some(shared) => {
                follow::agree_on_extraction(store.as_ref(), shared, &config)?;
                Some(follow::Follower::new(shared.head()?))
            }
            None => None,
        };
        // A replica of a shared store that ranks in memory ranks stored models from copies of
        // their signatures, so that it ranks while the database is down; one whose first
        // stage is in the database cannot rank without it anyway.
        let copies = match store.shared() {
            Some(_) if config.index == config::FirstStageKind::Memory => {
                let dir = config.shelf_dir.clone().unwrap_or_else(std::env::temp_dir);
                Some(Arc::new(
                    copies::Copies::create_in(&dir).map_err(StartError::Shelf)?,
                ))
            }
            _ => None,
        };
        let (snapshot, stale_parameters, missing_descriptor) =
            load(&config, store.as_ref(), copies)?;
        pool::release_free_memory();
        let models = snapshot.records.len();
        let catalog = Catalog::new(snapshot);
        if stale_parameters + missing_descriptor > 0 {
            tracing::warn!(
                stale_parameters,
                missing_descriptor,
                "stored signatures are stale and keep serving until they are re-extracted"
            );
        }
        let config_rate = config.requests_per_minute;
        let pool = Pool::new(
            config.workers,
            config.queue_depth,
            Duration::from_secs(config.request_timeout_secs),
        )
        .map_err(|e| StartError::Threads(e.to_string()))?;
        let metrics = Metrics::default();
        metrics.models.set(models as i64);
        let rankers = rankers::Rankers::new(config.rankings, metrics.rankings_waiting.clone())
            .map_err(|e| StartError::Threads(e.to_string()))?;
        let reindex = reindex::Reindexer::load(store.as_ref())?;
        let dismissed = dismissed::Dismissed::load(store.as_ref())?;
        let patcher = patches::Patcher::new(metrics.patches_pending.clone());
        Ok(Self {
            config,
            store,
            catalog,
            pool,
            rankers: Arc::new(rankers),
            metrics,
            writes: tokio::sync::Mutex::new(()),
            reindex,
            keys: ArcSwap::from_pointee(keys),
            rates: std::num::NonZeroU32::new(config_rate)
                .map(|n| governor::RateLimiter::keyed(governor::Quota::per_minute(n))),
            queries: std::sync::Mutex::new(lru::LruCache::new(RECENT_QUERIES)),
            ranking_hook: None,
            duplicate_hook: None,
            backup_hook: None,
            backup_gate: tokio::sync::Mutex::new(()),
            verifier: duplicates::Verifier::default(),
            dismissed,
            duplicate_gate: tokio::sync::Mutex::new(()),
            patcher,
            follower,
        })
    }

    /// Reads the API keys again (on SIGHUP), so that a key is revoked without a restart. A
    /// file that cannot be used leaves the keys as they were. Returns the number of keys.
    pub fn reload_keys(&self) -> Result<usize, KeyError> {
        let keys = self.config.load_keys()?;
        let count = keys.len();
        self.keys.store(Arc::new(keys));
        Ok(count)
    }

    /// Sets the hook called on the ranking thread while it holds its snapshot (tests).
    pub fn set_ranking_hook(&mut self, hook: Hook) {
        self.ranking_hook = Some(hook);
    }

    /// Sets the hook called before an upload's duplicate check takes its locks (tests).
    pub fn set_duplicate_hook(&mut self, hook: Hook) {
        self.duplicate_hook = Some(hook);
    }

    /// Sets the hook called between a backup's copy and its catching up (tests).
    pub fn set_backup_hook(&mut self, hook: Hook) {
        self.backup_hook = Some(hook);
    }

    /// Starts the background work the store calls for: a re-extraction left unfinished by
    /// the last run, or one of the stale signatures found at start (unless
    /// `reindex_on_start` is off); and the patches of every model without them
    /// ([`patches`]). Needs a Tokio runtime.
    pub fn start_background(self: &Arc<Self>) {
        self.reindex_if_due();
        patches::start(self);
        follow::start(self);
    }

    /// Starts re-extracting if a run was left unfinished, or if signatures are stale and
    /// `reindex_on_start` is on; a run going on (here, or on another replica of a shared
    /// store) is left to go on.
    fn reindex_if_due(self: &Arc<Self>) {
        if self.reindex.was_running() || (self.config.reindex_on_start && self.stale_count() > 0) {
            reindex::start(self);
        }
    }

    /// How many models' patches are still to be made (`None` before the start's count).
    pub fn patches_pending(&self) -> tokio::sync::watch::Receiver<Option<usize>> {
        self.patcher.pending()
    }

    /// Models in the catalogue.
    pub fn catalog_len(&self) -> usize {
        self.catalog.snapshot().records.len()
    }

    /// The models whose rows this replica keeps in memory: every model with the in-memory
    /// index, none with the first stage in the database.
    pub fn rows_in_memory(&self) -> usize {
        self.catalog.snapshot().index.len()
    }

    /// Models whose stored signature is stale under the configured parameters.
    pub fn stale_count(&self) -> usize {
        self.catalog.snapshot().stale_count()
    }

    /// The progress of online re-extraction, as it changes.
    pub fn reindex_progress(&self) -> tokio::sync::watch::Receiver<ReindexProgress> {
        self.reindex.subscribe()
    }

    /// How long the key labelled `label` must wait before its next request, if it made too
    /// many (`requests_per_minute`).
    fn rate_limited(&self, label: &str) -> Option<std::time::Duration> {
        use governor::clock::{Clock, DefaultClock};
        let rates = self.rates.as_ref()?;
        rates
            .check_key(&label.to_string())
            .err()
            .map(|not_until| not_until.wait_time_from(DefaultClock::default().now()))
    }

    /// The signature of a query upload to `extent`: extracted, or remembered from a recent
    /// query with the same content (the page asks for a query's preview right after its
    /// search, and a search again with another method); a full one serves either extent.
    async fn extract_query(
        &self,
        upload: Arc<Upload>,
        extent: Extent,
    ) -> Result<Arc<Signature>, AppError> {
        let hash = upload.content_hash().to_string();
        let recent = self
            .queries
            .lock()
            .expect("never poisoned")
            .get(&hash)
            .cloned();
        match recent {
            Some((had, signature)) if had == Extent::Full || had == extent => Ok(signature),
            _ => {
                let signature = self.extract_to(upload, extent).await?;
                self.queries
                    .lock()
                    .expect("never poisoned")
                    .put(hash, (extent, signature.clone()));
                Ok(signature)
            }
        }
    }

    /// Extracts the signature of an upload on the pool, in its stored form.
    async fn extract(&self, upload: Arc<Upload>) -> Result<Arc<Signature>, AppError> {
        self.extract_to(upload, Extent::Full).await
    }

    /// [`App::extract`] to `extent`.
    async fn extract_to(
        &self,
        upload: Arc<Upload>,
        extent: Extent,
    ) -> Result<Arc<Signature>, AppError> {
        let params = self.config.params.clone();
        let limits = self.config.limits;
        let clock = Instant::now();
        let signature = self
            .pool
            .run(move || {
                let raw = load_bytes(&upload.mesh, upload.format, &upload.resources, &limits)?;
                upload.release_pages();
                signature_of_mesh(raw, (&params, extent))
            })
            .await??;
        self.metrics
            .extraction_seconds
            .observe(clock.elapsed().as_secs_f64());
        Ok(Arc::new(signature))
    }

    /// Runs `f` on a snapshot of the catalogue, on a ranking pool (ranking is CPU work)
    /// when its turn comes ([`rankers`]), in the request's tracing span. No lock is
    /// taken: a write meanwhile publishes a new snapshot and leaves this one as it was.
    async fn read_catalog<T: Send + 'static>(
        self: &Arc<Self>,
        f: impl FnOnce(&Snapshot) -> T + Send + 'static,
    ) -> Result<T, AppError> {
        let app = self.clone();
        let turn = self.rankers.turn().await;
        let snapshot = self.catalog.snapshot();
        let span = tracing::Span::current();
        tokio::task::spawn_blocking(move || {
            let _span = span.enter();
            if let Some(hook) = &app.ranking_hook {
                hook();
            }
            turn.install(|| f(&snapshot))
        })
        .await
        .map_err(|e| AppError::Internal(format!("ranking failed: {e}")))
    }

    /// Reads again a state value another replica changed (`follow`).
    fn reload_state(&self, key: &str) -> Result<(), StoreError> {
        match key {
            dismissed::STATE_KEY => self.dismissed.reload(self.store.as_ref()),
            reindex::STATE_KEY => self.reindex.reload(self.store.as_ref()),
            _ => Ok(()),
        }
    }

    /// The stored signature of model `id`: this replica's copy when it keeps one (on a shared
    /// store, so that `similar` ranks while the database is down), else the store's.
    async fn stored_signature(&self, id: &ModelId) -> Result<Option<Signature>, AppError> {
        let snapshot = self.catalog.snapshot();
        if !snapshot.keeps_copy(id) {
            let id = id.clone();
            return self
                .with_store(move |store| store.decoded_signature(id.as_str()))
                .await;
        }
        let id = id.clone();
        tokio::task::spawn_blocking(move || {
            let bytes = snapshot
                .copy_of(&id)
                .expect("kept, as checked above")
                .map_err(AppError::index)?;
            Ok(Some(Signature::from_bytes(&bytes)?))
        })
        .await
        .map_err(|e| AppError::Internal(format!("reading a signature failed: {e}")))?
    }

    /// Runs a store operation on a blocking thread, in the request's tracing span.
    async fn with_store<T: Send + 'static>(
        &self,
        f: impl FnOnce(&dyn Store) -> Result<T, StoreError> + Send + 'static,
    ) -> Result<T, AppError> {
        let store = self.store.clone();
        let span = tracing::Span::current();
        tokio::task::spawn_blocking(move || {
            let _span = span.enter();
            f(store.as_ref())
        })
        .await
        .map_err(|e| AppError::Internal(format!("store task failed: {e}")))?
        .map_err(AppError::from)
    }

    /// Holds the lock `name` across every replica of a shared store, and catches this one up
    /// to what the others committed before it: a check-then-write that must see every
    /// replica's writes runs under it. A store of its own needs none (`None`): the caller's
    /// lock in this process suffices. Never called under [`App::writes`], which catching up
    /// takes.
    async fn hold_shared(
        self: &Arc<Self>,
        lock: Across,
    ) -> Result<Option<Box<dyn Send>>, AppError> {
        let name = lock.name();
        let lock = self
            .with_store(move |store| store.shared().map(|s| s.lock(name)).transpose())
            .await?;
        if lock.is_some() {
            follow::catch_up(self).await?;
        }
        Ok(lock)
    }

    /// Lowers the priority of extraction ([`Config::extraction_nice`]) and of the background
    /// work that may wait for idle cores: for the serving process, once.
    pub fn lower_extraction_priority(&self) {
        pool::lower_extraction_priority(self.config.extraction_nice);
        self.pool.lower_idle_priority();
    }

    fn set_model_count(&self, models: usize) {
        self.metrics.models.set(models as i64);
    }
}

#[derive(OpenApi)]
#[openapi(
    info(
        title = "salient",
        description = "Content-based 3D model retrieval: upload a triangle mesh, get the most similar stored models, ranked by extended cone-curvature salient features under a penalised Earth Mover's Distance.",
        license(name = "MIT OR Apache-2.0")
    ),
    components(schemas(upload::MeshFile, upload::MeshForm)),
    tags(
        (name = "models", description = "Stored models"),
        (name = "search", description = "Similarity search and extraction"),
        (name = "duplicates", description = "Near-duplicate models"),
        (name = "admin", description = "Re-extraction of stored models"),
        (name = "operations", description = "Health, readiness, metrics")
    )
)]
struct ApiDoc;

/// Adds the API-key scheme that each operation's security names ([`AccessTable::declare`]).
fn describe_security(api: &mut utoipa::openapi::OpenApi) {
    use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
    let components = api.components.get_or_insert_with(Default::default);
    components.add_security_scheme(
        "api_key",
        SecurityScheme::Http(
            HttpBuilder::new()
            .scheme(HttpAuthScheme::Bearer)
            .description(Some(
                "An API key, `Authorization: Bearer KEY`, with the scope the operation names (read, write, admin; each includes the ones before). A server without keys, on loopback or with --allow-anonymous, needs none.",
            ))
            .build(),
        ),
    );
}

/// The operations whose body is a mesh upload ([`upload::MeshUpload`]): the file raw with its
/// media type, or a multipart form.
const MESH_UPLOADS: [&str; 4] = ["/v1/models", "/v1/search", "/v1/extract", "/v1/preview"];

/// Gives each of [`MESH_UPLOADS`] its request body: one description instead of a copy in
/// every handler's annotation (utoipa cannot share a `request_body` between them).
fn describe_uploads(api: &mut utoipa::openapi::OpenApi) {
    use utoipa::openapi::request_body::RequestBodyBuilder;
    use utoipa::openapi::{ContentBuilder, Ref, Required};
    let content = |schema: &str| {
        ContentBuilder::new()
            .schema(Some(Ref::from_schema_name(schema)))
            .build()
    };
    let mut body = RequestBodyBuilder::new()
        .description(Some(
            "The mesh (raw, with its content type) or a multipart form",
        ))
        .required(Some(Required::True));
    let media_types = Format::ALL.map(Format::media_type);
    for media_type in media_types.iter().chain(&["application/octet-stream"]) {
        body = body.content(*media_type, content("MeshFile"));
    }
    let body = body
        .content("multipart/form-data", content("MeshForm"))
        .build();
    for path in MESH_UPLOADS {
        let operation = api
            .paths
            .paths
            .get_mut(path)
            .and_then(|item| item.post.as_mut())
            .expect("every mesh upload route is a documented POST");
        operation.request_body = Some(body.clone());
    }
}

/// The routes and their OpenAPI description, from the same handler annotations.
fn routes() -> Routes {
    use auth::Access::{Key, Open};
    use auth::Scope::{Admin, Read, Write};
    use utoipa_axum::routes;
    // Searching, extracting and checking for duplicates are `POST`s that change nothing: `read`.
    Routes::new(ApiDoc::openapi())
        .with(Key(Write), routes!(models::add_model))
        .with(Key(Read), routes!(models::list_models))
        .with(Key(Read), routes!(models::get_model))
        .with(
            Key(Write),
            routes!(models::delete_model, models::patch_model),
        )
        .with(Key(Read), routes!(models::get_signature))
        .with(Key(Read), routes!(files::get_file))
        .with(Key(Read), routes!(files::get_resource))
        .with(Key(Read), routes!(previews::get_thumbnail))
        .with(Key(Read), routes!(previews::get_preview))
        .with(Key(Read), routes!(previews::query_preview))
        .with(Key(Read), routes!(previews::compare))
        .with(Key(Read), routes!(search::similar))
        .with(Key(Read), routes!(search::search))
        .with(Key(Read), routes!(search::extract))
        .with(Key(Read), routes!(duplicates::list_duplicates))
        .with(Key(Read), routes!(duplicates::check_duplicates))
        .with(Key(Read), routes!(dismissed::list_dismissed))
        .with(
            Key(Write),
            routes!(dismissed::dismiss, dismissed::undismiss),
        )
        .with(
            Key(Admin),
            routes!(reindex::start_reindex, reindex::get_reindex),
        )
        .with(Key(Admin), routes!(backup::backup))
        .with(Open, routes!(ops::healthz))
        .with(Open, routes!(ops::readyz))
        .with(Key(Admin), routes!(ops::metrics))
        .with(Open, routes!(ops::openapi_yaml))
}

/// The routes, their OpenAPI description and the access each needs, built together.
struct Routes {
    router: OpenApiRouter<AppState>,
    access: AccessTable,
}

impl Routes {
    fn new(api: utoipa::openapi::OpenApi) -> Self {
        Self {
            router: OpenApiRouter::with_openapi(api),
            access: AccessTable::default(),
        }
    }

    /// Adds the operations of `routes`, each needing `access`.
    fn with(mut self, access: Access, routes: UtoipaMethodRouter<AppState>) -> Self {
        let (schemas, mut paths, method_router) = routes;
        self.access.declare(access, &mut paths);
        self.router = self.router.routes((schemas, paths, method_router));
        self
    }
}

/// The OpenAPI document of the service, as committed in `openapi.yaml`.
pub fn openapi_yaml() -> String {
    let (_, mut api) = routes().router.split_for_parts();
    describe_uploads(&mut api);
    describe_security(&mut api);
    api.to_yaml().expect("the OpenAPI document serialises")
}

/// The service as a router, ready to serve or to drive from tests.
pub fn app(state: AppState) -> Router {
    let config = &state.config;
    let Routes { router, mut access } = routes();
    let (router, _) = router.split_for_parts();
    // The page is not part of the API's description.
    let router = router
        .route("/", axum::routing::get(page::index))
        .route("/page/{file}", axum::routing::get(page::file));
    access.declare_route(Method::GET, "/", Access::Open);
    access.declare_route(Method::GET, "/page/{file}", Access::Open);
    if config.metrics_open {
        access.declare_route(Method::GET, "/metrics", Access::Open);
    }
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
    .allow_methods([Method::GET, Method::POST, Method::PATCH, Method::DELETE])
    .allow_headers([
        header::AUTHORIZATION,
        header::CONTENT_TYPE,
        follow::POSITION_HEADER,
    ])
    .expose_headers([follow::POSITION_HEADER]);
    let request_id = HeaderName::from_static("x-request-id");
    router
        .layer(DefaultBodyLimit::max(config.max_body_bytes))
        .layer(middleware::from_fn_with_state(
            state.clone(),
            follow::read_your_writes,
        ))
        .layer(middleware::from_fn_with_state(
            (state.clone(), Arc::new(access)),
            authorize,
        ))
        .layer(middleware::from_fn_with_state(
            state.clone(),
            count_requests,
        ))
        .layer(CompressionLayer::new())
        .layer(cors)
        .layer(PropagateRequestIdLayer::new(request_id.clone()))
        .layer(TraceLayer::new_for_http().make_span_with(request_span))
        .layer(SetRequestIdLayer::new(request_id, MakeRequestUuid))
        .fallback(|| async { AppError::NotFound("no such route".into()) })
        .with_state(state)
}

/// The tracing span of a request: method, route and the request id, so that every log line
/// of a request (an internal error's detail among them) can be found from the `x-request-id`
/// the client got. The raw path is left out: it can hold ids that are not ours to log.
fn request_span(request: &Request) -> tracing::Span {
    let route = request
        .extensions()
        .get::<MatchedPath>()
        .map_or("unmatched", |p| p.as_str());
    let id = request
        .headers()
        .get("x-request-id")
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    tracing::info_span!(
        "request",
        method = %request.method(),
        route,
        request_id = id,
        key = tracing::field::Empty
    )
}

/// Lets a request through if its key's scope covers what the route needs
/// ([`auth::required_scope`]); a server without keys (loopback, or `--allow-anonymous`) lets
/// everyone through. The key's label goes into the request's span, the key nowhere.
async fn authorize(
    State((app, access)): State<(AppState, Arc<AccessTable>)>,
    request: Request,
    next: Next,
) -> Response {
    // An unmatched request gets the router's 404 whoever asks.
    let needed = request
        .extensions()
        .get::<MatchedPath>()
        .and_then(|route| access.needed(request.method(), route.as_str()));
    let keys = app.keys.load();
    let Some(needed) = needed.filter(|_| !keys.is_empty()) else {
        return next.run(request).await;
    };
    let presented = request
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.split_once(' '))
        .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
        .map(|(_, key)| key.trim());
    let error = match presented.map(|key| keys.check(key)) {
        None => AppError::Unauthorized(format!(
            "this request needs an API key with the {needed} scope: send Authorization: Bearer KEY"
        )),
        Some(None) => AppError::Unauthorized("the API key is not valid".into()),
        Some(Some((scope, label))) => {
            tracing::Span::current().record("key", label);
            if let Some(wait) = app.rate_limited(label) {
                return AppError::RateLimited {
                    retry_after_secs: wait.as_secs() + 1,
                }
                .into_response();
            }
            if scope >= needed {
                drop(keys);
                return next.run(request).await;
            }
            AppError::Forbidden(format!(
                "this request needs the {needed} scope; the key has {scope}"
            ))
        }
    };
    error.into_response()
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

//! `salient serve`: the HTTP service on its sled store, or on a PostgreSQL database.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;

use salient_core::display::UpAxis;
use salient_server::api::config::{FirstStageKind, Secret};
use salient_server::api::{app, first_stage, App, AppState, Config};
use salient_server::store::{SledStore, Store};

/// Flags override the environment (`SALIENT_*`), which overrides the configuration file,
/// which overrides the defaults. API keys come from `SALIENT_API_KEYS` (`SCOPE:KEY,…`; scopes
/// read, write, admin) and from `--keys FILE`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Address to listen on (port 0 picks a free one).
    #[arg(long, env = "SALIENT_ADDR")]
    addr: Option<SocketAddr>,
    /// Folder of the store (created if missing); with `--store`, of this process's caches.
    #[arg(long, env = "SALIENT_DATA")]
    data: Option<PathBuf>,
    /// A PostgreSQL database to keep the catalogue in instead of the sled store in `--data`
    /// (`postgres://…` or `key=value` pairs; `sslmode` honoured). Give it in the environment:
    /// a command line is visible to every user of the machine (`ps`).
    #[arg(long, env = "SALIENT_STORE", hide_env_values = true)]
    store: Option<String>,
    /// Folder of the ranking index's file of light field descriptors (made again at each
    /// start) and of upload bodies over 16 MiB while they are read; on a disk, not a memory
    /// file system. Default: the store's folder.
    #[arg(long, env = "SALIENT_SHELF_DIR")]
    shelf_dir: Option<PathBuf>,
    /// TOML configuration file (every field of the server configuration).
    #[arg(long, env = "SALIENT_CONFIG")]
    config: Option<PathBuf>,
    /// Extractions running at once.
    #[arg(long, env = "SALIENT_WORKERS")]
    workers: Option<usize>,
    /// Extractions that may wait for a worker before new ones get 503.
    #[arg(long, env = "SALIENT_QUEUE_DEPTH")]
    queue_depth: Option<usize>,
    /// Niceness (0–19) of the extraction threads: searches get the cores before an ingest.
    #[arg(long, env = "SALIENT_EXTRACTION_NICE")]
    extraction_nice: Option<i32>,
    /// Rankings running at once (each on its own threads); others wait in arrival order.
    #[arg(long, env = "SALIENT_RANKINGS")]
    rankings: Option<usize>,
    /// Largest request body, bytes, of every request but adding a model.
    #[arg(long, env = "SALIENT_MAX_BODY_BYTES")]
    max_body_bytes: Option<usize>,
    /// Largest body, bytes, of adding a model (POST /v1/models).
    #[arg(long, env = "SALIENT_MAX_UPLOAD_BYTES")]
    max_upload_bytes: Option<usize>,
    /// Time limit of a request, seconds.
    #[arg(long, env = "SALIENT_REQUEST_TIMEOUT_SECS")]
    request_timeout_secs: Option<u64>,
    /// Largest vertex count of an uploaded mesh (before welding).
    #[arg(long, env = "SALIENT_MAX_VERTICES")]
    max_vertices: Option<usize>,
    /// Largest triangle count of an uploaded mesh (polygons count as their triangles).
    #[arg(long, env = "SALIENT_MAX_TRIANGLES")]
    max_triangles: Option<usize>,
    /// Re-extract stale signatures in the background at start (`true` or `false`).
    #[arg(long, env = "SALIENT_REINDEX_ON_START")]
    reindex_on_start: Option<bool>,
    /// File of hashed API keys (`SCOPE SHA256 LABEL` lines; `salient keys new` writes them),
    /// read again on SIGHUP.
    #[arg(long = "keys", env = "SALIENT_KEYS_FILE")]
    keys_file: Option<PathBuf>,
    /// Serve without API keys on an address that is not loopback: everyone may write.
    #[arg(long, env = "SALIENT_ALLOW_ANONYMOUS", value_parser = clap::builder::BoolishValueParser::new(), num_args = 0..=1, default_missing_value = "true")]
    allow_anonymous: Option<bool>,
    /// Serve `/metrics` without a key.
    #[arg(long, env = "SALIENT_METRICS_OPEN", value_parser = clap::builder::BoolishValueParser::new(), num_args = 0..=1, default_missing_value = "true")]
    metrics_open: Option<bool>,
    /// The models' up axis for thumbnails and 3D views: `y` (glTF, most game assets) or `z`
    /// (CAD, 3D printing).
    #[arg(long, env = "SALIENT_UP_AXIS", value_parser = super::choice(&UpAxis::ALL, UpAxis::as_str))]
    up_axis: Option<UpAxis>,
    /// Requests a minute per API key, 0 for no limit; beyond, 429 with `Retry-After`.
    #[arg(long, env = "SALIENT_REQUESTS_PER_MINUTE")]
    requests_per_minute: Option<u32>,
    /// Origins allowed by CORS, comma-separated (`*` for any).
    #[arg(long, env = "SALIENT_CORS_ORIGINS", value_delimiter = ',')]
    cors_origins: Option<Vec<String>>,
    /// On a shared store whose models were extracted with other parameters: make this
    /// replica's parameters the store's and re-extract. Stop the other replicas first.
    #[arg(long, env = "SALIENT_ADOPT_EXTRACTION", value_parser = clap::builder::BoolishValueParser::new(), num_args = 0..=1, default_missing_value = "true")]
    adopt_extraction: Option<bool>,
    /// Folder for `POST /v1/admin/backup`'s snapshots of the sled store (`salient backup`).
    #[arg(long, env = "SALIENT_BACKUP_DIR")]
    backup_dir: Option<PathBuf>,
    /// Where the hybrid's rankings find their candidates: `memory` (exact, the default) or
    /// `pgvector` (with `--store`: pgvector's HNSW index in the database, approximate).
    #[arg(long, env = "SALIENT_INDEX", value_parser = super::choice(&FirstStageKind::ALL, FirstStageKind::as_str))]
    index: Option<FirstStageKind>,
}

impl Args {
    /// The configuration these arguments describe.
    pub fn config(&self) -> anyhow::Result<Config> {
        let mut config = Config::load(self.config.as_deref())?;
        let a = self.clone();
        config.addr = a.addr.unwrap_or(config.addr);
        config.data = a.data.unwrap_or(config.data);
        config.shelf_dir = a
            .shelf_dir
            .or(config.shelf_dir)
            .or_else(|| Some(config.data.clone()));
        config.workers = a.workers.unwrap_or(config.workers);
        config.queue_depth = a.queue_depth.unwrap_or(config.queue_depth);
        config.rankings = a.rankings.unwrap_or(config.rankings);
        config.extraction_nice = a.extraction_nice.unwrap_or(config.extraction_nice);
        config.max_body_bytes = a.max_body_bytes.unwrap_or(config.max_body_bytes);
        config.max_upload_bytes = a.max_upload_bytes.unwrap_or(config.max_upload_bytes);
        config.request_timeout_secs = a
            .request_timeout_secs
            .unwrap_or(config.request_timeout_secs);
        config.limits.max_input_vertices =
            a.max_vertices.unwrap_or(config.limits.max_input_vertices);
        config.limits.max_input_triangles =
            a.max_triangles.unwrap_or(config.limits.max_input_triangles);
        config.cors_origins = a.cors_origins.unwrap_or(config.cors_origins);
        config.reindex_on_start = a.reindex_on_start.unwrap_or(config.reindex_on_start);
        config.keys_file = a.keys_file.or(config.keys_file);
        config.allow_anonymous = a.allow_anonymous.unwrap_or(config.allow_anonymous);
        config.metrics_open = a.metrics_open.unwrap_or(config.metrics_open);
        config.up_axis = a.up_axis.unwrap_or(config.up_axis);
        config.requests_per_minute = a.requests_per_minute.unwrap_or(config.requests_per_minute);
        config.adopt_extraction = a.adopt_extraction.unwrap_or(config.adopt_extraction);
        config.backup_dir = a.backup_dir.or(config.backup_dir);
        config.index = a.index.unwrap_or(config.index);
        // Keys are secrets: the environment is the one place they come from, so that they
        // appear in no command line (`ps`) and no configuration file.
        config.inline_keys = std::env::var("SALIENT_API_KEYS").ok().map(Secret);
        config.validate().map_err(anyhow::Error::msg)?;
        Ok(config)
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "info,tower_http=info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    salient_server::api::pool::limit_malloc_arenas();
    let config = args.config()?;
    // The connection string is never printed: it may hold a password.
    let store: Arc<dyn Store> = match &args.store {
        Some(url) => {
            // sled makes its folder; here it holds only the caches (the index's shelf).
            std::fs::create_dir_all(&config.data).with_context(|| {
                format!("cannot make the cache folder {}", config.data.display())
            })?;
            Arc::new(
                first_stage::open_store(url, &config)
                    .context("cannot open the PostgreSQL store (--store)")?,
            )
        }
        None => Arc::new(
            SledStore::open(&config.data)
                .with_context(|| format!("cannot open the store in {}", config.data.display()))?,
        ),
    };
    let addr = config.addr;
    let app_state = AppState(Arc::new(App::new(config, store)?));
    app_state.0.lower_extraction_priority();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .with_context(|| format!("cannot listen on {addr}"))?;
        let local = listener.local_addr()?;
        app_state.start_background();
        tokio::spawn(reload_keys_on_hangup(app_state.0.clone()));
        // Tests and scripts read this line to find the port.
        println!("listening on http://{local}");
        tracing::info!(%local, models = app_state.0.catalog_len(), "serving");
        axum::serve(listener, app(app_state))
            .with_graceful_shutdown(shutdown())
            .await
            .context("server failed")
    })
}

/// Reads the API keys again on every SIGHUP; a key file that cannot be used keeps the keys
/// as they were.
async fn reload_keys_on_hangup(app: Arc<App>) {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        let Ok(mut hangups) = signal(SignalKind::hangup()) else {
            tracing::warn!("cannot listen for SIGHUP: API keys are read at start only");
            return;
        };
        while hangups.recv().await.is_some() {
            match app.reload_keys() {
                Ok(keys) => tracing::info!(keys, "API keys read again"),
                Err(error) => tracing::error!(%error, "API keys not read again; the old ones stay"),
            }
        }
    }
    #[cfg(not(unix))]
    let _ = app;
}

/// Resolves on Ctrl-C or SIGTERM.
async fn shutdown() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let terminate = async {
        if let Ok(mut s) = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        {
            s.recv().await;
        }
    };
    #[cfg(not(unix))]
    let terminate = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {},
        () = terminate => {},
    }
}

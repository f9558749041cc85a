//! Server configuration: defaults, then an optional TOML file, then `SALIENT_*` environment
//! variables and flags (the CLI applies the last two).

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use salient_core::display::UpAxis;
use salient_core::params::{Limits, Params};

/// Everything `salient serve` can be told.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Address to listen on.
    pub addr: SocketAddr,
    /// Folder of the sled store.
    pub data: PathBuf,
    /// Folder of the ranking index's file of light field descriptors, kept out of memory and
    /// made again at each start (`rank::shelf`), and of upload bodies over 16 MiB while they
    /// are read and extracted ([`crate::spool`]); a disk, not a memory file system. Default:
    /// `data` when serving from a store there, else the system's temporary folder.
    pub shelf_dir: Option<PathBuf>,
    /// Largest request body in bytes of every request but adding a model (searches, checks,
    /// previews); larger ones get 413.
    pub max_body_bytes: usize,
    /// Largest body in bytes of adding a model (`POST /v1/models`): a 3D-print library's STL
    /// files run to hundreds of megabytes, a search's query need not.
    pub max_upload_bytes: usize,
    /// Extractions running at once.
    pub workers: usize,
    /// Extractions waiting for a worker; when full, new ones get 503 with `Retry-After`.
    pub queue_depth: usize,
    /// Niceness (0–19) of the extraction threads when serving: a search waiting behind
    /// extractions of an ingest gets the cores first, and the ingest takes what is left.
    pub extraction_nice: i32,
    /// Rankings running at once, each on its own threads (the cores shared out); the others
    /// wait their turn in arrival order.
    pub rankings: usize,
    /// Time limit for one request, extraction included.
    pub request_timeout_secs: u64,
    /// Origins allowed by CORS; empty allows none, `["*"]` any.
    pub cors_origins: Vec<String>,
    /// Largest `k` a search may ask for.
    pub max_k: usize,
    /// Re-extract stale signatures in the background when the server starts and finds any
    /// (after an upgrade or a change of extraction parameters); they serve meanwhile.
    pub reindex_on_start: bool,
    /// Input limits (vertex and triangle counts).
    pub limits: Limits,
    /// Extraction and similarity parameters of the stored signatures.
    pub params: Params,
    /// File of hashed API keys (`SCOPE SHA256 LABEL` lines, from `salient keys new`), read
    /// again on SIGHUP.
    pub keys_file: Option<PathBuf>,
    /// API keys as `SCOPE:KEY,…`: from the environment (`SALIENT_API_KEYS`) only, never from
    /// the configuration file, and never printed.
    #[serde(skip)]
    pub inline_keys: Option<Secret>,
    /// Serve without keys on an address that is not loopback (everyone may write).
    pub allow_anonymous: bool,
    /// `/metrics` without a key (for a scraper inside a trusted network).
    pub metrics_open: bool,
    /// The models' up axis, for thumbnails and 3D views.
    pub up_axis: UpAxis,
    /// Requests a minute each API key may make (in bursts of as many); beyond, 429 with
    /// `Retry-After`. 0: no limit (a bulk ingest sends a few requests per model).
    pub requests_per_minute: u32,
    /// How long a request that carries a `Salient-Position` (on a store shared by replicas)
    /// waits for this replica to apply that change before it is answered 503.
    pub position_wait_ms: u64,
    /// On a store shared by replicas whose models were extracted with other parameters:
    /// make this replica's parameters the store's (and re-extract) rather than refuse to
    /// start. For a deliberate change, with the other replicas stopped.
    pub adopt_extraction: bool,
    /// Where `POST /v1/admin/backup` writes its snapshots of a sled store (each a store
    /// folder of its own); none: backups are not offered.
    pub backup_dir: Option<PathBuf>,
    /// On a store shared by replicas, how often one of them counts again the models that lack
    /// patches: those a replica stored and was stopped (or killed) before it made them.
    pub patch_recount_secs: u64,
    /// That count leaves out models stored this recently: the replica that stored them is
    /// making them. One stored within it by a replica killed since waits for the next count.
    pub patch_grace_secs: u64,
    /// Where a ranking's first stage runs ([`FirstStageKind`]).
    pub index: FirstStageKind,
    /// With `index = "pgvector"`: the candidates the first stage passes on, per result asked,
    /// to be ranked by their exact distance (`benches/first_stage.rs` measures recall by it).
    pub first_stage_oversampling: usize,
    /// The most candidates one ranking reads from the first stage (each with its signature,
    /// ~7 KB), whatever its `k`.
    pub first_stage_max_candidates: usize,
}

/// Where a ranking's first stage runs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FirstStageKind {
    /// The in-memory index: exact, every model's bounds in this process (the default).
    #[default]
    Memory,
    /// pgvector's HNSW index in the PostgreSQL store (#40): approximate, and nothing per
    /// model in this process for the hybrid's rankings.
    Pgvector,
}

impl FirstStageKind {
    pub const ALL: [FirstStageKind; 2] = [FirstStageKind::Memory, FirstStageKind::Pgvector];

    pub fn as_str(self) -> &'static str {
        match self {
            FirstStageKind::Memory => "memory",
            FirstStageKind::Pgvector => "pgvector",
        }
    }
}

/// A value that must not be printed: its `Debug` says only that it is there.
#[derive(Clone, PartialEq, Eq)]
pub struct Secret(pub String);

impl std::fmt::Debug for Secret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Secret(..)")
    }
}

impl Default for Config {
    fn default() -> Self {
        Self {
            addr: SocketAddr::from(([127, 0, 0, 1], 8080)),
            data: PathBuf::from("salient-data"),
            shelf_dir: None,
            max_body_bytes: 64 << 20,
            max_upload_bytes: 320 << 20,
            workers: std::thread::available_parallelism().map_or(2, |n| n.get()),
            queue_depth: 16,
            rankings: std::thread::available_parallelism().map_or(2, |n| n.get()),
            extraction_nice: 10,
            request_timeout_secs: 120,
            cors_origins: Vec::new(),
            max_k: 1000,
            reindex_on_start: true,
            // A binary STL at max_upload_bytes holds 6.7 M triangles over ~3.4 M vertices.
            limits: Limits {
                max_input_vertices: 4_000_000,
                max_input_triangles: 7_000_000,
                max_archive_entries: 1000,
                max_unpacked_bytes: 256 << 20,
            },
            params: Params::default(),
            keys_file: None,
            inline_keys: None,
            allow_anonymous: false,
            metrics_open: false,
            up_axis: UpAxis::Y,
            requests_per_minute: 0,
            position_wait_ms: 5000,
            adopt_extraction: false,
            backup_dir: None,
            patch_recount_secs: 600,
            patch_grace_secs: 600,
            index: FirstStageKind::Memory,
            first_stage_oversampling: 100,
            first_stage_max_candidates: 5000,
        }
    }
}

/// A configuration file that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("invalid configuration in {path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

impl Config {
    /// Where large upload bodies are spooled: [`Config::shelf_dir`]'s folder.
    pub fn spool_dir(&self) -> PathBuf {
        self.shelf_dir.clone().unwrap_or_else(std::env::temp_dir)
    }

    /// Defaults overlaid with `file` (TOML), if given.
    pub fn load(file: Option<&Path>) -> Result<Self, ConfigError> {
        let Some(path) = file else {
            return Ok(Self::default());
        };
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let config: Config = toml::from_str(&text).map_err(|e| ConfigError::Invalid {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        config.validate().map_err(|message| ConfigError::Invalid {
            path: path.to_path_buf(),
            message,
        })?;
        Ok(config)
    }

    /// The API keys of both sources (the environment's and the key file).
    pub fn load_keys(&self) -> Result<super::auth::KeySet, super::auth::KeyError> {
        super::auth::load_keys(
            self.inline_keys.as_ref().map(|s| s.0.as_str()),
            self.keys_file.as_deref(),
        )
    }

    /// Checks the values no server can run with.
    pub fn validate(&self) -> Result<(), String> {
        if self.workers == 0 || self.rankings == 0 {
            return Err("workers and rankings must be at least 1".into());
        }
        if !(0..=19).contains(&self.extraction_nice) {
            return Err("extraction_nice must be within 0..=19".into());
        }
        if self.max_body_bytes == 0
            || self.first_stage_oversampling == 0
            || self.first_stage_max_candidates == 0
            || self.max_upload_bytes == 0
            || self.request_timeout_secs == 0
            || self.max_k == 0
        {
            return Err(
                "max_body_bytes, max_upload_bytes, request_timeout_secs, max_k and the first stage's oversampling and candidates must be positive"
                    .into(),
            );
        }
        self.params.validate().map_err(|e| e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranking_turns_and_extraction_niceness_are_bounded() {
        assert_eq!(Config::default().validate(), Ok(()));
        let read = |text: &str| toml::from_str::<Config>(text).unwrap();
        let config = read("rankings = 2\nextraction_nice = 0");
        assert_eq!((config.rankings, config.extraction_nice), (2, 0));
        assert_eq!(config.validate(), Ok(()));
        for bad in [
            "rankings = 0",
            "extraction_nice = 20",
            "extraction_nice = -1",
        ] {
            assert!(read(bad).validate().is_err(), "{bad}");
        }
    }
}

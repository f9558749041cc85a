//! Keeps a replica in step with the others on a store they share (#37).
//!
//! Each replica holds the whole catalogue in memory. What another one writes reaches it
//! through the store's log of changes ([`Shared`]), read in commit order from the last
//! position this replica applied: woken by the store's notifications, and every
//! [`POLL`] in case one was lost. A change names a model (read again: stored, re-described
//! or gone) or a state key; applying one is idempotent, so this replica's own writes, already
//! in its catalogue, are applied again harmlessly.
//!
//! Read-your-writes: a write's response carries the position of its change
//! ([`POSITION_HEADER`]); a request that sends it back, to any replica, is answered once that
//! replica has applied it ([`Config::position_wait_ms`](super::Config), else 503).

use std::collections::BTreeSet;
use std::sync::{Arc, Weak};
use std::time::{Duration, Instant};

use axum::extract::{Request, State};
use axum::http::{HeaderName, HeaderValue, Method};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use tokio::sync::watch;

use super::error::AppError;
use super::{App, AppState};
use crate::model::ModelId;
use crate::store::{Change, Changes, Shared, Store, StoreError};
use salient_core::signature::Signature;

/// The header a write's response carries its change's position in, and a request sends back.
pub const POSITION_HEADER: HeaderName = HeaderName::from_static("salient-position");
/// How often the log is read when no notification came.
const POLL: Duration = Duration::from_secs(2);
/// Changes read and applied at a time, under the service's write lock.
const BATCH: usize = 256;
/// Changes older than this are trimmed from the log; a replica away for longer loads the
/// whole store again when it comes back.
const KEEP: Duration = Duration::from_secs(24 * 3600);
/// How often a replica trims the log.
const TRIM_EVERY: Duration = Duration::from_secs(3600);
/// How often a replica looks for background work another one claimed and may have left
/// (it stopped): re-extraction.
const TAKE_OVER_EVERY: Duration = Duration::from_secs(30);
/// The state key of the extraction parameters every replica on the store uses
/// ([`Params::extraction_key`](salient_core::params::Params::extraction_key)).
pub(crate) const EXTRACTION_KEY: &str = "extraction_params";

/// Makes sure this replica extracts as the store's other replicas do: a replica with other
/// parameters would mark every other's signatures stale and re-extract them, and they its.
/// The first replica on a store records its parameters; one with others is refused, unless
/// it adopts them ([`Config::adopt_extraction`](super::Config)): then they become the store's,
/// and its signatures stale, which this replica re-extracts.
pub fn agree_on_extraction(
    store: &dyn Store,
    shared: &dyn Shared,
    config: &super::Config,
) -> Result<(), super::StartError> {
    let _agreeing = shared.lock(EXTRACTION_KEY)?;
    let mine = config.params.extraction_key();
    match store.state(EXTRACTION_KEY)? {
        Some(theirs) if theirs == mine => Ok(()),
        Some(_) if !config.adopt_extraction => Err(super::StartError::OtherExtraction),
        recorded => {
            if recorded.is_some() {
                tracing::warn!("adopting this replica's extraction parameters for the shared store: its models will be re-extracted");
            }
            Ok(store.set_state(EXTRACTION_KEY, &mine)?)
        }
    }
}

/// How far this replica has applied the shared store's log.
pub struct Follower {
    applied: watch::Sender<u64>,
}

impl Follower {
    /// A replica whose catalogue was loaded after the log stood at `position`.
    pub fn new(position: u64) -> Self {
        Self {
            applied: watch::Sender::new(position),
        }
    }

    /// The last position applied: every change up to it is in the catalogue.
    pub fn applied(&self) -> u64 {
        *self.applied.borrow()
    }

    /// Whether `position` is applied within `wait`.
    async fn reached(&self, position: u64, wait: Duration) -> bool {
        let mut applied = self.applied.subscribe();
        tokio::time::timeout(wait, applied.wait_for(|&p| p >= position))
            .await
            .is_ok_and(|r| r.is_ok())
    }
}

/// Follows the store's log in the background, if the store is shared. The task holds the
/// service weakly and ends with it.
pub fn start(app: &Arc<App>) {
    let Some(shared) = app.store.shared() else {
        return;
    };
    let mut notified = shared.subscribe();
    let app: Weak<App> = Arc::downgrade(app);
    tokio::spawn(async move {
        let (mut trimmed, mut looked) = (Instant::now(), Instant::now());
        loop {
            let Some(app) = app.upgrade() else {
                return;
            };
            if let Err(e) = catch_up(&app).await {
                tracing::warn!(error = %e, "cannot read the store's changes; trying again");
            }
            if trimmed.elapsed() >= TRIM_EVERY {
                trimmed = Instant::now();
                if let Err(e) = app.with_store(|store| trim(store)).await {
                    tracing::warn!(error = %e, "cannot trim the store's change log");
                }
            }
            if looked.elapsed() >= TAKE_OVER_EVERY {
                looked = Instant::now();
                app.reindex_if_due();
            }
            drop(app);
            // A lost notification, or a closed channel, is made up by the poll.
            let _ = tokio::time::timeout(POLL, notified.changed()).await;
        }
    });
}

fn trim(store: &dyn Store) -> Result<u64, StoreError> {
    store.shared().map_or(Ok(0), |shared| shared.trim(KEEP))
}

/// Applies every change committed so far; returns the position reached. On a store that is
/// not shared there is nothing to follow.
pub async fn catch_up(app: &Arc<App>) -> Result<u64, AppError> {
    let Some(follower) = &app.follower else {
        return Ok(0);
    };
    loop {
        let _write = app.writes.lock().await;
        let after = follower.applied();
        let worker = app.clone();
        let reached = tokio::task::spawn_blocking(move || apply_next(&worker, after))
            .await
            .map_err(|e| AppError::Internal(format!("following the store failed: {e}")))??;
        match reached {
            Some(position) => {
                follower.applied.send_replace(position);
            }
            None => return Ok(after),
        }
    }
}

/// Applies the next batch of changes after `after`; returns the position reached, or `None`
/// when there was none.
fn apply_next(app: &App, after: u64) -> Result<Option<u64>, AppError> {
    let store = app.store.as_ref();
    let shared: &dyn Shared = store
        .shared()
        .ok_or_else(|| AppError::Internal("a follower on a store that is not shared".into()))?;
    let changes = match shared.changes_after(after, BATCH)? {
        Changes::Trimmed => return reload(app, shared).map(Some),
        Changes::Next(changes) => changes,
    };
    let Some(&(last, _)) = changes.last() else {
        return Ok(None);
    };
    // Each model once: what is read is its state now, which covers every change of it.
    let mut models = BTreeSet::new();
    let mut states = BTreeSet::new();
    for (_, change) in changes {
        match change {
            Change::Model(id) => models.insert(id),
            Change::State(key) => states.insert(key),
        };
    }
    for id in &models {
        apply_model(app, id)?;
    }
    for key in &states {
        app.reload_state(key)?;
    }
    if states.contains(EXTRACTION_KEY) {
        let agreed = store.state(EXTRACTION_KEY)? == Some(app.config.params.extraction_key());
        if !agreed {
            tracing::error!("another replica adopted other extraction parameters for the shared store: stop this one, and run every replica with the same configuration");
        }
        app.metrics.replica.other_extraction.set(i64::from(!agreed));
    }
    app.set_model_count(app.catalog_len());
    Ok(Some(last))
}

/// Puts a model into the catalogue as the store holds it now, or takes it out.
fn apply_model(app: &App, id: &ModelId) -> Result<(), AppError> {
    match app.store.model(id.as_str())? {
        Some(loaded) => {
            let signature = Signature::from_bytes(&loaded.signature)?;
            let held = app.catalog.hold(id, &signature, &loaded.signature)?;
            app.catalog.put(loaded.record, held);
        }
        None => {
            app.catalog.remove(id);
        }
    }
    Ok(())
}

/// Loads the whole store again (this replica fell behind the trimmed log); returns the
/// position it reflects.
fn reload(app: &App, shared: &dyn Shared) -> Result<u64, AppError> {
    tracing::warn!("this replica fell behind the store's change log; loading the store again");
    // Read first: changes committed during the load are applied again after it.
    let position = shared.head()?;
    let copies = app.catalog.snapshot().copies();
    let (snapshot, ..) = super::load(&app.config, app.store.as_ref(), copies)
        .map_err(|e| AppError::Internal(e.to_string()))?;
    app.catalog.replace(snapshot);
    for (key, _) in app.store.states()? {
        app.reload_state(&key)?;
    }
    Ok(position)
}

/// Middleware: a request carrying [`POSITION_HEADER`] waits until this replica has applied
/// that change (bounded); a write's successful response carries the position of the last
/// change this replica committed, which is at least its own.
pub async fn read_your_writes(
    State(app): State<AppState>,
    request: Request,
    next: Next,
) -> Response {
    let wanted = match request.headers().get(&POSITION_HEADER) {
        None => None,
        Some(value) => match value
            .to_str()
            .ok()
            .and_then(|v| v.trim().parse::<u64>().ok())
        {
            Some(position) => Some(position),
            None => {
                return AppError::bad_request(
                    "invalid_position",
                    "Salient-Position must be a change position from a write's response",
                )
                .into_response()
            }
        },
    };
    if let (Some(wanted), Some(follower)) = (wanted, &app.follower) {
        let wait = Duration::from_millis(app.config.position_wait_ms);
        if !follower.reached(wanted, wait).await {
            return AppError::Behind(wanted).into_response();
        }
    }
    let writes = !matches!(
        *request.method(),
        Method::GET | Method::HEAD | Method::OPTIONS
    );
    let mut response = next.run(request).await;
    let written = app.store.shared().map_or(0, Shared::written);
    if writes && written > 0 && response.status().is_success() {
        response
            .headers_mut()
            .insert(POSITION_HEADER, HeaderValue::from(written));
    }
    response
}

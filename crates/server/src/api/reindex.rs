//! Online re-extraction: stale signatures ([`salient_core::signature::Staleness`]) are extracted
//! again from the stored originals in the background, one model at a time, while the old
//! signatures keep serving; each new one replaces its old one atomically in the store and
//! the catalogue.
//!
//! Bounded: one extraction at a time, on one of the extraction pool's workers (it waits for
//! a free one rather than taking a queue slot, so uploads are never refused because of it),
//! and ranking keeps its own threads. Resumable: the progress, with the last model done, is
//! kept in the store's state after every model; a server restarted mid-run continues after
//! that model. A model replaced or deleted meanwhile is skipped, not overwritten.
//!
//! On a store shared by replicas one re-extracts at a time, holding a claim in the store
//! that ends with its session if it dies; the others look again now and then
//! ([`super::follow`]), and one of them takes the run over where the progress says it was.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use axum::extract::State;
use axum::http::StatusCode;
use axum::Json;
use serde::{Deserialize, Serialize};
use tokio::sync::watch;

use super::error::{AppError, ErrorBody};
use super::{App, AppState};
use crate::model::{now_unix, ModelId};
use crate::store::{Store, StoreResult};
use salient_core::params::Limits;
use salient_core::pipeline::{signature_of_file, Extent};

/// Key of the progress in the store's state, and name of the claim on a run.
pub(crate) const STATE_KEY: &str = "reindex";

/// Failures listed in the progress (the count goes on).
const MAX_FAILURES_LISTED: usize = 100;

/// Where a re-extraction run is.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ReindexState {
    /// No run since the store was made.
    #[default]
    Idle,
    Running,
    Finished,
}

/// A model that could not be re-extracted; it keeps its old signature.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ReindexFailure {
    pub id: String,
    pub reason: String,
}

/// The progress of the current or last run.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(default)]
pub struct ReindexProgress {
    pub state: ReindexState,
    /// Stale models when the run started.
    pub total: usize,
    /// Models re-extracted so far (skipped ones, replaced or deleted meanwhile, included).
    pub done: usize,
    pub failed: usize,
    /// Models stale now (counted when the progress is read).
    pub remaining: usize,
    /// The last model handled: a run resumed after a restart goes on after it.
    pub last_id: Option<String>,
    /// The first failures, with their reasons.
    pub failures: Vec<ReindexFailure>,
    pub started_unix: Option<u64>,
    pub finished_unix: Option<u64>,
}

/// The service's re-extraction: its progress, published to readers as it changes.
pub struct Reindexer {
    progress: watch::Sender<ReindexProgress>,
    /// A run is going on in this process (a `Running` state read from the store is a run
    /// that a restart interrupted).
    active: AtomicBool,
}

impl Reindexer {
    /// The progress the store kept from the last run.
    pub fn load(store: &dyn Store) -> StoreResult<Self> {
        let progress = store
            .state(STATE_KEY)?
            .and_then(|bytes| serde_json::from_slice(&bytes).ok())
            .unwrap_or_default();
        Ok(Self {
            progress: watch::Sender::new(progress),
            active: AtomicBool::new(false),
        })
    }

    /// Reads the progress again, as another replica's run changed it; this one's own run
    /// keeps its own.
    pub fn reload(&self, store: &dyn Store) -> StoreResult<()> {
        if !self.active.load(Ordering::SeqCst) {
            self.progress
                .send_replace(Self::load(store)?.progress.borrow().clone());
        }
        Ok(())
    }

    /// Whether the last process stopped in the middle of a run.
    pub fn was_running(&self) -> bool {
        self.progress.borrow().state == ReindexState::Running
    }

    pub fn subscribe(&self) -> watch::Receiver<ReindexProgress> {
        self.progress.subscribe()
    }
}

/// Starts a run unless one is going on; returns whether it started one. A run interrupted
/// by a restart is resumed after its last model, with its counts.
pub fn start(app: &Arc<App>) -> bool {
    if app.reindex.active.swap(true, Ordering::SeqCst) {
        return false;
    }
    let total = app.stale_count();
    app.reindex.progress.send_modify(|p| {
        if p.state != ReindexState::Running {
            *p = ReindexProgress {
                state: ReindexState::Running,
                total,
                started_unix: Some(now_unix()),
                ..ReindexProgress::default()
            };
        }
    });
    tokio::spawn(run(app.clone()));
    true
}

async fn run(app: Arc<App>) {
    let claim = app
        .with_store(|store| {
            let Some(shared) = store.shared() else {
                return Ok(Some(None));
            };
            let claim = shared.try_lock(STATE_KEY)?;
            // Taken over from a replica that stopped: go on where it was.
            let stored = Reindexer::load(store)?.progress.borrow().clone();
            Ok(claim.map(|claim| Some((claim, stored))))
        })
        .await;
    let _claim = match claim {
        Ok(Some(claim)) => claim.map(|(claim, stored)| {
            if stored.state == ReindexState::Running {
                app.reindex.progress.send_replace(stored);
            }
            claim
        }),
        Ok(None) => {
            tracing::debug!("another replica is re-extracting");
            app.reindex.active.store(false, Ordering::SeqCst);
            return;
        }
        Err(error) => {
            tracing::error!(%error, "cannot claim the re-extraction");
            app.reindex.active.store(false, Ordering::SeqCst);
            return;
        }
    };
    tracing::info!("re-extraction started");
    loop {
        let last = app.reindex.progress.borrow().last_id.clone();
        let last = last.and_then(|id| ModelId::parse(&id).ok());
        let next = app
            .catalog
            .snapshot()
            .stale_after(last.as_ref())
            .next()
            .cloned();
        let Some(id) = next else { break };
        let outcome = reextract(&app, &id).await;
        let mut progress = app.reindex.progress.borrow().clone();
        progress.last_id = Some(id.to_string());
        match outcome {
            Ok(()) => progress.done += 1,
            Err(reason) => {
                progress.failed += 1;
                if progress.failures.len() < MAX_FAILURES_LISTED {
                    progress.failures.push(ReindexFailure {
                        id: id.to_string(),
                        reason,
                    });
                }
            }
        }
        publish(&app, progress).await;
    }
    let mut progress = app.reindex.progress.borrow().clone();
    progress.state = ReindexState::Finished;
    progress.finished_unix = Some(now_unix());
    tracing::info!(
        done = progress.done,
        failed = progress.failed,
        "re-extraction finished"
    );
    // Published before the run lets another start: a run started in between would take
    // this one's `last_id` as its own and skip the models before it.
    publish(&app, progress).await;
    app.reindex.active.store(false, Ordering::SeqCst);
}

/// Keeps the progress in the store, then shows it to readers: whoever sees a state can
/// count on a restart finding it. A failure to keep it only costs resumability, so it is
/// logged.
async fn publish(app: &Arc<App>, progress: ReindexProgress) {
    let bytes = serde_json::to_vec(&progress).expect("progress serialises");
    if let Err(error) = app
        .with_store(move |store| store.set_state(STATE_KEY, &bytes))
        .await
    {
        tracing::error!(%error, "cannot keep the re-extraction progress");
    }
    app.reindex.progress.send_replace(progress);
}

/// Re-extracts one model; the error is the reason shown in the progress.
async fn reextract(app: &Arc<App>, id: &ModelId) -> Result<(), String> {
    let hidden = |error: AppError| {
        tracing::error!(%id, %error, "re-extraction failed");
        error.public_message()
    };
    let key = id.clone();
    let Some(upload) = app
        .with_store(move |store| store.upload(key.as_str()))
        .await
        .map_err(hidden)?
    else {
        return Ok(()); // deleted meanwhile
    };
    let upload = Arc::new(upload);
    let params = app.config.params.clone();
    let job = upload.clone();
    let signature = app
        .pool
        .run_background(move || {
            // The original was accepted under the limits of its upload: re-extraction does
            // not apply today's, which may be lower.
            signature_of_file(
                &job.mesh,
                job.format,
                &job.resources,
                (&params, Extent::Full),
                &Limits::unlimited(),
            )
        })
        .await
        .map_err(hidden)?
        .map_err(|e| e.to_string())?;

    // Under the lock of edits of a model's fields: the record written is the current one,
    // not one another replica changed meanwhile.
    let _across = app
        .hold_shared(super::Across::Edits)
        .await
        .map_err(hidden)?;
    let _write = app.writes.lock().await;
    let Some(current) = app.catalog.snapshot().records.get(id).cloned() else {
        return Ok(()); // deleted while extracting
    };
    if current.content_hash != upload.content_hash() {
        return Ok(()); // replaced while extracting: the new upload has a new signature
    }
    let mut record = (*current).clone();
    record.describe(&signature);
    let (stored, bytes) = (record.clone(), signature.to_bytes());
    let held = app.catalog.hold(id, &signature, &bytes).map_err(hidden)?;
    let updated = app
        .with_store(move |store| store.update_model(&stored, &bytes))
        .await
        .map_err(hidden)?;
    if updated {
        app.catalog.put(record, held);
        // Its patches were made from the mesh as the old parameters prepared it.
        app.patcher.stored(id.clone());
    }
    Ok(())
}

fn progress_now(app: &App) -> ReindexProgress {
    let mut progress = app.reindex.progress.borrow().clone();
    progress.remaining = app.stale_count();
    progress
}

/// Start re-extracting every stale signature in the background (after an upgrade or a
/// change of extraction parameters); the old signatures serve until each is replaced. A run
/// already going on is left to go on.
#[utoipa::path(
    post,
    path = "/v1/admin/reindex",
    tag = "admin",
    responses(
        (status = 202, description = "Started", body = ReindexProgress),
        (status = 200, description = "Already running", body = ReindexProgress),
        (status = 500, description = "Internal error", body = ErrorBody)
    )
)]
pub async fn start_reindex(
    State(state): State<AppState>,
) -> Result<(StatusCode, Json<ReindexProgress>), AppError> {
    let status = if start(&state) {
        StatusCode::ACCEPTED
    } else {
        StatusCode::OK
    };
    Ok((status, Json(progress_now(&state))))
}

/// The progress of the current or last re-extraction.
#[utoipa::path(
    get,
    path = "/v1/admin/reindex",
    tag = "admin",
    responses((status = 200, description = "Progress", body = ReindexProgress))
)]
pub async fn get_reindex(State(state): State<AppState>) -> Json<ReindexProgress> {
    Json(progress_now(&state))
}

//! Online backup of a sled store (#37): a consistent snapshot of the running service's
//! catalogue, taken while uploads go on.
//!
//! Only the serving process can read its sled store (sled locks its folder), so the service
//! takes the snapshot itself, into a new store folder under
//! [`Config::backup_dir`](super::Config). It copies every model without stopping writes
//! ([`copy::copy_all`]), noting the models written meanwhile ([`Catalog::track_changes`]
//! (super::catalog::Catalog)); then, holding the write lock, it copies those again and the
//! state values. The snapshot is the catalogue as it stood at that moment, and `salient
//! restore` (or pointing `--data` at it) serves it. A PostgreSQL store is backed up with
//! `pg_dump` (README).

use std::path::{Path, PathBuf};
use std::time::Instant;

use axum::extract::State;
use axum::http::StatusCode;
use axum::Json;
use serde::Serialize;

use super::error::{AppError, ErrorBody};
use super::AppState;
use crate::store::copy::{self, Copied};
use crate::store::{SledStore, Store};

/// A backup written.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct Backup {
    /// Its folder's name in the server's backup folder.
    pub name: String,
    pub copied: Copied,
    pub seconds: f64,
}

/// Write a consistent snapshot of the store to the server's backup folder while the
/// service runs; writes wait only while the models written during the copy are copied
/// again.
#[utoipa::path(
    post,
    path = "/v1/admin/backup",
    tag = "admin",
    responses(
        (status = 201, description = "Written", body = Backup),
        (status = 409, description = "No backup folder is configured, or the store is PostgreSQL (use pg_dump)", body = ErrorBody),
        (status = 500, description = "Internal error", body = ErrorBody)
    )
)]
pub async fn backup(State(app): State<AppState>) -> Result<(StatusCode, Json<Backup>), AppError> {
    let Some(dir) = app.config.backup_dir.clone() else {
        return Err(AppError::NotConfigured(
            "this server has no backup folder: start it with --backup-dir DIR (SALIENT_BACKUP_DIR)"
                .into(),
        ));
    };
    if app.store.shared().is_some() {
        return Err(AppError::NotConfigured(
            "the store is PostgreSQL: back it up with pg_dump (README, \"Scaling past one machine\")"
                .into(),
        ));
    }
    let clock = Instant::now();
    // One at a time: each tracks the catalogue's changes.
    let _one = app.backup_gate.lock().await;
    let (name, path) = new_folder(&dir)?;
    app.catalog.track_changes();
    let first = {
        let (app, path) = (app.clone(), path.clone());
        tokio::task::spawn_blocking(move || {
            let to = SledStore::open(&path)?;
            copy::copy_all(app.store.as_ref(), &to, |_| {}).map(|copied| (to, copied))
        })
    };
    let result = async {
        let (to, mut copied) = first
            .await
            .map_err(|e| AppError::Internal(format!("backup failed: {e}")))??;
        if let Some(hook) = app.backup_hook.clone() {
            tokio::task::spawn_blocking(move || hook())
                .await
                .map_err(|e| AppError::Internal(format!("backup hook failed: {e}")))?;
        }
        let _write = app.writes.lock().await;
        let changed = app.catalog.changes();
        let app = app.clone();
        tokio::task::spawn_blocking(move || {
            for id in &changed {
                copy::copy_model(app.store.as_ref(), &to, id)?;
            }
            copied.models = to.len();
            copied.states = copy::copy_states(app.store.as_ref(), &to)?;
            Ok::<_, AppError>(copied)
        })
        .await
        .map_err(|e| AppError::Internal(format!("backup failed: {e}")))?
    }
    .await;
    // Stopped noting changes whatever happened.
    app.catalog.changes();
    match result {
        Ok(copied) => {
            tracing::info!(name, models = copied.models, "backup written");
            Ok((
                StatusCode::CREATED,
                Json(Backup {
                    name,
                    copied,
                    seconds: clock.elapsed().as_secs_f64(),
                }),
            ))
        }
        Err(e) => {
            // A partial snapshot is not left to be taken for a whole one.
            let _ = std::fs::remove_dir_all(&path);
            Err(e)
        }
    }
}

/// A new folder in `dir` named by the time (Unix seconds), numbered if one already has it.
fn new_folder(dir: &Path) -> Result<(String, PathBuf), AppError> {
    let hidden = |e: std::io::Error| AppError::Internal(format!("backup folder: {}", e.kind()));
    std::fs::create_dir_all(dir).map_err(hidden)?;
    let stamp = crate::model::now_unix();
    let mut n = 1;
    loop {
        let name = match n {
            1 => format!("salient-backup-{stamp}"),
            n => format!("salient-backup-{stamp}-{n}"),
        };
        let path = dir.join(&name);
        match std::fs::create_dir(&path) {
            Ok(()) => return Ok((name, path)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => n += 1,
            Err(e) => return Err(hidden(e)),
        }
    }
}

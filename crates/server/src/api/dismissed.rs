//! `/v1/duplicates/dismissed`: pairs an operator has said are not duplicates. A dismissal is
//! kept by the two models' content hashes, as verdicts are (`duplicates`): it is about the
//! two files, so it holds for any model holding either file and ends when a model is
//! replaced by another file. The groups of `GET /v1/duplicates` and the matches of
//! `/v1/duplicates/check` (and so `on_duplicate=reject`) leave dismissed pairs out.

use std::collections::BTreeMap;
use std::sync::RwLock;

use axum::extract::State;
use axum::http::StatusCode;
use axum::Json;
use serde::{Deserialize, Serialize};

use super::error::{AppError, ErrorBody};
use super::models::record_of;
use super::request::AppPath;
use super::AppState;
use crate::model::ModelId;
use crate::store::{Store, StoreError, StoreResult};

/// The store's state key of the dismissals.
pub(crate) const STATE_KEY: &str = "dismissed_duplicates";

/// A pair of models that are not duplicates, whatever the verification says.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Dismissal {
    /// The models the operator named, in id order.
    pub a: String,
    pub b: String,
    /// Their files' content hashes when dismissed: the dismissal holds for these two files.
    pub a_hash: String,
    pub b_hash: String,
}

impl Dismissal {
    /// The pair of content hashes, smaller first: the key of a dismissal.
    fn key(&self) -> (String, String) {
        ordered(&self.a_hash, &self.b_hash)
    }
}

fn ordered(x: &str, y: &str) -> (String, String) {
    let (x, y) = if x <= y { (x, y) } else { (y, x) };
    (x.to_string(), y.to_string())
}

/// Every dismissal, by its pair of hashes.
#[derive(Debug, Default)]
pub struct Dismissed(RwLock<BTreeMap<(String, String), Dismissal>>);

/// What `GET /v1/duplicates/dismissed` lists.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct DismissedList {
    /// In the order of their ids.
    pub dismissed: Vec<Dismissal>,
}

/// The two models of a dismissal's routes.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Path)]
pub struct PairPath {
    /// One model's id.
    #[param(pattern = "^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$")]
    pub a: String,
    /// The other's.
    #[param(pattern = "^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$")]
    pub b: String,
}

impl Dismissed {
    /// The dismissals the store keeps. Ones that cannot be read stop the start rather than
    /// being forgotten.
    pub fn load(store: &dyn Store) -> StoreResult<Self> {
        let Some(bytes) = store.state(STATE_KEY)? else {
            return Ok(Self::default());
        };
        let list: Vec<Dismissal> =
            serde_json::from_slice(&bytes).map_err(|e| StoreError::Corrupt {
                key: STATE_KEY.into(),
                message: e.to_string(),
            })?;
        Ok(Self(RwLock::new(
            list.into_iter().map(|d| (d.key(), d)).collect(),
        )))
    }

    /// Reads the dismissals again, as another replica changed them.
    pub fn reload(&self, store: &dyn Store) -> StoreResult<()> {
        let loaded = Self::load(store)?.0.into_inner().expect("never poisoned");
        *self.0.write().expect("never poisoned") = loaded;
        Ok(())
    }

    /// Whether the files with content hashes `x` and `y` were dismissed as a pair.
    pub fn contains(&self, x: &str, y: &str) -> bool {
        self.0
            .read()
            .expect("never poisoned")
            .contains_key(&ordered(x, y))
    }

    /// Every dismissal, in the order of their ids.
    fn list(&self) -> Vec<Dismissal> {
        let mut list: Vec<Dismissal> = self
            .0
            .read()
            .expect("never poisoned")
            .values()
            .cloned()
            .collect();
        list.sort_by(|x, y| (&x.a, &x.b).cmp(&(&y.a, &y.b)));
        list
    }
}

/// The dismissals after `change`, kept in the store before they are used (under the
/// service's write lock and, on a shared store, a lock of every replica's, so that two
/// changes do not overwrite each other).
async fn change(
    app: &AppState,
    change: impl FnOnce(&mut BTreeMap<(String, String), Dismissal>) -> bool,
) -> Result<bool, AppError> {
    // Another replica's change is seen and not overwritten.
    let _across = app.hold_shared(super::Across::Dismissed).await?;
    let _write = app.writes.lock().await;
    let mut next = app.dismissed.0.read().expect("never poisoned").clone();
    if !change(&mut next) {
        return Ok(false);
    }
    let bytes = serde_json::to_vec(&next.values().collect::<Vec<_>>()).expect("serialises");
    app.with_store(move |store| store.set_state(STATE_KEY, &bytes))
        .await?;
    *app.dismissed.0.write().expect("never poisoned") = next;
    Ok(true)
}

/// The two models a path names, in id order; they must differ.
fn pair(path: &PairPath) -> Result<(ModelId, ModelId), AppError> {
    let (a, b) = (ModelId::parse(&path.a)?, ModelId::parse(&path.b)?);
    match a.cmp(&b) {
        std::cmp::Ordering::Less => Ok((a, b)),
        std::cmp::Ordering::Greater => Ok((b, a)),
        std::cmp::Ordering::Equal => Err(AppError::bad_request(
            "invalid_path",
            "a model is not a duplicate of itself: name two models",
        )),
    }
}

/// Say that two stored models are not duplicates.
///
/// They leave each other's groups in `GET /v1/duplicates` and each other's matches in
/// `POST /v1/duplicates/check`; `on_duplicate=reject` no longer refuses one for the other.
/// The dismissal is of the two files: it ends when either model is replaced by another file.
#[utoipa::path(
    put,
    path = "/v1/duplicates/dismissed/{a}/{b}",
    tag = "duplicates",
    params(PairPath),
    responses(
        (status = 200, description = "Dismissed (again)", body = Dismissal),
        (status = 400, description = "Bad ids, one model twice, or two models holding the same file", body = ErrorBody),
        (status = 404, description = "No such model", body = ErrorBody)
    )
)]
pub async fn dismiss(
    State(app): State<AppState>,
    AppPath(path): AppPath<PairPath>,
) -> Result<Json<Dismissal>, AppError> {
    let (a, b) = pair(&path)?;
    let (ra, rb) = (record_of(&app, &a)?, record_of(&app, &b)?);
    if ra.content_hash == rb.content_hash {
        return Err(AppError::bad_request(
            "identical_file",
            "the two models hold the same file: delete one rather than dismiss the pair",
        ));
    }
    let dismissal = Dismissal {
        a: a.to_string(),
        b: b.to_string(),
        a_hash: ra.content_hash.clone(),
        b_hash: rb.content_hash.clone(),
    };
    let kept = dismissal.clone();
    change(&app, move |all| {
        all.insert(kept.key(), kept.clone()) != Some(kept)
    })
    .await?;
    Ok(Json(dismissal))
}

/// The pairs dismissed as not duplicates.
#[utoipa::path(
    get,
    path = "/v1/duplicates/dismissed",
    tag = "duplicates",
    responses((status = 200, description = "Every dismissal", body = DismissedList))
)]
pub async fn list_dismissed(State(app): State<AppState>) -> Json<DismissedList> {
    Json(DismissedList {
        dismissed: app.dismissed.list(),
    })
}

/// Take back a dismissal: the two models may be duplicates again.
///
/// Removes the dismissal of the two models' current files, and any made under these two ids.
#[utoipa::path(
    delete,
    path = "/v1/duplicates/dismissed/{a}/{b}",
    tag = "duplicates",
    params(PairPath),
    responses(
        (status = 204, description = "Taken back"),
        (status = 400, description = "Bad ids, or one model twice", body = ErrorBody),
        (status = 404, description = "No such dismissal", body = ErrorBody)
    )
)]
pub async fn undismiss(
    State(app): State<AppState>,
    AppPath(path): AppPath<PairPath>,
) -> Result<StatusCode, AppError> {
    let (a, b) = pair(&path)?;
    let hashes = match (record_of(&app, &a), record_of(&app, &b)) {
        (Ok(ra), Ok(rb)) => Some(ordered(&ra.content_hash, &rb.content_hash)),
        _ => None,
    };
    let (a, b) = (a.to_string(), b.to_string());
    let removed = change(&app, move |all| {
        let before = all.len();
        all.retain(|key, d| Some(key) != hashes.as_ref() && (&d.a, &d.b) != (&a, &b));
        all.len() != before
    })
    .await?;
    if removed {
        Ok(StatusCode::NO_CONTENT)
    } else {
        Err(AppError::NotFound(format!(
            "no dismissal of {:?} and {:?}",
            path.a, path.b
        )))
    }
}

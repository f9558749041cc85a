//! `/v1/models`: add, replace, list, get, delete, and a model's signature.

use std::sync::Arc;

use axum::extract::State;
use axum::http::StatusCode;
use axum::Json;
use serde::{Deserialize, Serialize};

use super::duplicates::duplicates_of;
use super::error::{AppError, ErrorBody};
use super::request::{page_size, AppJson, AppPath, AppQuery, ModelPath};
use super::upload::{MeshUpload, ModelFields, NewModel};
use super::AppState;
use crate::model::{ModelId, ModelRecord};
use salient_core::display::UpAxis;
use salient_core::duplicate::Evidence;
use salient_core::signature::Signature;

/// What to do when an upload duplicates a stored model.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum OnDuplicate {
    /// Store it anyway (`GET /v1/duplicates` lists it with its copies).
    #[default]
    Allow,
    /// Answer 409 `duplicate` with the stored model and the evidence, and store nothing.
    /// Mirror images are not rejected: a left part and its right counterpart are two assets.
    Reject,
}

/// Query of `POST /v1/models` besides the model's fields.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct AddQuery {
    /// `allow` (default) or `reject` an upload that duplicates another stored model (the same
    /// file, the same mesh in another format or unit, or the same shape rotated, rescaled or
    /// remeshed; see `POST /v1/duplicates/check`). Uploading again what a model already holds
    /// under its own id is never a duplicate.
    #[param(value_type = Option<String>, pattern = "^(allow|reject)$")]
    pub on_duplicate: Option<OnDuplicate>,
}

/// Add a model, or replace the model with the same id.
///
/// The body is the mesh itself (`Content-Type: model/obj`, `model/gltf-binary`,
/// `model/gltf+json`, `model/stl`, `model/ply`, `model/x-off`, or `application/octet-stream`
/// to sniff it) with the fields in the query string, or `multipart/form-data` with the mesh
/// file, any glTF resource files and the fields. Uploading content already stored under the
/// same id (same parameters) changes nothing; without an id, content already stored is found
/// by its hash and returned.
#[utoipa::path(
    post,
    path = "/v1/models",
    tag = "models",
    params(ModelFields, AddQuery),
    responses(
        (status = 201, description = "Added", body = ModelRecord),
        (status = 200, description = "Replaced, or already present", body = ModelRecord),
        (status = 400, description = "Bad id, fields or mesh file", body = ErrorBody),
        (status = 409, description = "A duplicate of a stored model, with `on_duplicate=reject`", body = ErrorBody),
        (status = 413, description = "Body or mesh over the limits", body = ErrorBody),
        (status = 415, description = "Unsupported format", body = ErrorBody),
        (status = 422, description = "Unusable mesh", body = ErrorBody),
        (status = 503, description = "Extraction queue full or time limit reached", body = ErrorBody)
    )
)]
pub async fn add_model(
    State(app): State<AppState>,
    AppQuery(q): AppQuery<AddQuery>,
    NewModel(upload): NewModel,
) -> Result<(StatusCode, Json<ModelRecord>), AppError> {
    let MeshUpload { upload, fields } = upload;
    let content_hash = upload.content_hash().to_string();
    let named = fields.id()?;
    let existing = {
        let hash = content_hash.clone();
        app.with_store(move |store| store.find_content(&hash))
            .await?
    };
    let id = named
        .clone()
        .or(existing)
        .unwrap_or_else(|| ModelId::from_content(&content_hash));
    let wanted = fields.fields()?;
    let snapshot = app.catalog.snapshot();
    if let Some(record) = snapshot.records.get(&id) {
        let unchanged = record.content_hash == content_hash
            && !snapshot.is_stale(&id)
            && (named.is_none() || record.fields() == wanted);
        if unchanged {
            return Ok((StatusCode::OK, Json(ModelRecord::clone(record))));
        }
    }
    drop(snapshot);

    let upload = Arc::new(upload);
    let signature = app.extract(upload.clone()).await?;
    let mut record = ModelRecord::new(id, wanted, &upload, &signature);
    let bytes = signature.to_bytes();
    let held = app.catalog.hold(&record.id, &signature, &bytes)?;

    let _gate = match q.on_duplicate.unwrap_or_default() {
        OnDuplicate::Allow => None,
        OnDuplicate::Reject => {
            if let Some(hook) = app.duplicate_hook.clone() {
                tokio::task::spawn_blocking(move || hook())
                    .await
                    .map_err(|e| AppError::Internal(format!("duplicate hook failed: {e}")))?;
            }
            let gate = app.duplicate_gate.lock().await;
            let across = app.hold_shared(super::Across::Duplicates).await?;
            let found =
                duplicates_of(&app, upload.clone(), signature, Some(record.id.clone())).await?;
            if let Some(first) = found
                .into_iter()
                .find(|m| m.evidence <= Evidence::SameShape)
            {
                return Err(AppError::Duplicate(first));
            }
            Some((gate, across))
        }
    };
    let _write = app.writes.lock().await;
    let (to_store, stored_upload) = (record.clone(), upload.clone());
    let previous = app
        .with_store(move |store| store.put(&to_store, &bytes, &stored_upload))
        .await?;
    if let Some(previous) = &previous {
        record.created_unix = previous.created_unix;
    }
    let models = app.catalog.put(record.clone(), held);
    app.set_model_count(models);
    // The upload is let go before the background patches read it again from the store: a
    // print file of hundreds of megabytes is not held twice.
    drop(upload);
    app.patcher.stored(record.id.clone());
    let status = if previous.is_some() {
        StatusCode::OK
    } else {
        StatusCode::CREATED
    };
    Ok((status, Json(record)))
}

/// Query of `GET /v1/models`.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ListQuery {
    /// Page size, 1–1000 (default 100).
    #[param(minimum = 1, maximum = 1000)]
    pub limit: Option<usize>,
    /// Return models with ids after this one (the `next` of the previous page).
    pub after: Option<String>,
    /// Only models with this tag.
    pub tag: Option<String>,
    /// Only models of this class.
    pub class: Option<String>,
    /// Only the model holding an upload with this SHA-256 content hash.
    pub content_hash: Option<String>,
}

/// A page of models.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ModelPage {
    pub models: Vec<ModelRecord>,
    /// Pass as `after` to get the next page; absent on the last page.
    pub next: Option<String>,
}

/// List models in id order, a page at a time.
#[utoipa::path(
    get,
    path = "/v1/models",
    tag = "models",
    params(ListQuery),
    responses(
        (status = 200, description = "A page of models", body = ModelPage),
        (status = 400, description = "Bad query", body = ErrorBody)
    )
)]
pub async fn list_models(
    State(app): State<AppState>,
    AppQuery(q): AppQuery<ListQuery>,
) -> Result<Json<ModelPage>, AppError> {
    let limit = page_size(q.limit)?;
    let snapshot = app.catalog.snapshot();
    let after = q.after.as_deref().unwrap_or("");
    let mut matching = snapshot
        .records
        .range::<_, str>((std::ops::Bound::Excluded(after), std::ops::Bound::Unbounded))
        .map(|(_, r)| r)
        .filter(|r| q.tag.as_ref().is_none_or(|t| r.tags.contains(t)))
        .filter(|r| q.class.as_ref().is_none_or(|c| r.class.as_ref() == Some(c)))
        .filter(|r| q.content_hash.as_ref().is_none_or(|h| &r.content_hash == h));
    let models: Vec<ModelRecord> = matching
        .by_ref()
        .take(limit)
        .map(|r| ModelRecord::clone(r))
        .collect();
    let next = if matching.next().is_some() {
        models.last().map(|m| m.id.to_string())
    } else {
        None
    };
    Ok(Json(ModelPage { models, next }))
}

/// The answer to a request for a model that is not there.
pub fn no_model(id: &ModelId) -> AppError {
    AppError::NotFound(format!("no model {:?}", id.as_str()))
}

/// The current record of `id`.
pub fn record_of(app: &AppState, id: &ModelId) -> Result<Arc<ModelRecord>, AppError> {
    let snapshot = app.catalog.snapshot();
    snapshot
        .records
        .get(id)
        .cloned()
        .ok_or_else(|| no_model(id))
}

/// Get a model's record.
#[utoipa::path(
    get,
    path = "/v1/models/{id}",
    tag = "models",
    params(ModelPath),
    responses(
        (status = 200, description = "The model", body = ModelRecord),
        (status = 400, description = "Invalid id", body = ErrorBody),
        (status = 404, description = "No such model", body = ErrorBody)
    )
)]
pub async fn get_model(
    State(app): State<AppState>,
    AppPath(path): AppPath<ModelPath>,
) -> Result<Json<ModelRecord>, AppError> {
    let record = record_of(&app, &path.id()?)?;
    Ok(Json(ModelRecord::clone(&record)))
}

/// Delete a model (its files go when no other model uses them).
#[utoipa::path(
    delete,
    path = "/v1/models/{id}",
    tag = "models",
    params(ModelPath),
    responses(
        (status = 204, description = "Deleted"),
        (status = 400, description = "Invalid id", body = ErrorBody),
        (status = 404, description = "No such model", body = ErrorBody)
    )
)]
pub async fn delete_model(
    State(app): State<AppState>,
    AppPath(path): AppPath<ModelPath>,
) -> Result<StatusCode, AppError> {
    let id = path.id()?;
    let _write = app.writes.lock().await;
    let key = id.clone();
    let removed = app
        .with_store(move |store| store.delete(key.as_str()))
        .await?;
    if removed.is_none() {
        return Err(no_model(&id));
    }
    let models = app.catalog.remove(&id);
    app.set_model_count(models);
    Ok(StatusCode::NO_CONTENT)
}

/// Get a model's signature: salient features, parameters, statistics (SPEC §4).
#[utoipa::path(
    get,
    path = "/v1/models/{id}/signature",
    tag = "models",
    params(ModelPath),
    responses(
        (status = 200, description = "The signature (see `salient extract --json`)", body = Object),
        (status = 400, description = "Invalid id", body = ErrorBody),
        (status = 404, description = "No such model", body = ErrorBody)
    )
)]
pub async fn get_signature(
    State(app): State<AppState>,
    AppPath(path): AppPath<ModelPath>,
) -> Result<Json<Arc<Signature>>, AppError> {
    let id = path.id()?;
    let stored = id.clone();
    let signature = app
        .with_store(move |store| store.decoded_signature(stored.as_str()))
        .await?
        .ok_or_else(|| no_model(&id))?;
    Ok(Json(Arc::new(signature)))
}

/// `null` and a value are different things in a patch: `null` clears, absent keeps.
fn present<'de, D: serde::Deserializer<'de>, T: Deserialize<'de>>(
    deserializer: D,
) -> Result<Option<T>, D::Error> {
    T::deserialize(deserializer).map(Some)
}

/// The fields `PATCH /v1/models/{id}` changes; those left out keep their value.
#[derive(Debug, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ModelPatch {
    /// A new name; `null` removes it.
    #[serde(default, deserialize_with = "present")]
    #[schema(value_type = Option<String>)]
    pub name: Option<Option<String>>,
    /// The new tags (all of them).
    pub tags: Option<Vec<String>>,
    /// A new class; `null` removes it.
    #[serde(default, deserialize_with = "present")]
    #[schema(value_type = Option<String>)]
    pub class: Option<Option<String>>,
    /// A new up axis, `y` or `z`; `null` returns to the format's (or the server's).
    #[serde(default, deserialize_with = "present")]
    #[schema(value_type = Option<String>)]
    pub up: Option<Option<UpAxis>>,
}

/// Change a model's name, tags, class or up axis. Its shape is untouched: nothing is
/// re-extracted.
#[utoipa::path(
    patch,
    path = "/v1/models/{id}",
    tag = "models",
    params(ModelPath),
    request_body(content = ModelPatch, content_type = "application/json"),
    responses(
        (status = 200, description = "The changed model", body = ModelRecord),
        (status = 400, description = "Invalid id or body", body = ErrorBody),
        (status = 404, description = "No such model", body = ErrorBody),
        (status = 415, description = "The body is not JSON", body = ErrorBody)
    )
)]
pub async fn patch_model(
    State(app): State<AppState>,
    AppPath(path): AppPath<ModelPath>,
    AppJson(body): AppJson<serde_json::Map<String, serde_json::Value>>,
) -> Result<Json<ModelRecord>, AppError> {
    let id = path.id()?;
    // Through a JSON object: serde would also read a struct from an array, by position.
    let patch: ModelPatch = serde_json::from_value(serde_json::Value::Object(body))
        .map_err(|e| AppError::bad_request("invalid_json", e.to_string()))?;
    // Another replica's edit of the same model is seen and not overwritten.
    let _across = app.hold_shared(super::Across::Edits).await?;
    let _write = app.writes.lock().await;
    let Some(mut record) = app
        .catalog
        .snapshot()
        .records
        .get(&id)
        .map(|r| ModelRecord::clone(r))
    else {
        return Err(no_model(&id));
    };
    if let Some(name) = patch.name {
        record.name = name;
    }
    if let Some(tags) = patch.tags {
        record.tags = tags
            .iter()
            .map(|t| t.trim().to_string())
            .filter(|t| !t.is_empty())
            .collect();
    }
    if let Some(class) = patch.class {
        record.class = class;
    }
    if let Some(up) = patch.up {
        record.up = up;
    }
    record.updated_unix = crate::model::now_unix();
    // The signature is rewritten as stored: the record and signature change together.
    let stored = record.clone();
    let updated = app
        .with_store(move |store| match store.signature(stored.id.as_str())? {
            Some(bytes) => store.update_model(&stored, &bytes),
            None => Ok(false),
        })
        .await?;
    if !updated {
        return Err(no_model(&id));
    }
    app.catalog.set_record(record.clone());
    Ok(Json(record))
}

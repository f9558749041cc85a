//! `/v1/models`: add, replace, list, get, delete, and a model's signature.

use std::sync::Arc;
use std::time::{SystemTime, UNIX_EPOCH};

use axum::extract::rejection::{PathRejection, QueryRejection};
use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::Json;
use serde::{Deserialize, Serialize};

use super::error::{AppError, ErrorBody};
use super::upload::{check_id, MeshFile, MeshForm, MeshUpload, ModelFields, ModelPath};
use super::AppState;
use crate::params::PARAMS_VERSION;
use crate::signature::Signature;
use crate::store::ModelRecord;

fn now() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
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
    params(ModelFields),
    request_body(description = "The mesh (raw) or a multipart form", content(
            (MeshFile = "model/obj"),
            (MeshFile = "model/gltf-binary"),
            (MeshFile = "model/gltf+json"),
            (MeshFile = "model/stl"),
            (MeshFile = "model/ply"),
            (MeshFile = "model/x-off"),
            (MeshFile = "application/octet-stream"),
            (MeshForm = "multipart/form-data")
        )),
    responses(
        (status = 201, description = "Added", body = ModelRecord),
        (status = 200, description = "Replaced, or already present", body = ModelRecord),
        (status = 400, description = "Bad id, fields or mesh file", body = ErrorBody),
        (status = 413, description = "Body or mesh over the limits", body = ErrorBody),
        (status = 415, description = "Unsupported format", body = ErrorBody),
        (status = 422, description = "Unusable mesh", body = ErrorBody),
        (status = 503, description = "Extraction queue full or time limit reached", body = ErrorBody)
    )
)]
pub async fn add_model(
    State(state): State<AppState>,
    upload: MeshUpload,
) -> Result<(StatusCode, Json<ModelRecord>), AppError> {
    let app = &state.0;
    let MeshUpload { upload, fields } = upload;
    let content_hash = upload.content_hash();
    let existing_id = app.store.find_content(&content_hash)?;
    let id = match (&fields.id, &existing_id) {
        (Some(id), _) => {
            check_id(id)?;
            id.clone()
        }
        (None, Some(existing)) => existing.clone(),
        (None, None) => content_hash[..16].to_string(),
    };
    let stored = app
        .catalog
        .read()
        .expect("catalog lock poisoned")
        .records
        .get(&id)
        .cloned();
    if let Some(record) = stored {
        let unchanged = record.content_hash == content_hash
            && record.params_version == PARAMS_VERSION
            && (fields.id.is_none()
                || (record.name == fields.name
                    && record.tags == fields.tag_list()
                    && record.class == fields.class));
        if unchanged {
            return Ok((StatusCode::OK, Json(record)));
        }
    }

    let upload = Arc::new(upload);
    let signature = app.extract(upload.clone()).await?;
    let (mesh_blob, resources) = upload.blobs();
    let stats = &signature.stats.extraction.mesh;
    let mut record = ModelRecord {
        id: id.clone(),
        name: fields.name.clone(),
        tags: fields.tag_list(),
        class: fields.class.clone(),
        content_hash,
        format: upload.format,
        mesh_blob,
        resources,
        vertices: stats.vertices,
        triangles: stats.triangles,
        features: signature.features.len(),
        params_version: PARAMS_VERSION,
        created_unix: now(),
        updated_unix: now(),
    };
    let bytes = signature.to_bytes();

    let _write = app.writes.lock().await;
    let store = app.store.clone();
    let (to_store, upload_owned) = (record.clone(), upload.clone());
    let previous = tokio::task::spawn_blocking(move || store.put(&to_store, &bytes, &upload_owned))
        .await
        .map_err(|e| AppError::Internal(e.to_string()))??;
    if let Some(previous) = &previous {
        record.created_unix = previous.created_unix;
    }
    {
        let mut catalog = app.catalog.write().expect("catalog lock poisoned");
        catalog.index.insert(id.clone(), signature);
        catalog.records.insert(id, record.clone());
        app.metrics.models.set(catalog.records.len() as i64);
    }
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
    State(state): State<AppState>,
    query: Result<Query<ListQuery>, QueryRejection>,
) -> Result<Json<ModelPage>, AppError> {
    let Query(q) = query?;
    let limit = q.limit.unwrap_or(100);
    if !(1..=1000).contains(&limit) {
        return Err(AppError::bad_request(
            "invalid_query",
            "limit must be between 1 and 1000",
        ));
    }
    let catalog = state.0.catalog.read().expect("catalog lock poisoned");
    let after = q.after.clone().unwrap_or_default();
    let mut matching = catalog
        .records
        .range::<String, _>((
            std::ops::Bound::Excluded(&after),
            std::ops::Bound::Unbounded,
        ))
        .map(|(_, r)| r)
        .filter(|r| q.tag.as_ref().is_none_or(|t| r.tags.contains(t)))
        .filter(|r| q.class.as_ref().is_none_or(|c| r.class.as_ref() == Some(c)))
        .filter(|r| q.content_hash.as_ref().is_none_or(|h| &r.content_hash == h));
    let models: Vec<ModelRecord> = matching.by_ref().take(limit).cloned().collect();
    let next = if matching.next().is_some() {
        models.last().map(|m| m.id.clone())
    } else {
        None
    };
    Ok(Json(ModelPage { models, next }))
}

fn record_of(state: &AppState, id: &str) -> Result<ModelRecord, AppError> {
    check_id(id)?;
    let catalog = state.0.catalog.read().expect("catalog lock poisoned");
    catalog
        .records
        .get(id)
        .cloned()
        .ok_or_else(|| AppError::NotFound(format!("no model {id:?}")))
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
    State(state): State<AppState>,
    id: Result<Path<ModelPath>, PathRejection>,
) -> Result<Json<ModelRecord>, AppError> {
    Ok(Json(record_of(&state, &id?.0.id)?))
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
    State(state): State<AppState>,
    id: Result<Path<ModelPath>, PathRejection>,
) -> Result<StatusCode, AppError> {
    let id = id?.0.id;
    check_id(&id)?;
    let app = &state.0;
    let _write = app.writes.lock().await;
    let store = app.store.clone();
    let key = id.clone();
    let removed = tokio::task::spawn_blocking(move || store.delete(&key))
        .await
        .map_err(|e| AppError::Internal(e.to_string()))??;
    if removed.is_none() {
        return Err(AppError::NotFound(format!("no model {id:?}")));
    }
    let mut catalog = app.catalog.write().expect("catalog lock poisoned");
    catalog.index.remove(&id);
    catalog.records.remove(&id);
    app.metrics.models.set(catalog.records.len() as i64);
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
    State(state): State<AppState>,
    id: Result<Path<ModelPath>, PathRejection>,
) -> Result<Json<Signature>, AppError> {
    let id = id?.0.id;
    record_of(&state, &id)?;
    let catalog = state.0.catalog.read().expect("catalog lock poisoned");
    catalog
        .index
        .get(&id)
        .cloned()
        .map(Json)
        .ok_or_else(|| AppError::NotFound(format!("no model {id:?}")))
}

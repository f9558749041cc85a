//! A model's original files, byte for byte: the mesh as uploaded, and the resources of a
//! multi-file glTF. Each answer carries the file's SHA-256 as its `ETag`, so a client that
//! has it already gets a 304.

use axum::body::Bytes;
use axum::extract::State;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;

use super::error::{AppError, ErrorBody};
use super::models::record_of;
use super::request::{AppPath, ModelPath};
use super::upload::MeshFile;
use super::AppState;

/// The `{id}` and `{name}` of a glTF resource route.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Path)]
pub struct ResourcePath {
    /// Model id.
    #[param(pattern = "^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$")]
    pub id: String,
    /// The resource's URI as the glTF document names it, percent-encoded (`/` as `%2F`).
    pub name: String,
}

/// A 304 when the request's `If-None-Match` names `etag` (a quoted strong tag of safe
/// characters): the client's copy is current.
pub(super) fn not_modified(request: &HeaderMap, etag: &str) -> Option<Response> {
    let cached = request
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|tags| tags.split(',').any(|t| t.trim() == etag || t.trim() == "*"));
    cached.then(|| {
        let etag = HeaderValue::from_str(etag).expect("an ETag of safe characters");
        (StatusCode::NOT_MODIFIED, [(header::ETAG, etag)]).into_response()
    })
}

/// Serves `hash`'s bytes from the store, or a 304 when the client holds them.
async fn serve(
    app: &AppState,
    hash: String,
    content_type: &str,
    file_name: &str,
    request: &HeaderMap,
) -> Result<Response, AppError> {
    let etag = format!("\"{hash}\"");
    if let Some(unchanged) = not_modified(request, &etag) {
        return Ok(unchanged);
    }
    let etag_header = HeaderValue::from_str(&etag).expect("hex is a valid header value");
    let bytes: Bytes = app
        .with_store(move |store| store.blob(&hash))
        .await?
        .ok_or_else(|| AppError::Internal("a model's file is missing from the store".into()))?;
    // Only safe characters in the header's quoted file name; ids and URIs are nearly so.
    let safe: String = file_name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "._-".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect();
    let disposition = HeaderValue::from_str(&format!("attachment; filename=\"{safe}\""))
        .expect("a sanitised file name is a valid header value");
    Ok((
        [
            (
                header::CONTENT_TYPE,
                HeaderValue::from_str(content_type).expect("a media type"),
            ),
            (header::ETAG, etag_header),
            (header::CONTENT_DISPOSITION, disposition),
            // The bytes under an id change when the model is replaced: revalidate each time.
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
        ],
        bytes,
    )
        .into_response())
}

/// The original mesh file, byte for byte, as it was uploaded.
#[utoipa::path(
    get,
    path = "/v1/models/{id}/file",
    tag = "models",
    params(ModelPath),
    responses(
        (status = 200, description = "The file; `ETag` is its SHA-256", content(
            (MeshFile = "model/obj"),
            (MeshFile = "model/gltf-binary"),
            (MeshFile = "model/gltf+json"),
            (MeshFile = "model/stl"),
            (MeshFile = "model/ply"),
            (MeshFile = "model/x-off")
        )),
        (status = 304, description = "The client's copy (`If-None-Match`) is current"),
        (status = 400, description = "Invalid id", body = ErrorBody),
        (status = 404, description = "No such model", body = ErrorBody)
    )
)]
pub async fn get_file(
    State(app): State<AppState>,
    AppPath(path): AppPath<ModelPath>,
    headers: HeaderMap,
) -> Result<Response, AppError> {
    let id = path.id()?;
    let record = record_of(&app, &id)?;
    let name = format!("{id}.{}", record.format.extension());
    let media_type = record.format.media_type();
    serve(&app, record.mesh_blob.clone(), media_type, &name, &headers).await
}

/// A resource of a multi-file glTF (a buffer or an image), byte for byte.
#[utoipa::path(
    get,
    path = "/v1/models/{id}/files/{name}",
    tag = "models",
    params(ResourcePath),
    responses(
        (status = 200, description = "The file; `ETag` is its SHA-256", body = MeshFile, content_type = "application/octet-stream"),
        (status = 304, description = "The client's copy (`If-None-Match`) is current"),
        (status = 400, description = "Invalid id", body = ErrorBody),
        (status = 404, description = "No such model, or no such resource", body = ErrorBody)
    )
)]
pub async fn get_resource(
    State(app): State<AppState>,
    AppPath(path): AppPath<ResourcePath>,
    headers: HeaderMap,
) -> Result<Response, AppError> {
    let id = ModelPath { id: path.id }.id()?;
    let record = record_of(&app, &id)?;
    let hash = record.resources.get(&path.name).cloned().ok_or_else(|| {
        AppError::NotFound(format!(
            "model {:?} has no resource {:?}",
            id.as_str(),
            path.name
        ))
    })?;
    let file_name = path.name.rsplit('/').next().unwrap_or(&path.name);
    serve(&app, hash, "application/octet-stream", file_name, &headers).await
}

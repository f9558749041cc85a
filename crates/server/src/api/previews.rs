//! What a person sees of a model (SPEC §8): its thumbnail, the mesh of the page's 3D
//! view, the same for an uploaded query, and a picture of two models with their matched
//! regions in the same colours.
//!
//! The costly part, a model's [`Preview`], is made on the extraction pool from the stored
//! upload and cached in the store under the key of what it was made from; pictures are drawn
//! from it per request (milliseconds) and cached by clients through their `ETag`.

use std::sync::Arc;

use axum::extract::State;
use axum::http::{header, HeaderMap, HeaderValue};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;

use super::error::{AppError, ErrorBody};
use super::files::not_modified;
use super::models::no_model;
use super::request::{AppPath, AppQuery, ModelPath};
use super::upload::{up_named, MeshFile, MeshUpload};
use super::AppState;
use crate::model::{up_axis, ModelId};
use crate::store::Derived;
use salient_core::display::UpAxis;
use salient_core::pipeline::{preview_of_file, Extent};
use salient_core::preview::Preview;
use salient_core::render::{comparison, png, thumbnail};
use salient_core::signature::Signature;
use salient_core::similarity::explain;

/// Sides of pictures, pixels.
const DEFAULT_SIZE: u32 = 256;
const MIN_SIZE: u32 = 16;
const MAX_SIZE: u32 = 1024;

const PNG: &str = "image/png";
const GLB: &str = "model/gltf-binary";

/// Query of a thumbnail.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ThumbnailQuery {
    /// Side in pixels (default 256).
    #[param(minimum = 16, maximum = 1024)]
    pub size: Option<u32>,
    /// Colour the salient regions and mark the salient points (default false).
    pub features: Option<bool>,
}

/// Query of a comparison picture.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct CompareQuery {
    /// Model ids: `a` on the left, its regions in their own colours; `b` on the right, each
    /// region in the colour of the region of `a` matched to it.
    #[param(pattern = "^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$")]
    pub a: String,
    #[param(pattern = "^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$")]
    pub b: String,
    /// Side of each model's half in pixels (default 256).
    #[param(minimum = 16, maximum = 1024)]
    pub size: Option<u32>,
}

/// Query of an uploaded mesh's preview.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct QueryPreviewQuery {
    /// Label the salient regions (default true; needs the query's extraction, which is
    /// cached for a while after a search with the same file).
    pub features: Option<bool>,
    /// The mesh's up axis, `y` or `z`: the preview turns it up. Default: its format's (glTF
    /// +y; 3MF, STL +z), else the server's `--up-axis`.
    pub up: Option<String>,
}

fn size_of(size: Option<u32>) -> Result<u32, AppError> {
    let size = size.unwrap_or(DEFAULT_SIZE);
    if (MIN_SIZE..=MAX_SIZE).contains(&size) {
        Ok(size)
    } else {
        Err(AppError::bad_request(
            "invalid_query",
            format!("size must be between {MIN_SIZE} and {MAX_SIZE}"),
        ))
    }
}

/// A stored model's signature and the key its preview is made under.
struct Source {
    id: ModelId,
    content_hash: String,
    /// The axis its pictures stand on ([`crate::model::ModelRecord::up_axis`]).
    up: UpAxis,
    signature: Arc<Signature>,
    key: [u8; 32],
}

impl Source {
    /// The model's record and signature, read together from the store (the index keeps no
    /// positions).
    async fn of(app: &AppState, id: ModelId) -> Result<Self, AppError> {
        let stored = id.clone();
        let found = app
            .with_store(move |store| {
                let record = store.get(stored.as_str())?;
                Ok(record.zip(store.decoded_signature(stored.as_str())?))
            })
            .await?;
        let (record, signature) = found.ok_or_else(|| no_model(&id))?;
        Ok(Source {
            key: Preview::key(&record.content_hash, &signature),
            up: record.up_axis(app.config.up_axis),
            content_hash: record.content_hash,
            signature: Arc::new(signature),
            id,
        })
    }

    /// An `ETag` naming this preview and a variant of what is drawn from it.
    fn etag(&self, variant: &str) -> String {
        format!("\"{}-{variant}\"", hex::encode(&self.key[..16]))
    }

    /// The model's preview: from the store's cache, or made from its upload and cached.
    async fn preview(&self, app: &AppState) -> Result<Arc<Preview>, AppError> {
        let id = self.id.clone();
        let cached = app
            .with_store(move |store| store.derived(Derived::Preview, id.as_str()))
            .await?;
        if let Some(preview) = cached.and_then(|e| Preview::from_cache_entry(&e, &self.key)) {
            return Ok(Arc::new(preview));
        }
        let id = self.id.clone();
        let upload = app
            .with_store(move |store| store.upload(id.as_str()))
            .await?
            .ok_or_else(|| no_model(&self.id))?;
        let (signature, limits) = (self.signature.clone(), app.config.limits);
        let preview = app
            .pool
            .run(move || {
                preview_of_file(
                    &upload.mesh,
                    upload.format,
                    &upload.resources,
                    (&signature.params, &signature.features),
                    &limits,
                )
            })
            .await??;
        let entry = preview.to_cache_entry(&self.key);
        let (id, content_hash) = (self.id.clone(), self.content_hash.clone());
        app.with_store(move |store| {
            store.put_derived(Derived::Preview, id.as_str(), &content_hash, &entry)
        })
        .await?;
        Ok(Arc::new(preview))
    }
}

/// `bytes` of `content_type`, with its `ETag`, revalidated on every use (the model under an
/// id can be replaced).
fn cacheable(content_type: &'static str, etag: &str, bytes: Vec<u8>) -> Response {
    (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(content_type)),
            (
                header::ETAG,
                HeaderValue::from_str(etag).expect("an ETag of hex digits"),
            ),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
        ],
        bytes,
    )
        .into_response()
}

/// A picture of the model: one shaded view, optionally with its salient regions.
#[utoipa::path(
    get,
    path = "/v1/models/{id}/thumbnail.png",
    tag = "models",
    params(ModelPath, ThumbnailQuery),
    responses(
        (status = 200, description = "The picture", content_type = "image/png", body = MeshFile),
        (status = 304, description = "The client's copy (`If-None-Match`) is current"),
        (status = 400, description = "Invalid id or size", body = ErrorBody),
        (status = 404, description = "No such model", body = ErrorBody),
        (status = 503, description = "Extraction queue full or time limit reached", body = ErrorBody)
    )
)]
pub async fn get_thumbnail(
    State(app): State<AppState>,
    AppPath(path): AppPath<ModelPath>,
    AppQuery(q): AppQuery<ThumbnailQuery>,
    headers: HeaderMap,
) -> Result<Response, AppError> {
    let size = size_of(q.size)?;
    let features = q.features.unwrap_or(false);
    let source = Source::of(&app, path.id()?).await?;
    let up = source.up;
    let etag = source.etag(&format!(
        "{size}{}{}",
        if features { "f" } else { "" },
        up.as_str()
    ));
    if let Some(unchanged) = not_modified(&headers, &etag) {
        return Ok(unchanged);
    }
    let preview = source.preview(&app).await?;
    let bytes = app
        .pool
        .run(move || png(&thumbnail(&preview, size, features, up)))
        .await?;
    Ok(cacheable(PNG, &etag, bytes))
}

/// The model as a compact binary glTF for a 3D view: at most 6 000 triangles in its own
/// coordinates, `COLOR_0` with the salient regions, `_REGION` (each vertex's feature index,
/// 65535 for none) and the salient points under `asset.extras.salient.points`.
#[utoipa::path(
    get,
    path = "/v1/models/{id}/preview.glb",
    tag = "models",
    params(ModelPath),
    responses(
        (status = 200, description = "The mesh", content_type = "model/gltf-binary", body = MeshFile),
        (status = 304, description = "The client's copy (`If-None-Match`) is current"),
        (status = 400, description = "Invalid id", body = ErrorBody),
        (status = 404, description = "No such model", body = ErrorBody),
        (status = 503, description = "Extraction queue full or time limit reached", body = ErrorBody)
    )
)]
pub async fn get_preview(
    State(app): State<AppState>,
    AppPath(path): AppPath<ModelPath>,
    headers: HeaderMap,
) -> Result<Response, AppError> {
    let source = Source::of(&app, path.id()?).await?;
    let up = source.up;
    let etag = source.etag(up.as_str());
    if let Some(unchanged) = not_modified(&headers, &etag) {
        return Ok(unchanged);
    }
    let glb = source.preview(&app).await?.to_glb(up);
    Ok(cacheable(GLB, &etag, glb))
}

/// The preview of an uploaded mesh, stored nowhere: the same layout as a model's
/// `preview.glb`, feature indices as in the search's explanation.
#[utoipa::path(
    post,
    path = "/v1/preview",
    tag = "search",
    params(QueryPreviewQuery),
    responses(
        (status = 200, description = "The mesh", content_type = "model/gltf-binary", body = MeshFile),
        (status = 400, description = "Bad mesh file", body = ErrorBody),
        (status = 413, description = "Body or mesh over the limits", body = ErrorBody),
        (status = 415, description = "Unsupported format", body = ErrorBody),
        (status = 422, description = "Unusable mesh", body = ErrorBody),
        (status = 503, description = "Extraction queue full or time limit reached", body = ErrorBody)
    )
)]
pub async fn query_preview(
    State(app): State<AppState>,
    AppQuery(q): AppQuery<QueryPreviewQuery>,
    upload: MeshUpload,
) -> Result<Response, AppError> {
    let chosen = up_named(q.up.as_deref())?.or(upload.fields.up()?);
    let up = up_axis(chosen, upload.upload.format, app.config.up_axis);
    let upload = Arc::new(upload.upload);
    // Without features: the mesh as the extraction would prepare it, no regions.
    let features = match q.features.unwrap_or(true) {
        true => app
            .extract_query(upload.clone(), Extent::Full)
            .await?
            .features
            .clone(),
        false => Vec::new(),
    };
    let (params, limits) = (app.config.params.clone(), app.config.limits);
    let glb = app
        .pool
        .run(move || {
            preview_of_file(
                &upload.mesh,
                upload.format,
                &upload.resources,
                (&params, &features),
                &limits,
            )
            .map(|p| p.to_glb(up))
        })
        .await??;
    Ok((
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(GLB)),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-store")),
        ],
        glb,
    )
        .into_response())
}

/// Two stored models side by side, matched regions in the same colours: the picture of the
/// explanation `explain=true` gives.
#[utoipa::path(
    get,
    path = "/v1/compare",
    tag = "search",
    params(CompareQuery),
    responses(
        (status = 200, description = "The picture", content_type = "image/png", body = MeshFile),
        (status = 304, description = "The client's copy (`If-None-Match`) is current"),
        (status = 400, description = "Invalid id or size", body = ErrorBody),
        (status = 404, description = "No such model", body = ErrorBody),
        (status = 503, description = "Extraction queue full or time limit reached", body = ErrorBody)
    )
)]
pub async fn compare(
    State(app): State<AppState>,
    AppQuery(q): AppQuery<CompareQuery>,
    headers: HeaderMap,
) -> Result<Response, AppError> {
    let size = size_of(q.size)?;
    let a = Source::of(&app, ModelId::parse(&q.a)?).await?;
    let b = Source::of(&app, ModelId::parse(&q.b)?).await?;
    let up = (a.up, b.up);
    let etag = format!(
        "\"{}-{}-{size}{}{}\"",
        hex::encode(&a.key[..12]),
        hex::encode(&b.key[..12]),
        up.0.as_str(),
        up.1.as_str()
    );
    if let Some(unchanged) = not_modified(&headers, &etag) {
        return Ok(unchanged);
    }
    let (pa, pb) = (a.preview(&app).await?, b.preview(&app).await?);
    let params = app.config.params.similarity.clone();
    let bytes = app
        .pool
        .run(move || {
            let (_, matches) = explain(&a.signature, &b.signature, &params);
            png(&comparison((&pa, &pb), &matches, size, up))
        })
        .await?;
    Ok(cacheable(PNG, &etag, bytes))
}

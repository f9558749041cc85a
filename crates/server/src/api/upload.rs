//! Mesh uploads, as a raw body with the mesh's content type or as `multipart/form-data`
//! (one mesh file, any glTF resources as further files, and the model's fields).

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, FromRequest, Multipart, Request};
use axum::http::header::{CONTENT_LENGTH, CONTENT_TYPE};
use http_body_util::BodyExt;
use serde::Deserialize;

use super::error::{AppError, BODY_LIMIT, UPLOAD_LIMIT};
use super::AppState;
use crate::model::{Fields, ModelId, Upload};
use crate::spool::{Body, CollectError, Collector};
use salient_core::display::UpAxis;
use salient_core::mesh::load::archive;
use salient_core::mesh::{self, Format};
use salient_core::Limits;

/// Descriptive fields of a model, from the query string or multipart fields.
#[derive(Debug, Clone, Default, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ModelFields {
    /// Model id: letters, digits, `.`, `_`, `-`, at most 128, not starting with `.`.
    /// Defaults to the first 16 hex digits of the content hash.
    #[param(pattern = "^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$")]
    pub id: Option<String>,
    pub name: Option<String>,
    /// Comma-separated tags.
    pub tags: Option<String>,
    pub class: Option<String>,
    /// The model's up axis, `y` or `z`, when its format's (glTF +y; 3MF, STL +z) or the
    /// server's `--up-axis` is not the right one. Turns pictures only.
    pub up: Option<String>,
    /// Format of a raw body when its content type does not say it
    /// (`obj`, `gltf`, `glb`, `off`, `ply`, `stl`, `3mf`, or `zip` for an archive of one mesh).
    pub format: Option<String>,
}

impl ModelFields {
    /// The model's id, if the upload names one.
    pub fn id(&self) -> Result<Option<ModelId>, AppError> {
        Ok(self.id.as_deref().map(ModelId::parse).transpose()?)
    }

    /// The up axis the upload names, if any.
    pub fn up(&self) -> Result<Option<UpAxis>, AppError> {
        up_named(self.up.as_deref())
    }

    /// The descriptive fields; tags trimmed, empty ones dropped.
    pub fn fields(&self) -> Result<Fields, AppError> {
        Ok(Fields {
            name: self.name.clone(),
            tags: self
                .tags
                .as_deref()
                .unwrap_or("")
                .split(',')
                .map(str::trim)
                .filter(|t| !t.is_empty())
                .map(String::from)
                .collect(),
            class: self.class.clone(),
            up: self.up()?,
        })
    }
}

/// The up axis an `up` parameter names: `y` or `z`.
pub fn up_named(name: Option<&str>) -> Result<Option<UpAxis>, AppError> {
    name.map(|name| {
        UpAxis::parse(name).ok_or_else(|| {
            AppError::bad_request(
                "invalid_parameter",
                format!("up must be `y` or `z`, not {name:?}"),
            )
        })
    })
    .transpose()
}

/// A mesh file in a request body (documentation type for the OpenAPI description).
#[derive(utoipa::ToSchema)]
#[schema(value_type = String, format = Binary)]
pub struct MeshFile(#[allow(dead_code)] Vec<u8>);

/// The multipart form of an upload (documentation type for the OpenAPI description).
#[derive(utoipa::ToSchema)]
#[allow(dead_code)]
pub struct MeshForm {
    /// The mesh file: OBJ, glTF/GLB (compressed with meshopt or Draco, instanced), OFF, PLY,
    /// STL, 3MF, or a zip of one of them (a `.gltf` with its buffers). Its format comes from
    /// `format`, else its file name's extension, else its content. Further files are a
    /// `.gltf`'s resources, matched by file name (or base name, when unambiguous).
    #[schema(value_type = String, format = Binary)]
    file: Vec<u8>,
    id: Option<String>,
    name: Option<String>,
    tags: Option<String>,
    class: Option<String>,
    up: Option<String>,
    format: Option<String>,
}

/// An upload and the fields that came inside it (multipart); query fields are merged by the
/// handler.
pub struct MeshUpload {
    pub upload: Upload,
    pub fields: ModelFields,
}

/// The format a `format=` field or a file name's extension names; a kind salient does not
/// read is refused with how to convert it.
fn format_named(name: &str, body: &[u8]) -> Result<Format, AppError> {
    let extension = name.rsplit('.').next().unwrap_or(name);
    Format::from_extension(extension).ok_or_else(|| match mesh::unsupported(body, Some(name)) {
        Some(error) => error.into(),
        None => AppError::UnsupportedMediaType(format!("unknown mesh format {name:?}")),
    })
}

/// The format of a body nothing names: its content's, or a kind salient does not read.
fn format_sniffed(body: &[u8]) -> Result<Format, AppError> {
    Format::sniff(body).ok_or_else(|| match mesh::unsupported(body, None) {
        Some(error) => error.into(),
        None => AppError::UnsupportedMediaType(
            "cannot tell the mesh format from the body; set Content-Type or ?format=".into(),
        ),
    })
}

/// Whether an upload is a zip archive of a mesh: named so (`format=zip`, a `.zip` file name, a
/// zip media type), or nothing names it and its content is one (and not a format that is a
/// zip package itself: 3MF, or a 3D application's own, [`mesh::unsupported`]).
fn is_archive(named: Option<&str>, media_type: &str, body: &[u8]) -> bool {
    let named = named.map(|n| n.rsplit('.').next().unwrap_or(n).to_ascii_lowercase());
    match named.as_deref() {
        Some("zip") => true,
        Some(_) => false,
        None => {
            matches!(
                media_type,
                "application/zip" | "application/x-zip-compressed"
            ) || (archive::is_zip(body)
                && Format::sniff(body) != Some(Format::ThreeMf)
                && mesh::unsupported(body, None).is_none())
        }
    }
}

/// A raw upload's body, refused past `limit`: in one buffer of its declared length (axum's
/// `Bytes` extractor gathers the chunks and then copies them into one buffer, which holds a
/// 200 MB print file twice), or past [`crate::spool::SPOOL_BYTES`] in a spool.
async fn body_bytes(request: Request, limit: usize, state: &AppState) -> Result<Body, AppError> {
    let declared = request
        .headers()
        .get(CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok()?.parse::<usize>().ok());
    if declared.is_some_and(|n| n > limit) {
        return Err(CollectError::TooLarge.into());
    }
    let mut collector = Collector::new(declared, limit, state.config.spool_dir().into());
    let mut body = request.into_body();
    while let Some(frame) = body.frame().await {
        let frame = frame.map_err(|e| AppError::bad_request("invalid_body", e.to_string()))?;
        if let Ok(data) = frame.into_data() {
            collector.push(&data).await?;
        }
    }
    Ok(collector.finish().await?)
}

/// The mesh and resources of a zip archive ([`archive::unpack`]), as an upload.
fn unpacked(body: &[u8], limits: &Limits) -> Result<Upload, AppError> {
    let unpacked = archive::unpack(body, limits)?;
    let resources = unpacked
        .resources
        .into_iter()
        .map(|(name, bytes)| (name, Bytes::from(bytes)))
        .collect();
    Ok(Upload::new(
        unpacked.format,
        Bytes::from(unpacked.mesh),
        resources,
    ))
}

/// A mesh upload that adds a model (`POST /v1/models`): its body may be as large as
/// `max_upload_bytes`, where every other upload (a search's query) is held to
/// `max_body_bytes`.
pub struct NewModel(pub MeshUpload);

impl FromRequest<AppState> for NewModel {
    type Rejection = AppError;

    async fn from_request(request: Request, state: &AppState) -> Result<Self, AppError> {
        let limit = state.config.max_upload_bytes;
        MeshUpload::read(request, state, limit)
            .await
            .map(NewModel)
            .map_err(|e| match e {
                // The body's limit is this route's: the count limits say their own.
                AppError::PayloadTooLarge(message) if message == BODY_LIMIT => {
                    AppError::PayloadTooLarge(UPLOAD_LIMIT.into())
                }
                e => e,
            })
    }
}

impl FromRequest<AppState> for MeshUpload {
    type Rejection = AppError;

    async fn from_request(request: Request, state: &AppState) -> Result<Self, AppError> {
        MeshUpload::read(request, state, state.config.max_body_bytes).await
    }
}

impl MeshUpload {
    /// Reads an upload whose body may take up to `body_limit` bytes.
    async fn read(
        mut request: Request,
        state: &AppState,
        body_limit: usize,
    ) -> Result<Self, AppError> {
        DefaultBodyLimit::max(body_limit).apply(&mut request);
        let limits = state.config.limits;
        let content_type = request
            .headers()
            .get(CONTENT_TYPE)
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string();
        let query: ModelFields = axum::extract::Query::<ModelFields>::try_from_uri(request.uri())
            .map(|q| q.0)
            .map_err(AppError::from)?;
        if content_type.starts_with("multipart/form-data") {
            let multipart = Multipart::from_request(request, state)
                .await
                .map_err(|r| AppError::bad_request("invalid_multipart", r.body_text()))?;
            return from_multipart(multipart, query, &limits, state.config.spool_dir().into())
                .await;
        }
        let Body { bytes: body, spool } = body_bytes(request, body_limit, state).await?;
        if body.is_empty() {
            return Err(AppError::bad_request(
                "empty_body",
                "the request has no mesh in its body",
            ));
        }
        let essence = content_type
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_lowercase();
        let fields = ModelFields {
            format: None,
            ..query.clone()
        };
        // `format` names the kind over the content type.
        let named = query.format.as_deref();
        if (named.is_some() || Format::from_content_type(&content_type).is_none())
            && is_archive(named, &essence, &body)
        {
            return Ok(MeshUpload {
                upload: unpacked(&body, &limits)?,
                fields,
            });
        }
        let format = match (&query.format, Format::from_content_type(&content_type)) {
            (Some(name), _) => format_named(name, &body)?,
            (None, Some(format)) => format,
            (None, None) if essence.is_empty() || essence == "application/octet-stream" => {
                format_sniffed(&body)?
            }
            (None, None) => {
                if let Some(error) = mesh::unsupported(&body, None) {
                    return Err(error.into());
                }
                return Err(AppError::UnsupportedMediaType(format!(
                    "unsupported content type {essence:?}; use model/obj, model/gltf-binary, model/gltf+json, model/stl, model/ply or model/x-off"
                )));
            }
        };
        Ok(MeshUpload {
            upload: Upload::new(format, body, BTreeMap::new()).in_spool(spool),
            fields,
        })
    }
}

/// Multipart: text fields `id`, `name`, `tags`, `class`, `up`, `format` (over those of the query
/// string); file fields are the mesh — the first whose file name has a mesh extension, else
/// the field named `file` whatever its file name (a browser's `FormData` names a Blob `blob`)
/// — and its resources (by file name). The mesh's format is `format`'s, else its file name's,
/// else its content's.
async fn from_multipart(
    mut multipart: Multipart,
    mut fields: ModelFields,
    limits: &Limits,
    spool_dir: Arc<Path>,
) -> Result<MeshUpload, AppError> {
    // Every file, in order: (field name, file name, body).
    let mut files: Vec<(String, String, Body)> = Vec::new();
    while let Some(mut field) = multipart.next_field().await? {
        let name = field.name().unwrap_or("").to_string();
        match (field.file_name().map(String::from), name.as_str()) {
            (None, "id" | "name" | "tags" | "class" | "up" | "format") => {
                let value = field.text().await?;
                let slot = match name.as_str() {
                    "id" => &mut fields.id,
                    "name" => &mut fields.name,
                    "tags" => &mut fields.tags,
                    "class" => &mut fields.class,
                    "up" => &mut fields.up,
                    _ => &mut fields.format,
                };
                *slot = Some(value);
            }
            (Some(file_name), _) => {
                let mut collector = Collector::new(None, usize::MAX, spool_dir.clone());
                while let Some(chunk) = field.chunk().await? {
                    collector.push(&chunk).await?;
                }
                files.push((name, file_name, collector.finish().await?));
            }
            (None, other) => {
                return Err(AppError::bad_request(
                    "invalid_multipart",
                    format!("unexpected field {other:?}"),
                ));
            }
        }
    }
    let named_mesh = |file_name: &str| Format::from_path(Path::new(file_name)).is_some();
    let chosen = files
        .iter()
        .position(|(_, file_name, _)| named_mesh(file_name))
        .or_else(|| files.iter().position(|(field, _, _)| field == "file"))
        .ok_or_else(|| {
            AppError::bad_request(
                "empty_body",
                "no mesh file in the form (a file with a mesh extension, or a file field named `file`)",
            )
        })?;
    let (_, file_name, Body { bytes: mesh, spool }) = files.remove(chosen);
    let format_field = fields.format.take();
    // The file name counts when it names a mesh or a zip, not when it is a browser's `blob`.
    let named = format_field.as_deref().or_else(|| {
        Path::new(&file_name)
            .extension()
            .and_then(|e| e.to_str())
            .filter(|e| e.eq_ignore_ascii_case("zip") || Format::from_extension(e).is_some())
    });
    if is_archive(named, "", &mesh) {
        return Ok(MeshUpload {
            upload: unpacked(&mesh, limits)?,
            fields,
        });
    }
    let resources: BTreeMap<String, Bytes> = files
        .into_iter()
        .map(|(_, file_name, body)| (file_name, body.bytes))
        .collect();
    let format = match format_field {
        Some(name) => format_named(&name, &mesh)?,
        None if named_mesh(&file_name) => format_named(&file_name, &mesh)?,
        None => match mesh::unsupported(&mesh, Some(&file_name)) {
            Some(error) => return Err(error.into()),
            None => format_sniffed(&mesh)?,
        },
    };
    Ok(MeshUpload {
        upload: Upload::new(format, mesh, resources).in_spool(spool),
        fields,
    })
}

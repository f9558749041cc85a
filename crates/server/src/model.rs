//! What a stored model is, apart from its shape: its id (the one rule for ids), its record,
//! and the files it was uploaded as. The store keeps these, the service and the ingest client
//! build them, and each rule about them lives here once.

use std::collections::BTreeMap;
use std::fmt;
use std::sync::Arc;

use bytes::Bytes;
use salient_core::display::UpAxis;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::spool::Spool;
use salient_core::mesh::Format;
use salient_core::signature::Signature;

/// Longest model id.
pub const MAX_ID_LEN: usize = 128;

/// A model id: 1–[`MAX_ID_LEN`] ASCII letters, digits, `.`, `_` or `-`, not starting with
/// `.`. Ids name store keys and appear in URLs and file names, so no separators and no
/// hidden-file names. Cheap to clone: the catalogue holds one per model in several maps.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct ModelId(Arc<str>);

/// A string that is not a valid [`ModelId`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "invalid model id {0:?}: use 1–128 letters, digits, '.', '_' or '-', not starting with '.'"
)]
pub struct InvalidId(pub String);

impl ModelId {
    /// Checks `id` against the rule.
    pub fn parse(id: &str) -> Result<Self, InvalidId> {
        if Self::is_valid_char_sequence(id) {
            Ok(Self(id.into()))
        } else {
            Err(InvalidId(id.to_string()))
        }
    }

    /// The id a model gets when its upload names none: the first 16 hex digits of its
    /// content hash.
    pub fn from_content(content_hash: &str) -> Self {
        Self(content_hash[..16].into())
    }

    /// Whether a character may appear in an id (`.` not first).
    pub fn allowed(c: char) -> bool {
        c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-')
    }

    fn is_valid_char_sequence(id: &str) -> bool {
        !id.is_empty()
            && id.len() <= MAX_ID_LEN
            && !id.starts_with('.')
            && id.chars().all(Self::allowed)
    }

    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl fmt::Display for ModelId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::borrow::Borrow<str> for ModelId {
    fn borrow(&self) -> &str {
        &self.0
    }
}

impl TryFrom<String> for ModelId {
    type Error = InvalidId;
    fn try_from(id: String) -> Result<Self, InvalidId> {
        Self::parse(&id)
    }
}

impl From<ModelId> for Arc<str> {
    fn from(id: ModelId) -> Arc<str> {
        id.0
    }
}

impl From<ModelId> for String {
    fn from(id: ModelId) -> String {
        id.0.to_string()
    }
}

/// Lower-case hex SHA-256, the name of a blob and of an upload's content.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

/// The files of an upload: a mesh and, for a `.gltf`, the resources it references. The
/// content hash is computed once, when the upload is made.
#[derive(Debug, Clone)]
pub struct Upload {
    pub format: Format,
    pub mesh: Bytes,
    /// glTF resources by the URI the document uses.
    pub resources: BTreeMap<String, Bytes>,
    content_hash: String,
    /// The file behind `mesh`, when its body was spooled.
    spool: Option<Spool>,
}

/// Uploads are equal when their files are (a spool is where the bytes are, not what).
impl PartialEq for Upload {
    fn eq(&self, other: &Self) -> bool {
        (self.format, &self.mesh, &self.resources) == (other.format, &other.mesh, &other.resources)
    }
}

impl Upload {
    pub fn new(format: Format, mesh: Bytes, resources: BTreeMap<String, Bytes>) -> Self {
        let mut hasher = Sha256::new();
        hasher.update(&mesh);
        for (uri, bytes) in &resources {
            hasher.update(uri.as_bytes());
            hasher.update(bytes);
        }
        let content_hash = hex::encode(hasher.finalize());
        Self {
            format,
            mesh,
            resources,
            content_hash,
            spool: None,
        }
    }

    /// This upload, whose mesh is the bytes of `spool` ([`crate::spool`]).
    pub fn in_spool(self, spool: Option<Spool>) -> Self {
        Self { spool, ..self }
    }

    /// Lets the pages of a spooled mesh go from resident memory (once it is loaded: the
    /// extraction that follows needs the memory more).
    pub fn release_pages(&self) {
        if let Some(spool) = &self.spool {
            spool.release_pages();
        }
    }

    /// A single-file upload.
    pub fn single(format: Format, mesh: impl Into<Bytes>) -> Self {
        Self::new(format, mesh.into(), BTreeMap::new())
    }

    /// SHA-256 over the mesh bytes, then each resource's URI and bytes in URI order. For a
    /// single file that is the plain SHA-256 of the file, which a client can compute itself.
    pub fn content_hash(&self) -> &str {
        &self.content_hash
    }

    /// Blob names of the mesh and of each resource, as a record stores them.
    pub fn blobs(&self) -> (String, BTreeMap<String, String>) {
        let resources: BTreeMap<String, String> = self
            .resources
            .iter()
            .map(|(uri, bytes)| (uri.clone(), sha256_hex(bytes)))
            .collect();
        // A single file's content hash is its SHA-256: not computed twice for a large one.
        let mesh = match resources.is_empty() {
            true => self.content_hash.clone(),
            false => sha256_hex(&self.mesh),
        };
        (mesh, resources)
    }
}

/// What the service knows about a stored model. Stored as JSON: a field added later needs
/// a `#[serde(default)]`, so that records written before it still read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ModelRecord {
    #[schema(value_type = String, pattern = "^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$")]
    pub id: ModelId,
    pub name: Option<String>,
    pub tags: Vec<String>,
    pub class: Option<String>,
    /// SHA-256 of the upload (the mesh file, then any glTF resources in name order):
    /// identical uploads have identical hashes.
    pub content_hash: String,
    #[schema(value_type = String, example = "obj")]
    pub format: Format,
    /// The model's up axis (`y` or `z`), set on upload or by `PATCH`; `null`: its format's
    /// (glTF +y; 3MF and STL +z), else the server's `--up-axis`. Turns pictures only.
    #[serde(default)]
    #[schema(value_type = Option<String>, example = "z")]
    pub up: Option<UpAxis>,
    /// SHA-256 of the mesh file's bytes in the blob store.
    pub mesh_blob: String,
    /// glTF resources (`uri` → blob SHA-256) uploaded with the mesh.
    pub resources: BTreeMap<String, String>,
    /// Vertices and triangles of the prepared mesh, and salient features found.
    pub vertices: usize,
    pub triangles: usize,
    pub features: usize,
    /// `PARAMS_VERSION` of the parameters the signature was made with.
    pub params_version: u32,
    /// Seconds since the Unix epoch.
    pub created_unix: u64,
    pub updated_unix: u64,
}

/// The descriptive fields a client gives a model.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Fields {
    pub name: Option<String>,
    pub tags: Vec<String>,
    pub class: Option<String>,
    pub up: Option<UpAxis>,
}

/// Seconds since the Unix epoch.
pub fn now_unix() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

impl ModelRecord {
    /// The record of `upload` stored under `id` with `signature`: the one place a record is
    /// made, for new models, replacements and re-extractions alike.
    pub fn new(id: ModelId, fields: Fields, upload: &Upload, signature: &Signature) -> Self {
        let (mesh_blob, resources) = upload.blobs();
        let now = now_unix();
        let mut record = Self {
            id,
            name: fields.name,
            tags: fields.tags,
            class: fields.class,
            content_hash: upload.content_hash().to_string(),
            format: upload.format,
            up: fields.up,
            mesh_blob,
            resources,
            vertices: 0,
            triangles: 0,
            features: 0,
            params_version: 0,
            created_unix: now,
            updated_unix: now,
        };
        record.describe(signature);
        record
    }

    /// Takes the counts and parameter version from a (new) signature of the same upload.
    pub fn describe(&mut self, signature: &Signature) {
        let stats = &signature.stats.extraction.mesh;
        self.vertices = stats.vertices;
        self.triangles = stats.triangles;
        self.features = signature.features.len();
        self.params_version = signature.params.version;
        self.updated_unix = now_unix();
    }

    pub fn fields(&self) -> Fields {
        Fields {
            name: self.name.clone(),
            tags: self.tags.clone(),
            class: self.class.clone(),
            up: self.up,
        }
    }

    /// The axis that points up in the model's pictures: its own, else its format's, else
    /// the server's default (SPEC §9: the one place this is decided).
    pub fn up_axis(&self, default: UpAxis) -> UpAxis {
        up_axis(self.up, self.format, default)
    }
}

/// The up axis of a mesh of `format`: `chosen`, else the format's, else `default`.
pub fn up_axis(chosen: Option<UpAxis>, format: Format, default: UpAxis) -> UpAxis {
    chosen
        .or_else(|| UpAxis::of_format(format))
        .unwrap_or(default)
}

//! Persistent storage of models: records, signatures and the original files (SPEC §8).
//!
//! Behind a small trait so that the backend can change; [`SledStore`] is the default, as the
//! product requires. Writes for one model are atomic and durable when they return: a model is
//! either fully present (record, signature, files) or absent.

mod sled_store;

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::mesh::Format;
use crate::signature::hex;

pub use sled_store::SledStore;

/// What the service knows about a stored model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ModelRecord {
    pub id: String,
    pub name: Option<String>,
    pub tags: Vec<String>,
    pub class: Option<String>,
    /// SHA-256 of the upload (the mesh file, then any glTF resources in name order):
    /// identical uploads have identical hashes.
    pub content_hash: String,
    #[schema(value_type = String, example = "obj")]
    pub format: Format,
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

/// A file of an upload.
#[derive(Debug, Clone, PartialEq)]
pub struct Upload {
    pub format: Format,
    pub mesh: Vec<u8>,
    /// glTF resources by the URI the document uses.
    pub resources: BTreeMap<String, Vec<u8>>,
}

/// Lower-case hex SHA-256, the name of a blob.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

impl Upload {
    /// Blob names of the mesh and of each resource, as a record stores them.
    pub fn blobs(&self) -> (String, BTreeMap<String, String>) {
        let resources = self
            .resources
            .iter()
            .map(|(uri, bytes)| (uri.clone(), sha256_hex(bytes)))
            .collect();
        (sha256_hex(&self.mesh), resources)
    }

    /// SHA-256 over the mesh bytes, then each resource's URI and bytes in URI order. For a
    /// single file that is the plain SHA-256 of the file, which a client can compute itself.
    pub fn content_hash(&self) -> String {
        let mut hasher = Sha256::new();
        hasher.update(&self.mesh);
        for (uri, bytes) in &self.resources {
            hasher.update(uri.as_bytes());
            hasher.update(bytes);
        }
        hex(&hasher.finalize())
    }
}

/// Errors of the storage layer.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("storage backend: {0}")]
    Backend(#[from] sled::Error),
    /// Stored bytes do not decode; the store is damaged.
    #[error("corrupt store entry {key}: {message}")]
    Corrupt { key: String, message: String },
    /// The store was written by a newer version of salient.
    #[error("the store has schema version {found}, this salient supports up to {supported}; upgrade salient")]
    Incompatible { found: u32, supported: u32 },
}

pub type StoreResult<T> = Result<T, StoreError>;

/// A stored model as the index needs it at start.
pub struct Loaded {
    pub record: ModelRecord,
    pub signature: Vec<u8>,
}

/// The storage operations the service uses.
pub trait Store: Send + Sync {
    /// Adds or replaces `record.id` with its signature and files, atomically and durably.
    /// Returns the replaced record, if any.
    fn put(
        &self,
        record: &ModelRecord,
        signature: &[u8],
        upload: &Upload,
    ) -> StoreResult<Option<ModelRecord>>;
    fn get(&self, id: &str) -> StoreResult<Option<ModelRecord>>;
    fn signature(&self, id: &str) -> StoreResult<Option<Vec<u8>>>;
    /// The original upload of a model, for re-extraction.
    fn upload(&self, id: &str) -> StoreResult<Option<Upload>>;
    /// Removes a model and the files no other model uses. Returns the removed record.
    fn delete(&self, id: &str) -> StoreResult<Option<ModelRecord>>;
    /// Records in id order, starting after `after`, at most `limit`.
    fn list(&self, after: Option<&str>, limit: usize) -> StoreResult<Vec<ModelRecord>>;
    /// The id of the model holding an upload with this content hash.
    fn find_content(&self, content_hash: &str) -> StoreResult<Option<String>>;
    /// Every model with its signature, in id order. Streamed: loading a large store holds one
    /// model's bytes at a time, not all of them (700 MB at 100 000 models).
    fn load_all(&self) -> Box<dyn Iterator<Item = StoreResult<Loaded>> + '_>;
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

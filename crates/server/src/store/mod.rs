//! Persistent storage of models: records, signatures and the original files (SPEC §8).
//!
//! Behind a small trait so that the backend can change; [`SledStore`] is the default, as the
//! product requires, [`PostgresStore`] is shared by replicas, and [`InMemoryStore`] serves
//! tests and trials. Writes for one model are atomic and durable when they return: a model is
//! either fully present (record, signature, files) or absent.

pub mod copy;
mod memory;
mod postgres;
mod sled_store;

use bytes::Bytes;

use crate::model::{ModelId, ModelRecord, Upload};
pub use memory::InMemoryStore;
pub use postgres::PostgresStore;
use salient_core::signature::Signature;
pub use sled_store::SledStore;

/// Errors of the storage layer.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("storage backend: {0}")]
    Backend(Box<dyn std::error::Error + Send + Sync>),
    /// The backend cannot be reached now (a database that is down or restarting): retry.
    #[error("storage unavailable: {0}")]
    Unavailable(Box<dyn std::error::Error + Send + Sync>),
    /// The store's settings (a connection string) cannot be used.
    #[error("storage configuration: {0}")]
    Config(String),
    /// A blob file could not be written or read.
    #[error("storage file: {0}")]
    File(#[from] std::io::Error),
    /// Stored bytes do not decode; the store is damaged.
    #[error("corrupt store entry {key}: {message}")]
    Corrupt { key: String, message: String },
    /// The store was written by a newer version of salient.
    #[error("the store has schema version {found}, this salient supports up to {supported}; upgrade salient")]
    Incompatible { found: u32, supported: u32 },
}

pub type StoreResult<T> = Result<T, StoreError>;

impl From<sled::Error> for StoreError {
    fn from(e: sled::Error) -> Self {
        StoreError::Backend(Box::new(e))
    }
}

/// The upload `record` names, its files read by `blob` (SHA-256 → bytes); a file the record
/// names but the store lacks means a damaged store.
fn assemble_upload(
    record: &ModelRecord,
    blob: impl Fn(&str) -> StoreResult<Option<Bytes>>,
) -> StoreResult<Upload> {
    let read = |hash: &str| {
        blob(hash)?.ok_or_else(|| StoreError::Corrupt {
            key: hash.to_string(),
            message: format!("blob of model {} missing", record.id),
        })
    };
    let resources = record
        .resources
        .iter()
        .map(|(uri, hash)| Ok((uri.clone(), read(hash)?)))
        .collect::<StoreResult<_>>()?;
    Ok(Upload::new(
        record.format,
        read(&record.mesh_blob)?,
        resources,
    ))
}

/// Every blob of a record: the mesh, then its resources.
fn blob_hashes(record: &ModelRecord) -> impl Iterator<Item = &str> {
    std::iter::once(record.mesh_blob.as_str()).chain(record.resources.values().map(String::as_str))
}

/// The files of `upload` with their SHA-256 (the blobs `record` names): the mesh, then its
/// resources.
fn upload_files<'a>(
    record: &ModelRecord,
    upload: &'a Upload,
) -> impl Iterator<Item = (String, &'a Bytes)> + 'a {
    std::iter::once((record.mesh_blob.clone(), &upload.mesh)).chain(
        upload
            .resources
            .values()
            .map(|bytes| (crate::model::sha256_hex(bytes), bytes)),
    )
}

/// Data made from a model's upload and kept beside it, bound to its content: made again
/// whenever missing, removed with the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Derived {
    /// What a person sees of it (`salient_core::preview`).
    Preview,
    /// What a partial search picks its candidates by (`salient_core::descriptor::patch::Packed`).
    Patches,
}

impl Derived {
    pub const ALL: [Derived; 2] = [Derived::Preview, Derived::Patches];
}

/// A stored model as the index needs it at start.
pub struct Loaded {
    pub record: ModelRecord,
    pub signature: Vec<u8>,
}

/// What changed at a position of a shared store's log ([`Shared`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Change {
    /// A model was stored, re-described or deleted: read it again.
    Model(ModelId),
    /// A [`Store::set_state`] key was written.
    State(String),
}

/// Changes read from a shared store's log ([`Shared::changes_after`]).
#[derive(Debug)]
pub enum Changes {
    /// The next changes in commit order, each with its position (none when caught up).
    Next(Vec<(u64, Change)>),
    /// The log no longer holds the change after the position asked for (it was trimmed):
    /// the reader must load the whole store again.
    Trimmed,
}

/// What a store shared by several processes offers beyond [`Store`] (#37), and sled never
/// needed: the log of changes in commit order that replicas follow to stay in step, and
/// locks that hold across processes.
pub trait Shared: Send + Sync {
    /// The position of the last committed change (0 for none).
    fn head(&self) -> StoreResult<u64>;
    /// At most `limit` changes after `position`, in commit order.
    fn changes_after(&self, position: u64, limit: usize) -> StoreResult<Changes>;
    /// Told, with the position when known, each time a change may have been committed since
    /// (a notification, or a reconnection after which some may have been missed).
    fn subscribe(&self) -> tokio::sync::watch::Receiver<u64>;
    /// Whether the store answers (its listening connection is up), as it changes.
    fn connected(&self) -> tokio::sync::watch::Receiver<bool>;
    /// How often this process lost its connection to the store and made it again.
    fn reconnections(&self) -> u64;
    /// The position of the last change this process committed (0 for none).
    fn written(&self) -> u64;
    /// Removes changes older than `age` from the log (not the last one).
    fn trim(&self, age: std::time::Duration) -> StoreResult<u64>;
    /// Holds the lock `name` for every process on the store until the guard is dropped.
    fn lock(&self, name: &str) -> StoreResult<Box<dyn Send>>;
    /// [`Shared::lock`] if no process holds it now, else `None`: a claim on work that one
    /// process does at a time, released when the guard is dropped or the process dies.
    fn try_lock(&self, name: &str) -> StoreResult<Option<Box<dyn Send>>>;
}

/// How a store makes what a first stage kept in the database holds of each model (#40): one
/// vector of `dimensions` and the model's compact form ([`Kept`]) from its stored signature
/// (`None`: the model has none, as a stale signature), made for the ranking parameters `key`
/// names.
#[derive(Clone)]
pub struct VectorSpec {
    pub dimensions: usize,
    pub key: String,
    pub vector: VectorOf,
}

/// What a first stage keeps of a model: its vector; what the exact ranking of the candidates
/// reads of it but the light field descriptor ([`salient_core::rank::compact`]), returned with
/// it; and that descriptor packed as the in-memory index shelves it, which the ranking reads
/// for the candidates its bounds leave.
pub struct Kept {
    pub vector: Vec<f32>,
    pub compact: Vec<u8>,
    pub light_field: Vec<u8>,
}

/// [`Kept`] from a stored signature's bytes ([`VectorSpec`]).
pub type VectorOf = std::sync::Arc<dyn Fn(&[u8]) -> Option<Kept> + Send + Sync>;

/// A model a first stage found, in its compact form.
pub struct Candidate {
    pub id: ModelId,
    pub compact: Vec<u8>,
}

/// A first stage of ranking kept in the store (pgvector's HNSW index, #40): the models
/// nearest a vector by L1 distance, approximately.
pub trait FirstStage: Send + Sync {
    /// About the `count` models nearest `vector` that have `tag` (any model when `None`),
    /// `without` left out, each in its compact form, in one round trip.
    fn nearest(
        &self,
        vector: &[f32],
        count: usize,
        tag: Option<&str>,
        without: Option<&str>,
    ) -> StoreResult<Vec<Candidate>>;

    /// The compact forms of the models `ids` that have one, in one round trip: the
    /// candidates a caller chose itself (a partial search's, by their patches).
    fn compacts(&self, ids: &[&str]) -> StoreResult<Vec<Candidate>>;

    /// The packed light field descriptors ([`Kept::light_field`]) of the models `ids` that
    /// have one, in one round trip: the second round of a ranking, for the candidates the
    /// compact forms' bounds leave.
    fn light_fields(&self, ids: &[&str]) -> StoreResult<Vec<(ModelId, Vec<u8>)>>;
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
    /// Replaces the record and signature of `record.id` if the model still holds the upload
    /// `record.content_hash` names (a re-extraction, an edit of its fields), atomically and
    /// durably. Returns false, changing nothing, when the model was deleted or replaced
    /// meanwhile.
    fn update_model(&self, record: &ModelRecord, signature: &[u8]) -> StoreResult<bool>;
    fn get(&self, id: &str) -> StoreResult<Option<ModelRecord>>;
    fn signature(&self, id: &str) -> StoreResult<Option<Vec<u8>>>;
    /// [`Store::signature`] decoded: what a response shows of a model's features (the
    /// ranking index keeps only what it compares).
    fn decoded_signature(&self, id: &str) -> StoreResult<Option<Signature>> {
        self.signature(id)?
            .map(|bytes| {
                Signature::from_bytes(&bytes).map_err(|e| StoreError::Corrupt {
                    key: id.to_string(),
                    message: e.to_string(),
                })
            })
            .transpose()
    }
    /// A model's record and signature, as one read where the backend can.
    fn model(&self, id: &str) -> StoreResult<Option<Loaded>> {
        let Some(record) = self.get(id)? else {
            return Ok(None);
        };
        Ok(self
            .signature(id)?
            .map(|signature| Loaded { record, signature }))
    }
    /// The original upload of a model, for re-extraction.
    fn upload(&self, id: &str) -> StoreResult<Option<Upload>>;
    /// One stored file by its SHA-256 (a record's `mesh_blob` or one of its `resources`).
    fn blob(&self, hash: &str) -> StoreResult<Option<Bytes>>;
    /// Removes a model and the files no other model uses. Returns the removed record.
    fn delete(&self, id: &str) -> StoreResult<Option<ModelRecord>>;
    /// Records in id order, starting after `after`, at most `limit`.
    fn list(&self, after: Option<&str>, limit: usize) -> StoreResult<Vec<ModelRecord>>;
    /// The id of the model holding an upload with this content hash.
    fn find_content(&self, content_hash: &str) -> StoreResult<Option<ModelId>>;
    /// Every model with its signature, in id order. Streamed: loading a large store holds one
    /// model's bytes at a time, not all of them (700 MB at 100 000 models).
    fn load_all(&self) -> Box<dyn Iterator<Item = StoreResult<Loaded>> + '_>;
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// A model's entry of a derived cache, as [`Store::put_derived`] stored it.
    fn derived(&self, cache: Derived, id: &str) -> StoreResult<Option<Vec<u8>>>;
    /// Keeps `entry` in a derived cache for `id` if the model still holds the upload
    /// `content_hash`; a model deleted or replaced meanwhile gets none (returns false). Not
    /// flushed: an entry lost in a crash is made again. The entry goes with the model when it
    /// is deleted or replaced.
    fn put_derived(
        &self,
        cache: Derived,
        id: &str,
        content_hash: &str,
        entry: &[u8],
    ) -> StoreResult<bool>;
    /// Every entry of a derived cache, in id order.
    fn all_derived(
        &self,
        cache: Derived,
    ) -> Box<dyn Iterator<Item = StoreResult<(ModelId, Vec<u8>)>> + '_>;
    /// The models whose entry in a derived cache begins with `prefix` (its layout), in id
    /// order. A count of what is made, which on a shared store reads ids rather than every
    /// entry (720 MB of patches at 100 000 models).
    fn derived_ids(
        &self,
        cache: Derived,
        prefix: &[u8],
    ) -> Box<dyn Iterator<Item = StoreResult<ModelId>> + '_> {
        let prefix = prefix.to_vec();
        Box::new(
            self.all_derived(cache)
                .filter_map(move |entry| match entry {
                    Ok((id, bytes)) => bytes.starts_with(&prefix).then_some(Ok(id)),
                    Err(e) => Some(Err(e)),
                }),
        )
    }
    /// A small value the service keeps between runs (the progress of a re-extraction).
    fn state(&self, key: &str) -> StoreResult<Option<Vec<u8>>>;
    fn set_state(&self, key: &str, value: &[u8]) -> StoreResult<()>;
    /// Every state value, by key.
    fn states(&self) -> StoreResult<Vec<(String, Vec<u8>)>>;
    /// The log and locks of a store that other processes share, if it is one.
    fn shared(&self) -> Option<&dyn Shared> {
        None
    }
    /// The first stage the store keeps, if it keeps one.
    fn first_stage(&self) -> Option<&dyn FirstStage> {
        None
    }
}

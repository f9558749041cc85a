//! The sled backend.
//!
//! sled 0.34 is the last stable release. Durability: every write is one multi-tree
//! transaction followed by `flush()`, so an acknowledged model survives a crash; an
//! interrupted write leaves nothing (see `tests/durability.rs`, which kills the server
//! mid-ingest).

use std::path::Path;

use sled::transaction::{ConflictableTransactionError, TransactionalTree};
use sled::Transactional;

use super::{Derived, Loaded, StoreError, StoreResult};
use crate::model::{sha256_hex, ModelId, ModelRecord, Upload};

#[path = "../../../../migrations/mod.rs"]
mod migrations;

/// Schema version this code writes (the newest migration).
pub fn schema_version() -> u32 {
    migrations::MIGRATIONS.last().map_or(0, |m| m.version)
}

const VERSION_KEY: &[u8] = b"schema_version";

/// A sled database with the trees of `migrations/`.
pub struct SledStore {
    db: sled::Db,
    models: sled::Tree,
    signatures: sled::Tree,
    blobs: sled::Tree,
    blob_refs: sled::Tree,
    content: sled::Tree,
    state: sled::Tree,
    previews: sled::Tree,
    patches: sled::Tree,
}

fn corrupt(key: &[u8], message: impl ToString) -> StoreError {
    StoreError::Corrupt {
        key: String::from_utf8_lossy(key).into_owned(),
        message: message.to_string(),
    }
}

fn decode_record(key: &[u8], bytes: &[u8]) -> StoreResult<ModelRecord> {
    serde_json::from_slice(bytes).map_err(|e| corrupt(key, e))
}

/// A failed transaction: our own abort, or the backend's error.
fn transaction_error(e: sled::transaction::TransactionError<StoreError>) -> StoreError {
    match e {
        sled::transaction::TransactionError::Abort(e) => e,
        sled::transaction::TransactionError::Storage(e) => StoreError::Backend(e),
    }
}

fn count(bytes: Option<sled::IVec>) -> u64 {
    bytes
        .and_then(|b| <[u8; 8]>::try_from(b.as_ref()).ok())
        .map_or(0, u64::from_be_bytes)
}

/// sled's page cache. The service ranks from its own in-memory index and reads the store for
/// single records, so sled's default (1 GiB, filled by the start-up scan of every signature)
/// would only add to the resident size (measured at 100 000 models: 2 215 MiB with it, 1 904
/// MiB with this cap).
const CACHE_BYTES: u64 = 64 << 20;

impl SledStore {
    /// Opens (creating if needed) the store in `dir` and brings its schema up to date.
    pub fn open(dir: &Path) -> StoreResult<Self> {
        let db = sled::Config::new()
            .path(dir)
            .cache_capacity(CACHE_BYTES)
            .open()?;
        Self::migrate(&db)?;
        Ok(Self {
            models: db.open_tree("models")?,
            signatures: db.open_tree("signatures")?,
            blobs: db.open_tree("blobs")?,
            blob_refs: db.open_tree("blob_refs")?,
            content: db.open_tree("content")?,
            state: db.open_tree("state")?,
            previews: db.open_tree("previews")?,
            patches: db.open_tree("patches")?,
            db,
        })
    }

    /// The schema version recorded in the store (0 for a new store).
    pub fn stored_version(db: &sled::Db) -> StoreResult<u32> {
        Ok(match db.get(VERSION_KEY)? {
            None => 0,
            Some(v) => u32::from_be_bytes(
                v.as_ref()
                    .try_into()
                    .map_err(|_| corrupt(VERSION_KEY, "not a u32"))?,
            ),
        })
    }

    fn migrate(db: &sled::Db) -> StoreResult<()> {
        let found = Self::stored_version(db)?;
        let supported = schema_version();
        if found > supported {
            return Err(StoreError::Incompatible { found, supported });
        }
        for migration in migrations::MIGRATIONS.iter().filter(|m| m.version > found) {
            tracing::info!(
                version = migration.version,
                name = migration.name,
                "migrating store"
            );
            (migration.apply)(db)?;
            db.insert(VERSION_KEY, &migration.version.to_be_bytes())?;
            db.flush()?;
        }
        Ok(())
    }

    fn tree(&self, cache: Derived) -> &sled::Tree {
        match cache {
            Derived::Preview => &self.previews,
            Derived::Patches => &self.patches,
        }
    }

    /// The underlying database (tests write older fixture versions through it).
    pub fn db(&self) -> &sled::Db {
        &self.db
    }
}

/// Adds one reference to a blob, storing its bytes on the first.
fn add_blob(
    blobs: &TransactionalTree,
    refs: &TransactionalTree,
    hash: &str,
    bytes: &[u8],
) -> Result<(), ConflictableTransactionError<StoreError>> {
    let n = count(refs.get(hash)?);
    if n == 0 {
        blobs.insert(hash, bytes)?;
    }
    refs.insert(hash, &(n + 1).to_be_bytes())?;
    Ok(())
}

/// Drops one reference to a blob, removing it with the last.
fn release_blob(
    blobs: &TransactionalTree,
    refs: &TransactionalTree,
    hash: &str,
) -> Result<(), ConflictableTransactionError<StoreError>> {
    match count(refs.get(hash)?) {
        0 | 1 => {
            refs.remove(hash)?;
            blobs.remove(hash)?;
        }
        n => {
            refs.insert(hash, &(n - 1).to_be_bytes())?;
        }
    }
    Ok(())
}

/// Every blob of a record: the mesh, then its resources.
fn blob_hashes(record: &ModelRecord) -> impl Iterator<Item = &str> {
    std::iter::once(record.mesh_blob.as_str()).chain(record.resources.values().map(String::as_str))
}

/// The trees a write of a whole model changes, in a transaction: models, signatures, blobs,
/// blob references, content, previews, patches.
type ModelTrees = (
    TransactionalTree,
    TransactionalTree,
    TransactionalTree,
    TransactionalTree,
    TransactionalTree,
    TransactionalTree,
    TransactionalTree,
);

/// Removes `old` from the trees of a transaction.
fn unlink(
    trees: &ModelTrees,
    old: &ModelRecord,
) -> Result<(), ConflictableTransactionError<StoreError>> {
    let (models, signatures, blobs, refs, content, previews, patches) = trees;
    for tree in [models, signatures, previews, patches] {
        tree.remove(old.id.as_str().as_bytes())?;
    }
    for hash in blob_hashes(old) {
        release_blob(blobs, refs, hash)?;
    }
    if content.get(&old.content_hash)?.as_deref() == Some(old.id.as_str().as_bytes()) {
        content.remove(old.content_hash.as_bytes())?;
    }
    Ok(())
}

impl super::Store for SledStore {
    fn put(
        &self,
        record: &ModelRecord,
        signature: &[u8],
        upload: &Upload,
    ) -> StoreResult<Option<ModelRecord>> {
        let encoded = serde_json::to_vec(record).expect("records serialise");
        let files: Vec<(String, &[u8])> =
            std::iter::once((record.mesh_blob.clone(), &upload.mesh[..]))
                .chain(
                    upload
                        .resources
                        .values()
                        .map(|bytes| (sha256_hex(bytes), &bytes[..])),
                )
                .collect();
        let trees = (
            &self.models,
            &self.signatures,
            &self.blobs,
            &self.blob_refs,
            &self.content,
            &self.previews,
            &self.patches,
        );
        let previous = trees
            .transaction(|view| {
                let (models, signatures, blobs, refs, content, _, _) = view;
                let previous = match models.get(record.id.as_str().as_bytes())? {
                    Some(bytes) => {
                        let old = decode_record(record.id.as_str().as_bytes(), &bytes)
                            .map_err(ConflictableTransactionError::Abort)?;
                        unlink(view, &old)?;
                        Some(old)
                    }
                    None => None,
                };
                for (hash, bytes) in &files {
                    add_blob(blobs, refs, hash, bytes)?;
                }
                models.insert(record.id.as_str().as_bytes(), encoded.as_slice())?;
                signatures.insert(record.id.as_str().as_bytes(), signature)?;
                content.insert(
                    record.content_hash.as_bytes(),
                    record.id.as_str().as_bytes(),
                )?;
                Ok(previous)
            })
            .map_err(transaction_error)?;
        self.db.flush()?;
        Ok(previous)
    }

    fn update_model(&self, record: &ModelRecord, signature: &[u8]) -> StoreResult<bool> {
        let encoded = serde_json::to_vec(record).expect("records serialise");
        let key = record.id.as_str().as_bytes();
        let updated = (&self.models, &self.signatures)
            .transaction(|(models, signatures)| {
                let Some(bytes) = models.get(key)? else {
                    return Ok(false);
                };
                let stored =
                    decode_record(key, &bytes).map_err(ConflictableTransactionError::Abort)?;
                if stored.content_hash != record.content_hash {
                    return Ok(false);
                }
                models.insert(key, encoded.as_slice())?;
                signatures.insert(key, signature)?;
                Ok(true)
            })
            .map_err(transaction_error)?;
        self.db.flush()?;
        Ok(updated)
    }

    fn get(&self, id: &str) -> StoreResult<Option<ModelRecord>> {
        self.models
            .get(id)?
            .map(|b| decode_record(id.as_bytes(), &b))
            .transpose()
    }

    fn signature(&self, id: &str) -> StoreResult<Option<Vec<u8>>> {
        Ok(self.signatures.get(id)?.map(|b| b.to_vec()))
    }

    fn upload(&self, id: &str) -> StoreResult<Option<Upload>> {
        let Some(record) = self.get(id)? else {
            return Ok(None);
        };
        super::assemble_upload(&record, |hash| self.blob(hash)).map(Some)
    }

    fn blob(&self, hash: &str) -> StoreResult<Option<bytes::Bytes>> {
        Ok(self
            .blobs
            .get(hash)?
            .map(|b| bytes::Bytes::copy_from_slice(&b)))
    }

    fn delete(&self, id: &str) -> StoreResult<Option<ModelRecord>> {
        let trees = (
            &self.models,
            &self.signatures,
            &self.blobs,
            &self.blob_refs,
            &self.content,
            &self.previews,
            &self.patches,
        );
        let removed = trees
            .transaction(|view| {
                let Some(bytes) = view.0.get(id.as_bytes())? else {
                    return Ok(None);
                };
                let old = decode_record(id.as_bytes(), &bytes)
                    .map_err(ConflictableTransactionError::Abort)?;
                unlink(view, &old)?;
                Ok(Some(old))
            })
            .map_err(transaction_error)?;
        self.db.flush()?;
        Ok(removed)
    }

    fn list(&self, after: Option<&str>, limit: usize) -> StoreResult<Vec<ModelRecord>> {
        let range = match after {
            Some(after) => self.models.range::<&[u8], _>((
                std::ops::Bound::Excluded(after.as_bytes()),
                std::ops::Bound::Unbounded,
            )),
            None => self.models.iter(),
        };
        range
            .take(limit)
            .map(|entry| {
                let (key, value) = entry?;
                decode_record(&key, &value)
            })
            .collect()
    }

    fn find_content(&self, content_hash: &str) -> StoreResult<Option<ModelId>> {
        self.content
            .get(content_hash)?
            .map(|id| {
                std::str::from_utf8(&id)
                    .ok()
                    .and_then(|id| ModelId::parse(id).ok())
                    .ok_or_else(|| corrupt(content_hash.as_bytes(), "not a model id"))
            })
            .transpose()
    }

    fn load_all(&self) -> Box<dyn Iterator<Item = StoreResult<Loaded>> + '_> {
        Box::new(self.models.iter().map(|entry| {
            let (key, value) = entry?;
            let record = decode_record(&key, &value)?;
            let signature = self
                .signatures
                .get(&key)?
                .ok_or_else(|| corrupt(&key, "model without signature"))?
                .to_vec();
            Ok(Loaded { record, signature })
        }))
    }

    fn len(&self) -> usize {
        self.models.len()
    }

    fn derived(&self, cache: Derived, id: &str) -> StoreResult<Option<Vec<u8>>> {
        Ok(self.tree(cache).get(id)?.map(|v| v.to_vec()))
    }

    fn put_derived(
        &self,
        cache: Derived,
        id: &str,
        content_hash: &str,
        entry: &[u8],
    ) -> StoreResult<bool> {
        (&self.models, self.tree(cache))
            .transaction(|(models, derived)| {
                let Some(bytes) = models.get(id)? else {
                    return Ok(false);
                };
                let stored = decode_record(id.as_bytes(), &bytes)
                    .map_err(ConflictableTransactionError::Abort)?;
                if stored.content_hash != content_hash {
                    return Ok(false);
                }
                derived.insert(id.as_bytes(), entry)?;
                Ok(true)
            })
            .map_err(transaction_error)
    }

    fn all_derived(
        &self,
        cache: Derived,
    ) -> Box<dyn Iterator<Item = StoreResult<(ModelId, Vec<u8>)>> + '_> {
        Box::new(self.tree(cache).iter().map(|entry| {
            let (key, value) = entry?;
            let id = std::str::from_utf8(&key)
                .ok()
                .and_then(|id| ModelId::parse(id).ok())
                .ok_or_else(|| corrupt(&key, "not a model id"))?;
            Ok((id, value.to_vec()))
        }))
    }

    fn state(&self, key: &str) -> StoreResult<Option<Vec<u8>>> {
        Ok(self.state.get(key)?.map(|v| v.to_vec()))
    }

    fn set_state(&self, key: &str, value: &[u8]) -> StoreResult<()> {
        self.state.insert(key, value)?;
        self.db.flush()?;
        Ok(())
    }
}

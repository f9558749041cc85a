//! The sled backend.
//!
//! sled 0.34 is the last stable release. Durability: every write is one multi-tree
//! transaction followed by `flush()`, so an acknowledged model survives a crash; an
//! interrupted write leaves nothing (see `tests/durability.rs`, which kills the server
//! mid-ingest).

use std::cell::RefCell;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use sled::transaction::{ConflictableTransactionError, TransactionalTree};
use sled::Transactional;

use super::{blob_hashes, upload_files, Derived, Loaded, StoreError, StoreResult};
use crate::model::{ModelId, ModelRecord, Upload};

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
    /// Blobs kept as files: hash → size.
    blob_files: sled::Tree,
    blob_refs: sled::Tree,
    content: sled::Tree,
    state: sled::Tree,
    previews: sled::Tree,
    patches: sled::Tree,
    /// The folder of the file blobs.
    files: PathBuf,
    /// Held while blob files are written or removed with the transaction that goes with
    /// them, so that no write finds a file a removal is about to delete.
    file_lock: Mutex<()>,
}

/// Blobs this large are kept as files beside sled (`files/` in the store's folder), sled
/// holding only their size: sled copies a value twice on its way to its log and caches it,
/// so a 200 MB print file cost 400 MB of memory to store (`benches/big.rs`).
const FILE_BLOB_BYTES: usize = 1 << 20;

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
        sled::transaction::TransactionError::Storage(e) => StoreError::from(e),
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
        let files = dir.join("files");
        std::fs::create_dir_all(&files)?;
        Ok(Self {
            models: db.open_tree("models")?,
            signatures: db.open_tree("signatures")?,
            blobs: db.open_tree("blobs")?,
            blob_files: db.open_tree("blob_files")?,
            blob_refs: db.open_tree("blob_refs")?,
            content: db.open_tree("content")?,
            state: db.open_tree("state")?,
            previews: db.open_tree("previews")?,
            patches: db.open_tree("patches")?,
            files,
            file_lock: Mutex::new(()),
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

    /// The trees of a model, in [`ModelTrees`] order.
    #[allow(clippy::type_complexity)]
    fn model_trees(
        &self,
    ) -> (
        &sled::Tree,
        &sled::Tree,
        &sled::Tree,
        &sled::Tree,
        &sled::Tree,
        &sled::Tree,
        &sled::Tree,
        &sled::Tree,
    ) {
        (
            &self.models,
            &self.signatures,
            &self.blobs,
            &self.blob_files,
            &self.blob_refs,
            &self.content,
            &self.previews,
            &self.patches,
        )
    }

    /// Writes a blob's file durably: to a temporary name, synced, then renamed (a crash
    /// leaves no partial file under a blob's name, at worst a file no record refers to).
    fn write_file(&self, hash: &str, bytes: &[u8]) -> StoreResult<()> {
        let partial = self.files.join(format!("{hash}.partial"));
        let mut file = std::fs::File::create(&partial)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&partial, self.files.join(hash))?;
        std::fs::File::open(&self.files)?.sync_all()?;
        Ok(())
    }

    /// Deletes the files of blobs a committed transaction released. A file that cannot be
    /// deleted only takes disk space: the records no longer name it.
    fn remove_files(&self, hashes: &[String]) {
        for hash in hashes {
            if let Err(e) = std::fs::remove_file(self.files.join(hash)) {
                tracing::warn!(error = %e, "a released blob file was not removed");
            }
        }
    }
}

/// Adds one reference to a blob, storing it on the first: its bytes, or (a large one, whose
/// file is written before the transaction) its size.
fn add_blob(
    trees: &ModelTrees,
    hash: &str,
    bytes: &[u8],
) -> Result<(), ConflictableTransactionError<StoreError>> {
    let (_, _, blobs, files, refs, ..) = trees;
    let n = count(refs.get(hash)?);
    if n == 0 {
        if bytes.len() >= FILE_BLOB_BYTES {
            files.insert(hash, &(bytes.len() as u64).to_be_bytes())?;
        } else {
            blobs.insert(hash, bytes)?;
        }
    }
    refs.insert(hash, &(n + 1).to_be_bytes())?;
    Ok(())
}

/// Drops one reference to a blob, removing it with the last; a removed file blob's hash goes
/// to `released`, for its file to be deleted once the transaction commits.
fn release_blob(
    trees: &ModelTrees,
    hash: &str,
    released: &RefCell<Vec<String>>,
) -> Result<(), ConflictableTransactionError<StoreError>> {
    let (_, _, blobs, files, refs, ..) = trees;
    match count(refs.get(hash)?) {
        0 | 1 => {
            refs.remove(hash)?;
            blobs.remove(hash)?;
            if files.remove(hash)?.is_some() {
                released.borrow_mut().push(hash.to_string());
            }
        }
        n => {
            refs.insert(hash, &(n - 1).to_be_bytes())?;
        }
    }
    Ok(())
}

/// The trees a write of a whole model changes, in a transaction: models, signatures, blobs,
/// blob files, blob references, content, previews, patches.
type ModelTrees = (
    TransactionalTree,
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
    released: &RefCell<Vec<String>>,
) -> Result<(), ConflictableTransactionError<StoreError>> {
    let (models, signatures, _, _, _, content, previews, patches) = trees;
    for tree in [models, signatures, previews, patches] {
        tree.remove(old.id.as_str().as_bytes())?;
    }
    for hash in blob_hashes(old) {
        release_blob(trees, hash, released)?;
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
        let files: Vec<(String, &[u8])> = upload_files(record, upload)
            .map(|(hash, bytes)| (hash, &bytes[..]))
            .collect();
        let _files = self.file_lock.lock().expect("never poisoned");
        for (hash, bytes) in &files {
            if bytes.len() >= FILE_BLOB_BYTES && !self.blob_refs.contains_key(hash)? {
                self.write_file(hash, bytes)?;
            }
        }
        let released = RefCell::new(Vec::new());
        let previous = self
            .model_trees()
            .transaction(|view| {
                released.borrow_mut().clear();
                let (models, signatures, _, _, _, content, _, _) = view;
                let previous = match models.get(record.id.as_str().as_bytes())? {
                    Some(bytes) => {
                        let old = decode_record(record.id.as_str().as_bytes(), &bytes)
                            .map_err(ConflictableTransactionError::Abort)?;
                        unlink(view, &old, &released)?;
                        Some(old)
                    }
                    None => None,
                };
                for (hash, bytes) in &files {
                    add_blob(view, hash, bytes)?;
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
        self.remove_files(&released.into_inner());
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
        if let Some(bytes) = self.blobs.get(hash)? {
            return Ok(Some(bytes::Bytes::copy_from_slice(&bytes)));
        }
        if !self.blob_files.contains_key(hash)? {
            return Ok(None);
        }
        // Mapped, not read: a download or a re-extraction of a print file of hundreds of
        // megabytes shares the page cache instead of a heap copy per request.
        let file = std::fs::File::open(self.files.join(hash))?;
        // SAFETY: a blob file is written whole under a temporary name and renamed into place
        // (`write_file`), never written again; removing it unlinks it, which leaves a map of
        // it valid. Only something outside salient changing the store's folder breaks this.
        let map = unsafe { memmap2::Mmap::map(&file)? };
        Ok(Some(bytes::Bytes::from_owner(map)))
    }

    fn delete(&self, id: &str) -> StoreResult<Option<ModelRecord>> {
        let _files = self.file_lock.lock().expect("never poisoned");
        let released = RefCell::new(Vec::new());
        let removed = self
            .model_trees()
            .transaction(|view| {
                released.borrow_mut().clear();
                let Some(bytes) = view.0.get(id.as_bytes())? else {
                    return Ok(None);
                };
                let old = decode_record(id.as_bytes(), &bytes)
                    .map_err(ConflictableTransactionError::Abort)?;
                unlink(view, &old, &released)?;
                Ok(Some(old))
            })
            .map_err(transaction_error)?;
        self.db.flush()?;
        self.remove_files(&released.into_inner());
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

    fn states(&self) -> StoreResult<Vec<(String, Vec<u8>)>> {
        self.state
            .iter()
            .map(|entry| {
                let (key, value) = entry?;
                let key = String::from_utf8(key.to_vec()).map_err(|e| StoreError::Corrupt {
                    key: "state".into(),
                    message: e.to_string(),
                })?;
                Ok((key, value.to_vec()))
            })
            .collect()
    }
}

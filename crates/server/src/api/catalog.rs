//! The in-memory view of the store that requests read: every record and the ranking index.
//!
//! Published as immutable snapshots behind an [`ArcSwap`]: a reader takes the current
//! snapshot (an `Arc`, no lock) and keeps it for as long as it ranks, on whatever thread; a
//! writer, already serialised with the store by the service's write mutex, builds the next
//! snapshot from the current one and swaps it in. So a reader never waits for a writer, and
//! no lock is ever held on an async thread. Records are a persistent map (`imbl`) and index
//! entries are kept in shared chunks, so a new snapshot copies pointers and a chunk or two.

use std::collections::BTreeSet;
use std::io;
use std::path::PathBuf;
use std::sync::Arc;

use arc_swap::ArcSwap;

use super::copies::{Copies, Spot};
use crate::api::error::AppError;
use crate::model::{ModelId, ModelRecord};
use salient_core::params::{Params, SimilarityParams};
use salient_core::rank::{Index, Row};
use salient_core::signature::Signature;

/// One consistent state of the catalogue.
#[derive(Clone)]
pub struct Snapshot {
    pub records: imbl::OrdMap<ModelId, Arc<ModelRecord>>,
    pub index: Index,
    /// This replica's copies of the stored signatures, on a shared store ([`copies`]).
    copies: Option<Arc<Copies>>,
    spots: imbl::OrdMap<ModelId, Spot>,
}

/// What the catalogue keeps of a model beside its record, made before the store is written
/// ([`Catalog::hold`]).
pub struct Held {
    row: Row,
    copy: Option<Spot>,
}

impl Snapshot {
    /// An empty catalogue whose index shelves light field descriptors in `shelf_dir`, or
    /// in the system's temporary folder, and that keeps copies of signatures in `copies`.
    pub fn empty(
        similarity: SimilarityParams,
        shelf_dir: Option<PathBuf>,
        copies: Option<Arc<Copies>>,
    ) -> Self {
        Self {
            records: imbl::OrdMap::new(),
            index: Index::shelved_in(similarity, shelf_dir.unwrap_or_else(std::env::temp_dir)),
            copies,
            spots: imbl::OrdMap::new(),
        }
    }

    /// The index entry of model `id` (its light field shelved) and the copy of its stored
    /// signature `bytes`, if this catalogue keeps copies.
    pub fn hold(&self, id: &ModelId, signature: &Signature, bytes: &[u8]) -> io::Result<Held> {
        Ok(Held {
            row: self.index.row(id.as_str(), signature)?,
            copy: self.copies.as_ref().map(|c| c.put(bytes)).transpose()?,
        })
    }

    /// Adds or replaces a model with what [`Snapshot::hold`] made of it.
    pub fn put(&mut self, record: ModelRecord, held: Held) {
        self.index.put(held.row);
        match held.copy {
            Some(spot) => self.spots.insert(record.id.clone(), spot),
            None => self.spots.remove(&record.id),
        };
        self.records.insert(record.id.clone(), Arc::new(record));
    }

    /// This replica's copy of model `id`'s stored signature, if it keeps copies.
    pub fn copy_of(&self, id: &ModelId) -> Option<io::Result<Vec<u8>>> {
        let (copies, spot) = (self.copies.as_ref()?, self.spots.get(id)?);
        Some(copies.get(*spot))
    }

    /// Whether this replica keeps a copy of model `id`'s stored signature.
    pub fn keeps_copy(&self, id: &ModelId) -> bool {
        self.copies.is_some() && self.spots.contains_key(id)
    }

    /// The file this catalogue keeps its copies of signatures in, if any.
    pub fn copies(&self) -> Option<Arc<Copies>> {
        self.copies.clone()
    }

    /// The ids of models whose signature is stale under `params`, in id order, after `after`.
    pub fn stale_after<'a>(
        &'a self,
        after: Option<&'a ModelId>,
        params: &'a Params,
    ) -> impl Iterator<Item = &'a ModelId> + 'a {
        let start = after.map_or(std::ops::Bound::Unbounded, std::ops::Bound::Excluded);
        let records = self
            .records
            .range::<_, ModelId>((start, std::ops::Bound::Unbounded))
            .map(|(id, _)| id);
        records.filter(|id| self.index.stale(id.as_str(), params) == Some(true))
    }
}

/// The published snapshot and how to change it.
pub struct Catalog {
    current: ArcSwap<Snapshot>,
    /// While an online backup copies the store, the models changed since it began
    /// ([`Catalog::track_changes`]).
    changed: std::sync::Mutex<Option<BTreeSet<ModelId>>>,
}

impl Catalog {
    pub fn new(snapshot: Snapshot) -> Self {
        Self {
            current: ArcSwap::from_pointee(snapshot),
            changed: std::sync::Mutex::new(None),
        }
    }

    /// Starts noting which models change, until [`Catalog::changes`]: every write to the
    /// store is followed, under the service's write lock, by one here.
    pub fn track_changes(&self) {
        *self.changed.lock().expect("never poisoned") = Some(BTreeSet::new());
    }

    /// The models changed since [`Catalog::track_changes`]; stops noting them.
    pub fn changes(&self) -> BTreeSet<ModelId> {
        self.changed
            .lock()
            .expect("never poisoned")
            .take()
            .unwrap_or_default()
    }

    fn note(&self, ids: impl IntoIterator<Item = ModelId>) {
        if let Some(changed) = &mut *self.changed.lock().expect("never poisoned") {
            changed.extend(ids);
        }
    }

    /// The current snapshot; it stays valid (and unchanged) for as long as it is held.
    pub fn snapshot(&self) -> Arc<Snapshot> {
        self.current.load_full()
    }

    /// Publishes a changed copy of the current snapshot and returns its number of models.
    /// Callers serialise their writes (the service's write mutex), so no change is lost
    /// between load and store.
    fn update(&self, change: impl FnOnce(&mut Snapshot)) -> usize {
        let mut next = Snapshot::clone(&self.current.load());
        change(&mut next);
        let len = next.records.len();
        self.current.store(Arc::new(next));
        len
    }

    /// What the catalogue keeps of a model about to be stored, its signature `bytes` as
    /// stored: made first, since shelving may fail (a full disk) and the store must then
    /// stay unchanged.
    pub fn hold(
        &self,
        id: &ModelId,
        signature: &Signature,
        bytes: &[u8],
    ) -> Result<Held, AppError> {
        let snapshot = self.current.load();
        snapshot.hold(id, signature, bytes).map_err(AppError::index)
    }

    /// Adds or replaces a model; returns the number of models.
    pub fn put(&self, record: ModelRecord, held: Held) -> usize {
        self.note([record.id.clone()]);
        self.update(|s| s.put(record, held))
    }

    /// Replaces a model's record, its signature unchanged.
    pub fn set_record(&self, record: ModelRecord) {
        self.note([record.id.clone()]);
        self.update(|s| {
            s.records.insert(record.id.clone(), Arc::new(record));
        });
    }

    /// Replaces the whole catalogue (loaded again from the store).
    pub fn replace(&self, snapshot: Snapshot) {
        let (before, after) = (self.snapshot(), &snapshot);
        self.note(before.records.keys().chain(after.records.keys()).cloned());
        self.current.store(Arc::new(snapshot));
    }

    /// Removes a model; returns the number of models.
    pub fn remove(&self, id: &ModelId) -> usize {
        self.note([id.clone()]);
        self.update(|s| {
            s.index.remove(id.as_str());
            s.records.remove(id);
            s.spots.remove(id);
        })
    }
}

//! The in-memory view of the store that requests read: every record and the ranking index.
//!
//! Published as immutable snapshots behind an [`ArcSwap`]: a reader takes the current
//! snapshot (an `Arc`, no lock) and keeps it for as long as it ranks, on whatever thread; a
//! writer, already serialised with the store by the service's write mutex, builds the next
//! snapshot from the current one and swaps it in. So a reader never waits for a writer, and
//! no lock is ever held on an async thread. Records are a persistent map (`imbl`) and index
//! entries are kept in shared chunks, so a new snapshot copies pointers and a chunk or two.

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::sync::Arc;

use arc_swap::ArcSwap;

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
}

impl Snapshot {
    /// An empty catalogue whose index shelves light field descriptors in `shelf_dir`, or
    /// in the system's temporary folder.
    pub fn empty(similarity: SimilarityParams, shelf_dir: Option<PathBuf>) -> Self {
        Self {
            records: imbl::OrdMap::new(),
            index: Index::shelved_in(similarity, shelf_dir.unwrap_or_else(std::env::temp_dir)),
        }
    }

    /// Adds or replaces a model, with its index entry made by [`Catalog::row`] or this
    /// snapshot's index.
    pub fn put(&mut self, record: ModelRecord, row: Row) {
        self.index.put(row);
        self.records.insert(record.id.clone(), Arc::new(record));
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

    /// The index entry of a model about to be stored: made first, since shelving its light
    /// field descriptor may fail (a full disk) and the store must then stay unchanged.
    pub fn row(&self, id: &ModelId, signature: &Signature) -> Result<Row, AppError> {
        let index = &self.current.load().index;
        index.row(id.as_str(), signature).map_err(AppError::index)
    }

    /// Adds or replaces a model; returns the number of models.
    pub fn put(&self, record: ModelRecord, row: Row) -> usize {
        self.note([record.id.clone()]);
        self.update(|s| s.put(record, row))
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
        })
    }
}

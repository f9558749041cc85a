//! The in-memory view of the store that requests read: every record, which models are stale,
//! and the ranking index (empty on a replica whose first stage is in the database).
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
use salient_core::params::Params;
use salient_core::rank::{Coverage, Index, Row, Scope};
use salient_core::signature::Signature;

/// One consistent state of the catalogue.
#[derive(Clone)]
pub struct Snapshot {
    pub records: imbl::OrdMap<ModelId, Arc<ModelRecord>>,
    /// Every model's row when this replica ranks in memory; none when its first stage is in
    /// the database (`--index pgvector`, #40), where each ranking makes an index of its
    /// candidates and nothing per model stays in this process but its record.
    pub index: Index,
    in_memory: bool,
    /// The parameters a signature is stale under: this replica's.
    params: Arc<Params>,
    /// The models whose signature is stale ([`Signature::staleness`]), and whether it holds
    /// every descriptor (what the first stage's vectors are made of): usually none.
    stale: imbl::OrdMap<ModelId, Stale>,
    /// This replica's copies of the stored signatures, on a shared store ([`copies`]).
    copies: Option<Arc<Copies>>,
    spots: imbl::OrdMap<ModelId, Spot>,
}

#[derive(Clone, Copy)]
struct Stale {
    complete: bool,
}

/// What the catalogue keeps of a model beside its record, made before the store is written
/// ([`Catalog::hold`]).
pub struct Held {
    row: Option<Row>,
    stale: Option<Stale>,
    copy: Option<Spot>,
}

impl Snapshot {
    /// An empty catalogue of a replica with `params`, whose index keeps every model's row
    /// `in_memory` (its light field descriptors shelved in `shelf_dir`, or in the system's
    /// temporary folder) or none, and that keeps copies of signatures in `copies`.
    pub fn empty(
        params: &Params,
        in_memory: bool,
        shelf_dir: Option<PathBuf>,
        copies: Option<Arc<Copies>>,
    ) -> Self {
        let dir = shelf_dir.unwrap_or_else(std::env::temp_dir);
        Self {
            records: imbl::OrdMap::new(),
            index: Index::shelved_in(params.similarity.clone(), dir),
            in_memory,
            params: Arc::new(params.clone()),
            stale: imbl::OrdMap::new(),
            copies,
            spots: imbl::OrdMap::new(),
        }
    }

    /// What the catalogue keeps of model `id`: its index entry (its light field shelved) if
    /// it ranks in memory, whether it is stale, and the copy of its stored signature `bytes`,
    /// if this catalogue keeps copies.
    pub fn hold(&self, id: &ModelId, signature: &Signature, bytes: &[u8]) -> io::Result<Held> {
        let row = self
            .in_memory
            .then(|| self.index.row(id.as_str(), signature));
        Ok(Held {
            row: row.transpose()?,
            stale: signature.staleness(&self.params).map(|_| Stale {
                complete: signature.lfd.is_some() && signature.geodesic.is_some(),
            }),
            copy: self.copies.as_ref().map(|c| c.put(bytes)).transpose()?,
        })
    }

    /// Adds or replaces a model with what [`Snapshot::hold`] made of it.
    pub fn put(&mut self, record: ModelRecord, held: Held) {
        if let Some(row) = held.row {
            self.index.put(row);
        }
        match held.stale {
            Some(stale) => self.stale.insert(record.id.clone(), stale),
            None => self.stale.remove(&record.id),
        };
        match held.copy {
            Some(spot) => self.spots.insert(record.id.clone(), spot),
            None => self.spots.remove(&record.id),
        };
        self.records.insert(record.id.clone(), Arc::new(record));
    }

    /// Whether this replica ranks every model in memory (else each ranking's candidates come
    /// from the first stage in the database).
    pub fn in_memory(&self) -> bool {
        self.in_memory
    }

    /// Whether model `id`'s signature is stale under this replica's parameters.
    pub fn is_stale(&self, id: &ModelId) -> bool {
        self.stale.contains_key(id)
    }

    /// The number of stale signatures.
    pub fn stale_count(&self) -> usize {
        self.stale.len()
    }

    /// What a ranking with the first stage in the database leaves out of `scope`: the models
    /// without the descriptors its vectors are made of, which no method ranks there until
    /// they are re-extracted.
    pub fn unranked(&self, scope: &Scope) -> Coverage {
        let left_out = self
            .stale
            .iter()
            .filter(|(id, stale)| {
                !stale.complete
                    && scope.without != Some(id.as_str())
                    && scope.keep.is_none_or(|keep| keep(id.as_str()))
            })
            .count();
        Coverage {
            left_out,
            partial: 0,
        }
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

    /// The ids of models whose signature is stale, in id order, after `after`.
    pub fn stale_after<'a>(
        &'a self,
        after: Option<&'a ModelId>,
    ) -> impl Iterator<Item = &'a ModelId> + 'a {
        let start = after.map_or(std::ops::Bound::Unbounded, std::ops::Bound::Excluded);
        self.stale
            .range::<_, ModelId>((start, std::ops::Bound::Unbounded))
            .map(|(id, _)| id)
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
            s.stale.remove(id);
            s.records.remove(id);
            s.spots.remove(id);
        })
    }
}

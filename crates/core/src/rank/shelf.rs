//! Light field descriptors on a shelf: a file of fixed-size records instead of the heap.
//!
//! At 4.5 KB a model the descriptors would be two thirds of the index (450 MB at 100 000
//! models), yet a ranking reads few of them: its passes over every entry read the LFD sketch
//! and summary, which stay in memory, and only the candidates those bounds cannot reject are
//! read whole, one positioned read each. Their pages are the kernel's page cache: reclaimable,
//! and not the process's resident memory. The file is an unlinked temporary (`tempfile`), so
//! it goes with the process; the store remains the record of every descriptor.
//!
//! A slot is freed when the last index copy holding it is dropped (the service's older
//! snapshots may still be ranking with it), and reused by the next descriptor.
//!
//! An index of a database's first-stage candidates (#40) keeps its descriptors *away*
//! instead: in the database, fetched for the candidates its bounds leave, many per round trip
//! ([`Place::fetch`]), and held for the rest of the ranking.

use std::collections::HashMap;
use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};

use crate::descriptor::lfd::PACKED;
use crate::descriptor::LightFieldDescriptor;

/// Fetches the light field descriptors of models by id, in one round trip; a model it does
/// not return has none.
pub type Fetch =
    Arc<dyn Fn(&[Arc<str>]) -> io::Result<Vec<(Arc<str>, LightFieldDescriptor)>> + Send + Sync>;

/// Where an index keeps its descriptors.
pub enum Place {
    /// On a shelf created in `dir` when the first descriptor arrives.
    Shelf {
        dir: PathBuf,
        shelf: Mutex<Option<Arc<Shelf>>>,
    },
    /// Away, fetched when needed.
    Away(Arc<Away>),
}

impl std::fmt::Debug for Place {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Place::Shelf { dir, .. } => f.debug_struct("Shelf").field("dir", dir).finish(),
            Place::Away(away) => f.debug_tuple("Away").field(&away.held().len()).finish(),
        }
    }
}

impl Place {
    pub fn new(dir: PathBuf) -> Self {
        Place::Shelf {
            dir,
            shelf: Mutex::new(None),
        }
    }

    pub fn away(fetch: Fetch) -> Self {
        Place::Away(Arc::new(Away {
            fetch,
            held: Mutex::default(),
        }))
    }

    /// Keeps `descriptor`, the model `id`'s.
    pub fn put(&self, id: &Arc<str>, descriptor: &LightFieldDescriptor) -> io::Result<Arc<Slot>> {
        match self {
            Place::Shelf { dir, shelf } => {
                let shelf = {
                    let mut shelf = shelf.lock().unwrap_or_else(PoisonError::into_inner);
                    match &*shelf {
                        Some(shelf) => shelf.clone(),
                        None => shelf.insert(Shelf::create_in(dir)?).clone(),
                    }
                };
                shelf.put(descriptor)
            }
            Place::Away(away) => {
                away.held()
                    .insert(id.clone(), Some(Arc::new(descriptor.clone())));
                Ok(away.slot(id))
            }
        }
    }

    /// The slot of the model `id`'s descriptor, kept away; `None` on a shelf, which holds
    /// only what it was given.
    pub fn away_slot(&self, id: &Arc<str>) -> Option<Arc<Slot>> {
        match self {
            Place::Shelf { .. } => None,
            Place::Away(away) => Some(away.slot(id)),
        }
    }

    pub fn is_away(&self) -> bool {
        matches!(self, Place::Away(_))
    }

    /// Fetches the descriptors of `ids` kept away in one round trip; nothing on a shelf.
    pub fn fetch<'a>(&self, ids: impl Iterator<Item = &'a Arc<str>>) -> io::Result<()> {
        match self {
            Place::Shelf { .. } => Ok(()),
            Place::Away(away) => away.fetch(&ids.cloned().collect::<Vec<_>>()),
        }
    }
}

/// The error of a read of a descriptor kept away and not fetched yet.
#[derive(Debug)]
struct NotFetched;

impl std::fmt::Display for NotFetched {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("a light field descriptor kept away was read before it was fetched")
    }
}

impl std::error::Error for NotFetched {}

/// Whether `error` is a read of a descriptor kept away that [`Place::fetch`] would fetch.
pub fn is_away(error: &io::Error) -> bool {
    error.get_ref().is_some_and(|e| e.is::<NotFetched>())
}

/// Descriptors kept elsewhere, and those fetched so far (`None`: the model has none, or is
/// gone since the first stage named it).
pub struct Away {
    fetch: Fetch,
    held: Mutex<HashMap<Arc<str>, Option<Arc<LightFieldDescriptor>>>>,
}

impl Away {
    fn held(
        &self,
    ) -> std::sync::MutexGuard<'_, HashMap<Arc<str>, Option<Arc<LightFieldDescriptor>>>> {
        self.held.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn slot(self: &Arc<Self>, id: &Arc<str>) -> Arc<Slot> {
        Arc::new(Slot::Away {
            away: self.clone(),
            id: id.clone(),
        })
    }

    fn fetch(&self, ids: &[Arc<str>]) -> io::Result<()> {
        let missing: Vec<Arc<str>> = {
            let held = self.held();
            ids.iter()
                .filter(|id| !held.contains_key(*id))
                .cloned()
                .collect()
        };
        if missing.is_empty() {
            return Ok(());
        }
        let fetched = (self.fetch)(&missing)?;
        let mut held = self.held();
        for id in missing {
            held.insert(id, None);
        }
        for (id, descriptor) in fetched {
            held.insert(id, Some(Arc::new(descriptor)));
        }
        Ok(())
    }

    fn get(&self, id: &Arc<str>) -> io::Result<Option<LightFieldDescriptor>> {
        match self.held().get(id) {
            Some(descriptor) => Ok(descriptor.as_deref().cloned()),
            None => Err(io::Error::other(NotFetched)),
        }
    }
}

/// The file and which of its slots are taken.
#[derive(Debug)]
pub struct Shelf {
    file: File,
    slots: Mutex<Slots>,
}

#[derive(Debug, Default)]
struct Slots {
    /// Slots ever used: the file holds `used · PACKED` bytes.
    used: u64,
    free: Vec<u64>,
}

impl Shelf {
    fn create_in(dir: &Path) -> io::Result<Arc<Self>> {
        Ok(Arc::new(Self {
            file: tempfile::tempfile_in(dir)?,
            slots: Mutex::default(),
        }))
    }

    fn slots(&self) -> std::sync::MutexGuard<'_, Slots> {
        self.slots.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn put(self: &Arc<Self>, descriptor: &LightFieldDescriptor) -> io::Result<Arc<Slot>> {
        let number = {
            let mut slots = self.slots();
            match slots.free.pop() {
                Some(number) => number,
                None => {
                    slots.used += 1;
                    slots.used - 1
                }
            }
        };
        // From here the slot is returned to the free list if the write fails.
        let slot = Arc::new(Slot::Shelved {
            shelf: self.clone(),
            number,
        });
        self.file
            .write_all_at(&descriptor.packed(), number * PACKED as u64)?;
        Ok(slot)
    }
}

/// One kept descriptor.
pub enum Slot {
    Shelved { shelf: Arc<Shelf>, number: u64 },
    Away { away: Arc<Away>, id: Arc<str> },
}

impl std::fmt::Debug for Slot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Slot::Shelved { number, .. } => f.debug_tuple("Shelved").field(number).finish(),
            Slot::Away { id, .. } => f.debug_tuple("Away").field(id).finish(),
        }
    }
}

impl Slot {
    /// The descriptor; `None` for one kept away whose model is gone.
    pub fn get(&self) -> io::Result<Option<LightFieldDescriptor>> {
        match self {
            Slot::Shelved { shelf, number } => {
                let mut packed = [0u8; PACKED];
                shelf
                    .file
                    .read_exact_at(&mut packed, number * PACKED as u64)?;
                Ok(Some(LightFieldDescriptor::unpacked(&packed)))
            }
            Slot::Away { away, id } => away.get(id),
        }
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        if let Slot::Shelved { shelf, number } = self {
            shelf.slots().free.push(*number);
        }
    }
}

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

use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};

use crate::descriptor::lfd::PACKED;
use crate::descriptor::LightFieldDescriptor;

/// Where an index keeps its shelf: created in `dir` when the first descriptor arrives.
#[derive(Debug)]
pub struct Place {
    dir: PathBuf,
    shelf: Mutex<Option<Arc<Shelf>>>,
}

impl Place {
    pub fn new(dir: PathBuf) -> Self {
        Self {
            dir,
            shelf: Mutex::new(None),
        }
    }

    /// Shelves `descriptor`.
    pub fn put(&self, descriptor: &LightFieldDescriptor) -> io::Result<Arc<Slot>> {
        let shelf = {
            let mut shelf = self.shelf.lock().unwrap_or_else(PoisonError::into_inner);
            match &*shelf {
                Some(shelf) => shelf.clone(),
                None => shelf.insert(Shelf::create_in(&self.dir)?).clone(),
            }
        };
        shelf.put(descriptor)
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
        let slot = Arc::new(Slot {
            shelf: self.clone(),
            number,
        });
        self.file
            .write_all_at(&descriptor.packed(), number * PACKED as u64)?;
        Ok(slot)
    }
}

/// One shelved descriptor.
#[derive(Debug)]
pub struct Slot {
    shelf: Arc<Shelf>,
    number: u64,
}

impl Slot {
    pub fn get(&self) -> io::Result<LightFieldDescriptor> {
        let mut packed = [0u8; PACKED];
        self.shelf
            .file
            .read_exact_at(&mut packed, self.number * PACKED as u64)?;
        Ok(LightFieldDescriptor::unpacked(&packed))
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        self.shelf.slots().free.push(self.number);
    }
}

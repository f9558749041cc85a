//! A replica's own copy of every stored signature (#37), so that ranking a stored model
//! (`similar`) needs memory and local disk only: on a store shared by replicas the database
//! may be down or restarting, and ranking must go on meanwhile. The ranking index keeps only
//! what it compares, not the signature a stored model is ranked with.
//!
//! Written as the catalogue loads and changes, beside the light-field shelf and for the same
//! reasons ([`salient_core::rank`]'s shelf): an unlinked temporary file, appended to, whose
//! pages are the kernel's page cache and not the process's resident memory (~7 KB a model,
//! 700 MB at 100 000). A replaced signature's old bytes stay until the process ends; the file
//! is made again at every start.

use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

/// The file of copies.
#[derive(Debug)]
pub struct Copies {
    file: File,
    /// Where the next copy goes.
    end: AtomicU64,
}

/// Where one copy is.
#[derive(Debug, Clone, Copy)]
pub struct Spot {
    offset: u64,
    len: u32,
}

impl Copies {
    /// An empty file of copies in `dir`.
    pub fn create_in(dir: &Path) -> io::Result<Self> {
        Ok(Self {
            file: tempfile::tempfile_in(dir)?,
            end: AtomicU64::new(0),
        })
    }

    /// Keeps a copy of `bytes`; copies are written in parallel, each at its own place.
    pub fn put(&self, bytes: &[u8]) -> io::Result<Spot> {
        let len = u32::try_from(bytes.len())
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "a signature over 4 GiB"))?;
        let offset = self.end.fetch_add(u64::from(len), Ordering::Relaxed);
        self.file.write_all_at(bytes, offset)?;
        Ok(Spot { offset, len })
    }

    /// The bytes kept at `spot`.
    pub fn get(&self, spot: Spot) -> io::Result<Vec<u8>> {
        let mut bytes = vec![0; spot.len as usize];
        self.file.read_exact_at(&mut bytes, spot.offset)?;
        Ok(bytes)
    }
}

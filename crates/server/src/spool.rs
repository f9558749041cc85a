//! Large request bodies, spooled to a file while they arrive: a 3D-print library's STL runs to
//! hundreds of megabytes, and a body held in memory stays resident through its extraction
//! (`benches/big.rs`). A spooled body is read through a memory map, whose pages are the
//! file's: the service lets them go once the mesh is loaded ([`Spool::release_pages`]), and
//! a later reader (the store, a duplicate check) takes them again from the page cache.

use std::fs::File;
use std::io::Write;
use std::path::Path;
use std::sync::Arc;

use bytes::Bytes;
use memmap2::Mmap;

/// Bodies past this many bytes are spooled; smaller ones are gathered in memory.
pub const SPOOL_BYTES: usize = 16 << 20;

/// A spooled body is written in pieces of this size.
const WRITE_BYTES: usize = 1 << 20;

/// A request body gathered in memory up to [`SPOOL_BYTES`], then in an unnamed file.
pub struct Collector {
    buffer: Vec<u8>,
    file: Option<File>,
    length: usize,
    limit: usize,
    dir: Arc<Path>,
}

/// What a [`Collector`] gathered.
pub struct Body {
    pub bytes: Bytes,
    /// The spool behind `bytes`, when it went to a file.
    pub spool: Option<Spool>,
}

impl Collector {
    /// A collector of at most `limit` bytes, expecting `declared` (a `Content-Length`), that
    /// spools into `dir`.
    pub fn new(declared: Option<usize>, limit: usize, dir: Arc<Path>) -> Self {
        Self {
            buffer: Vec::with_capacity(declared.unwrap_or(0).min(SPOOL_BYTES)),
            file: None,
            length: 0,
            limit,
            dir,
        }
    }

    /// Appends a chunk of the body.
    pub async fn push(&mut self, data: &[u8]) -> Result<(), CollectError> {
        self.length += data.len();
        if self.length > self.limit {
            return Err(CollectError::TooLarge);
        }
        self.buffer.extend_from_slice(data);
        let spooling = self.file.is_some() || self.buffer.len() > SPOOL_BYTES;
        if spooling && self.buffer.len() >= WRITE_BYTES {
            self.write().await?;
        }
        Ok(())
    }

    /// Writes the buffer to the spool, opened on the first write. File writes block: they run
    /// off the async workers.
    async fn write(&mut self) -> Result<(), CollectError> {
        let dir = self.dir.clone();
        let buffered = std::mem::replace(&mut self.buffer, Vec::with_capacity(WRITE_BYTES));
        let file = self.file.take();
        let file = tokio::task::spawn_blocking(move || {
            let mut file = match file {
                Some(open) => open,
                None => tempfile::tempfile_in(&*dir)?,
            };
            file.write_all(&buffered)?;
            Ok::<_, std::io::Error>(file)
        })
        .await
        .expect("spool writes do not panic")
        .map_err(CollectError::Spool)?;
        self.file = Some(file);
        Ok(())
    }

    /// The whole body.
    pub async fn finish(mut self) -> Result<Body, CollectError> {
        if self.file.is_some() {
            self.write().await?;
        }
        let Some(file) = self.file else {
            return Ok(Body {
                bytes: Bytes::from(self.buffer),
                spool: None,
            });
        };
        let spool = tokio::task::spawn_blocking(move || Spool::map(file))
            .await
            .expect("maps do not panic")
            .map_err(CollectError::Spool)?;
        Ok(Body {
            bytes: spool.bytes(),
            spool: Some(spool),
        })
    }
}

/// Gathering a body failed.
#[derive(Debug)]
pub enum CollectError {
    /// The body exceeds the collector's limit.
    TooLarge,
    /// The spool's file could not be written or mapped (a full disk, a missing folder).
    Spool(std::io::Error),
}

/// A body in an unnamed file (gone when the last map of it is), mapped read-only.
#[derive(Clone)]
pub struct Spool(Arc<Mmap>);

impl Spool {
    fn map(file: File) -> std::io::Result<Self> {
        // SAFETY: the file is unnamed (`tempfile_in`), so no other process can open it, and
        // this process wrote it to the end before mapping it and never writes it again.
        let map = unsafe { Mmap::map(&file)? };
        Ok(Self(Arc::new(map)))
    }

    /// The body, backed by the map.
    pub fn bytes(&self) -> Bytes {
        Bytes::from_owner(self.clone())
    }

    /// Takes the map's pages out of the process's resident memory; a later read faults them
    /// in again from the page cache (or the file).
    pub fn release_pages(&self) {
        // SAFETY: the map is read-only and of a file, so dropping its pages loses nothing: a
        // read afterwards sees the file's contents, which never change (see `map`).
        let result = unsafe { self.0.unchecked_advise(memmap2::UncheckedAdvice::DontNeed) };
        if let Err(e) = result {
            tracing::debug!(error = %e, "a spooled body's pages were not released");
        }
    }
}

impl AsRef<[u8]> for Spool {
    fn as_ref(&self) -> &[u8] {
        &self.0
    }
}

impl std::fmt::Debug for Spool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Spool({} bytes)", self.0.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Collects `body` in chunks of `chunk` bytes.
    async fn collect(body: &[u8], chunk: usize, limit: usize) -> Result<Body, CollectError> {
        let dir = tempfile::tempdir().unwrap();
        let mut collector = Collector::new(None, limit, dir.path().into());
        for piece in body.chunks(chunk) {
            collector.push(piece).await?;
        }
        collector.finish().await
    }

    #[tokio::test]
    async fn small_bodies_stay_in_memory_and_large_ones_are_spooled_intact() {
        let small = collect(&[7; 1000], 64, usize::MAX).await.unwrap();
        assert!(small.spool.is_none());
        assert_eq!(small.bytes, vec![7u8; 1000]);

        let large: Vec<u8> = (0..SPOOL_BYTES + 3 * WRITE_BYTES + 5)
            .map(|i| (i % 251) as u8)
            .collect();
        let body = collect(&large, 65_536 + 7, usize::MAX).await.unwrap();
        let spool = body.spool.expect("spooled");
        assert!(body.bytes == large);
        // Pages let go are read again from the file.
        spool.release_pages();
        assert!(body.bytes == large);
    }

    #[tokio::test]
    async fn a_body_over_the_limit_is_refused_spooled_or_not() {
        for size in [2_000, SPOOL_BYTES + 2] {
            let body = vec![0; size];
            let error = collect(&body, 4096, size - 1).await.err();
            assert!(matches!(error, Some(CollectError::TooLarge)), "{size}");
            assert!(collect(&body, 4096, size).await.is_ok(), "{size}");
        }
    }
}

//! Folders of mesh files: finding them, and a disk cache of their signatures keyed by content,
//! so that searching or evaluating a collection again extracts nothing that has not changed.

use std::fs;
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use crate::descriptor::patch::Packed;
use crate::mesh::{load_path, Format};
use crate::params::{Limits, Params};
use crate::partial::stored_patches;
use crate::pipeline::{describe, extract_path};
use crate::signature::{Signature, SIGNATURE_FORMAT};
use crate::{Error, Result};

/// Name of the cache folder [`SignatureCache::beside`] creates in a collection.
pub const CACHE_DIR: &str = ".salient-cache";

/// Mesh files below `dir` in a recognised format, and zip archives (of one mesh each,
/// [`crate::mesh::load::archive`]), sorted by path. Hidden files and folders (such as the
/// cache) are skipped.
pub fn find_meshes(dir: &Path) -> Result<Vec<PathBuf>> {
    let io = |source: std::io::Error| Error::Io {
        path: dir.to_path_buf(),
        source,
    };
    if !dir.is_dir() {
        return Err(io(std::io::Error::new(
            std::io::ErrorKind::NotFound,
            "not a folder",
        )));
    }
    let mut files = Vec::new();
    let walker = walkdir::WalkDir::new(dir).sort_by_file_name().into_iter();
    let visible =
        |e: &walkdir::DirEntry| e.depth() == 0 || !e.file_name().to_string_lossy().starts_with('.');
    for entry in walker.filter_entry(visible) {
        let entry = entry.map_err(|e| io(e.into()))?;
        if entry.file_type().is_file() && is_mesh_file(entry.path()) {
            files.push(entry.into_path());
        }
    }
    Ok(files)
}

/// Whether `path` names a mesh file: a recognised format, or a zip archive.
pub fn is_mesh_file(path: &Path) -> bool {
    Format::from_path(path).is_some()
        || path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("zip"))
}

/// Signatures on disk, one file per (file content, extraction parameters, signature format)
/// triple: a new format may hold descriptors an old entry lacks. Ranking parameters are not
/// part of the key ([`Params::extraction_key`]).
#[derive(Debug, Clone)]
pub struct SignatureCache {
    dir: PathBuf,
    params: Params,
    params_key: Vec<u8>,
}

/// Whether [`SignatureCache::signature`] found the signature or extracted it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    Cached,
    Extracted,
}

impl SignatureCache {
    /// A cache in `dir` for signatures made with `params`.
    pub fn new(dir: impl Into<PathBuf>, params: &Params) -> Self {
        Self {
            dir: dir.into(),
            params: params.clone(),
            params_key: params.extraction_key(),
        }
    }

    /// A cache in the collection's own `.salient-cache` folder.
    pub fn beside(collection: &Path, params: &Params) -> Self {
        Self::new(collection.join(CACHE_DIR), params)
    }

    /// The signature of the mesh at `path`: from the cache when its bytes and the parameters
    /// are unchanged, else extracted and stored. A cache entry that cannot be read is
    /// replaced; a cache that cannot be written only costs the next run its time.
    ///
    /// The key covers the file itself, not the sibling buffers a `.gltf` may reference.
    pub fn signature(
        &self,
        path: &Path,
        params: &Params,
        limits: &Limits,
    ) -> Result<(Signature, Source)> {
        let bytes = read(path)?;
        if let Some(signature) = self.get(&bytes) {
            return Ok((signature, Source::Cached));
        }
        let signature = describe(&extract_path(path, params, limits)?, params);
        Ok((self.put(&bytes, &signature)?, Source::Extracted))
    }

    /// The stored signature of a mesh file with content `bytes`, if there is a readable one
    /// that is not stale (one written before a descriptor existed is extracted again).
    pub fn get(&self, bytes: &[u8]) -> Option<Signature> {
        fs::read(self.entry(bytes))
            .ok()
            .and_then(|b| Signature::from_bytes(&b).ok())
            .filter(|s| s.staleness(&self.params).is_none())
    }

    /// Stores `signature` as that of the mesh file with content `bytes` (made with this
    /// cache's parameters: callers that extract once for several parameter sets use it), and
    /// returns the stored form, so that a result never depends on whether it came from the
    /// cache.
    pub fn put(&self, bytes: &[u8], signature: &Signature) -> Result<Signature> {
        let entry = self.entry(bytes);
        let bytes = signature.to_bytes();
        self.write(&entry, &bytes);
        Signature::from_bytes(&bytes)
    }

    /// The packed patch descriptors of the mesh at `path` that a partial search reads
    /// ([`stored_patches`]; about 30 ms of a core a model to make), from the cache when its
    /// bytes and the parameters are unchanged, else made and stored. An entry of another
    /// packing or a damaged one is made again.
    pub fn patches(&self, path: &Path, limits: &Limits) -> Result<Packed> {
        let entry = self.entry(&read(path)?).with_extension("patches");
        if let Some(packed) = fs::read(&entry).ok().and_then(|b| Packed::from_bytes(&b)) {
            return Ok(packed);
        }
        let packed = stored_patches(&load_path(path, limits)?, &self.params.mesh)?;
        self.write(&entry, &packed.to_bytes());
        Ok(packed)
    }

    /// Writes an entry, to a temporary name then renamed so that a reader never sees half a
    /// file; a cache that cannot be written only costs the next run its time.
    fn write(&self, entry: &Path, bytes: &[u8]) {
        let mut temporary = entry.as_os_str().to_owned();
        temporary.push(format!(".tmp{}", std::process::id()));
        let temporary = PathBuf::from(temporary);
        let stored = fs::create_dir_all(&self.dir)
            .and_then(|()| fs::write(&temporary, bytes))
            .and_then(|()| fs::rename(&temporary, entry));
        if stored.is_err() {
            let _ = fs::remove_file(&temporary);
        }
    }

    fn entry(&self, bytes: &[u8]) -> PathBuf {
        let mut hasher = Sha256::new();
        hasher.update(bytes);
        hasher.update(&self.params_key);
        hasher.update(SIGNATURE_FORMAT.to_le_bytes());
        self.dir
            .join(format!("{}.sig", hex::encode(hasher.finalize())))
    }
}

/// The bytes of a file, with its path in the error.
pub fn read(path: &Path) -> Result<Vec<u8>> {
    fs::read(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

//! A store in memory: the same contract as [`super::SledStore`] without a disk, for tests
//! and for trying the service out. Everything is lost with the process.

use std::collections::BTreeMap;
use std::sync::{Mutex, MutexGuard};

use bytes::Bytes;

use super::{Derived, Loaded, Store, StoreResult};
use crate::model::{sha256_hex, ModelId, ModelRecord, Upload};

#[derive(Default)]
struct Inner {
    models: BTreeMap<ModelId, (ModelRecord, Vec<u8>)>,
    /// SHA-256 → bytes and the number of models using them.
    blobs: BTreeMap<String, (Bytes, u64)>,
    content: BTreeMap<String, ModelId>,
    state: BTreeMap<String, Vec<u8>>,
    derived: BTreeMap<(Derived, ModelId), Vec<u8>>,
}

impl Inner {
    fn add_blobs(&mut self, record: &ModelRecord, upload: &Upload) {
        let files = std::iter::once((record.mesh_blob.clone(), upload.mesh.clone())).chain(
            upload
                .resources
                .values()
                .map(|bytes| (sha256_hex(bytes), bytes.clone())),
        );
        for (hash, bytes) in files {
            self.blobs.entry(hash).or_insert((bytes, 0)).1 += 1;
        }
    }

    fn unlink(&mut self, old: &ModelRecord) {
        self.models.remove(&old.id);
        for cache in [Derived::Preview, Derived::Patches] {
            self.derived.remove(&(cache, old.id.clone()));
        }
        let hashes = std::iter::once(&old.mesh_blob).chain(old.resources.values());
        for hash in hashes {
            if let Some((_, refs)) = self.blobs.get_mut(hash) {
                *refs -= 1;
                if *refs == 0 {
                    self.blobs.remove(hash);
                }
            }
        }
        if self.content.get(&old.content_hash) == Some(&old.id) {
            self.content.remove(&old.content_hash);
        }
    }
}

/// Models, signatures and files in maps behind one mutex: every operation is atomic.
#[derive(Default)]
pub struct InMemoryStore {
    inner: Mutex<Inner>,
}

impl InMemoryStore {
    pub fn new() -> Self {
        Self::default()
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        // A panic while holding the lock leaves maps that are still consistent: every
        // operation completes its changes before it can panic.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl Store for InMemoryStore {
    fn put(
        &self,
        record: &ModelRecord,
        signature: &[u8],
        upload: &Upload,
    ) -> StoreResult<Option<ModelRecord>> {
        let mut inner = self.lock();
        let previous = inner.models.get(&record.id).map(|(r, _)| r.clone());
        if let Some(old) = &previous {
            inner.unlink(old);
        }
        inner.add_blobs(record, upload);
        inner
            .models
            .insert(record.id.clone(), (record.clone(), signature.to_vec()));
        inner
            .content
            .insert(record.content_hash.clone(), record.id.clone());
        Ok(previous)
    }

    fn update_model(&self, record: &ModelRecord, signature: &[u8]) -> StoreResult<bool> {
        let mut inner = self.lock();
        match inner.models.get_mut(&record.id) {
            Some(stored) if stored.0.content_hash == record.content_hash => {
                *stored = (record.clone(), signature.to_vec());
                Ok(true)
            }
            _ => Ok(false),
        }
    }

    fn get(&self, id: &str) -> StoreResult<Option<ModelRecord>> {
        Ok(self.lock().models.get(id).map(|(r, _)| r.clone()))
    }

    fn signature(&self, id: &str) -> StoreResult<Option<Vec<u8>>> {
        Ok(self.lock().models.get(id).map(|(_, s)| s.clone()))
    }

    fn upload(&self, id: &str) -> StoreResult<Option<Upload>> {
        let inner = self.lock();
        let Some((record, _)) = inner.models.get(id) else {
            return Ok(None);
        };
        super::assemble_upload(record, |hash| {
            Ok(inner.blobs.get(hash).map(|(bytes, _)| bytes.clone()))
        })
        .map(Some)
    }

    fn blob(&self, hash: &str) -> StoreResult<Option<Bytes>> {
        Ok(self.lock().blobs.get(hash).map(|(bytes, _)| bytes.clone()))
    }

    fn delete(&self, id: &str) -> StoreResult<Option<ModelRecord>> {
        let mut inner = self.lock();
        let old = inner.models.get(id).map(|(r, _)| r.clone());
        if let Some(old) = &old {
            inner.unlink(old);
        }
        Ok(old)
    }

    fn list(&self, after: Option<&str>, limit: usize) -> StoreResult<Vec<ModelRecord>> {
        let inner = self.lock();
        Ok(inner
            .models
            .values()
            .map(|(r, _)| r)
            .filter(|r| after.is_none_or(|after| r.id.as_str() > after))
            .take(limit)
            .cloned()
            .collect())
    }

    fn find_content(&self, content_hash: &str) -> StoreResult<Option<ModelId>> {
        Ok(self.lock().content.get(content_hash).cloned())
    }

    fn load_all(&self) -> Box<dyn Iterator<Item = StoreResult<Loaded>> + '_> {
        let all: Vec<_> = self
            .lock()
            .models
            .values()
            .map(|(record, signature)| {
                Ok(Loaded {
                    record: record.clone(),
                    signature: signature.clone(),
                })
            })
            .collect();
        Box::new(all.into_iter())
    }

    fn len(&self) -> usize {
        self.lock().models.len()
    }

    fn derived(&self, cache: Derived, id: &str) -> StoreResult<Option<Vec<u8>>> {
        let Ok(id) = ModelId::parse(id) else {
            return Ok(None);
        };
        Ok(self.lock().derived.get(&(cache, id)).cloned())
    }

    fn put_derived(
        &self,
        cache: Derived,
        id: &str,
        content_hash: &str,
        entry: &[u8],
    ) -> StoreResult<bool> {
        let mut inner = self.lock();
        let Some((record, _)) = inner.models.get(id) else {
            return Ok(false);
        };
        if record.content_hash != content_hash {
            return Ok(false);
        }
        let id = record.id.clone();
        inner.derived.insert((cache, id), entry.to_vec());
        Ok(true)
    }

    fn all_derived(
        &self,
        cache: Derived,
    ) -> Box<dyn Iterator<Item = StoreResult<(ModelId, Vec<u8>)>> + '_> {
        let all: Vec<_> = self
            .lock()
            .derived
            .iter()
            .filter(|((c, _), _)| *c == cache)
            .map(|((_, id), entry)| Ok((id.clone(), entry.clone())))
            .collect();
        Box::new(all.into_iter())
    }

    fn state(&self, key: &str) -> StoreResult<Option<Vec<u8>>> {
        Ok(self.lock().state.get(key).cloned())
    }

    fn set_state(&self, key: &str, value: &[u8]) -> StoreResult<()> {
        self.lock().state.insert(key.to_string(), value.to_vec());
        Ok(())
    }

    fn states(&self) -> StoreResult<Vec<(String, Vec<u8>)>> {
        Ok(self.lock().state.clone().into_iter().collect())
    }
}

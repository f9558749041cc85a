//! Copying a catalogue from one store to another: `salient migrate-store` (sled and
//! PostgreSQL, either way), `salient restore`, and the service's online backup
//! ([`crate::api`]'s `POST /v1/admin/backup`), which copies while uploads go on and then
//! copies again, under the write lock, the models written meanwhile.

use crate::model::ModelId;
use crate::store::{Derived, Store, StoreError, StoreResult};

/// What a copy wrote.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, serde::Serialize, utoipa::ToSchema)]
pub struct Copied {
    pub models: usize,
    /// Entries of the derived caches (previews, patches); missing ones are made again.
    pub derived: usize,
    /// Small values: dismissed pairs, a re-extraction's progress, the extraction parameters.
    pub states: usize,
}

/// Models read per page while copying.
const PAGE: usize = 256;
/// How often a model replaced while it is read is read again.
const READS: usize = 3;

/// Makes `to` hold model `id` as `from` holds it now — record, signature, files and derived
/// entries — or not at all if `from` has none. Returns the number of derived entries copied,
/// or `None` when `from` had no such model.
pub fn copy_model(from: &dyn Store, to: &dyn Store, id: &ModelId) -> StoreResult<Option<usize>> {
    // Record and files are two reads: one replaced in between is read again.
    for _ in 0..READS {
        let (Some(loaded), Some(upload)) = (from.model(id.as_str())?, from.upload(id.as_str())?)
        else {
            to.delete(id.as_str())?;
            return Ok(None);
        };
        if loaded.record.content_hash != upload.content_hash() {
            continue;
        }
        to.put(&loaded.record, &loaded.signature, &upload)?;
        let mut derived = 0;
        for cache in Derived::ALL {
            if let Some(entry) = from.derived(cache, id.as_str())? {
                to.put_derived(cache, id.as_str(), &loaded.record.content_hash, &entry)?;
                derived += 1;
            }
        }
        return Ok(Some(derived));
    }
    Err(StoreError::Corrupt {
        key: id.to_string(),
        message: format!("replaced each of the {READS} times it was read"),
    })
}

/// Copies every model of `from` into `to`, then every state value; `each` is told of each
/// model copied. Models written to `from` meanwhile may or may not be in the copy: the
/// online backup copies those again ([`copy_model`]).
pub fn copy_all(
    from: &dyn Store,
    to: &dyn Store,
    mut each: impl FnMut(&ModelId),
) -> StoreResult<Copied> {
    let mut copied = Copied::default();
    let mut after: Option<ModelId> = None;
    loop {
        let page = from.list(after.as_ref().map(ModelId::as_str), PAGE)?;
        let Some(last) = page.last() else { break };
        after = Some(last.id.clone());
        for record in &page {
            // One deleted since the page was read is not copied.
            if let Some(derived) = copy_model(from, to, &record.id)? {
                copied.models += 1;
                copied.derived += derived;
                each(&record.id);
            }
        }
    }
    copied.states = copy_states(from, to)?;
    Ok(copied)
}

/// Copies every state value of `from` into `to`; returns how many.
pub fn copy_states(from: &dyn Store, to: &dyn Store) -> StoreResult<usize> {
    let states = from.states()?;
    for (key, value) in &states {
        to.set_state(key, value)?;
    }
    Ok(states.len())
}

/// The models whose record or signature differ between `a` and `b`, or that only one holds
/// (at most `limit` of them): what a copy is checked with.
pub fn differences(a: &dyn Store, b: &dyn Store, limit: usize) -> StoreResult<Vec<ModelId>> {
    let mut differ = Vec::new();
    let mut held = 0;
    for loaded in a.load_all() {
        let x = loaded?;
        held += 1;
        let same = b
            .model(x.record.id.as_str())?
            .is_some_and(|y| y.record == x.record && y.signature == x.signature);
        if !same {
            differ.push(x.record.id);
            if differ.len() == limit {
                return Ok(differ);
            }
        }
    }
    // Every model of `a` is in `b`: any more of `b` are models `a` lacks.
    if b.len() != held {
        for loaded in b.load_all() {
            let y = loaded?;
            if a.get(y.record.id.as_str())?.is_none() {
                differ.push(y.record.id);
                if differ.len() == limit {
                    break;
                }
            }
        }
    }
    Ok(differ)
}

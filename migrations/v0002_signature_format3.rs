//! Version 2: signatures in the sectioned binary format 3, and the `state` tree.
//!
//! - `signatures`: every value of format 1 or 2 (release 0.1.0: positional `postcard` with
//!   the parameters and statistics embedded) is decoded and written again in format 3, whose
//!   parameters and statistics tolerate added fields (`crates/core/src/signature.rs`). Values already in
//!   format 3 or later are left alone, so an interrupted run simply starts again. (It writes
//!   today's format, which reads back the same.)
//! - `state`: small values the service keeps between runs (`reindex`: the progress of an
//!   online re-extraction).
//!
//! This changes the encoding only: what each signature says is unchanged, and a signature
//! that is stale under the current parameters stays stale (it is re-extracted, not migrated).

use crate::store::{StoreError, StoreResult};
use salient_core::signature::Signature;

pub fn apply(db: &sled::Db) -> StoreResult<()> {
    db.open_tree("state")?;
    let signatures = db.open_tree("signatures")?;
    for entry in signatures.iter() {
        let (key, bytes) = entry?;
        if Signature::format_of(&bytes).is_some_and(|format| format >= 3) {
            continue;
        }
        let signature = Signature::from_bytes(&bytes).map_err(|e| StoreError::Corrupt {
            key: String::from_utf8_lossy(&key).into_owned(),
            message: e.to_string(),
        })?;
        signatures.insert(key, signature.to_bytes())?;
    }
    Ok(())
}

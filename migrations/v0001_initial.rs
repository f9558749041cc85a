//! Version 1: the first layout. An empty store (version 0) gets its trees.
//!
//! - `models`: id → model record (JSON)
//! - `signatures`: id → signature (binary, `Signature::to_bytes`)
//! - `blobs`: SHA-256 → original file bytes (meshes and glTF resources, deduplicated)
//! - `blob_refs`: SHA-256 → number of models using the blob (u64, big endian)
//! - `content`: content hash of an upload → id of the model holding it

pub fn apply(db: &sled::Db) -> crate::store::StoreResult<()> {
    for tree in ["models", "signatures", "blobs", "blob_refs", "content"] {
        db.open_tree(tree)?;
    }
    Ok(())
}

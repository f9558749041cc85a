//! Version 5: tree `blob_files`, hash → size of a blob kept as a file under `files/` in the
//! store's folder (blobs of 1 MiB and more: print files of hundreds of megabytes cost sled
//! twice their size in memory to store). Blobs written before stay in `blobs` and read as
//! they are; a release before this one would not find the files, hence the version.

pub fn apply(db: &sled::Db) -> crate::store::StoreResult<()> {
    db.open_tree("blob_files")?;
    Ok(())
}

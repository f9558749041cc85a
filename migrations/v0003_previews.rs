//! Version 3: tree `previews`, id → the model's cached preview (`Preview::to_cache_entry`):
//! derived data, made again whenever missing or made from something else, and removed with
//! its model.

pub fn apply(db: &sled::Db) -> crate::store::StoreResult<()> {
    db.open_tree("previews")?;
    Ok(())
}

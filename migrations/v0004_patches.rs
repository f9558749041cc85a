//! Version 4: tree `patches`, id → the model's packed patch descriptors
//! (`descriptor::patch::Packed`), which pick a partial search's candidates: derived data, made
//! in the background whenever missing or made with another layout, and removed with its
//! model.

pub fn apply(db: &sled::Db) -> crate::store::StoreResult<()> {
    db.open_tree("patches")?;
    Ok(())
}

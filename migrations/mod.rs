//! Ordered store migrations, applied at open (see README.md in this folder).

mod v0001_initial;

/// One step of the store's schema.
pub struct Migration {
    pub version: u32,
    pub name: &'static str,
    pub apply: fn(&sled::Db) -> sled::Result<()>,
}

/// Every migration, in version order; the last version is the schema the code writes.
pub const MIGRATIONS: &[Migration] = &[Migration {
    version: 1,
    name: "initial layout",
    apply: v0001_initial::apply,
}];

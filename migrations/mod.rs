//! Ordered store migrations, applied at open (see README.md in this folder).

mod v0001_initial;
mod v0002_signature_format3;
mod v0003_previews;
mod v0004_patches;
mod v0005_blob_files;

use crate::store::StoreResult;

/// One step of the store's schema.
pub struct Migration {
    pub version: u32,
    pub name: &'static str,
    pub apply: fn(&sled::Db) -> StoreResult<()>,
}

/// Every migration, in version order; the last version is the schema the code writes.
pub const MIGRATIONS: &[Migration] = &[
    Migration {
        version: 1,
        name: "initial layout",
        apply: v0001_initial::apply,
    },
    Migration {
        version: 2,
        name: "signature format 3, state tree",
        apply: v0002_signature_format3::apply,
    },
    Migration {
        version: 3,
        name: "preview cache",
        apply: v0003_previews::apply,
    },
    Migration {
        version: 4,
        name: "patch descriptor cache",
        apply: v0004_patches::apply,
    },
    Migration {
        version: 5,
        name: "large blobs as files",
        apply: v0005_blob_files::apply,
    },
];

//! Mesh loading and preparation (SPEC §1): load → weld → orient → simplify → normalise →
//! smooth.

pub mod load;
pub mod orient;
pub mod prepare;
pub mod simplify;
pub mod smooth;
pub mod topology;
pub mod weld;

pub use load::{load_bytes, load_path, Format, Resources};
pub use prepare::{prepare, PrepareStats, PreparedMesh};
pub use topology::Topology;

use glam::DVec3;

/// A triangle soup as read from a file, in the file's own coordinates (glTF node transforms
/// applied). Nothing is welded or cleaned yet; indices are checked to be in range and
/// coordinates to be finite.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RawMesh {
    pub positions: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

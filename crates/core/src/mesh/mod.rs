//! Mesh loading and preparation (SPEC §1): load → weld → orient → simplify → normalise →
//! smooth.

pub mod cut;
pub mod load;
pub mod orient;
pub mod prepare;
pub mod refine;
pub mod simplify;
pub mod smooth;
pub mod topology;
pub mod weld;
pub mod write;

pub use load::{load_bytes, load_path, unsupported, Format, Resources};
pub use prepare::{prepare, PrepareStats, PreparedMesh};
pub use topology::Topology;

use glam::DVec3;

/// A `n × n` grid on the unit square in the plane z = 0, two triangles a cell, vertices row
/// by row: the flat surface unit tests know every answer on.
#[cfg(test)]
pub(crate) fn grid(n: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let row = n + 1;
    let positions = (0..row * row)
        .map(|i| DVec3::new((i % row) as f64, (i / row) as f64, 0.0) / n as f64)
        .collect();
    let mut triangles = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let v = y * row + x;
            triangles.push([v, v + 1, v + row + 1]);
            triangles.push([v, v + row + 1, v + row]);
        }
    }
    (positions, triangles)
}

/// A triangle soup as read from a file, in the file's own coordinates (glTF node transforms
/// applied). Nothing is welded or cleaned yet; indices are checked to be in range and
/// coordinates to be finite.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RawMesh {
    pub positions: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// Meshes are passed on borrowed, or by value where the callee may let them go early
/// ([`prepare`]): a print file's millions of triangles.
impl<'a> From<&'a RawMesh> for std::borrow::Cow<'a, RawMesh> {
    fn from(mesh: &'a RawMesh) -> Self {
        std::borrow::Cow::Borrowed(mesh)
    }
}

impl From<RawMesh> for std::borrow::Cow<'_, RawMesh> {
    fn from(mesh: RawMesh) -> Self {
        std::borrow::Cow::Owned(mesh)
    }
}

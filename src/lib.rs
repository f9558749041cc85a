//! `salient`: content-based 3D model retrieval with extended cone-curvature (ECC) salient
//! features. The modules follow the method's pipeline (see `SPEC.md`):
//!
//! - [`mesh`]: load OBJ / glTF / OFF / PLY / STL, weld, orient, simplify, normalise (§1);
//! - [`geodesic`]: local Dijkstra geodesics bounded by `D_g` (§2.1);
//! - [`waves`]: geodesic iso-lines traced into closed loops, their validity (§2.2–2.3);
//! - [`ecc`]: the extended cone-curvature vector of every vertex (§2.4);
//! - [`extract`]: the pipeline from a loaded mesh to per-vertex ECC, with statistics.

pub mod ecc;
pub mod error;
pub mod extract;
pub mod geodesic;
pub mod mesh;
pub mod params;
pub mod waves;

pub use error::{Error, Result};
pub use params::{EccParams, HeightRule, Limits, MeshParams, Params};

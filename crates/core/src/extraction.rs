//! What the first stages of the pipeline ([`crate::pipeline::extract`]) make: a prepared mesh
//! with the ECC of every vertex (SPEC §1–2), and what they counted and timed. Salient
//! features, descriptors and pictures start from it.

use serde::{Deserialize, Serialize};

use crate::ecc::{EccField, EccStats};
use crate::mesh::{PrepareStats, PreparedMesh, Topology};

/// A prepared mesh with the ECC vector of each of its vertices.
#[derive(Debug, Clone)]
pub struct Extraction {
    pub mesh: PreparedMesh,
    pub topology: Topology,
    pub ecc: EccField,
    pub stats: ExtractionStats,
}

/// Everything an extraction counted and timed.
/// Stored with every signature as JSON: a field added later takes its default in older ones.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ExtractionStats {
    pub load_seconds: f64,
    pub mesh: PrepareStats,
    pub topology_seconds: f64,
    /// Mean edge length of the prepared mesh, in normalised units.
    pub mean_edge_length: f64,
    pub ecc: EccStats,
    pub total_seconds: f64,
}

//! The extraction pipeline from a loaded mesh to per-vertex ECC, with the statistics and
//! per-stage timings every extraction reports.

use std::path::Path;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::ecc::{self, EccField, EccStats};
use crate::mesh::{self, PrepareStats, PreparedMesh, RawMesh, Topology};
use crate::params::{Limits, Params};
use crate::Result;

/// A prepared mesh with the ECC vector of each of its vertices.
#[derive(Debug, Clone)]
pub struct Extraction {
    pub mesh: PreparedMesh,
    pub topology: Topology,
    pub ecc: EccField,
    pub stats: ExtractionStats,
}

/// Everything an extraction counted and timed.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ExtractionStats {
    pub load_seconds: f64,
    pub mesh: PrepareStats,
    pub topology_seconds: f64,
    /// Mean edge length of the prepared mesh, in normalised units.
    pub mean_edge_length: f64,
    pub ecc: EccStats,
    pub total_seconds: f64,
}

/// Loads `path` (format from its extension, or sniffed) and extracts.
pub fn extract_path(path: &Path, params: &Params, limits: &Limits) -> Result<Extraction> {
    let clock = Instant::now();
    let raw = mesh::load_path(path, limits)?;
    let load_seconds = clock.elapsed().as_secs_f64();
    let mut extraction = extract(&raw, params)?;
    extraction.stats.load_seconds = load_seconds;
    extraction.stats.total_seconds += load_seconds;
    Ok(extraction)
}

/// Prepares `raw` (SPEC §1) and computes the ECC of every vertex (SPEC §2).
pub fn extract(raw: &RawMesh, params: &Params) -> Result<Extraction> {
    params.validate()?;
    let clock = Instant::now();
    let mesh = mesh::prepare(raw, &params.mesh)?;
    let topology_clock = Instant::now();
    let topology = Topology::new(&mesh.positions, &mesh.triangles);
    let topology_seconds = topology_clock.elapsed().as_secs_f64();
    let ecc = ecc::compute(&mesh, &topology, &params.ecc);
    let stats = ExtractionStats {
        load_seconds: 0.0,
        mesh: mesh.stats.clone(),
        topology_seconds,
        mean_edge_length: topology.mean_edge_length(),
        ecc: ecc.stats.clone(),
        total_seconds: clock.elapsed().as_secs_f64(),
    };
    Ok(Extraction {
        mesh,
        topology,
        ecc,
        stats,
    })
}

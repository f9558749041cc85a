//! Extraction parameters with the SPEC's defaults. They are serialised with every signature,
//! so a stored signature always says how it was made; [`PARAMS_VERSION`] changes whenever a
//! default or the meaning of a field changes (that means re-extraction, not a store migration).

use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// Version of the parameter set and of the extraction algorithm's semantics.
pub const PARAMS_VERSION: u32 = 1;

/// All parameters that influence a signature.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// [`PARAMS_VERSION`] at the time these parameters were written.
    pub version: u32,
    pub mesh: MeshParams,
    pub ecc: EccParams,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            version: PARAMS_VERSION,
            mesh: MeshParams::default(),
            ecc: EccParams::default(),
        }
    }
}

impl Params {
    /// Checks that every value is in the range the method is defined for, so that a bad
    /// parameter file is a clear error rather than a panic or a meaningless signature.
    pub fn validate(&self) -> Result<()> {
        let checks: [(bool, &'static str, &'static str); 5] = [
            (
                self.mesh.weld_tolerance > 0.0 && self.mesh.weld_tolerance < 0.1,
                "mesh.weld_tolerance",
                "must be in (0, 0.1)",
            ),
            (
                self.mesh.max_vertices >= 4,
                "mesh.max_vertices",
                "must be at least 4",
            ),
            (
                self.ecc.local_size > 0.0 && self.ecc.local_size <= 2.0,
                "ecc.local_size",
                "must be in (0, 2]",
            ),
            (
                (1..=64).contains(&self.ecc.waves),
                "ecc.waves",
                "must be between 1 and 64",
            ),
            (
                self.ecc.flat_max >= 0.0,
                "ecc.flat_max",
                "must not be negative",
            ),
        ];
        match checks.into_iter().find(|(ok, _, _)| !ok) {
            Some((_, name, message)) => Err(Error::InvalidParameter { name, message }),
            None => Ok(()),
        }
    }
}

/// Mesh preparation (SPEC §1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MeshParams {
    /// Vertices with positions equal after quantisation to this fraction of the bounding-box
    /// diagonal are merged (SPEC §1.2).
    pub weld_tolerance: f64,
    /// Meshes with more welded vertices are simplified to this count (SPEC §1.5).
    pub max_vertices: usize,
}

impl Default for MeshParams {
    fn default() -> Self {
        Self {
            weld_tolerance: 1e-6,
            max_vertices: 20_000,
        }
    }
}

/// How the cone height `D_s^i` is accumulated (SPEC §2.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum HeightRule {
    /// Only the steps along the wave normal count: exact on planes, spheres and cones.
    #[default]
    Axial,
    /// The paper's Definition 3 read literally: full distances between successive centres.
    Paper,
}

/// Extended cone-curvature (SPEC §2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EccParams {
    /// Local size `D_g` in normalised units (§3.2.1).
    pub local_size: f64,
    /// Number of waves `N`, the length of an ECC vector (§3.2.2).
    pub waves: usize,
    /// Largest accepted wave flatness (SPEC §2.3).
    pub flat_max: f64,
    /// Cone height rule (SPEC §2.4).
    pub height: HeightRule,
}

impl Default for EccParams {
    fn default() -> Self {
        Self {
            local_size: 0.3,
            waves: 10,
            flat_max: 0.5,
            height: HeightRule::Axial,
        }
    }
}

/// Resource limits on untrusted input. They protect the process, they do not change results,
/// so they are not part of [`Params`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Limits {
    /// Largest number of vertices a file may declare or contain before welding.
    pub max_input_vertices: usize,
    /// Largest number of triangles (after triangulating polygons).
    pub max_input_triangles: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_input_vertices: 5_000_000,
            max_input_triangles: 10_000_000,
        }
    }
}

//! The preparation pipeline of SPEC §1: weld → orient → simplify → normalise.

use std::borrow::Cow;

use std::time::Instant;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::orient::{orient, OrientStats};
use super::simplify::simplify;
use super::smooth::{denoise, Denoising};
use super::weld::{canonical_order, weld};
use super::RawMesh;
use crate::params::MeshParams;
use crate::Result;

/// A mesh ready for extraction: welded, oriented, bounded in size and normalised.
#[derive(Debug, Clone)]
pub struct PreparedMesh {
    /// Vertices in the input file's coordinates (after glTF node transforms).
    pub input_positions: Vec<DVec3>,
    /// The same vertices normalised into the unit sphere (SPEC §1.4),
    /// `(input - centre) * scale`, then smoothed (`MeshParams::smoothing`).
    pub positions: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Area-weighted surface centroid, in input coordinates.
    pub centre: DVec3,
    /// Inverse of the largest centre-to-vertex distance.
    pub scale: f64,
    pub stats: PrepareStats,
}

/// Counts and timings of preparation, reported with every extraction.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PrepareStats {
    pub input_vertices: usize,
    pub input_triangles: usize,
    pub welded_vertices: usize,
    pub degenerate_triangles_removed: usize,
    pub duplicate_triangles_removed: usize,
    pub orientation: OrientStats,
    /// True when the mesh had more than `max_vertices` and was simplified (SPEC §1.5).
    pub simplified: bool,
    /// Whether the mesh was rough and how much it was smoothed (`MeshParams::smoothing`).
    pub denoising: Denoising,
    pub vertices: usize,
    pub triangles: usize,
    pub weld_seconds: f64,
    pub orient_seconds: f64,
    pub simplify_seconds: f64,
    pub normalise_seconds: f64,
}

/// Runs SPEC §1.2–1.5 on a loaded mesh. A mesh given by value is let go once it is welded: a
/// print file's millions of triangles are not kept through the rest.
pub fn prepare<'a>(raw: impl Into<Cow<'a, RawMesh>>, params: &MeshParams) -> Result<PreparedMesh> {
    let raw = raw.into();
    let mut stats = PrepareStats {
        input_vertices: raw.positions.len(),
        input_triangles: raw.triangles.len(),
        ..Default::default()
    };
    let clock = Instant::now();
    let welded = weld(&raw, params.weld_tolerance)?;
    drop(raw);
    stats.weld_seconds = clock.elapsed().as_secs_f64();
    stats.welded_vertices = welded.positions.len();
    stats.degenerate_triangles_removed = welded.degenerate_removed;
    stats.duplicate_triangles_removed = welded.duplicates_removed;

    let clock = Instant::now();
    let mut triangles = welded.triangles;
    stats.orientation = orient(&welded.positions, &mut triangles);
    canonical_order(&mut triangles);
    stats.orient_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let (input_positions, triangles) =
        match simplify(&welded.positions, &triangles, params.max_vertices) {
            Some(smaller) => {
                stats.simplified = true;
                smaller
            }
            None => (welded.positions, triangles),
        };
    stats.simplify_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let (centre, scale) = normalisation(&input_positions, &triangles);
    let mut positions: Vec<DVec3> = input_positions
        .iter()
        .map(|&p| (p - centre) * scale)
        .collect();
    stats.denoising = denoise(&mut positions, &triangles, params);
    stats.normalise_seconds = clock.elapsed().as_secs_f64();
    stats.vertices = input_positions.len();
    stats.triangles = triangles.len();
    Ok(PreparedMesh {
        input_positions,
        positions,
        triangles,
        centre,
        scale,
        stats,
    })
}

/// SPEC §1.4: the area-weighted surface centroid goes to the origin, the farthest vertex to
/// distance 1.
pub fn normalisation(positions: &[DVec3], triangles: &[[u32; 3]]) -> (DVec3, f64) {
    let (mut weighted, mut area) = (DVec3::ZERO, 0.0);
    for t in triangles {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        let twice_area = (b - a).cross(c - a).length();
        weighted += (a + b + c) / 3.0 * twice_area;
        area += twice_area;
    }
    let centre = weighted / area;
    let radius = positions
        .iter()
        .map(|p| p.distance(centre))
        .fold(0.0, f64::max);
    (centre, 1.0 / radius)
}

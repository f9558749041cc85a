//! An intrinsic, global descriptor (issue #12): the distributions of geodesic distances on
//! the surface, which bending an articulated model leaves nearly unchanged, where D2 and the
//! light field see a new shape.
//!
//! Two histograms from [`SOURCES`] full Dijkstra runs over the edge graph (the metric of
//! SPEC §2.1, unbounded):
//! - **distances** from each source to every vertex (weighted by the vertex's area), divided
//!   by their mean — Hamza and Krim's geodesic shape distribution (2003);
//! - **eccentricity**: each vertex's largest distance to a source, divided by its mean, an
//!   approximation of the geodesic eccentricity of Ion et al. (2008) that is exact where a
//!   source sits on the farthest point, as farthest-point sampling tends to make it.
//!
//! Dividing by the mean makes both invariant to scale without the extrinsic radius of SPEC
//! §1.4, which bending changes. Sources are spread by farthest-point sampling in space,
//! which is cheap and covers every sizeable part of the surface.
//!
//! **Several components** (most web assets): a geodesic between two components does not
//! exist, so only distances within a component count; the sampling spreads sources over the
//! components, and each distance is divided by the mean over all of them. A model made of two
//! copies of a part gets nearly the descriptor of one (each copy gets about half the
//! sources). Vertices no source reaches (a component too small to get one) are left out.
//!
//! Hand-written: no crate computes shape distributions on meshes.

use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::geodesic::GeodesicScratch;
use crate::mesh::{PreparedMesh, Topology};

/// Dijkstra sources.
pub const SOURCES: usize = 32;
/// Bins of each histogram.
pub const BINS: usize = 32;
/// The distance histogram spans `[0, 3)` mean distances, the eccentricity one `[0, 2)` mean
/// eccentricities; larger values fall in the last bin.
const DISTANCE_RANGE: f64 = 3.0;
const ECCENTRICITY_RANGE: f64 = 2.0;

/// The two geodesic histograms, each summing to 1 (all zeros for a surface without area).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GeodesicDescriptor {
    pub distances: Vec<f32>,
    pub eccentricity: Vec<f32>,
}

impl GeodesicDescriptor {
    pub fn compute(mesh: &PreparedMesh, topology: &Topology) -> Self {
        let positions = &mesh.positions;
        let areas = vertex_areas(positions, &mesh.triangles);
        let sources = farthest_points(positions, SOURCES);
        // Each run is exact and independent; the sums below run in a fixed order, so the
        // result does not depend on the thread count.
        let runs: Vec<Vec<f32>> = sources
            .par_iter()
            .map_init(
                || GeodesicScratch::new(positions.len()),
                |scratch, &s| {
                    let d = scratch.run(topology, s, f64::INFINITY);
                    (0..positions.len() as u32)
                        .map(|v| d.get(v) as f32)
                        .collect()
                },
            )
            .collect();
        let mut eccentricity = vec![f32::NEG_INFINITY; positions.len()];
        for run in &runs {
            for (e, &d) in eccentricity.iter_mut().zip(run) {
                if d.is_finite() {
                    *e = e.max(d);
                }
            }
        }
        let distances = runs
            .iter()
            .flat_map(|run| run.iter().zip(&areas).map(|(&d, &a)| (d, a)));
        Self {
            distances: histogram(distances, DISTANCE_RANGE),
            eccentricity: histogram(
                eccentricity.iter().copied().zip(areas.iter().copied()),
                ECCENTRICITY_RANGE,
            ),
        }
    }

    /// The mean over the two histograms of the earth mover's distance on the line, in units
    /// of each histogram's range, so in [0, 1]. Unlike the L1 distance of the bins, it grows
    /// with how far mass moves, so a small stretch of the surface costs little.
    pub fn distance(&self, other: &Self) -> f64 {
        (emd_1d(&self.distances, &other.distances)
            + emd_1d(&self.eccentricity, &other.eccentricity))
            / 2.0
    }
}

/// A third of the area of each incident triangle: the surface each vertex stands for.
fn vertex_areas(positions: &[DVec3], triangles: &[[u32; 3]]) -> Vec<f64> {
    let mut areas = vec![0.0; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        let third = (b - a).cross(c - a).length() / 6.0;
        for v in t {
            areas[*v as usize] += third;
        }
    }
    areas
}

/// `count` vertices by farthest-point sampling in space, from the vertex farthest from the
/// centroid (the origin of the normalised mesh); ties go to the lower index.
fn farthest_points(positions: &[DVec3], count: usize) -> Vec<u32> {
    let farthest = |values: &[f64]| {
        values
            .iter()
            .enumerate()
            .fold((0, f64::NEG_INFINITY), |best, (i, &x)| {
                if x > best.1 {
                    (i, x)
                } else {
                    best
                }
            })
            .0
    };
    let mut nearest: Vec<f64> = positions.iter().map(|p| p.length_squared()).collect();
    let mut chosen = Vec::with_capacity(count.min(positions.len()));
    while chosen.len() < count.min(positions.len()) {
        let next = farthest(&nearest);
        if !chosen.is_empty() && nearest[next] == 0.0 {
            break; // every vertex coincides with a source
        }
        chosen.push(next as u32);
        let p = positions[next];
        for (n, q) in nearest.iter_mut().zip(positions) {
            *n = if chosen.len() == 1 {
                q.distance_squared(p)
            } else {
                n.min(q.distance_squared(p))
            };
        }
    }
    chosen
}

/// The `(value, weight)` pairs with finite values, divided by their weighted mean, in
/// [`BINS`] bins over `[0, range)`, summing to 1.
fn histogram(values: impl Iterator<Item = (f32, f64)> + Clone, range: f64) -> Vec<f32> {
    let finite = values.filter(|(v, w)| v.is_finite() && *w > 0.0);
    let (sum, weight) = finite
        .clone()
        .fold((0.0, 0.0), |(s, t), (v, w)| (s + v as f64 * w, t + w));
    let mut bins = vec![0.0f64; BINS];
    if weight <= 0.0 || sum <= 0.0 {
        return vec![0.0; BINS];
    }
    let mean = sum / weight;
    for (v, w) in finite {
        let bin = (v as f64 / mean / range * BINS as f64) as usize;
        bins[bin.min(BINS - 1)] += w;
    }
    bins.into_iter().map(|b| (b / weight) as f32).collect()
}

/// Earth mover's distance between two histograms of equal bins on the line: the L1 distance
/// of their cumulative sums, over the number of bins.
fn emd_1d(a: &[f32], b: &[f32]) -> f64 {
    let (mut carried, mut total) = (0.0f64, 0.0f64);
    for (&x, &y) in a.iter().zip(b) {
        carried += x as f64 - y as f64;
        total += carried.abs();
    }
    total / a.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_dimensional_emd_by_hand() {
        let at = |k: usize| {
            let mut h = vec![0.0f32; 4];
            h[k] = 1.0;
            h
        };
        assert_eq!(emd_1d(&at(0), &at(0)), 0.0);
        assert_eq!(emd_1d(&at(0), &at(1)), 0.25);
        assert_eq!(emd_1d(&at(0), &at(3)), 0.75);
        assert_eq!(emd_1d(&at(3), &at(0)), 0.75);
    }

    #[test]
    fn histogram_divides_by_the_weighted_mean_and_skips_unreachable_values() {
        // Values 1 and 3 with weights 3 and 1: mean 1.5, so 2/3 and 2 of the mean.
        let values = [(1.0f32, 3.0), (3.0, 1.0), (f32::INFINITY, 5.0)];
        let h = histogram(values.into_iter(), 3.0);
        let bin = |x: f64| (x / 3.0 * BINS as f64) as usize;
        assert_eq!(h[bin(2.0 / 3.0)], 0.75);
        assert_eq!(h[bin(2.0)], 0.25);
        assert!((h.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    }
}

//! An intrinsic, global descriptor (SPEC §9, the hybrid's intrinsic part): the distributions of geodesic distances on
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

use super::Span;
use crate::geodesic::{GeodesicScratch, Surface};
use crate::mesh::{PreparedMesh, Topology};
use crate::params::GeodesicRule;

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
                // Dijkstra whatever the ECC uses: these histograms are normalised by their
                // mean, which takes out most of its uniform excess, and their tuned scale
                // stays what it was.
                || GeodesicScratch::new(positions.len(), GeodesicRule::Dijkstra),
                |scratch, &s| {
                    let d = scratch.run(Surface::new(mesh, topology), s, f64::INFINITY);
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
        self.cumulative().distance(&other.cumulative())
    }

    /// The two histograms' cumulative sums: what [`GeodesicDescriptor::distance`] compares, kept
    /// by the ranking for every entry.
    pub fn cumulative(&self) -> Cumulative {
        let mut sums = [0.0f32; 2 * BINS];
        let (left, right) = sums.split_at_mut(BINS);
        for (out, histogram) in [(left, &self.distances), (right, &self.eccentricity)] {
            // A histogram of another length (a hand-made signature) counts as cut or padded.
            let mut carried = 0.0f32;
            for (k, s) in out.iter_mut().enumerate() {
                carried += histogram.get(k).copied().unwrap_or(0.0);
                *s = carried;
            }
        }
        Cumulative(sums)
    }
}

/// Both histograms' cumulative sums ([`GeodesicDescriptor::cumulative`]). On the line, the
/// earth mover's distance of two histograms of equal bins is the L1 distance of their
/// cumulative sums over the number of bins.
#[derive(Debug, Clone, PartialEq)]
pub struct Cumulative([f32; 2 * BINS]);

impl Cumulative {
    /// The mean of the two histograms' EMDs ([`GeodesicDescriptor::distance`]). Eight
    /// partial sums in a fixed order: the same value everywhere, and it vectorises.
    pub fn distance(&self, other: &Self) -> f64 {
        super::lane_sum(&self.0, &other.0, |x, y| (x - y).abs()) / (2 * BINS) as f64
    }

    /// Never above [`Cumulative::distance`] to any descriptor in `span` ([`Span::lane_sum`]).
    pub fn distance_to(&self, span: &Span) -> f64 {
        span.lane_sum(&self.0, |x, y| (x - y).abs()) / (2 * BINS) as f64
    }

    /// What a [`Span`] of these holds.
    pub fn values(&self) -> &[f32] {
        &self.0
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_dimensional_emd_by_hand() {
        // All mass in bin `k` of both histograms; bin `d` of the eccentricity in the second.
        let at = |k: usize, e: usize| {
            let one = |i: usize| {
                (0..BINS)
                    .map(|j| if j == i { 1.0f32 } else { 0.0 })
                    .collect()
            };
            GeodesicDescriptor {
                distances: one(k),
                eccentricity: one(e),
            }
        };
        let bins = BINS as f64;
        assert_eq!(at(0, 0).distance(&at(0, 0)), 0.0);
        assert_eq!(at(0, 0).distance(&at(1, 1)), 1.0 / bins);
        assert_eq!(at(0, 0).distance(&at(3, 0)), 1.5 / bins);
        assert_eq!(at(3, 0).distance(&at(0, 0)), 1.5 / bins);
        // A histogram cut short counts as zeros beyond its end.
        let mut short = at(0, 0);
        short.distances.truncate(1);
        assert_eq!(short.distance(&at(0, 0)), 0.0);
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

//! Salient points and salient regions (SPEC §3, paper §4.1–4.2).
//!
//! k-means over all ECC vectors picks the candidate cluster, non-maximum suppression keeps
//! one point per tip, and each point's region is the geodesic disk its waves covered.

mod kmeans;
mod region;

pub use kmeans::{kmeans, Clustering};
pub use region::{area, region, Region};

use serde::{Deserialize, Serialize};

use crate::extraction::Extraction;
use crate::geodesic::GeodesicScratch;
use crate::params::{CandidateRule, Params, RegionRule};

/// A salient point with its region.
#[derive(Debug, Clone, PartialEq)]
pub struct SalientPoint {
    pub vertex: u32,
    /// The final region size `D` of the vertex (SPEC §2.3); `D_g` for a fallback point whose
    /// waves all failed.
    pub region_size: f64,
    pub region: Region,
}

/// What detection counted (SPEC §3).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SalientStats {
    pub kmeans_iterations: usize,
    /// Members of the candidate cluster.
    pub candidates: usize,
    /// Candidates left after non-maximum suppression.
    pub after_suppression: usize,
    /// Points dropped for a small region (SPEC §3.4), or for an empty one.
    pub small_regions_dropped: usize,
    /// Points beyond `max_features`.
    pub capped: usize,
    /// True when nothing survived and the vertex of largest ECC norm was kept (SPEC §3.5).
    pub fallback: bool,
}

/// The salience score that orders candidates: mean or norm of the ECC vector (SPEC §3.1–3.2).
fn score(rule: CandidateRule, ecc: &[f64]) -> f64 {
    match rule {
        CandidateRule::Mean => ecc.iter().sum::<f64>() / ecc.len() as f64,
        CandidateRule::Norm => norm(ecc),
    }
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// Detects the salient points of an extraction, most salient first.
pub fn detect(extraction: &Extraction, params: &Params) -> (Vec<SalientPoint>, SalientStats) {
    let p = &params.salient;
    let ecc = &extraction.ecc;
    let mesh = &extraction.mesh;
    let mut stats = SalientStats::default();

    // §3.1: candidates are the members of the cluster with the most salient centre.
    let clustering = kmeans(
        ecc.values(),
        ecc.dimension(),
        p.clusters,
        p.restarts,
        p.seed,
    );
    stats.kmeans_iterations = clustering.iterations;
    let best = (0..clustering.centres.len())
        .max_by(|&a, &b| {
            score(p.candidates, &clustering.centres[a])
                .total_cmp(&score(p.candidates, &clustering.centres[b]))
                .then(b.cmp(&a))
        })
        .unwrap_or(0) as u32;
    let mut candidates: Vec<u32> = (0..ecc.len() as u32)
        .filter(|&v| clustering.labels[v as usize] == best)
        .collect();
    stats.candidates = candidates.len();

    // §3.2: non-maximum suppression within D_e, most salient first, ties by vertex index.
    let scores: Vec<f64> = ecc.vectors().map(|e| score(p.candidates, e)).collect();
    candidates.sort_by(|&a, &b| {
        scores[b as usize]
            .total_cmp(&scores[a as usize])
            .then(a.cmp(&b))
    });
    let mut accepted: Vec<u32> = Vec::new();
    for v in candidates {
        let here = mesh.positions[v as usize];
        if accepted
            .iter()
            .all(|&a| mesh.positions[a as usize].distance(here) >= p.suppression_distance)
        {
            accepted.push(v);
        }
    }
    stats.after_suppression = accepted.len();

    // §3.3–3.4: regions, then drop empty and small ones.
    let mut scratch = GeodesicScratch::new(mesh.positions.len(), params.ecc.geodesic);
    let mut points: Vec<SalientPoint> = accepted
        .into_iter()
        .filter(|&v| ecc.region_size[v as usize] > 0.0)
        .map(|v| {
            let size = ecc.region_size[v as usize];
            let region = region(mesh, &extraction.topology, &mut scratch, v, size);
            SalientPoint {
                vertex: v,
                region_size: size,
                region,
            }
        })
        .collect();
    let measure = |s: &SalientPoint| match p.region_rule {
        RegionRule::Size => s.region_size,
        RegionRule::Area => s.region.area,
    };
    let largest = points.iter().map(measure).fold(0.0, f64::max);
    points.retain(|s| s.region.area > 0.0 && measure(s) >= p.min_region_ratio * largest);
    stats.small_regions_dropped = stats.after_suppression - points.len();
    stats.capped = points.len().saturating_sub(p.max_features);
    points.truncate(p.max_features);

    // §3.5: always at least one feature.
    if points.is_empty() {
        stats.fallback = true;
        let v = (0..ecc.len())
            .max_by(|&a, &b| {
                norm(ecc.vector(a))
                    .total_cmp(&norm(ecc.vector(b)))
                    .then(b.cmp(&a))
            })
            .unwrap_or(0) as u32;
        let size = match ecc.region_size[v as usize] {
            d if d > 0.0 => d,
            _ => params.ecc.local_size,
        };
        let region = region(mesh, &extraction.topology, &mut scratch, v, size);
        points.push(SalientPoint {
            vertex: v,
            region_size: size,
            region,
        });
    }
    (points, stats)
}

//! Denoising by Taubin's λ|μ smoothing (SPEC §1.7; `docs/results/noise-shrec07-watertight/`): vertex-scale roughness of a
//! scanned or noisy mesh is read by the first waves (at `D_g / N`) as cone curvature and makes
//! spurious salient points (24 on CAPOD's dog at 1 % noise).
//!
//! Only a mesh that is rough is smoothed. Smoothing every mesh cost clean retrieval on the
//! tuning halves (CAPOD's low-poly pianos and chairs lose their thin parts; tuning mAP 0.881
//! → 0.856 over 0.08), so the rule tests for noise first: on a smooth surface the normal
//! component of the umbrella vector changes slowly, so it correlates with its neighbours'
//! (≥ 0.23 on every clean model of both collections but CAPOD's coarse pianos), while noise
//! makes it flip from vertex to vertex (≤ 0.18 on every SHREC'07 model at 0.5 % noise;
//! `docs/results/README.md`, "Noise").
//!
//! Plain Laplacian smoothing shrinks every convex tip, the very thing salient points are; the
//! μ step (slightly larger than λ, negative) undoes the shrinking of low frequencies, so the
//! pair is a low-pass filter (G. Taubin, "A signal processing approach to fair surface
//! design", SIGGRAPH 1995). The steps are whole umbrella steps, tangential part included:
//! noise of an edge length folds triangles, their normals are then noise too, and a step
//! along them left 13 spurious salient points on the dog where the whole step leaves none.
//! Hand-written: no crate of the registry smooths an index mesh, and it is a few lines.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::topology::{face_neighbours, NO_FACE};
use super::Topology;
use crate::params::MeshParams;

/// Taubin's pass-band pair: `1/λ + 1/μ ≈ 0.1`, the value of his paper.
const LAMBDA: f64 = 0.5;
const MU: f64 = -0.53;

/// Most λ|μ pairs a mesh gets, however fine or rough it is.
pub const MAX_ITERATIONS: usize = 40;

/// What [`denoise`] found and did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Denoising {
    /// The neighbour correlation of the normal umbrella field before smoothing ([`correlation`]).
    pub correlation: f64,
    /// λ|μ pairs applied; 0 for a smooth mesh.
    pub iterations: usize,
}

/// Smooths `positions` in place if the mesh is rough (`correlation` below
/// `params.rough_correlation`), over `params.smoothing` ([`taubin`]).
pub fn denoise(positions: &mut [DVec3], triangles: &[[u32; 3]], params: &MeshParams) -> Denoising {
    if params.smoothing <= 0.0 || positions.is_empty() {
        return Denoising::default();
    }
    let stencils = stencils(positions, triangles);
    let correlation = correlation(positions, triangles, &stencils);
    let iterations = if correlation < params.rough_correlation {
        let until = Some((triangles, params.rough_correlation));
        taubin(positions, &stencils, params.smoothing, until)
    } else {
        0
    };
    Denoising {
        correlation,
        iterations,
    }
}

/// The umbrella vector of `p`: the weighted mean of its stencil, minus `p`.
fn umbrella(positions: &[DVec3], p: DVec3, stencil: &[(u32, f64)]) -> Option<DVec3> {
    let (mut sum, mut weight) = (DVec3::ZERO, 0.0);
    for &(w, k) in stencil {
        sum += k * (positions[w as usize] - p);
        weight += k;
    }
    (weight > 0.0).then(|| sum / weight)
}

/// How much the normal component of each vertex's umbrella vector, over its mean edge length,
/// agrees with its neighbours' mean: `Σ s_v · mean(s_u) / Σ s_v²`. Near 1 on a smooth surface,
/// near 0 or below on noise; 1 for a surface without curvature.
pub fn correlation(positions: &[DVec3], triangles: &[[u32; 3]], stencils: &[Stencil]) -> f64 {
    let normals = vertex_normals(positions, triangles);
    let s: Vec<f64> = stencils
        .iter()
        .enumerate()
        .map(|(v, stencil)| {
            umbrella(positions, positions[v], stencil).map_or(0.0, |u| {
                let edge =
                    stencil.iter().map(|&(_, k)| 1.0 / k).sum::<f64>() / stencil.len() as f64;
                u.dot(normals[v]) / edge
            })
        })
        .collect();
    let (mut agreement, mut energy) = (0.0, 0.0);
    for (v, stencil) in stencils.iter().enumerate() {
        if !stencil.is_empty() {
            let mean =
                stencil.iter().map(|&(w, _)| s[w as usize]).sum::<f64>() / stencil.len() as f64;
            agreement += s[v] * mean;
            energy += s[v] * s[v];
        }
    }
    if energy > 0.0 {
        agreement / energy
    } else {
        1.0
    }
}

/// Smooths `positions` in place over about `length` (normalised units) and returns the number
/// of λ|μ pairs that took: `(length / mean edge length)²`, rounded down, at most
/// [`MAX_ITERATIONS`]. A step diffuses over about one edge, so its count follows the
/// resolution. Noise lengthens edges (at 1 % of the diagonal by half on CAPOD's dog), so the
/// mean is measured again after each pair and the count follows it down to the resolution of
/// the smoothed surface. With `until` (the triangles and a correlation), pairs go on while the
/// surface is still rough by [`correlation`]: noise of a third of an edge on a 2 500-vertex
/// star needs more pairs than the length gives. Deterministic: every step reads the previous
/// positions only.
pub fn taubin(
    positions: &mut [DVec3],
    stencils: &[Stencil],
    length: f64,
    until: Option<(&[[u32; 3]], f64)>,
) -> usize {
    let target = |positions: &[DVec3]| {
        let (sum, count) = stencils
            .iter()
            .enumerate()
            .flat_map(|(v, s)| s.iter().map(move |&(w, _)| (v, w)))
            .fold((0.0, 0usize), |(s, c), (v, w)| {
                (s + positions[v].distance(positions[w as usize]), c + 1)
            });
        match sum / count.max(1) as f64 {
            mean if mean > 0.0 => (length / mean).powi(2).floor() as usize,
            _ => 0,
        }
    };
    let rough = |positions: &[DVec3]| {
        until
            .is_some_and(|(triangles, smooth)| correlation(positions, triangles, stencils) < smooth)
    };
    // A mesh coarser than the length is left alone, rough or not: its edges are its shape
    // (CAPOD's 360-vertex pianos measure 0.13).
    if target(positions) == 0 {
        return 0;
    }
    let mut moved = positions.to_vec();
    let mut iterations = 0;
    while iterations < MAX_ITERATIONS && (iterations < target(positions) || rough(positions)) {
        iterations += 1;
        for factor in [LAMBDA, MU] {
            for ((out, &p), stencil) in moved.iter_mut().zip(positions.iter()).zip(stencils) {
                *out = umbrella(positions, p, stencil).map_or(p, |u| p + factor * u);
            }
            positions.copy_from_slice(&moved);
        }
    }
    iterations
}

/// The neighbours a vertex averages, with their weights (inverse edge lengths).
pub type Stencil = Vec<(u32, f64)>;

/// The neighbours each vertex averages, with their weights. A vertex on a boundary or a
/// non-manifold edge stays where it is (an empty stencil): sliding along the rim shrinks small
/// open pieces (a tree's leaves in CAPOD) to their centre, and their edges are the shape.
pub fn stencils(positions: &[DVec3], triangles: &[[u32; 3]]) -> Vec<Stencil> {
    let mut rim = vec![false; positions.len()];
    for (t, across) in triangles.iter().zip(face_neighbours(triangles).neighbour) {
        for k in (0..3).filter(|&k| across[k] == NO_FACE) {
            rim[t[k] as usize] = true;
            rim[t[(k + 1) % 3] as usize] = true;
        }
    }
    let topology = Topology::new(positions, triangles);
    (0..positions.len() as u32)
        .map(|v| match rim[v as usize] {
            true => Vec::new(),
            false => topology
                .neighbours(v)
                .map(|(w, length)| (w, 1.0 / length.max(f64::MIN_POSITIVE)))
                .collect(),
        })
        .collect()
}

/// Area-weighted unit normals; zero at a vertex whose faces cancel.
fn vertex_normals(positions: &[DVec3], triangles: &[[u32; 3]]) -> Vec<DVec3> {
    let mut normals = vec![DVec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        let n = (b - a).cross(c - a);
        for &v in t {
            normals[v as usize] += n;
        }
    }
    normals.into_iter().map(DVec3::normalize_or_zero).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::mesh::grid;

    #[test]
    fn a_plane_stays_flat_and_a_spike_flattens() {
        // Edges of 1/20 and 1/20·√2 (mean about 0.057): a length of 0.13 makes 5 pairs, of
        // 0.01 none.
        let (mut p, t) = grid(20);
        let s = stencils(&p, &t);
        assert_eq!(taubin(&mut p.clone(), &s, 0.01, None), 0);
        assert_eq!(taubin(&mut p, &s, 0.13, None), 5);
        assert!(p.iter().all(|q| q.z == 0.0), "a plane stays flat");
        // The rim stays where it is.
        assert_eq!(p[10], DVec3::new(0.5, 0.0, 0.0));
        assert_eq!(p[10 * 21], DVec3::new(0.0, 0.5, 0.0));

        // One vertex lifted by a tenth of the side: a spike of one vertex.
        let centre = 10 * 21 + 10;
        p[centre].z = 0.1;
        taubin(&mut p, &s, 0.13, None);
        assert!(p[centre].z < 0.04, "spike left at {}", p[centre].z);
    }

    /// A latitude-longitude sphere of radius 1.
    fn sphere() -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let (rings, segments) = (24u32, 48u32);
        let mut p = vec![DVec3::Z];
        for r in 1..rings {
            let theta = std::f64::consts::PI * r as f64 / rings as f64;
            for s in 0..segments {
                let phi = std::f64::consts::TAU * s as f64 / segments as f64;
                p.push(DVec3::new(
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                ));
            }
        }
        p.push(-DVec3::Z);
        let ring = |r: u32, s: u32| 1 + (r - 1) * segments + s % segments;
        let mut t = Vec::new();
        for s in 0..segments {
            t.push([0, ring(1, s), ring(1, s + 1)]);
            t.push([
                p.len() as u32 - 1,
                ring(rings - 1, s + 1),
                ring(rings - 1, s),
            ]);
            for r in 1..rings - 1 {
                t.push([ring(r, s), ring(r + 1, s), ring(r + 1, s + 1)]);
                t.push([ring(r, s), ring(r + 1, s + 1), ring(r, s + 1)]);
            }
        }
        (p, t)
    }

    /// Largest distance of a vertex from the unit sphere.
    fn off_sphere(p: &[DVec3]) -> f64 {
        p.iter()
            .map(|q| (q.length() - 1.0).abs())
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_sphere_keeps_its_radius() {
        let (mut p, t) = sphere();
        let s = stencils(&p, &t);
        assert!(taubin(&mut p, &s, 0.4, None) >= 10);
        assert!(off_sphere(&p) < 0.01, "{}", off_sphere(&p));
    }

    /// The rule smooths noise and leaves a smooth surface as it is.
    #[test]
    fn only_a_rough_mesh_is_smoothed() {
        use rand::{Rng, SeedableRng};
        // Edges of about 0.13: smoothing over 0.4 makes several pairs.
        let params = MeshParams {
            smoothing: 0.4,
            ..Default::default()
        };
        let (clean, t) = sphere();
        let mut p = clean.clone();
        let smooth = denoise(&mut p, &t, &params);
        assert!(smooth.correlation > 0.5, "{smooth:?}");
        assert_eq!((smooth.iterations, &p), (0, &clean));

        // Radial noise of a quarter of an edge.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut p: Vec<DVec3> = clean
            .iter()
            .map(|&q| q * (1.0 + rng.gen_range(-0.03..0.03)))
            .collect();
        let rms = |p: &[DVec3]| {
            (p.iter().map(|q| (q.length() - 1.0).powi(2)).sum::<f64>() / p.len() as f64).sqrt()
        };
        let before = rms(&p);
        let rough = denoise(&mut p, &t, &params);
        assert!(rough.correlation < params.rough_correlation, "{rough:?}");
        assert!(rough.iterations > 0);
        assert!(rms(&p) < before / 2.0, "{} of {before}", rms(&p));
    }
}

//! Patch descriptors for partial retrieval (issue #14): a model described piece by piece, so
//! that a part cut from it finds the piece it was. Around [`CENTRES`] vertices spread over the
//! surface (farthest-point sampling), the surface inside a ball of each of [`RADII`] (its
//! largest connected piece, as a part is cut) gets a small, rotation- and scale-invariant
//! description ([`piece`]): the D2 distribution and the distribution of distances from the
//! piece's centroid, both in units of the piece's mean distance from its centroid, and the
//! piece's principal spreads in the same unit. A part is described the same way, whole, and a
//! model is as near as its nearest patch ([`Patches::nearest`]). Scale-invariant, so a part's
//! size in its model need not be known.

use glam::DVec3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::d2::sample_surface;
use crate::mesh::RawMesh;
use crate::partial::cut;

/// Patch centres per model.
pub const CENTRES: usize = 64;
/// Ball radii of the patches around each centre, in normalised units (the model's radius is
/// 1, SPEC §1.4): the sizes of the parts `salient eval partial` cuts.
pub const RADII: [f64; 3] = [0.3, 0.4, 0.5];
const D2_BINS: usize = 16;
const D1_BINS: usize = 8;
const SPREADS: usize = 3;
/// Values of one piece's description.
pub const LEN: usize = D2_BINS + D1_BINS + SPREADS;
/// Points sampled on a piece.
const SAMPLES: usize = 256;
/// D2 distances up to this many mean radii, D1 up to this many (longer ones in the last bin).
const D2_RANGE: f64 = 4.0;
const D1_RANGE: f64 = 2.5;

/// A piece of surface: its description and the frame it was described in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Piece {
    /// [`LEN`] values, the same however the piece is moved, turned or scaled.
    pub description: [f32; LEN],
    pub frame: Frame,
}

/// Where a piece is: its samples' centroid, their mean distance from it (`unit`), and their
/// principal axes as rows, largest spread first. Matching two pieces' frames places one on the
/// other, up to the axes' signs and near-equal spreads' order
/// ([`crate::register::signed_permutations`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    pub centre: DVec3,
    pub unit: f64,
    pub axes: [DVec3; 3],
}

/// The description of one piece of surface, or `None` if it has no area.
pub fn piece(triangles: &[[DVec3; 3]], rng: &mut ChaCha8Rng) -> Option<Piece> {
    let points = sample_surface(triangles, SAMPLES, rng)?;
    let centre = points.iter().copied().sum::<DVec3>() / points.len() as f64;
    let unit = points.iter().map(|p| p.distance(centre)).sum::<f64>() / points.len() as f64;
    if unit <= 0.0 {
        return None;
    }
    let scaled: Vec<DVec3> = points.iter().map(|&p| (p - centre) / unit).collect();
    let mut out = [0.0f32; LEN];
    let pairs = (SAMPLES * (SAMPLES - 1) / 2) as f32;
    for (i, a) in scaled.iter().enumerate() {
        for b in &scaled[i + 1..] {
            let bin = ((a.distance(*b) / D2_RANGE * D2_BINS as f64) as usize).min(D2_BINS - 1);
            out[bin] += 1.0 / pairs;
        }
        let bin = ((a.length() / D1_RANGE * D1_BINS as f64) as usize).min(D1_BINS - 1);
        out[D2_BINS + bin] += 1.0 / SAMPLES as f32;
    }
    // Principal spreads: the square roots of the covariance's eigenvalues, largest first.
    let mut covariance = [0.0; 9];
    for p in &scaled {
        for (k, c) in covariance.iter_mut().enumerate() {
            *c += p[k / 3] * p[k % 3] / SAMPLES as f64;
        }
    }
    let eigen = glamx::DSymmetricEigen3::new(glamx::DMat3::from_cols_array(&covariance));
    let mut principal: Vec<(f64, DVec3)> = (0..3)
        .map(|k| {
            let axis = DVec3::from_array(eigen.eigenvectors.col(k).to_array());
            (eigen.eigenvalues[k].max(0.0).sqrt(), axis)
        })
        .collect();
    principal.sort_by(|a, b| b.0.total_cmp(&a.0));
    for (k, (spread, _)) in principal.iter().enumerate() {
        out[D2_BINS + D1_BINS + k] = *spread as f32;
    }
    Some(Piece {
        description: out,
        frame: Frame {
            centre,
            unit,
            axes: [principal[0].1, principal[1].1, principal[2].1],
        },
    })
}

/// How different two pieces are: half the L1 distance of each distribution (each in [0, 1])
/// plus the L1 distance of the spreads.
pub fn piece_distance(a: &[f32], b: &[f32]) -> f64 {
    let l1 = |r: std::ops::Range<usize>| -> f64 {
        a[r.clone()]
            .iter()
            .zip(&b[r])
            .map(|(x, y)| (x - y).abs() as f64)
            .sum()
    };
    l1(0..D2_BINS) / 2.0 + l1(D2_BINS..D2_BINS + D1_BINS) / 2.0 + l1(D2_BINS + D1_BINS..LEN)
}

/// A model's patches: [`LEN`] values each, and each one's frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Patches {
    pub values: Vec<f32>,
    pub frames: Vec<Frame>,
}

impl Patches {
    /// The patches of a normalised mesh (SPEC §1.4), their samples seeded by `seed`.
    pub fn compute(positions: &[DVec3], triangles: &[[u32; 3]], seed: u64) -> Self {
        let raw = RawMesh {
            positions: positions.to_vec(),
            triangles: triangles.to_vec(),
        };
        let mut values = Vec::with_capacity(CENTRES * RADII.len() * LEN);
        let mut frames = Vec::with_capacity(CENTRES * RADII.len());
        let mut stream = 0;
        for centre in farthest_points(positions, triangles, CENTRES) {
            for radius in RADII {
                stream += 1;
                let Some(piece_mesh) = cut(&raw, positions[centre], radius) else {
                    continue;
                };
                let corners: Vec<[DVec3; 3]> = piece_mesh
                    .triangles
                    .iter()
                    .map(|t| t.map(|v| piece_mesh.positions[v as usize]))
                    .collect();
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(stream);
                if let Some(described) = piece(&corners, &mut rng) {
                    values.extend(described.description);
                    frames.push(described.frame);
                }
            }
        }
        Self { values, frames }
    }

    pub fn len(&self) -> usize {
        self.values.len() / LEN
    }

    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// The distance of `part` ([`piece`]) to the nearest patch; infinite without patches.
    pub fn nearest(&self, part: &[f32]) -> f64 {
        self.closest(part, 1).first().map_or(f64::INFINITY, |c| c.0)
    }

    /// The `n` patches nearest `part`, nearest first: each one's distance and frame.
    pub fn closest(&self, part: &[f32], n: usize) -> Vec<(f64, Frame)> {
        let mut all: Vec<(f64, Frame)> = self
            .values
            .chunks_exact(LEN)
            .map(|p| piece_distance(part, p))
            .zip(self.frames.iter().copied())
            .collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0));
        all.truncate(n);
        all
    }
}

/// `count` vertices spread over the used ones by farthest-point sampling (Euclidean), from the
/// vertex farthest from the origin (ties by index): deterministic for a mesh.
fn farthest_points(positions: &[DVec3], triangles: &[[u32; 3]], count: usize) -> Vec<usize> {
    let mut used = vec![false; positions.len()];
    for &v in triangles.iter().flatten() {
        used[v as usize] = true;
    }
    // The first is the vertex farthest from the origin; then each the farthest from those
    // chosen.
    let mut nearest: Vec<f64> = used
        .iter()
        .map(|&u| if u { f64::INFINITY } else { f64::NEG_INFINITY })
        .collect();
    let mut chosen = Vec::with_capacity(count);
    let farthest = |score: &[f64]| {
        score
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
            .map(|(i, &d)| (i, d))
    };
    let from_origin: Vec<f64> = positions
        .iter()
        .zip(&used)
        .map(|(p, &u)| if u { p.length() } else { f64::NEG_INFINITY })
        .collect();
    let mut next = farthest(&from_origin);
    while let Some((v, d)) = next {
        if chosen.len() == count || d <= 0.0 || d == f64::NEG_INFINITY {
            break;
        }
        chosen.push(v);
        let here = positions[v];
        for (n, p) in nearest.iter_mut().zip(positions) {
            *n = n.min(p.distance(here));
        }
        next = farthest(&nearest);
    }
    chosen
}

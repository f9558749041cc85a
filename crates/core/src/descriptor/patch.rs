//! Patch descriptors for partial retrieval (`docs/results/partial/`): a model described piece by piece, so
//! that a part cut from it finds the piece it was. Around vertices spread over the surface
//! (farthest-point sampling), the surface inside a ball of each of a [`Layout`]'s radii (its
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
use crate::mesh::cut::{cut, near};
use crate::mesh::RawMesh;

/// Where a model's patches are cut: around how many centres, and balls of which radii, in
/// normalised units (the model's radius is 1, SPEC §1.4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Layout {
    pub centres: usize,
    pub radii: &'static [f64],
}

impl Layout {
    /// Registration's starts (`crate::partial::Probe::residual`): 64 centres, the sizes of the
    /// parts `salient eval partial` cuts.
    pub const FRAMES: Layout = Layout {
        centres: 64,
        radii: &[0.3, 0.4, 0.5],
    };
    /// Stored for every model ([`Packed`]) to pick a partial search's candidates, each radius
    /// in turn ([`crate::part_search::candidates`]). Chosen on the tuning halves
    /// (`docs/results/partial/`) for parts of 15–50 % of the surface: ranking every model by
    /// its patches alone, the source among the 50 nearest for 0.81–0.90 of CAPOD's parts and
    /// 0.60–0.85 of SHREC'07's, where one radius of 0.4 gave 0.70–0.71 and 0.49–0.68. Served
    /// (only models the part fits are candidates), CAPOD's tuning half registered the source
    /// for 0.60–0.74 of them (0.56–0.65 with one radius). ~3.4× the cost (~185 ms a model).
    pub const STORED: Layout = Layout {
        centres: 64,
        radii: &[0.25, 0.4, 0.6, 0.9],
    };
}

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
    // Pairs counted in f32 with integer counts: 32 640 distances a piece, and a model has
    // ~200 pieces.
    let single: Vec<glam::Vec3A> = scaled.iter().map(|p| p.as_vec3().into()).collect();
    let mut counts = [0u32; D2_BINS];
    let per_range = D2_BINS as f32 / D2_RANGE as f32;
    for (i, a) in single.iter().enumerate() {
        for b in &single[i + 1..] {
            counts[((a.distance(*b) * per_range) as usize).min(D2_BINS - 1)] += 1;
        }
    }
    let pairs = (SAMPLES * (SAMPLES - 1) / 2) as f32;
    for (o, c) in out.iter_mut().zip(counts) {
        *o = c as f32 / pairs;
    }
    for a in &scaled {
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
    /// Which of the layout's radii each piece was cut with (its index): a piece too small to
    /// describe is left out, so the order alone does not say.
    pub radii: Vec<u8>,
}

impl Patches {
    /// The patches of a normalised mesh (SPEC §1.4) in a `layout`, their samples seeded by
    /// `seed`.
    pub fn compute(positions: &[DVec3], triangles: &[[u32; 3]], seed: u64, layout: Layout) -> Self {
        let Layout { centres, radii } = layout;
        let raw = RawMesh {
            positions: positions.to_vec(),
            triangles: triangles.to_vec(),
        };
        let mut values = Vec::with_capacity(centres * radii.len() * LEN);
        let mut frames = Vec::with_capacity(centres * radii.len());
        let mut kept = Vec::with_capacity(centres * radii.len());
        let mut stream = 0;
        let largest = radii.iter().copied().fold(0.0, f64::max);
        for centre in farthest_points(positions, triangles, centres) {
            let around = near(&raw, positions[centre], largest);
            for (index, &radius) in radii.iter().enumerate() {
                stream += 1;
                let Some(piece_mesh) = cut(&around, positions[centre], radius) else {
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
                    kept.push(index as u8);
                }
            }
        }
        Self {
            values,
            frames,
            radii: kept,
        }
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

/// Patch descriptions as stored ([`Layout::STORED`]), a byte a value: distributions in
/// 1/255ths, spreads in 1/127ths clamped at 2 mean radii (a straight segment's is 1.15), each
/// with its radius. 7 170 bytes a model; the rounding moved no tuning half's candidate recall
/// by more than 0.012.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packed {
    /// Each piece's radius (its index in the layout) and description.
    pieces: Vec<(u8, PackedPiece)>,
    /// The layout's radii.
    radii: u8,
}

/// A part's description in [`Packed`]'s units.
pub type PackedPiece = [u8; LEN];

/// The first byte of a stored [`Packed`]: entries of another layout or encoding are made again
/// (1: 64 × 0.4 of the radius, no radius a piece).
pub const PACKED_LAYOUT: u8 = 2;
const DISTRIBUTION_STEPS: f32 = 255.0;
const SPREAD_STEPS: f32 = 127.0;

impl Packed {
    /// `patches` cut in `layout`.
    pub fn of(patches: &Patches, layout: Layout) -> Self {
        Self {
            pieces: (patches.radii.iter().copied())
                .zip(patches.values.chunks_exact(LEN).map(Self::piece))
                .collect(),
            radii: layout.radii.len() as u8,
        }
    }

    /// One description in bytes.
    pub fn piece(description: &[f32]) -> PackedPiece {
        let mut out = [0u8; LEN];
        for (k, (o, v)) in out.iter_mut().zip(description).enumerate() {
            let steps = if k < D2_BINS + D1_BINS {
                DISTRIBUTION_STEPS
            } else {
                SPREAD_STEPS
            };
            *o = (v * steps).round().clamp(0.0, 255.0) as u8;
        }
        out
    }

    /// [`piece_distance`] from `part` to the nearest piece of each radius of the layout;
    /// infinite for a radius without pieces.
    pub fn nearest(&self, part: &PackedPiece) -> Vec<f64> {
        let mut nearest = vec![f64::INFINITY; usize::from(self.radii)];
        for (radius, p) in &self.pieces {
            let l1 = |r: std::ops::Range<usize>| -> u32 {
                p[r.clone()]
                    .iter()
                    .zip(&part[r])
                    .map(|(a, b)| u32::from(a.abs_diff(*b)))
                    .sum()
            };
            let d = f64::from(l1(0..D2_BINS + D1_BINS)) / (2.0 * f64::from(DISTRIBUTION_STEPS))
                + f64::from(l1(D2_BINS + D1_BINS..LEN)) / f64::from(SPREAD_STEPS);
            let kept = &mut nearest[usize::from(*radius)];
            *kept = kept.min(d);
        }
        nearest
    }

    /// The layout's byte, the number of radii, then each piece's radius and description.
    pub fn to_bytes(&self) -> Vec<u8> {
        let pieces = self
            .pieces
            .iter()
            .flat_map(|(radius, p)| std::iter::once(*radius).chain(p.iter().copied()));
        [PACKED_LAYOUT, self.radii]
            .into_iter()
            .chain(pieces)
            .collect()
    }

    /// `None` for an entry of another layout (made again) or a damaged one.
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        let [layout, radii, pieces @ ..] = bytes else {
            return None;
        };
        if *layout != PACKED_LAYOUT || pieces.len() % (LEN + 1) != 0 {
            return None;
        }
        let pieces: Vec<(u8, PackedPiece)> = pieces
            .chunks_exact(LEN + 1)
            .map(|c| (c[0], c[1..].try_into().expect("LEN bytes")))
            .collect();
        pieces
            .iter()
            .all(|(radius, _)| radius < radii)
            .then_some(Self {
                pieces,
                radii: *radii,
            })
    }
}

//! Partial retrieval (`docs/results/partial/`, the paper's stated reason for local features): the query is
//! a piece of a model — cut from it, an open surface with a boundary — and a stored model
//! ranks by how well the piece's salient features fit among its own.
//!
//! Three things differ from a whole-model search:
//! - **Size.** SPEC §1.4 scales every mesh to the unit sphere, which magnifies a part two or
//!   three times against its source, and `D_g`-sized features no longer correspond. A part's
//!   size in its model is unknown (a query's units say nothing about a stored model's), so
//!   the part is described at each of a few sizes ([`PartialParams::scales`], or the one the
//!   caller knows) by [`Params::at_scale`], and each model ranks by the size that fits it
//!   best.
//! - **Transport.** All of the part's features must find a place in the model, but the rest
//!   of the model is free ([`part_in`]); no count penalty.
//! - **Verification.** A part's few salient features are generic (a tip fits among the tips
//!   of many models), so the best fits are checked on the geometry: the part's surface is
//!   registered into each one's ([`Probe::residual`]) and they rank by how far it stays from
//!   it ([`crate::part_search`]).
//!
//! The cut boundary needs no rule of its own: a wave that reaches a boundary is invalid
//! (SPEC §2.3), so a vertex near the cut has a shrunk region or none, and no region spans it.

use glam::{DMat3, DMat4, DVec3};
use glamx::{Mat3, Vec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::descriptor::d2::sample_surface;
use crate::descriptor::patch::{piece, Frame, Layout, Packed, Patches, Piece};
use crate::mesh::{prepare, RawMesh};
use crate::params::{MeshParams, Params, PartialParams, SimilarityParams};
use crate::pipeline::compute_features;
use crate::register::{signed_permutations, Motion, Surface};
use crate::similarity::{part_bound, part_in, CostMatrix, Features, Summary};
use crate::{Error, Result};

/// A part described at each size it is searched at.
#[derive(Debug, Clone)]
pub struct Part {
    views: Vec<View>,
}

/// The part at one size.
#[derive(Debug, Clone)]
struct View {
    scale: f64,
    features: Features,
    summary: Summary,
}

/// How a part compares with one model: the distance and the size it was found at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fit {
    pub distance: f64,
    pub scale: f64,
}

impl Part {
    /// Describes `raw` at each of `scales` (each in [`PartialParams::RANGE`]) with the
    /// extraction parameters of `params`; `similarity` must be the one the ranking uses (its
    /// `W` shapes the bounds' summaries). Sizes at which the part has no salient feature are
    /// left out; a part with none at any size is an error.
    pub fn extract(
        raw: &RawMesh,
        params: &Params,
        scales: &[f64],
        similarity: &SimilarityParams,
    ) -> Result<Self> {
        if scales.is_empty()
            || scales.len() > PartialParams::MAX_SCALES
            || !scales.iter().all(|r| PartialParams::RANGE.contains(r))
        {
            return Err(Error::InvalidParameter {
                name: "part scale",
                message: "1 to 8 sizes, each in [0.2, 1]",
            });
        }
        let mut views = Vec::with_capacity(scales.len());
        for &scale in scales {
            let signature = compute_features(raw, &params.at_scale(scale))?;
            let features = Features::of(&signature.features);
            if !features.is_empty() {
                views.push(View {
                    scale,
                    summary: Summary::of(&features, similarity),
                    features,
                });
            }
        }
        if views.is_empty() {
            return Err(Error::NoFeatures);
        }
        Ok(Self { views })
    }

    /// The sizes the part was described at, with its salient feature count at each.
    pub fn sizes(&self) -> impl Iterator<Item = (f64, usize)> + '_ {
        self.views.iter().map(|v| (v.scale, v.features.len()))
    }

    /// A lower bound on [`Part::fit`]'s distance from a model's summary ([`part_bound`] at
    /// the best size).
    pub fn bound(&self, model: &Summary) -> f64 {
        self.views
            .iter()
            .map(|v| part_bound(&v.summary, model))
            .fold(f64::INFINITY, f64::min)
    }

    /// The best fit of the part into `model` over its sizes, or `None` when none is within
    /// `limit` (sizes whose nearest-feature bound exceeds it are not solved).
    pub fn fit(&self, model: &Features, similarity: &SimilarityParams, limit: f64) -> Option<Fit> {
        self.views
            .iter()
            .filter_map(|v| {
                let costs = CostMatrix::new(&v.features, model, similarity);
                (costs.nearest_bound() <= limit).then(|| Fit {
                    distance: part_in(&costs),
                    scale: v.scale,
                })
            })
            .filter(|f| f.distance <= limit)
            .min_by(|a, b| a.distance.total_cmp(&b.distance))
    }
}

/// A stored model as verification places parts in it: its normalised surface, before
/// smoothing (the part is not smoothed), and its patches ([`crate::descriptor::patch`]).
pub struct Target {
    surface: Surface,
    patches: Patches,
    /// SPEC §1.4's normalisation of the model: its surface is `(p - centre) * scale`.
    centre: DVec3,
    scale: f64,
}

impl Target {
    /// The target of a stored model, prepared as extraction prepares it (SPEC §1).
    pub fn new(raw: &RawMesh, params: &MeshParams) -> Result<Self> {
        let mesh = prepare(raw, params)?;
        let positions: Vec<Vec3> = mesh
            .input_positions
            .iter()
            .map(|&p| Vec3::from_array(((p - mesh.centre) * mesh.scale).as_vec3().to_array()))
            .collect();
        Ok(Self {
            surface: Surface::new(positions, mesh.triangles.clone())?,
            patches: Patches::compute(&mesh.positions, &mesh.triangles, 7, Layout::FRAMES),
            centre: mesh.centre,
            scale: mesh.scale,
        })
    }

    pub fn patches(&self) -> &Patches {
        &self.patches
    }
}

/// The stored patches of a model's upload ([`Layout::STORED`]), prepared as extraction
/// prepares it (SPEC §1).
pub fn stored_patches<'a>(
    raw: impl Into<std::borrow::Cow<'a, RawMesh>>,
    params: &MeshParams,
) -> Result<Packed> {
    let mesh = prepare(raw, params)?;
    let patches = Patches::compute(&mesh.positions, &mesh.triangles, 7, Layout::STORED);
    Ok(Packed::of(&patches, Layout::STORED))
}

/// Patches of a target whose frames start a placement. These settings were chosen on CAPOD's
/// tuning half (`docs/results/partial/`: from 3 starts, 2 refined, 10 rounds, the source in
/// the top 5 rose 0.47 → 0.59); more starts and rounds help because a patch is cut around
/// other centres than the part, so its frame places the part only roughly.
const STARTS: usize = 12;
/// Part samples that score the starts, and the starts refined by ICP.
const COARSE: usize = 64;
const REFINED: usize = 4;
/// Part samples ICP fits on and the residual is measured on, and ICP's rounds.
const SAMPLES: usize = 256;
const ROUNDS: usize = 30;
/// While scoring starts, a sample farther than this many part units from the surface counts
/// as this far.
const CAP: f32 = 0.5;

/// RMS distance, in the part's units, within which a part is plain ([`Probe::is_plain`]): a
/// relief of 2 % of its size is no feature.
pub const PLAIN: f32 = 0.02;

/// The RMS distance of `points` from their algebraic best-fit sphere (`|p|² = 2 c·p + d` by
/// least squares), or `None` when no sphere is determined (points on a plane or a line).
/// Hand-written: one 4 × 4 solve, not worth a linear-algebra crate.
fn sphere_rms(points: &[Vec3]) -> Option<f32> {
    let (mut normal, mut right) = (glam::DMat4::ZERO, glam::DVec4::ZERO);
    let wide = |p: &Vec3| DVec3::new(p.x.into(), p.y.into(), p.z.into());
    for p in points.iter().map(wide) {
        let row = glam::DVec4::new(2.0 * p.x, 2.0 * p.y, 2.0 * p.z, 1.0);
        normal += glam::DMat4::from_cols(row * row.x, row * row.y, row * row.z, row * row.w);
        right += row * p.length_squared();
    }
    if normal.determinant().abs() < 1e-9 * (points.len() as f64).powi(4) {
        return None;
    }
    let solution = normal.inverse() * right;
    let centre = solution.truncate();
    let radius = (solution.w + centre.length_squared()).max(0.0).sqrt();
    let squares: f64 = points
        .iter()
        .map(|p| (wide(p).distance(centre) - radius).powi(2))
        .sum();
    Some((squares / points.len() as f64).sqrt() as f32)
}

/// A part as verification places it: its description and frame, and samples of its surface in
/// that frame (centred, in its units, along its principal axes).
pub struct Probe {
    piece: Piece,
    samples: Vec<Vec3>,
}

impl Probe {
    /// The probe of a part in any units; `None` when it has no area.
    pub fn new(raw: &RawMesh) -> Option<Self> {
        let corners: Vec<[DVec3; 3]> = raw
            .triangles
            .iter()
            .map(|t| t.map(|v| raw.positions[v as usize]))
            .collect();
        let mut rng = ChaCha8Rng::seed_from_u64(0x9a27);
        let piece = piece(&corners, &mut rng)?;
        let Frame { centre, unit, axes } = piece.frame;
        let samples = sample_surface(&corners, SAMPLES, &mut rng)?
            .into_iter()
            .map(|p| {
                let q = (p - centre) / unit;
                Vec3::new(
                    axes[0].dot(q) as f32,
                    axes[1].dot(q) as f32,
                    axes[2].dot(q) as f32,
                )
            })
            .collect();
        Some(Self { piece, samples })
    }

    /// Whether the part is plain: its samples lie within [`PLAIN`] of their best plane or
    /// their best sphere. Such a part lies on any surface like it (every flat face, every
    /// ball), so finding it is weak evidence for a model: the evaluation counts these parts
    /// as featureless and reports them apart.
    pub fn is_plain(&self) -> bool {
        let n = self.samples.len() as f32;
        // The samples are along the part's principal axes, least spread last: the plane's
        // normal.
        let depth = self.samples.iter().map(|q| q.z).sum::<f32>() / n;
        let plane = (self
            .samples
            .iter()
            .map(|q| (q.z - depth).powi(2))
            .sum::<f32>()
            / n)
            .sqrt();
        plane <= PLAIN || sphere_rms(&self.samples).is_some_and(|rms| rms <= PLAIN)
    }

    pub fn description(&self) -> &[f32] {
        &self.piece.description
    }

    /// How well the part registers into `target` ([`Probe::register`]); infinite when it
    /// cannot be placed.
    pub fn residual(&self, target: &Target) -> f64 {
        self.register(target).map_or(f64::INFINITY, |r| r.residual)
    }

    /// The part registered into `target`: placed by the frames of the target's patches
    /// nearest its description (their size, centre and principal axes, each proper signed
    /// order of the axes), the best starts refined by ICP. Its residual is the mean distance
    /// of its samples from the target's surface in units of the part's size there: near 0 for
    /// the model the part was cut from; lower is better.
    pub fn register(&self, target: &Target) -> Option<Registration> {
        let coarse = &self.samples[..COARSE.min(self.samples.len())];
        let mut starts: Vec<(f32, Mat3, Vec3, f32)> = Vec::new();
        for (_, frame) in target.patches.closest(&self.piece.description, STARTS) {
            let unit = frame.unit as f32;
            let column = |k: usize| Vec3::from_array(frame.axes[k].as_vec3().to_array());
            // Columns are the patch's axes: a point in the part's frame goes along them.
            let axes = Mat3::from_cols(column(0), column(1), column(2));
            let centre = Vec3::from_array(frame.centre.as_vec3().to_array());
            for order in signed_permutations().filter(|s| s.determinant() > 0.0) {
                let linear = axes * order * unit;
                let score = target
                    .surface
                    .mean_distance(coarse.iter().map(|&q| linear * q + centre), CAP * unit)
                    / unit;
                starts.push((score, linear, centre, unit));
            }
        }
        starts.sort_by(|a, b| a.0.total_cmp(&b.0));
        starts
            .iter()
            .take(REFINED)
            .map(|&(_, linear, centre, unit)| {
                let placed: Vec<Vec3> = self.samples.iter().map(|&q| linear * q + centre).collect();
                // The patch's size is the part's only roughly (the cuts differ): ICP fits
                // the scale too, and the residual is in units of the part's fitted size.
                let motion = target.surface.icp(&placed, ROUNDS, true);
                let sum: f32 = placed
                    .iter()
                    .map(|&p| target.surface.distance(motion.apply(p)))
                    .sum();
                let residual = f64::from(sum / placed.len() as f32 / (unit * motion.scale));
                (residual, linear, centre, motion)
            })
            .filter(|r| r.0.is_finite())
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(residual, linear, centre, motion)| Registration {
                residual,
                placement: self.placement(target, linear, centre, &motion),
            })
    }

    /// The similarity taking the part's own coordinates to the target's: into the part's
    /// frame, by the start (`linear`, `centre`) and ICP's `motion` onto the target's
    /// normalised surface, then out of SPEC §1.4's normalisation.
    fn placement(&self, target: &Target, linear: Mat3, centre: Vec3, motion: &Motion) -> DMat4 {
        let wide3 = |m: Mat3| DMat3::from_cols_array(&m.to_cols_array().map(f64::from));
        let wide = |v: Vec3| DVec3::new(v.x.into(), v.y.into(), v.z.into());
        let Frame {
            centre: c,
            unit,
            axes,
        } = self.piece.frame;
        let into_frame = DMat4::from_mat3(DMat3::from_cols(axes[0], axes[1], axes[2]).transpose())
            * DMat4::from_scale(DVec3::splat(1.0 / unit))
            * DMat4::from_translation(-c);
        let start = DMat4::from_translation(wide(centre)) * DMat4::from_mat3(wide3(linear));
        let fitted = DMat4::from_translation(wide(motion.shift))
            * DMat4::from_mat3(wide3(motion.rotation) * f64::from(motion.scale));
        let out = DMat4::from_translation(target.centre)
            * DMat4::from_scale(DVec3::splat(1.0 / target.scale));
        out * fitted * start * into_frame
    }
}

/// Where a part lies in a model and how well it fits there ([`Probe::register`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Registration {
    pub residual: f64,
    /// Takes the part's coordinates to the model's (as uploaded): a rotation, a uniform
    /// scale and a shift.
    pub placement: DMat4,
}

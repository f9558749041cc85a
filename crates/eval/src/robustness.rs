//! Robustness of the salient points (SPEC §7; paper §6.1, Fig. 11, Tables 2–3): the mesh is
//! simplified to fractions of its faces, displaced by Gaussian noise, and moved and scaled
//! rigidly; each version is extracted again and compared with the original — how many of the
//! original salient points reappear within `D_e`, and `SIM` between the two signatures.
//!
//! Points are matched in the original's normalised frame (SPEC §1.4): a version's salient
//! points are taken back to the original's input coordinates (simplification and noise keep
//! them; the motion is undone) and normalised with the original's centre and scale, so that
//! the matching measures the points, not a change of frame.

use std::path::Path;

use glam::{DMat4, DQuat, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use super::report::{score, write, write_json, Table};
use salient_core::mesh::simplify::simplify_to_triangles;
use salient_core::mesh::weld::bounds;
use salient_core::mesh::{prepare, PreparedMesh, RawMesh};
use salient_core::params::Params;
use salient_core::pipeline::compute;
use salient_core::similarity::compare;
use salient_core::Result;

/// Face fractions of the resolution levels: the paper's simplification rates 20, 40, 60, 80
/// and 99.4 % (Table 2).
pub const FACE_FRACTIONS: [f64; 5] = [0.8, 0.6, 0.4, 0.2, 0.006];

/// Root-mean-square length of the Gaussian noise displacement, as fractions of the
/// bounding-box diagonal.
pub const NOISE_LEVELS: [f64; 2] = [0.005, 0.01];

/// One version of the mesh and what extraction found on it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Trial {
    pub name: String,
    pub vertices: usize,
    pub faces: usize,
    /// Extraction time of the signature (preparation, ECC, salient points, D2), as Table 3.
    pub extraction_seconds: f64,
    /// Salient points found on this version.
    pub points: usize,
    /// Original salient points with one of this version's within `D_e`.
    pub found: usize,
    /// This version's salient points with no original one within `D_e`.
    pub unmatched: usize,
    /// `SIM` between the original's signature and this version's (SPEC §5); 0 for the
    /// original.
    pub sim: f64,
}

/// Everything `salient eval robustness` reports for one mesh.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RobustnessReport {
    pub mesh: String,
    /// `D_e`, the matching radius in normalised units.
    pub match_distance: f64,
    /// The seed of the noise and the motion.
    pub seed: u64,
    /// The original first.
    pub trials: Vec<Trial>,
}

/// Runs every trial on `raw` with `params`; `seed` draws the noise and the motion.
pub fn run(name: &str, raw: &RawMesh, params: &Params, seed: u64) -> Result<RobustnessReport> {
    // The welded, oriented (and, if large, bounded) mesh every version starts from.
    let base = prepare(raw, &params.mesh)?;
    let frame = |p: DVec3| (p - base.centre) * base.scale;
    let positions = &base.input_positions;
    let faces = base.triangles.len();

    let original_mesh = RawMesh {
        positions: positions.clone(),
        triangles: base.triangles.clone(),
    };
    let original = compute(&original_mesh, params)?;
    let reference: Vec<DVec3> = original
        .features
        .iter()
        .map(|f| frame(DVec3::from(f.position)))
        .collect();
    let trial = |name: String, mesh: &RawMesh, back: &dyn Fn(DVec3) -> DVec3| -> Result<Trial> {
        let signature = compute(mesh, params)?;
        let points: Vec<DVec3> = signature
            .features
            .iter()
            .map(|f| frame(back(DVec3::from(f.position))))
            .collect();
        let near = |p: &DVec3, set: &[DVec3]| {
            set.iter()
                .any(|q| p.distance(*q) <= params.salient.suppression_distance)
        };
        Ok(Trial {
            name,
            vertices: signature.stats.extraction.mesh.vertices,
            faces: signature.stats.extraction.mesh.triangles,
            extraction_seconds: signature.stats.extraction.total_seconds,
            points: points.len(),
            found: reference.iter().filter(|p| near(p, &points)).count(),
            unmatched: points.iter().filter(|p| !near(p, &reference)).count(),
            sim: compare(&original, &signature, &params.similarity).sim,
        })
    };
    let same = |p: DVec3| p;

    let mut trials = vec![trial("original".into(), &original_mesh, &same)?];
    for fraction in FACE_FRACTIONS {
        let target = ((faces as f64 * fraction).round() as usize).max(1);
        let (positions, triangles) = simplify_to_triangles(positions, &base.triangles, target);
        let mesh = RawMesh {
            positions,
            triangles,
        };
        trials.push(trial(
            format!("{} % of faces", fraction * 100.0),
            &mesh,
            &same,
        )?);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for level in NOISE_LEVELS {
        let mesh = noisy(&base, level, &mut rng);
        trials.push(trial(
            format!("noise {} % of diagonal", level * 100.0),
            &mesh,
            &same,
        )?);
    }
    let motion = random_motion(&mut rng, &base);
    let moved = RawMesh {
        positions: positions
            .iter()
            .map(|&p| motion.transform_point3(p))
            .collect(),
        triangles: base.triangles.clone(),
    };
    let inverse = motion.inverse();
    trials.push(trial("rigid motion + scale".into(), &moved, &|p| {
        inverse.transform_point3(p)
    })?);
    Ok(RobustnessReport {
        mesh: name.to_string(),
        match_distance: params.salient.suppression_distance,
        seed,
        trials,
    })
}

/// A change applied to every model of a collection before extraction, for retrieval on a
/// disguised copy of it (`salient eval retrieval --perturb noise=0.01`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Perturbation {
    /// Gaussian noise, RMS length as a fraction of the bounding-box diagonal (see [`noisy`]).
    pub noise: f64,
}

impl Perturbation {
    /// `mesh` welded and displaced, with noise drawn from a seed of `name` (a model's id), so
    /// the copy is the same on every run.
    pub fn apply(&self, mesh: &RawMesh, params: &Params, name: &str) -> Result<RawMesh> {
        use sha2::{Digest, Sha256};
        let digest = Sha256::digest(name.as_bytes());
        let seed = u64::from_le_bytes(digest[..8].try_into().expect("a SHA-256 has 32 bytes"));
        let base = prepare(mesh, &params.mesh)?;
        Ok(noisy(
            &base,
            self.noise,
            &mut ChaCha8Rng::seed_from_u64(seed),
        ))
    }

    /// A name for file and folder names: `noise-0.01`.
    pub fn name(&self) -> String {
        format!("noise-{}", self.noise)
    }
}

impl std::str::FromStr for Perturbation {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let bad = || format!("expected noise=LEVEL with LEVEL in (0, 0.1], not `{s}`");
        let level = s.strip_prefix("noise=").ok_or_else(bad)?;
        match level.parse::<f64>() {
            Ok(noise) if noise > 0.0 && noise <= 0.1 => Ok(Self { noise }),
            _ => Err(bad()),
        }
    }
}

/// Every vertex displaced by an isotropic Gaussian whose root-mean-square length is `level` ×
/// the bounding-box diagonal (each coordinate's deviation is that over √3). Noise is added
/// after welding, so seams stay closed.
fn noisy(base: &PreparedMesh, level: f64, rng: &mut ChaCha8Rng) -> RawMesh {
    let (lo, hi) = bounds(&base.input_positions);
    let deviation = level * lo.distance(hi) / 3f64.sqrt();
    let normal = Normal::new(0.0, deviation).expect("a finite deviation");
    RawMesh {
        positions: base
            .input_positions
            .iter()
            .map(|&p| p + DVec3::new(normal.sample(rng), normal.sample(rng), normal.sample(rng)))
            .collect(),
        triangles: base.triangles.clone(),
    }
}

/// A uniformly random rotation, a translation up to the mesh's size and a scale between
/// 1/10 and 10 (log-uniform).
fn random_motion(rng: &mut ChaCha8Rng, base: &PreparedMesh) -> DMat4 {
    let rotation = random_rotation(rng);
    let size = 1.0 / base.scale;
    let translation = DVec3::new(
        rng.gen_range(-size..size),
        rng.gen_range(-size..size),
        rng.gen_range(-size..size),
    );
    let scale = 10f64.powf(rng.gen_range(-1.0..1.0));
    DMat4::from_scale_rotation_translation(DVec3::splat(scale), rotation, translation)
}

/// A uniformly random rotation (Shoemake's random unit quaternion).
pub(crate) fn random_rotation(rng: &mut ChaCha8Rng) -> DQuat {
    let (u1, u2, u3): (f64, f64, f64) = (rng.gen(), rng.gen(), rng.gen());
    let tau = std::f64::consts::TAU;
    DQuat::from_xyzw(
        (1.0 - u1).sqrt() * (tau * u2).sin(),
        (1.0 - u1).sqrt() * (tau * u2).cos(),
        u1.sqrt() * (tau * u3).sin(),
        u1.sqrt() * (tau * u3).cos(),
    )
}

impl RobustnessReport {
    /// One row per version, as the paper's Tables 2–3 with the matches added.
    pub fn markdown(&self) -> String {
        let original = &self.trials[0];
        let mut table = Table::new([
            "version",
            "vertices",
            "faces",
            "extraction s",
            "salient points",
            "original points found again",
            "new points",
            "SIM to original",
        ]);
        for t in &self.trials {
            table.row([
                t.name.clone(),
                t.vertices.to_string(),
                t.faces.to_string(),
                format!("{:.3}", t.extraction_seconds),
                t.points.to_string(),
                format!("{} of {}", t.found, original.points),
                t.unmatched.to_string(),
                score(t.sim),
            ]);
        }
        format!(
            "# Robustness: {}\n\nThe mesh simplified to fractions of its faces (paper Table 2), \
             with Gaussian noise, and moved rigidly and scaled; each version extracted again. \
             A salient point is found again when one of the version's lies within D_e = {} of \
             it (normalised units, in the original's frame). Seed {}.\n\n{}",
            self.mesh,
            self.match_distance,
            self.seed,
            table.markdown()
        )
    }

    /// Writes `robustness.json` and `robustness.md` into `dir`.
    pub fn write(&self, dir: &Path) -> Result<()> {
        write_json(&dir.join("robustness.json"), self)?;
        write(&dir.join("robustness.md"), self.markdown())
    }
}

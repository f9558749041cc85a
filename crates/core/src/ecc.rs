//! Extended cone-curvature (SPEC §2.4, paper §3.1 Definitions 3–6 and §3.2.3).
//!
//! For each vertex `s`: bounded geodesics (SPEC §2.1), `N` waves at `g_i = i·D/N`
//! (SPEC §2.2), the stop-and-shrink rule (SPEC §2.3), then per wave a cone from the corrected
//! apex `S'_i` to the wave whose opening gives `α_i`. All vertices run in parallel; each is
//! computed independently with sequential arithmetic, so the result does not depend on the
//! number of threads.

use std::f64::consts::FRAC_PI_2;
use std::time::{Duration, Instant};

use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::geodesic::{GeodesicScratch, Surface};
use crate::mesh::{PreparedMesh, Topology};
use crate::params::{EccParams, HeightRule};
use crate::waves::{Source, WaveDefect, WaveSet, WaveTracer};

/// The ECC vectors of all vertices of a mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct EccField {
    waves: usize,
    values: Vec<f64>,
    /// Final region size `D` of each vertex: `D_g`, a shrunk size, or 0 when even the first
    /// wave was invalid (SPEC §2.3).
    pub region_size: Vec<f64>,
    pub stats: EccStats,
}

impl EccField {
    /// The ECC vector `(α_1, …, α_N)` of vertex `v`, in radians (Eq. 5).
    pub fn vector(&self, v: usize) -> &[f64] {
        &self.values[v * self.waves..(v + 1) * self.waves]
    }

    /// One ECC vector per vertex, in vertex order.
    pub fn vectors(&self) -> impl ExactSizeIterator<Item = &[f64]> {
        self.values.chunks_exact(self.waves)
    }

    /// All vectors in one row-major `vertices × N` array.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// `N`, the length of each vector.
    pub fn dimension(&self) -> usize {
        self.waves
    }

    pub fn len(&self) -> usize {
        self.region_size.len()
    }

    pub fn is_empty(&self) -> bool {
        self.region_size.is_empty()
    }
}

/// How each vertex's waves ended (SPEC §2.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Outcome {
    /// All `N` waves valid at the full local size.
    Complete,
    /// Wave `k > 1` was invalid for this reason; the region shrank to `g_{k-1}`.
    Shrunk(WaveDefect),
    /// Wave 1 was invalid: ECC 0, region 0.
    Flat(WaveDefect),
}

/// Counts per outcome and per reason, plus per-stage timings.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct EccStats {
    pub vertices: usize,
    /// Vertices whose `N` waves were all valid at `D_g`.
    pub complete: usize,
    /// Vertices whose region shrank once (SPEC §2.3).
    pub shrunk: usize,
    /// Vertices whose first wave was invalid (ECC 0, region 0).
    pub wave1_invalid: usize,
    /// Why the first invalid wave was invalid, over shrunk and wave-1 vertices.
    pub first_defect: DefectCounts,
    /// Waves of shrunk regions that were themselves invalid but, as SPEC §2.3 says, accepted.
    pub accepted_invalid_waves: usize,
    /// Seconds of CPU time in each stage, summed over worker threads.
    pub geodesic_seconds: f64,
    pub waves_seconds: f64,
    pub cone_seconds: f64,
    /// Wall-clock seconds of the whole parallel stage, and the threads it used.
    pub wall_seconds: f64,
    pub threads: usize,
}

/// One counter per [`WaveDefect`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct DefectCounts {
    pub missing: usize,
    pub branching: usize,
    pub open: usize,
    pub too_few_points: usize,
    pub not_flat: usize,
}

impl std::fmt::Display for DefectCounts {
    /// `"256 branching, 19 not flat"`; `"none"` when all are zero.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let parts: Vec<String> = [
            (self.missing, "missing"),
            (self.branching, "branching"),
            (self.open, "open"),
            (self.too_few_points, "too few points"),
            (self.not_flat, "not flat"),
        ]
        .iter()
        .filter(|(count, _)| *count > 0)
        .map(|(count, what)| format!("{count} {what}"))
        .collect();
        if parts.is_empty() {
            f.write_str("none")
        } else {
            f.write_str(&parts.join(", "))
        }
    }
}

impl DefectCounts {
    fn add(&mut self, defect: WaveDefect) {
        *match defect {
            WaveDefect::Missing => &mut self.missing,
            WaveDefect::Branching => &mut self.branching,
            WaveDefect::Open => &mut self.open,
            WaveDefect::TooFewPoints => &mut self.too_few_points,
            WaveDefect::NotFlat => &mut self.not_flat,
        } += 1;
    }
}

/// Per-thread state, reused across the vertices a worker handles.
struct Worker<'a> {
    mesh: &'a PreparedMesh,
    topology: &'a Topology,
    params: &'a EccParams,
    geodesic: GeodesicScratch,
    tracer: WaveTracer,
    set: WaveSet,
}

#[derive(Debug, Clone, Copy, Default)]
struct Timings {
    geodesic: Duration,
    waves: Duration,
    cone: Duration,
    accepted_invalid: usize,
}

impl std::ops::Add for Timings {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self {
            geodesic: self.geodesic + o.geodesic,
            waves: self.waves + o.waves,
            cone: self.cone + o.cone,
            accepted_invalid: self.accepted_invalid + o.accepted_invalid,
        }
    }
}

impl Worker<'_> {
    /// SPEC §2.1–2.4 for one source vertex; writes its ECC vector into `alpha`.
    fn vertex(&mut self, s: u32, alpha: &mut [f64]) -> (f64, Outcome, Timings) {
        let p = self.params;
        let n = p.waves;
        let mut time = Timings::default();
        let clock = Instant::now();
        let surface = Surface::new(self.mesh, self.topology);
        let distances = self.geodesic.run(surface, s, p.local_size);
        time.geodesic = clock.elapsed();

        let clock = Instant::now();
        let source = Source {
            position: self.mesh.positions[s as usize],
            normal: self.topology.vertex_normals[s as usize],
        };
        self.tracer
            .set_region(&self.mesh.triangles, self.topology, &distances);
        let mut trace_all = |size: f64, set: &mut WaveSet, stop_at_invalid: bool| {
            set.clear();
            for i in 1..=n {
                self.tracer.trace(
                    &self.mesh.positions,
                    &self.mesh.triangles,
                    self.topology,
                    &distances,
                    source,
                    i as f64 * size / n as f64,
                    set,
                );
                if let Some(defect) = set.waves()[i - 1].defect(p.flat_max) {
                    if stop_at_invalid {
                        return Some((i, defect));
                    }
                }
            }
            None
        };
        let mut size = p.local_size;
        let outcome = match trace_all(size, &mut self.set, true) {
            None => Outcome::Complete,
            Some((1, defect)) => Outcome::Flat(defect),
            Some((k, defect)) => {
                size = (k - 1) as f64 * p.local_size / n as f64;
                trace_all(size, &mut self.set, false);
                time.accepted_invalid = self
                    .set
                    .waves()
                    .iter()
                    .filter(|w| w.defect(p.flat_max).is_some())
                    .count();
                Outcome::Shrunk(defect)
            }
        };
        time.waves = clock.elapsed();

        let clock = Instant::now();
        if let Outcome::Flat(_) = outcome {
            alpha.fill(0.0);
            size = 0.0;
        } else {
            cone_curvature(source.position, &self.set, p.height, alpha);
        }
        time.cone = clock.elapsed();
        (size, outcome, time)
    }
}

/// Definitions 3–5 with SPEC §2.4's resolutions: per wave, the accumulated height `D_s^i`,
/// the side `σ_i`, the corrected apex `S'_i = O_i + σ_i·D_s^i·n_i` and
/// `α_i = σ_i·(π/2 − mean_j ∠(O_i − S'_i, W_j − S'_i))` (Eq. 4).
pub fn cone_curvature(source: DVec3, set: &WaveSet, rule: HeightRule, alpha: &mut [f64]) {
    let mut height = 0.0;
    let mut previous = source;
    for (wave, out) in set.waves().iter().zip(alpha.iter_mut()) {
        let (centre, normal) = (wave.centre, wave.normal);
        let step = centre - previous;
        height += match rule {
            HeightRule::Axial => step.dot(normal).abs(),
            HeightRule::Paper => step.length(),
        };
        previous = centre;
        let sigma = if (source - centre).dot(normal) >= 0.0 {
            1.0
        } else {
            -1.0
        };
        let apex = centre + sigma * height * normal;
        // Direction from S' to O_i; taken from the normal so that a zero height (a plane)
        // still has an axis and gives α = 0.
        let axis = -sigma * normal;
        let points = set.points(wave);
        if points.is_empty() {
            *out = 0.0;
            continue;
        }
        let mean_angle = points
            .iter()
            .map(|&w| {
                let v = w - apex;
                axis.cross(v).length().atan2(axis.dot(v))
            })
            .sum::<f64>()
            / points.len() as f64;
        *out = sigma * (FRAC_PI_2 - mean_angle);
    }
}

/// Computes the ECC vector of every vertex of `mesh` in parallel on the current rayon pool.
pub fn compute(mesh: &PreparedMesh, topology: &Topology, params: &EccParams) -> EccField {
    let n = params.waves;
    let vertex_count = mesh.positions.len();
    let clock = Instant::now();
    let mut values = vec![0.0; vertex_count * n];
    let mut region_size = vec![0.0; vertex_count];
    let mut outcomes = vec![Outcome::Complete; vertex_count];
    let timings = values
        .par_chunks_mut(n)
        .zip(region_size.par_iter_mut())
        .zip(outcomes.par_iter_mut())
        .enumerate()
        .with_min_len(64)
        .map_init(
            || Worker {
                mesh,
                topology,
                params,
                geodesic: GeodesicScratch::new(vertex_count, params.geodesic),
                tracer: WaveTracer::new(mesh.triangles.len()),
                set: WaveSet::default(),
            },
            |worker, (v, ((alpha, size), outcome))| {
                let (d, o, t) = worker.vertex(v as u32, alpha);
                *size = d;
                *outcome = o;
                t
            },
        )
        .reduce(Timings::default, |a, b| a + b);

    let mut stats = EccStats {
        vertices: vertex_count,
        accepted_invalid_waves: timings.accepted_invalid,
        geodesic_seconds: timings.geodesic.as_secs_f64(),
        waves_seconds: timings.waves.as_secs_f64(),
        cone_seconds: timings.cone.as_secs_f64(),
        wall_seconds: clock.elapsed().as_secs_f64(),
        threads: rayon::current_num_threads(),
        ..Default::default()
    };
    for outcome in &outcomes {
        match *outcome {
            Outcome::Complete => stats.complete += 1,
            Outcome::Shrunk(d) => {
                stats.shrunk += 1;
                stats.first_defect.add(d);
            }
            Outcome::Flat(d) => {
                stats.wave1_invalid += 1;
                stats.first_defect.add(d);
            }
        }
    }
    EccField {
        waves: n,
        values,
        region_size,
        stats,
    }
}

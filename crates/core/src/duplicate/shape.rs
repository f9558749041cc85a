//! The extrinsic check behind a near-duplicate: is one surface the other one moved, rotated,
//! uniformly scaled or remeshed? Retrieval distances cannot say it (they confuse "same class"
//! with "same shape"), so both meshes go to a canonical frame — area centroid at the origin,
//! unit RMS radius, principal axes — and are aligned over the 48 signed permutations of those
//! axes (second moments fix neither the axes' signs nor, when two are near-equal, their
//! order, which remeshing can swap, nor then the axes in their plane at all: turns about the
//! third are tried too), the best starts refined by ICP. What is
//! left are the distances from each surface's samples to the other surface, in RMS radii and
//! in sizes of the coarser mesh's triangles there ([`Distances`]), and the coarser mesh's
//! vertices' distances in lengths of their edges; these decide (`crate::duplicate::judge`).
//!
//! Distances and ICP come from [`crate::register`]. Types are glam's as parry re-exports them
//! (`glamx`), f32 as parry's are.

use glamx::{DMat3, DVec3, Mat3, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rstar::primitives::GeomWithData;
use rstar::RTree;
use rustc_hash::FxHashSet;

use crate::mesh::weld::weld;
use crate::mesh::RawMesh;
use crate::params::DuplicateParams;
use crate::register::{signed_permutations, Motion, Surface};
use crate::{Error, Result};

/// Samples whose distances decide a match.
const SAMPLES: usize = 1024;
/// Samples that choose the starts worth refining.
const COARSE: usize = 128;
/// Samples ICP fits on, and its rounds.
const FIT: usize = 256;
const ROUNDS: usize = 10;
/// Rounds of the vertex fit ([`Shape::vertex_fit`]): ICP converges slowly along a surface,
/// and ten rounds left a simplified tree's vertices up to 0.05 RMS radii off its source.
const VERTEX_ROUNDS: usize = 30;
/// A coarser mesh with at least this share of its triangles among the finer's, vertex for
/// vertex once fitted, is the finer's own triangles: a sub-mesh ([`Deviation::added`]).
/// A simplification re-tessellates around the vertices it removes: meshoptimizer's edge
/// collapse of CAPOD's trees m55 and m59 to half their vertices, which deletes leaves whole
/// (16–22 % of the area) and leaves the others alone, keeps 87–90 % of its triangles as they
/// were; CAPOD's airplane m47 measures 0.99 in m48 (its every face).
const SUB_MESH: f64 = 0.95;
/// A coarser vertex within this share of its mean edge length of a finer vertex is that
/// vertex, once fitted on pairs of vertices within each of [`PAIRED`] in turn (a vertex's
/// neighbours lie about an edge away).
const SAME_VERTEX: f32 = 0.01;
const PAIRED: [f32; 5] = [0.5, 0.5, 0.25, 0.1, 0.05];
/// A fit that puts at least this share of one mesh's vertices on the other's exactly paired
/// them: less, and it slid along the surface (a smooth blob) ([`Deviation::moved`]).
const ONE_MESH: f64 = 0.5;
/// Vertices a turn that may pair more of them is tried on before it is refitted
/// ([`Shape::edited_from`]): this many of those the fit left unpaired, and as many of all.
const TURN_SAMPLES: usize = 128;
/// Coarser triangles checked for the sub-mesh share, spread over the mesh.
const SUB_MESH_CHECKED: usize = 2048;
/// Two second moments within this ratio leave the principal axes in their plane arbitrary
/// (the trees of CAPOD: within 1 %), so starts turned about the third axis are tried too.
const NEAR_EQUAL: f64 = 1.2;
/// Those turns, in degrees: with the signed permutations' quarter turns, every 15°.
const TURNS: [f32; 5] = [15.0, 30.0, 45.0, 60.0, 75.0];
/// A connected piece of a mesh with less than this share of its area is small: a
/// simplification may delete it whole (an edge collapse takes an isolated triangle, a tree's
/// leaf, away), which the check forgives ([`Deviation::kept`]).
const SMALL_PIECE: f64 = 0.01;
/// Starts of each handedness refined by ICP.
const REFINED: usize = 2;
/// Samples of each shape a start is glanced at before it is scored in full, and added at a
/// time after ([`Shape::best_starts`]).
const GLANCE: usize = 8;
/// Distances above this many RMS radii count as this much while choosing starts, so that a
/// few far samples do not outweigh a good alignment elsewhere.
const CAP: f32 = 0.5;

/// A welded mesh as the duplicate check compares it.
pub struct Shape {
    /// The surface in the canonical frame.
    surface: Surface,
    /// Area-uniform samples of the surface, canonical frame; the same for the same mesh.
    samples: Vec<Vec3>,
    /// Whether each sample lies on a small piece of the mesh ([`SMALL_PIECE`]).
    on_small_piece: Vec<bool>,
    /// The canonical axes about which the other two moments are near-equal ([`NEAR_EQUAL`]).
    spins: Vec<usize>,
    /// The triangle of each sample.
    sampled: Vec<u32>,
    /// Each triangle's longest edge: how far a remeshing that leaves this triangle may have
    /// moved the surface under it.
    sizes: Vec<f32>,
    /// Each vertex's mean edge length.
    edges: Vec<f32>,
    /// The principal axes as rows: `canonical = axes · (p − centroid) / radius`.
    axes: Mat3,
    /// The typical size of a triangle, `√(area / triangles)`, in RMS radii: how far a
    /// remeshing at this resolution may move the surface on the whole.
    spacing: f64,
    /// The area in square RMS radii.
    area: f64,
}

/// How close two shapes came under the best proper rotation, and under the best reflection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    pub rotated: Deviation,
    pub mirrored: Deviation,
}

/// How far two aligned shapes are apart.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Deviation {
    /// The distances from each surface's samples to the other surface: each statistic the
    /// larger of the two directions.
    pub surfaces: Distances,
    /// The same leaving out the samples of the finer mesh (the one with more vertices) that
    /// lie on its small pieces beyond [`Reach`] of the coarser: the pieces a simplification
    /// deleted.
    pub kept: Distances,
    /// The share of the finer mesh's samples left out of `kept`.
    pub deleted: f64,
    /// The coarser mesh's vertices' distances from the finer surface ([`Shape::vertex_fit`]),
    /// each over the mean length of the vertex's edges.
    pub vertices: Spread,
    /// When the coarser mesh is a sub-mesh of the finer ([`SUB_MESH`]): the share of the
    /// finer's area it lacks, parts the finer adds (CAPOD's airplane m48 is m47's every
    /// triangle and ten parts more, its car m174 is m175 and 4 % more, its tree m54 is m49 and
    /// 17 % more leaves: other designs). 0 otherwise, and where the vertices were not fitted.
    pub added: f64,
    /// When both meshes have as many vertices and triangles and the fit pairs at least half
    /// the vertices exactly ([`ONE_MESH`]): the farthest a vertex of the coarser lies from the
    /// finer's nearest vertex once the two are fitted vertex on vertex (in the mirror too), in
    /// its mean edge lengths. One mesh with vertices edited (a morph, a pose, a part moved:
    /// CAPOD's pianos m124 and m125 share 334 of 362 vertices, desktop computers m76 and m77
    /// 350 of 396) is another design however near the surfaces stay; a re-triangulation or a
    /// quantised export moves none. 0 otherwise.
    pub moved: f64,
}

/// Distances from one surface to another, in two units.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Distances {
    /// In RMS radii.
    pub absolute: Spread,
    /// In sizes (longest edges) of the coarser mesh's triangle at the sample — its own for
    /// its samples, the closest for the finer mesh's. A simplification moves the surface by
    /// a fraction of the triangles it leaves, wherever they are large or small (a fin of
    /// three triangles, a leg of a spider clustered on a coarse grid), while a pose or a
    /// morph moves it whatever the triangles.
    pub local: Spread,
    /// Each distance over the [`Reach`] at its sample: beyond it above 1.
    pub reached: Spread,
}

/// How far a sample may lie from the other surface and still be on it: `absolute` RMS radii
/// or `local` sizes of the coarser mesh's triangle there ([`Distances`]), whichever is more —
/// chosen per sample, as a tree's leaves lie far from its trunk's large triangles while a
/// branch's small ones stay close.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reach {
    pub absolute: f64,
    pub local: f64,
}

impl Reach {
    /// The reach `params` allow, the coarser mesh of typical triangle size `spacing`
    /// ([`Shape::coarser`]).
    pub fn new(params: &DuplicateParams, spacing: f64) -> Self {
        Self {
            absolute: params.surface_limits(spacing).1,
            local: params.largest_per_triangle,
        }
    }
}

/// Statistics of a set of distances.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Spread {
    pub mean: f64,
    pub p90: f64,
    pub p99: f64,
    pub max: f64,
}

impl Spread {
    const NONE: Spread = Spread {
        mean: f64::INFINITY,
        p90: f64::INFINITY,
        p99: f64::INFINITY,
        max: f64::INFINITY,
    };

    fn of(mut distances: Vec<f32>) -> Self {
        distances.sort_by(f32::total_cmp);
        let at = |q: f64| f64::from(distances[((distances.len() - 1) as f64 * q).round() as usize]);
        Self {
            mean: distances.iter().map(|&d| f64::from(d)).sum::<f64>() / distances.len() as f64,
            p90: at(0.9),
            p99: at(0.99),
            max: at(1.0),
        }
    }

    fn larger(self, other: Self) -> Self {
        Self {
            mean: self.mean.max(other.mean),
            p90: self.p90.max(other.p90),
            p99: self.p99.max(other.p99),
            max: self.max.max(other.max),
        }
    }
}

impl Distances {
    const NONE: Distances = Distances {
        absolute: Spread::NONE,
        local: Spread::NONE,
        reached: Spread::NONE,
    };

    /// Of the samples' [`Sampled`] distances; none when there are none.
    fn of(samples: impl Iterator<Item = Sampled>) -> Self {
        let samples: Vec<Sampled> = samples.collect();
        if samples.is_empty() {
            return Self::NONE;
        }
        let of = |f: fn(&Sampled) -> f32| Spread::of(samples.iter().map(f).collect());
        Self {
            absolute: of(|s| s.distance),
            local: of(|s| s.local),
            reached: of(|s| s.reached),
        }
    }

    fn larger(self, other: Self) -> Self {
        Self {
            absolute: self.absolute.larger(other.absolute),
            local: self.local.larger(other.local),
            reached: self.reached.larger(other.reached),
        }
    }
}

/// A sample's distance from the other surface in RMS radii, in triangle sizes, and over its
/// [`Reach`].
#[derive(Debug, Clone, Copy)]
struct Sampled {
    distance: f32,
    local: f32,
    reached: f32,
}

impl Deviation {
    const NONE: Deviation = Deviation {
        surfaces: Distances::NONE,
        kept: Distances::NONE,
        deleted: 1.0,
        vertices: Spread::NONE,
        added: 0.0,
        moved: 0.0,
    };
}

impl Shape {
    /// Welds `raw` as extraction does (SPEC §1.2, `weld_tolerance`) and puts it in its frame.
    pub fn new(raw: &RawMesh, weld_tolerance: f64) -> Result<Self> {
        let welded = weld(raw, weld_tolerance)?;
        let positions: Vec<DVec3> = welded
            .positions
            .iter()
            .map(|p| DVec3::from_array(p.to_array()))
            .collect();
        let triangles = welded.triangles;
        let (centroid, moments, area) = moments(&positions, &triangles);
        let trace = moments.col(0).x + moments.col(1).y + moments.col(2).z;
        if !(area > 0.0 && trace > 0.0) {
            return Err(Error::NoTriangles);
        }
        let (moments, axes) = principal_axes(moments / trace);
        let radius = trace.sqrt();
        let canonical: Vec<Vec3> = positions
            .iter()
            .map(|&p| (axes * ((p - centroid) / radius)).as_vec3())
            .collect();
        let (samples, sampled): (Vec<Vec3>, Vec<u32>) =
            sample(&canonical, &triangles, SAMPLES).into_iter().unzip();
        let on_small_piece = small_pieces(&canonical, &triangles);
        let on_small_piece = sampled
            .iter()
            .map(|&t| on_small_piece[t as usize])
            .collect();
        let (sizes, edges) = sizes(&canonical, &triangles);
        let [first, second, third] = moments.to_array();
        let spins = [(first / second, 2), (second / third, 0)]
            .into_iter()
            .filter(|&(ratio, _)| ratio < NEAR_EQUAL)
            .map(|(_, axis)| axis)
            .collect();
        let area = area / (radius * radius);
        let spacing = (area / triangles.len() as f64).sqrt();
        let surface = Surface::new(canonical, triangles)?;
        Ok(Self {
            surface,
            samples,
            on_small_piece,
            spins,
            sampled,
            sizes,
            edges,
            axes: axes.as_mat3(),
            spacing,
            area,
        })
    }

    /// Welded vertices.
    pub fn vertices(&self) -> usize {
        self.surface.vertices().len()
    }

    /// Whether either mesh is one subdivision step of the other: its triangles each split in
    /// four, by their connectivity, or a Catmull–Clark step, by their counts
    /// ([`super::subdivision`]).
    pub fn split_of(&self, other: &Shape) -> bool {
        let triangles = |s: &Shape| s.surface.triangles().len();
        let (fine, coarse) = if triangles(self) > triangles(other) {
            (self, other)
        } else {
            (other, self)
        };
        super::subdivision::is_split(
            fine.surface.triangles(),
            (coarse.vertices(), triangles(coarse)),
        ) || super::subdivision::is_catmull_clark(
            (fine.vertices(), triangles(fine)),
            (coarse.vertices(), coarse.surface.triangles()),
        )
    }

    /// Whether `self` is the coarser of the two, the one whose vertices a simplification keeps
    /// on the other surface: fewer vertices; between as many (a re-triangulated copy), fewer
    /// triangles, then less area, so that the roles do not depend on the order asked in.
    fn is_coarser(&self, other: &Shape) -> bool {
        let key = |s: &Shape| (s.vertices(), s.surface.triangles().len(), s.area);
        key(self).partial_cmp(&key(other)) != Some(std::cmp::Ordering::Greater)
    }

    /// The coarser of two shapes' triangle sizes ([`Shape::spacing`]).
    pub fn coarser(&self, other: &Shape) -> f64 {
        self.spacing.max(other.spacing)
    }

    /// The largest distance of either mesh's vertices from the other's surface, in RMS
    /// radii, with no rotation allowed, if it is within `limit` (`None` at the first vertex
    /// beyond: most candidates are told apart in a few). Within a small limit only for the
    /// same welded mesh moved or uniformly scaled (`identical_geometry`): the vertices of a
    /// remeshed copy lie on the original surface, but not the original's on the copy's.
    /// Vertex counts are not compared: a float32 export can weld a near-coincident pair
    /// differently.
    pub fn geometry_deviation(&self, other: &Shape, limit: f64) -> Option<f64> {
        // The two canonical frames differ by the rotation between their axes.
        let to_other = other.axes * self.axes.transpose();
        let largest = |from: &Shape, to: &Shape, rotation: Mat3| {
            from.surface
                .vertices()
                .iter()
                .map(|&v| f64::from(to.surface.distance(rotation * v)))
                .try_fold(0.0f64, |worst, d| (d <= limit).then_some(worst.max(d)))
        };
        Some(largest(self, other, to_other)?.max(largest(other, self, to_other.transpose())?))
    }

    /// Aligns `self` onto `other` from the starts ([`Shape::starts`]), refines the best of
    /// each handedness by ICP, and measures what is left: the surfaces' distances (leaving
    /// out, for `kept`, small pieces of the finer mesh beyond `reach` of the coarser), and
    /// the vertices' ([`Shape::vertex_fit`], as costly again) only where `surfaces_pass`
    /// (infinite elsewhere). The starts are ranked by samples of both shapes, each moved onto
    /// the other, so that the answer does not depend on which model came first (the service
    /// remembers a verdict by the unordered pair): ranked by the first's samples alone, three
    /// of CAPOD's 720 held-out copies (a vase re-triangulated, a tree's quadric and clustered
    /// copies) were linked to their model one way and not the other.
    pub fn align(
        &self,
        other: &Shape,
        reach: Reach,
        surfaces_pass: impl Fn(&Deviation) -> bool,
    ) -> Alignment {
        let best = |proper: bool| {
            self.best_starts(other, proper)
                .into_iter()
                .map(|s| {
                    let motion = self.refined(other, s);
                    (self.deviation(other, motion, reach), motion)
                })
                .min_by(|a, b| (a.0.surfaces.absolute.mean).total_cmp(&b.0.surfaces.absolute.mean))
                .map_or(Deviation::NONE, |(mut deviation, motion)| {
                    if surfaces_pass(&deviation) {
                        let (vertices, edit) = self.vertex_fit(other, motion);
                        (deviation.vertices, deviation.added, deviation.moved) =
                            (vertices, edit.added, edit.moved);
                    }
                    deviation
                })
        };
        Alignment {
            rotated: best(true),
            mirrored: best(false),
        }
    }

    /// The [`REFINED`] starts of one handedness ([`Shape::starts`]) whose samples lie nearest
    /// the other surface: half of [`COARSE`] samples of each shape, each moved onto the other
    /// (their mean distances' sum, capped at [`CAP`]; ties to the earlier start). Every start
    /// is first glanced at on a few samples (a lower bound of its score: distances are not
    /// negative and the rest are added on in the same order), and only those whose bound
    /// does not exceed the best scores so far are scored in full, a few samples at a time:
    /// the same starts as scoring all of them, at a fraction of the queries.
    fn best_starts(&self, other: &Shape, proper: bool) -> Vec<Mat3> {
        let (ours, theirs) = (
            &self.samples[..(COARSE / 2).min(self.samples.len())],
            &other.samples[..(COARSE / 2).min(other.samples.len())],
        );
        let (n_ours, n_theirs) = (ours.len().max(1) as f32, theirs.len().max(1) as f32);
        // Sums of the capped distances of samples `from..to` of each side, added to `sums`.
        let add = |s: Mat3, (forth, back): (f32, f32), from: usize, to: usize| {
            let side = |surface: &crate::register::Surface, points: &[Vec3], m: Mat3, sum| {
                points[from.min(points.len())..to.min(points.len())]
                    .iter()
                    .fold(sum, |sum, &x| sum + surface.capped_distance(m * x, CAP))
            };
            (
                side(&other.surface, ours, s, forth),
                side(&self.surface, theirs, s.transpose(), back),
            )
        };
        let score = |(forth, back): (f32, f32)| forth / n_ours + back / n_theirs;
        let mut glanced: Vec<(f32, usize, Mat3, (f32, f32))> = self
            .starts(other)
            .into_iter()
            .enumerate()
            .filter(|(_, s)| (s.determinant() > 0.0) == proper)
            .map(|(i, s)| {
                let sums = add(s, (0.0, 0.0), 0, GLANCE);
                (score(sums), i, s, sums)
            })
            .collect();
        glanced.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut best: Vec<(f32, usize, Mat3)> = Vec::with_capacity(REFINED + 1);
        let samples = ours.len().max(theirs.len());
        for (bound, i, s, mut sums) in glanced {
            let beaten = |bound: f32, best: &[(f32, usize, Mat3)]| {
                best.len() == REFINED && best.last().is_some_and(|w| bound > w.0)
            };
            if beaten(bound, &best) {
                break;
            }
            let mut done = GLANCE;
            while done < samples && !beaten(score(sums), &best) {
                sums = add(s, sums, done, done + GLANCE);
                done += GLANCE;
            }
            if done >= samples {
                best.push((score(sums), i, s));
                best.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                best.truncate(REFINED);
            }
        }
        best.into_iter().map(|(_, _, s)| s).collect()
    }

    /// The rotations (and reflections) of `self`'s canonical frame onto `other`'s to start
    /// from: the 48 signed permutations of the axes, and each turned about an axis of either
    /// frame whose plane's moments are near-equal ([`NEAR_EQUAL`]).
    fn starts(&self, other: &Shape) -> Vec<Mat3> {
        let turns = |spins: &[usize]| -> Vec<Mat3> {
            spins
                .iter()
                .flat_map(|&axis| {
                    TURNS.map(|degrees| {
                        Mat3::from_axis_angle(Vec3::AXES[axis], degrees.to_radians())
                    })
                })
                .collect()
        };
        let (before, after) = (turns(&self.spins), turns(&other.spins));
        signed_permutations()
            .flat_map(|s| {
                std::iter::once(s)
                    .chain(before.iter().map(move |&t| s * t))
                    .chain(after.iter().map(move |&t| t * s))
            })
            .collect()
    }

    /// ICP from the start `s` (`self`'s frame onto `other`'s): the mesh with fewer vertices —
    /// a simplification, whose surface lies on its source's — is moved onto the other's
    /// surface, with a uniform scale since each frame's RMS radius is measured on its own faces
    /// (which a simplification pulls in, and its deleted pieces shrink). The motion of `self`
    /// onto `other`.
    fn refined(&self, other: &Shape, s: Mat3) -> Motion {
        let onto = |from: &Shape, to: &Shape, s: Mat3| {
            let fit: Vec<Vec3> = from.samples[..FIT.min(from.samples.len())]
                .iter()
                .map(|&x| s * x)
                .collect();
            let icp = to.surface.icp(&fit, ROUNDS, true);
            Motion {
                rotation: icp.rotation * s,
                ..icp
            }
        };
        if self.is_coarser(other) {
            onto(self, other, s)
        } else {
            onto(other, self, s.transpose()).inverse()
        }
    }

    /// The surfaces' distances both ways once `self` is moved onto `other` by `motion`, and
    /// without the finer mesh's small pieces beyond `reach` ([`Deviation::kept`]).
    fn deviation(&self, other: &Shape, motion: Motion, reach: Reach) -> Deviation {
        let self_coarser = self.is_coarser(other);
        // (distance, local distance) of each sample of `from`, `from_coarser` saying whose
        // triangles set the local size. Both frames are in RMS radii.
        let distances = |from: &Shape, to: &Shape, motion: Motion, from_coarser: bool| {
            from.samples
                .iter()
                .zip(&from.sampled)
                .map(|(&p, &own)| {
                    let (d, closest) = to.surface.distance_and_triangle(motion.apply(p));
                    let size = if from_coarser {
                        from.sizes[own as usize]
                    } else {
                        to.sizes[closest as usize]
                    };
                    let reach = (reach.absolute as f32).max(reach.local as f32 * size);
                    Sampled {
                        distance: d,
                        local: d / size.max(f32::MIN_POSITIVE),
                        reached: d / reach.max(f32::MIN_POSITIVE),
                    }
                })
                .collect::<Vec<Sampled>>()
        };
        let (forth, back) = (
            distances(self, other, motion, self_coarser),
            distances(other, self, motion.inverse(), !self_coarser),
        );
        let (fine, finer) = if self_coarser {
            (&back, other)
        } else {
            (&forth, self)
        };
        let kept: Vec<Sampled> = fine
            .iter()
            .zip(&finer.on_small_piece)
            .filter(|&(s, &small)| !(small && s.reached > 1.0))
            .map(|(&s, _)| s)
            .collect();
        let deleted = 1.0 - kept.len() as f64 / fine.len() as f64;
        // A mesh all of small pieces, all far, keeps nothing.
        let kept = Distances::of(kept.into_iter());
        let (forth, back) = (
            Distances::of(forth.into_iter()),
            Distances::of(back.into_iter()),
        );
        let coarse = if self_coarser { forth } else { back };
        Deviation {
            surfaces: forth.larger(back),
            kept: coarse.larger(kept),
            deleted,
            vertices: Spread::NONE,
            added: 0.0,
            moved: 0.0,
        }
    }

    /// The coarser mesh's (fewer vertices) vertices' distances from the finer surface once
    /// fitted onto it by ICP with a uniform scale, from the motion `onto` of `self` onto
    /// `other`, each over the vertex's mean edge length. A simplification keeps its vertices
    /// on or near the surface it came from (an edge collapse keeps a subset of them, a
    /// remesher projects onto it, a quadric collapse places each where the planes of the
    /// faces it replaced meet, a clustering at the mean of nearby vertices) while its faces
    /// cut chords, so these stay a small fraction of an edge however coarse the copy; a morph
    /// or another pose moves vertices regardless of their edges.
    fn vertex_fit(&self, other: &Shape, onto: Motion) -> (Spread, Edit) {
        let (coarse, fine, start) = if self.is_coarser(other) {
            (self, other, onto)
        } else {
            (other, self, onto.inverse())
        };
        let all = coarse.surface.vertices();
        let step = all.len().div_ceil(SAMPLES);
        let points: Vec<Vec3> = all.iter().step_by(step).map(|&p| start.apply(p)).collect();
        let fit = fine.surface.icp(&points, VERTEX_ROUNDS, true);
        let scale = start.scale * fit.scale;
        let spread = Spread::of(
            points
                .iter()
                .zip(coarse.edges.iter().step_by(step))
                .map(|(&p, &edge)| {
                    fine.surface.distance(fit.apply(p)) / (edge * scale).max(f32::MIN_POSITIVE)
                })
                .collect(),
        );
        (
            spread,
            coarse.edited_from(fine, |p| fit.apply(start.apply(p)), scale),
        )
    }

    /// What `fine` did to `self` (the coarser, put in `fine`'s frame by `onto`, which scales by
    /// `scale`) if it is an edit of the same mesh.
    /// A sub-mesh re-tessellates nothing, so what it lacks is parts `fine` adds, attached or
    /// not, where a simplification's shortfall is its chords.
    fn edited_from(&self, fine: &Shape, onto: impl Fn(Vec3) -> Vec3, scale: f32) -> Edit {
        let (ours, theirs) = (self.surface.vertices(), fine.surface.vertices());
        // The finer vertices in a tree: the corners of the triangle a point lies nearest are
        // not its nearest vertex where a vertex lies on another triangle (a T-junction, or
        // parts overlapping: CAPOD's pianos), which took identical meshes for edited ones.
        let tree = RTree::bulk_load(
            theirs
                .iter()
                .zip(0u32..)
                .map(|(p, w)| GeomWithData::new(p.to_array(), w))
                .collect(),
        );
        // Our vertices in `fine`'s frame: a mirror image is reflected here, so that the vertex
        // fits below, proper motions, pair it too.
        let placed: Vec<Vec3> = ours.iter().map(|&p| onto(p)).collect();
        // The finer vertex nearest our vertex `v` once moved by `m`, and how far, in `v`'s
        // edges.
        let nearest = |v: u32, m: &Motion| {
            let p = m.apply(placed[v as usize]);
            // A degenerate fit may put a vertex at no finite place: it is no vertex's.
            let w = p
                .is_finite()
                .then(|| tree.nearest_neighbor(p.to_array()))
                .flatten()
                .map_or(u32::MAX, |w| w.data);
            let d = theirs
                .get(w as usize)
                .map_or(f32::INFINITY, |&q| q.distance(p));
            let edge = self.edges[v as usize] * scale * m.scale;
            (w, d / edge.max(f32::MIN_POSITIVE))
        };
        let triangles = self.surface.triangles();
        let checked: Vec<[u32; 3]> = triangles
            .iter()
            .step_by(triangles.len().div_ceil(SUB_MESH_CHECKED))
            .copied()
            .collect();
        // Each corner of the checked triangles' nearest finer vertex once moved by `m`, found
        // once per vertex (a vertex is a corner of about six triangles), by vertex.
        let mut corners: Vec<u32> = checked.iter().flatten().copied().collect();
        corners.sort_unstable();
        corners.dedup();
        let nearest_corners = |m: &Motion| {
            let mut found = vec![(u32::MAX, f32::INFINITY); ours.len()];
            for &v in &corners {
                found[v as usize] = nearest(v, m);
            }
            found
        };
        // The finer vertex a coarser one is, if any: the nearest, within `within` edges.
        let same = |found: &[(u32, f32)], v: u32, within: f32| {
            let (w, edges) = found[v as usize];
            (edges <= within).then_some(w)
        };
        let one_mesh =
            ours.len() == theirs.len() && triangles.len() == fine.surface.triangles().len();
        // The surfaces' fit leaves vertices off along the surface (a third of an edge on a
        // smooth blob, 0.08 in CAPOD's m47 in m48): fits on the vertices it pairs, each
        // pairing nearer, make a sub-mesh's pairs exact (ICP on the vertices), from `start`.
        let pair = |start: Motion| {
            let mut exact = start;
            for within in PAIRED {
                let found = nearest_corners(&exact);
                let (from, to): (Vec<Vec3>, Vec<Vec3>) = checked
                    .iter()
                    .flatten()
                    .filter_map(|&v| {
                        same(&found, v, within).map(|w| (placed[v as usize], theirs[w as usize]))
                    })
                    .unzip();
                if from.len() < 3 {
                    return None;
                }
                exact = crate::register::fit(&from, &to, true);
            }
            Some(exact)
        };
        // Every vertex's distance from the finer vertex nearest it, in its edges, and the
        // share of them paired.
        let offs = |m: &Motion| {
            let off: Vec<f32> = (0..ours.len() as u32).map(|v| nearest(v, m).1).collect();
            let paired =
                off.iter().filter(|&&d| d <= SAME_VERTEX).count() as f64 / off.len() as f64;
            (off, paired)
        };
        let Some(mut exact) = pair(Motion::IDENTITY) else {
            return Edit::NONE;
        };
        // `moved` only where the fit paired the vertices: one that slid (a smooth blob) would
        // take every vertex for moved.
        let moved = if one_mesh {
            let (mut off, mut paired) = offs(&exact);
            // A model symmetric under turns about an axis (a lathe, a fluted vase, a box
            // under a half turn) fits its surface as well turned by any step of its symmetry,
            // and pairs most vertices at each: only those of a small part that breaks the
            // symmetry tell the turn, and the surfaces' fit, which samples it a few times,
            // cannot (CAPOD's vase m64, four pieces of 0.3 % of its area, re-triangulated: 6
            // of 12 turns of it settled a step off, a vertex 5.6 edges from its own). An axis
            // of symmetry is a principal axis, so about each of `fine`'s: the farthest
            // vertex's own lies at its height and distance from the axis, each finer vertex
            // there gives a turn, and the one that pairs most of a sample of vertices (the
            // unpaired ones first) is refitted and kept if it pairs more.
            if (ONE_MESH..1.0).contains(&paired) {
                // The fit paired some three vertices, so there are some.
                let worst = (0..off.len())
                    .max_by(|&a, &b| off[a].total_cmp(&off[b]))
                    .unwrap_or_default();
                let misplaced: Vec<u32> = (0..ours.len() as u32)
                    .filter(|&v| off[v as usize] > SAME_VERTEX)
                    .collect();
                let sampled: Vec<u32> = misplaced
                    .iter()
                    .step_by(misplaced.len().div_ceil(TURN_SAMPLES).max(1))
                    .copied()
                    .chain((0..ours.len() as u32).step_by(ours.len().div_ceil(TURN_SAMPLES)))
                    .collect();
                let pairs = |m: &Motion| {
                    sampled
                        .iter()
                        .filter(|&&v| nearest(v, m).1 <= PAIRED[0])
                        .count()
                };
                let p = exact.apply(placed[worst]);
                let within = PAIRED[0] * self.edges[worst] * scale * exact.scale;
                let starts: Vec<Motion> = Vec3::AXES
                    .iter()
                    .filter_map(|&axis| {
                        turns_onto(p, axis, theirs, within)
                            .into_iter()
                            .map(|turn| exact.turned(turn))
                            // The first of those pairing most (`max_by_key` keeps the last).
                            .rev()
                            .max_by_key(pairs)
                    })
                    .collect();
                for start in starts {
                    if let Some(fit) = pair(start) {
                        let (fit_off, fit_paired) = offs(&fit);
                        if fit_paired > paired {
                            (exact, off, paired) = (fit, fit_off, fit_paired);
                        }
                    }
                }
            }
            if paired >= ONE_MESH {
                f64::from(off.into_iter().fold(0.0, f32::max))
            } else {
                0.0
            }
        } else {
            0.0
        };
        let corners = |mut t: [u32; 3]| {
            t.sort_unstable();
            t
        };
        let own: FxHashSet<[u32; 3]> = fine
            .surface
            .triangles()
            .iter()
            .map(|&t| corners(t))
            .collect();
        let found = nearest_corners(&exact);
        let shared = checked
            .iter()
            .filter(|t| {
                let [a, b, c] = t.map(|v| same(&found, v, SAME_VERTEX));
                matches!((a, b, c), (Some(a), Some(b), Some(c)) if own.contains(&corners([a, b, c])))
            })
            .count() as f64
            / checked.len() as f64;
        let scale = f64::from(scale * exact.scale);
        Edit {
            added: if shared < SUB_MESH {
                0.0
            } else {
                (1.0 - self.area * scale * scale / fine.area).max(0.0)
            },
            moved,
        }
    }
}

/// What the vertex fit found one mesh did to the other ([`Deviation::added`],
/// [`Deviation::moved`]).
#[derive(Debug, PartialEq)]
struct Edit {
    added: f64,
    moved: f64,
}

impl Edit {
    const NONE: Edit = Edit {
        added: 0.0,
        moved: 0.0,
    };
}

/// The turns about `axis` (through the origin) that put `p` within `within` of one of
/// `vertices`: one per vertex at `p`'s height along the axis and distance from it.
fn turns_onto(p: Vec3, axis: Vec3, vertices: &[Vec3], within: f32) -> Vec<Mat3> {
    let height = p.dot(axis);
    let radial = p - axis * height;
    vertices
        .iter()
        .filter_map(|&q| {
            let q_radial = q - axis * q.dot(axis);
            ((q.dot(axis) - height).abs() <= within
                && (q_radial.length() - radial.length()).abs() <= within)
                .then(|| {
                    let angle = axis.dot(radial.cross(q_radial)).atan2(radial.dot(q_radial));
                    Mat3::from_axis_angle(axis, angle)
                })
        })
        .collect()
}

/// Each triangle's longest edge and each vertex's mean edge length.
fn sizes(positions: &[Vec3], triangles: &[[u32; 3]]) -> (Vec<f32>, Vec<f32>) {
    let mut sum = vec![(0.0f32, 0u32); positions.len()];
    let longest = triangles
        .iter()
        .map(|t| {
            (0..3)
                .map(|k| {
                    let (a, b) = (t[k] as usize, t[(k + 1) % 3] as usize);
                    let length = positions[a].distance(positions[b]);
                    for v in [a, b] {
                        sum[v].0 += length;
                        sum[v].1 += 1;
                    }
                    length
                })
                .fold(0.0f32, f32::max)
        })
        .collect();
    let mean = sum.iter().map(|&(s, n)| s / n.max(1) as f32).collect();
    (longest, mean)
}

/// Whether each triangle lies on a small connected piece of the mesh ([`SMALL_PIECE`]).
fn small_pieces(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<bool> {
    let pieces = crate::mesh::topology::pieces(positions.len(), triangles);
    let areas: Vec<f64> = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|v| positions[v as usize]);
            f64::from((b - a).cross(c - a).length())
        })
        .collect();
    // Pieces are named by a vertex.
    let mut piece_area = vec![0.0; positions.len()];
    for (&piece, &area) in pieces.iter().zip(&areas) {
        piece_area[piece as usize] += area;
    }
    let total: f64 = areas.iter().sum();
    pieces
        .iter()
        .map(|&piece| piece_area[piece as usize] < SMALL_PIECE * total)
        .collect()
}

/// The eigenvalues of the symmetric `moments` (of unit trace), largest first, and their
/// eigenvectors as the rows of an orthonormal frame.
///
/// glamx's `DSymmetricEigen3::new` finds the smallest eigenvalue's vector first, from cross
/// products of `moments − λI`'s columns, and takes the x axis when they are below an absolute
/// 1e-20. When that eigenvalue is a double one (a cone or a tree, spun about its axis), the
/// products are rounding noise and the x axis is no eigenvector: a retriangulated cone at
/// 0.1 × its size then aligned 0.18 RMS radii off. As Eberly's robust solver does ("A Robust
/// Eigensolver for 3 × 3 Symmetric Matrices", 2014), the vector of the eigenvalue farthest from
/// the middle one comes first, and the middle one's is found in the plane orthogonal to it;
/// `moments` come in with unit trace, so no threshold depends on the model's size.
fn principal_axes(moments: DMat3) -> (DVec3, DMat3) {
    use glamx::DSymmetricEigen3 as Eigen;
    let values = Eigen::eigenvalues(moments);
    let [smallest, middle, largest] = values.to_array();
    // Each third vector is the cross product that `DSymmetricEigen3` takes, so the frame's
    // handedness is the same for every shape (only the two shapes' relative rotation counts).
    let (l, m, s) = if largest - middle > middle - smallest {
        let l = Eigen::eigenvector1(moments, largest);
        let m = Eigen::eigenvector2(moments, l, middle);
        (l, m, m.cross(l))
    } else {
        let s = Eigen::eigenvector1(moments, smallest);
        let m = Eigen::eigenvector2(moments, s, middle);
        (s.cross(m), m, s)
    };
    let axes = DMat3::from_cols(l, m, s).transpose();
    (DVec3::new(largest, middle, smallest), axes)
}

/// Area, area centroid and second moments about it of a triangle surface, from the exact
/// moments of each triangle: `∫ x xᵀ dA = A/12 · (a aᵀ + b bᵀ + c cᵀ + s sᵀ)`, `s = a + b + c`.
fn moments(positions: &[DVec3], triangles: &[[u32; 3]]) -> (DVec3, DMat3, f64) {
    let outer = |u: DVec3, v: DVec3| DMat3::from_cols(u * v.x, u * v.y, u * v.z);
    let (mut area, mut first, mut second) = (0.0, DVec3::ZERO, DMat3::ZERO);
    for t in triangles {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        let s = a + b + c;
        let da = (b - a).cross(c - a).length() / 2.0;
        area += da;
        first += s * (da / 3.0);
        second += (outer(a, a) + outer(b, b) + outer(c, c) + outer(s, s)) * (da / 12.0);
    }
    if area <= 0.0 {
        return (DVec3::ZERO, DMat3::ZERO, 0.0);
    }
    let centroid = first / area;
    let covariance = second * (1.0 / area) - outer(centroid, centroid);
    (centroid, covariance, area)
}

/// `n` points uniform in area over the triangles, each with its triangle, from a fixed seed:
/// the same mesh gives the same samples.
fn sample(positions: &[Vec3], triangles: &[[u32; 3]], n: usize) -> Vec<(Vec3, u32)> {
    let mut cumulative = Vec::with_capacity(triangles.len());
    let mut total = 0.0f64;
    for t in triangles {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        total += f64::from((b - a).cross(c - a).length());
        cumulative.push(total);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(0x5a11e47);
    (0..n)
        .map(|_| {
            let at = rng.gen::<f64>() * total;
            let i = cumulative
                .partition_point(|&c| c <= at)
                .min(triangles.len() - 1);
            let [a, b, c] = triangles[i].map(|v| positions[v as usize]);
            let (r1, r2) = (rng.gen::<f32>().sqrt(), rng.gen::<f32>());
            (
                a * (1.0 - r1) + b * (r1 * (1.0 - r2)) + c * (r1 * r2),
                i as u32,
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;

    const REACH: Reach = Reach {
        absolute: 0.08,
        local: 1.0,
    };

    /// Three bars of lengths 1, 2 and 3 along the axes from one corner: a chiral shape (no
    /// rotation maps it onto its mirror image) with distinct principal moments.
    fn lopsided() -> RawMesh {
        let mut raw = RawMesh::default();
        for (axis, length) in [(0, 1.0), (1, 2.0), (2, 3.0)] {
            let mut max = glam::DVec3::splat(0.2);
            max[axis] = length;
            let corners: Vec<glam::DVec3> = (0..8)
                .map(|i| {
                    glam::DVec3::new((i & 1) as f64, ((i >> 1) & 1) as f64, (i >> 2) as f64) * max
                })
                .collect();
            let base = raw.positions.len() as u32;
            raw.positions.extend(corners);
            const FACES: [[u32; 4]; 6] = [
                [0, 2, 3, 1],
                [4, 5, 7, 6],
                [0, 1, 5, 4],
                [2, 6, 7, 3],
                [0, 4, 6, 2],
                [1, 3, 7, 5],
            ];
            for [a, b, c, d] in FACES {
                raw.triangles.push([base + a, base + b, base + c]);
                raw.triangles.push([base + a, base + c, base + d]);
            }
        }
        raw
    }

    fn moved(raw: &RawMesh, f: impl Fn(glam::DVec3) -> glam::DVec3) -> RawMesh {
        RawMesh {
            positions: raw.positions.iter().map(|&p| f(p)).collect(),
            triangles: raw.triangles.clone(),
        }
    }

    /// The bars meet at T-junctions (a bar's corner on another's face), where the corners of
    /// the triangle a vertex lies on are not its nearest vertex: a mesh is no edit of itself.
    #[test]
    fn a_mesh_with_t_junctions_moves_no_vertex_against_itself() {
        let shape = Shape::new(&lopsided(), 1e-6).unwrap();
        assert_eq!(shape.edited_from(&shape, |p| p, 1.0), Edit::NONE);
    }

    /// A degenerate fit that puts the vertices nowhere finite pairs none of them (the
    /// R-tree's search cannot order a NaN).
    #[test]
    fn a_fit_to_no_finite_place_pairs_no_vertex() {
        let shape = Shape::new(&lopsided(), 1e-6).unwrap();
        assert_eq!(shape.edited_from(&shape, |_| Vec3::NAN, 1.0), Edit::NONE);
    }

    #[test]
    fn a_moved_scaled_copy_has_the_same_geometry_and_a_rotated_one_does_not() {
        let raw = lopsided();
        let shape = Shape::new(&raw, 1e-6).unwrap();
        let copy = Shape::new(
            &moved(&raw, |p| p * 25.4 + glam::DVec3::new(3.0, -1.0, 7.0)),
            1e-6,
        )
        .unwrap();
        assert!(shape.geometry_deviation(&copy, 1e-4).is_some());
        let turn = DQuat::from_axis_angle(glam::DVec3::new(1.0, 2.0, 0.5).normalize(), 1.1);
        let rotated = Shape::new(&moved(&raw, |p| turn * p), 1e-6).unwrap();
        assert_eq!(rotated.geometry_deviation(&shape, 1e-2), None);
        let alignment = rotated.align(&shape, REACH, |_| true);
        assert!(
            alignment.rotated.surfaces.absolute.max < 1e-3,
            "{alignment:?}"
        );
    }

    /// Pruning by a few samples' bound must not change which starts are refined: the same
    /// as scoring every start on all its samples and sorting (ties to the earlier start).
    #[test]
    fn the_starts_refined_are_those_all_samples_of_every_start_choose() {
        let raw = lopsided();
        let shape = Shape::new(&raw, 1e-6).unwrap();
        let turn = DQuat::from_axis_angle(glam::DVec3::new(1.0, 2.0, 0.5).normalize(), 1.1);
        let others = [
            moved(&raw, |p| turn * p),
            moved(&raw, |p| glam::DVec3::new(-p.x, p.y, p.z)),
            moved(&raw, |p| turn * (p * glam::DVec3::new(1.0, 0.4, 1.7))),
        ];
        for other in &others {
            let other = Shape::new(other, 1e-6).unwrap();
            let half = COARSE / 2;
            let mut all: Vec<(f32, Mat3)> = shape
                .starts(&other)
                .into_iter()
                .map(|s| {
                    let forth = (other.surface)
                        .mean_distance(shape.samples[..half].iter().map(|&x| s * x), CAP);
                    let back = (shape.surface).mean_distance(
                        other.samples[..half].iter().map(|&x| s.transpose() * x),
                        CAP,
                    );
                    (forth + back, s)
                })
                .collect();
            all.sort_by(|a, b| a.0.total_cmp(&b.0));
            for proper in [true, false] {
                let expected: Vec<Mat3> = all
                    .iter()
                    .filter(|(_, s)| (s.determinant() > 0.0) == proper)
                    .take(REFINED)
                    .map(|&(_, s)| s)
                    .collect();
                assert_eq!(shape.best_starts(&other, proper), expected);
            }
        }
    }

    /// A double eigenvalue, smallest or largest, exact or within rounding, leaves the frame
    /// one of eigenvectors.
    #[test]
    fn principal_axes_are_eigenvectors_when_two_moments_are_equal() {
        let turn = DMat3::from_quat(glamx::DQuat::from_axis_angle(
            DVec3::new(0.3, -1.0, 0.7).normalize(),
            2.0,
        ));
        for diagonal in [
            [0.3, 0.3, 0.4],
            [0.4, 0.3, 0.3],
            [0.3, 0.3 * (1.0 + 1e-12), 0.4],
            [0.2, 0.3, 0.5],
            [1.0 / 3.0; 3],
        ] {
            let moments =
                turn * DMat3::from_diagonal(DVec3::from_array(diagonal)) * turn.transpose();
            let (values, axes) = principal_axes(moments);
            for i in 0..3 {
                // The closed form's double roots are good to ~√ε; the vectors to ε.
                let v = axes.row(i);
                let value = v.dot(moments * v);
                assert!(
                    (moments * v - value * v).length() < 1e-12,
                    "{diagonal:?}: axis {i} {v}"
                );
                assert!((value - values[i]).abs() < 1e-7, "{diagonal:?}: {values}");
            }
            assert!(values[0] >= values[1] && values[1] >= values[2], "{values}");
            assert!((axes * axes.transpose()).abs_diff_eq(DMat3::IDENTITY, 1e-12));
        }
    }

    #[test]
    fn a_mirror_image_aligns_only_by_a_reflection() {
        let raw = lopsided();
        let shape = Shape::new(&raw, 1e-6).unwrap();
        let mirror = Shape::new(&moved(&raw, |p| glam::DVec3::new(-p.x, p.y, p.z)), 1e-6).unwrap();
        let alignment = mirror.align(&shape, REACH, |_| true);
        assert!(
            alignment.mirrored.surfaces.absolute.max < 1e-3,
            "{alignment:?}"
        );
        assert!(
            alignment.rotated.surfaces.absolute.mean > 1e-2,
            "{alignment:?}"
        );
    }
}

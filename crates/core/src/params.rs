//! Parameters with the SPEC's defaults. They are serialised with every signature, so a stored
//! signature always says how it was made.
//!
//! Two kinds, and the difference matters to every stored model:
//! - **extraction** parameters (`mesh`, `ecc`, `salient`, `d2`) and [`PARAMS_VERSION`] make
//!   the signature; changing one makes stored signatures stale, and they are re-extracted
//!   ([`crate::signature::Staleness`]);
//! - **ranking** parameters (`similarity`: `W`, the penalty, and later weights, scales and
//!   thresholds) only compare signatures; they are read from the configuration at query time
//!   and never make a signature stale.
//!
//! [`PARAMS_VERSION`] changes whenever a default or the meaning of an extraction field, or the
//! extraction itself (the weld), changes: that means re-extraction, not a store migration
//! (`migrations/README.md`). A new descriptor needs no new version: signatures without it
//! are stale by [`crate::signature::Staleness::MissingDescriptor`].

use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// Version of the parameter set and of the extraction algorithm's semantics.
///
/// - 1: release 0.1.0.
/// - 2: the weld merges every pair of vertices within the tolerance, across grid cells.
/// - 3: `D_g` 0.4 (was the paper's 0.3), chosen on the tuning halves (`docs/results/README.md`).
/// - 4: rough meshes are smoothed before extraction (`mesh.smoothing`, SPEC §1.7).
pub const PARAMS_VERSION: u32 = 4;

/// All parameters that influence a signature.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// [`PARAMS_VERSION`] at the time these parameters were written.
    pub version: u32,
    pub mesh: MeshParams,
    pub ecc: EccParams,
    pub salient: SalientParams,
    pub d2: D2Params,
    pub similarity: SimilarityParams,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            version: PARAMS_VERSION,
            mesh: MeshParams::default(),
            ecc: EccParams::default(),
            salient: SalientParams::default(),
            d2: D2Params::default(),
            similarity: SimilarityParams::default(),
        }
    }
}

impl Params {
    /// Whether signatures made with `self` and `other` are the same: the same extraction
    /// version and extraction parameters. Ranking parameters are ignored (module docs).
    pub fn same_extraction(&self, other: &Params) -> bool {
        (self.version, &self.mesh, &self.ecc, &self.salient, &self.d2)
            == (
                other.version,
                &other.mesh,
                &other.ecc,
                &other.salient,
                &other.d2,
            )
    }

    /// Bytes that name the extraction [`Params::same_extraction`] compares, for keys of
    /// signature caches: ranking parameters are left out, so retuning them reuses every
    /// cached signature.
    pub fn extraction_key(&self) -> Vec<u8> {
        serde_json::to_vec(&(self.version, &self.mesh, &self.ecc, &self.salient, &self.d2))
            .expect("parameters serialise")
    }

    /// The paper read literally, where SPEC resolves it otherwise: its local size `D_g` 0.3,
    /// Definition 3's cone height ([`HeightRule::Paper`], SPEC §2.4), the candidate cluster of
    /// largest norm ([`CandidateRule::Norm`], §3.1), the area filter on regions
    /// ([`RegionRule::Area`], §3.4), the tighter flatness limit 0.25 (§2.3) and meshes at
    /// full resolution (SPEC §1.5's 20 000 vertices). Evaluated beside the defaults (SPEC §7)
    /// so that the effect of SPEC's resolutions is measured, not asserted.
    pub fn paper() -> Self {
        let mut params = Self::default();
        params.mesh.max_vertices = 20_000;
        params.mesh.smoothing = 0.0;
        params.ecc.local_size = 0.3;
        params.ecc.height = HeightRule::Paper;
        params.ecc.flat_max = 0.25;
        params.salient.candidates = CandidateRule::Norm;
        params.salient.region_rule = RegionRule::Area;
        params
    }

    /// The parameters that extract a mesh normalised into the unit sphere as these extract it
    /// normalised into a sphere of radius `r` (SPEC §1.4): every length in normalised units
    /// (`D_g`, `D_e`, the smoothing length; the region histograms' range follows `D_g`)
    /// divided by `r`, while angles, counts and bins keep their meaning. How a part is
    /// described at the size it has in its whole model (`crate::partial`).
    pub fn at_scale(&self, r: f64) -> Params {
        let mut scaled = self.clone();
        scaled.ecc.local_size /= r;
        scaled.salient.suppression_distance /= r;
        scaled.mesh.smoothing /= r;
        // Already at the part's size: searched as it is.
        scaled.similarity.partial.scales = vec![1.0];
        scaled
    }

    /// Checks that every value is in the range the method is defined for, so that a bad
    /// parameter file is a clear error rather than a panic or a meaningless signature.
    pub fn validate(&self) -> Result<()> {
        let (m, e, s) = (&self.mesh, &self.ecc, &self.salient);
        let checks = [
            (
                self.version == PARAMS_VERSION,
                "version",
                "must be this release's extraction version (leave it out)",
            ),
            (
                m.weld_tolerance > 0.0 && m.weld_tolerance < 0.1,
                "mesh.weld_tolerance",
                "must be in (0, 0.1)",
            ),
            (
                m.max_vertices >= 4,
                "mesh.max_vertices",
                "must be at least 4",
            ),
            (
                (0.0..=1.0).contains(&m.smoothing),
                "mesh.smoothing",
                "must be in [0, 1]",
            ),
            (
                (-1.0..=1.0).contains(&m.rough_correlation),
                "mesh.rough_correlation",
                "must be in [-1, 1]",
            ),
            (
                e.local_size > 0.0 && e.local_size <= 2.0,
                "ecc.local_size",
                "must be in (0, 2]",
            ),
            (
                (1..=64).contains(&e.waves),
                "ecc.waves",
                "must be between 1 and 64",
            ),
            (e.flat_max >= 0.0, "ecc.flat_max", "must not be negative"),
            (
                (1..=64).contains(&s.clusters),
                "salient.clusters",
                "must be between 1 and 64",
            ),
            (
                s.suppression_distance >= 0.0,
                "salient.suppression_distance",
                "must not be negative",
            ),
            (
                (0.0..=1.0).contains(&s.min_region_ratio),
                "salient.min_region_ratio",
                "must be in [0, 1]",
            ),
            (
                (1..=1024).contains(&s.max_features),
                "salient.max_features",
                "must be between 1 and 1024",
            ),
            (
                (2..=100_000).contains(&self.d2.samples),
                "d2.samples",
                "must be between 2 and 100000",
            ),
            (
                (1..=4096).contains(&self.d2.bins),
                "d2.bins",
                "must be between 1 and 4096",
            ),
            (
                self.similarity.partial.scales.iter().all(|&r| {
                    e.local_size / r <= 2.0 && m.smoothing / r <= 1.0
                }),
                "similarity.partial.scales",
                "each must leave ecc.local_size / scale at most 2 and mesh.smoothing / scale at most 1",
            ),
        ];
        match checks
            .into_iter()
            .chain(self.similarity.checks())
            .find(|(ok, _, _)| !ok)
        {
            Some((_, name, message)) => Err(Error::InvalidParameter { name, message }),
            None => Ok(()),
        }
    }
}

/// Mesh preparation (SPEC §1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MeshParams {
    /// Vertices closer than this fraction of the bounding-box diagonal are merged (SPEC §1.2).
    pub weld_tolerance: f64,
    /// Meshes with more welded vertices are simplified to this count (SPEC §1.5). 3 000, not
    /// SPEC's first 20 000: the ECC's cost grows with the square of the count, and the
    /// cheapest bound whose tuning-half objective is within 0.002 of the best is taken; at
    /// 3 000 it was 0.884 (4 000 and 6 000: 0.881, 20 000: 0.883), with 5 uploads/s of
    /// 7 000-vertex meshes on 2 cores (`docs/results/README.md`, "Resolution").
    pub max_vertices: usize,
    /// The length (normalised units) over which a rough mesh is smoothed after normalisation
    /// (`mesh::smooth`), so that vertex-scale noise is not read as cone curvature (SPEC §1.7):
    /// at 0.08 the dog and the hand of `docs/results/robustness` at 1 % noise keep their
    /// salient points. 0 never smooths (the paper's mesh).
    pub smoothing: f64,
    /// A mesh is rough, and smoothed, when the neighbour correlation of its normal umbrella
    /// field (`mesh::smooth::correlation`) is below this: clean models of both collections
    /// measure at least 0.23 (but CAPOD's pianos, too coarse to be smoothed), SHREC'07's at
    /// 0.5 % noise at most 0.18.
    pub rough_correlation: f64,
}

impl Default for MeshParams {
    fn default() -> Self {
        Self {
            weld_tolerance: 1e-6,
            max_vertices: 3_000,
            smoothing: 0.08,
            rough_correlation: 0.2,
        }
    }
}

/// How the cone height `D_s^i` is accumulated (SPEC §2.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum HeightRule {
    /// Only the steps along the wave normal count: exact on planes, spheres and cones.
    #[default]
    Axial,
    /// The paper's Definition 3 read literally: full distances between successive centres.
    Paper,
}

/// How local geodesic distances are computed (SPEC §2.1, §9 "Geodesics").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum GeodesicRule {
    /// The paper's: shortest paths along the edges, a few per cent too long off the edge
    /// directions.
    #[default]
    Dijkstra,
    /// Fast marching (Kimmel and Sethian's triangle update, by a virtual source): exact on a
    /// plane, converging to the true geodesic as the mesh is refined.
    FastMarching,
}

/// Extended cone-curvature (SPEC §2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EccParams {
    /// Local size `D_g` in normalised units (§3.2.1). 0.4, not the paper's 0.3: at 20 000
    /// vertices larger regions gained held-out mAP on both shared collections, alone and in
    /// the hybrid (`PARAMS_VERSION` 3); at today's 3 000 the study no longer
    /// separates the two (`docs/results/README.md`, "Parameter study"). [`Params::paper`]
    /// keeps 0.3.
    pub local_size: f64,
    /// Number of waves `N`, the length of an ECC vector (§3.2.2).
    pub waves: usize,
    /// Largest accepted wave flatness (SPEC §2.3).
    pub flat_max: f64,
    /// Cone height rule (SPEC §2.4).
    pub height: HeightRule,
    /// Local geodesic distances (SPEC §2.1).
    pub geodesic: GeodesicRule,
}

impl Default for EccParams {
    fn default() -> Self {
        Self {
            local_size: 0.4,
            waves: 10,
            flat_max: 0.5,
            height: HeightRule::Axial,
            geodesic: GeodesicRule::Dijkstra,
        }
    }
}

/// Resource limits on untrusted input. They protect the process, they do not change results,
/// so they are not part of [`Params`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Limits {
    /// Largest number of vertices a file may declare or contain before welding.
    pub max_input_vertices: usize,
    /// Largest number of triangles (after triangulating polygons).
    pub max_input_triangles: usize,
    /// Largest number of entries a zip upload may hold.
    pub max_archive_entries: usize,
    /// Largest total size of the entries a zip upload unpacks to, in bytes: checked against
    /// what the archive declares before anything is inflated (a zip bomb is refused).
    pub max_unpacked_bytes: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_input_vertices: 5_000_000,
            max_input_triangles: 10_000_000,
            max_archive_entries: 10_000,
            max_unpacked_bytes: 1 << 30,
        }
    }
}

impl Limits {
    /// No limit: for re-extracting originals that were accepted under the limits of their
    /// upload.
    pub fn unlimited() -> Self {
        Self {
            max_input_vertices: usize::MAX,
            max_input_triangles: usize::MAX,
            max_archive_entries: usize::MAX,
            max_unpacked_bytes: usize::MAX,
        }
    }
}

/// Which cluster supplies the salient-point candidates (SPEC §3.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum CandidateRule {
    /// The cluster whose centre has the largest mean: convex tips, not deep pits.
    #[default]
    Mean,
    /// The paper's "largest norm", which can pick a cluster of concave pits.
    Norm,
}

/// Which salient regions are too small to keep (SPEC §3.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum RegionRule {
    /// Region size `D` below `min_region_ratio` × the largest `D`.
    #[default]
    Size,
    /// The paper's rule: region area below `min_region_ratio` × the largest area.
    Area,
}

/// Salient points and regions (SPEC §3).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SalientParams {
    /// `K` of k-means.
    pub clusters: usize,
    /// Seed of the k-means++ initialisation.
    pub seed: u64,
    /// k-means runs from different seeds; the one of least inertia is kept.
    pub restarts: usize,
    pub candidates: CandidateRule,
    /// `D_e`: candidates closer than this to an accepted one are suppressed.
    pub suppression_distance: f64,
    pub region_rule: RegionRule,
    /// Regions below this fraction of the largest are dropped.
    pub min_region_ratio: f64,
    /// At most this many features, the most salient first. Not in the paper: it bounds the
    /// signature size and the EMD cost on smooth shapes, where nearly every vertex is a
    /// candidate.
    pub max_features: usize,
}

impl Default for SalientParams {
    fn default() -> Self {
        Self {
            clusters: 5,
            seed: 0x05a1_1e47,
            restarts: 8,
            candidates: CandidateRule::Mean,
            suppression_distance: 0.15,
            region_rule: RegionRule::Size,
            min_region_ratio: 0.3,
            max_features: 32,
        }
    }
}

/// D2 shape distributions (SPEC §4 and §6): of each salient region over `[0, 2·D_g]`, and of
/// the whole normalised mesh over `[0, 2]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct D2Params {
    /// Points sampled uniformly by area; all pairs are measured.
    pub samples: usize,
    pub bins: usize,
}

impl Default for D2Params {
    fn default() -> Self {
        Self {
            samples: 2000,
            bins: 64,
        }
    }
}

/// Comparing signatures (SPEC §5) and fusing the methods' distances (SPEC §9).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimilarityParams {
    /// `W` of Eq. 11: weight of the ECC distance against the region D2 distance.
    pub ecc_weight: f64,
    /// Multiply the EMD by `max(m, n) / min(m, n)` (Eq. 13).
    pub penalty: bool,
    /// The penalty's power: `(max(m, n) / min(m, n))^p`. 1 is Eq. 13; below 1 softens it
    /// for classes whose feature counts vary. The hybrid's ECC part has its own
    /// ([`HybridParams::penalty_power`]).
    pub penalty_power: f64,
    /// The `hybrid` method's parts.
    pub hybrid: HybridParams,
    /// When two models are one asset (`crate::duplicate`).
    pub duplicates: DuplicateParams,
    /// Searching with a part of a model (`crate::partial`).
    pub partial: PartialParams,
}

impl Default for SimilarityParams {
    fn default() -> Self {
        Self {
            ecc_weight: 0.5,
            penalty: true,
            penalty_power: 1.0,
            hybrid: HybridParams::default(),
            duplicates: DuplicateParams::default(),
            partial: PartialParams::default(),
        }
    }
}

impl SimilarityParams {
    /// These parameters with the hybrid's penalty power: what its ECC part compares with.
    pub fn hybrid_ecc(&self) -> SimilarityParams {
        SimilarityParams {
            penalty_power: self.hybrid.penalty_power,
            ..self.clone()
        }
    }

    fn checks(&self) -> [(bool, &'static str, &'static str); 7] {
        let h = &self.hybrid;
        let parts = h.terms();
        let d = &self.duplicates;
        [
            (
                !self.partial.scales.is_empty()
                    && self.partial.scales.len() <= PartialParams::MAX_SCALES
                    && self
                        .partial
                        .scales
                        .iter()
                        .all(|r| PartialParams::RANGE.contains(r)),
                "similarity.partial.scales",
                "must hold 1 to 8 sizes, each in [0.2, 1]",
            ),
            (
                self.partial.verified <= PartialParams::MAX_VERIFIED,
                "similarity.partial.verified",
                "must be at most 100",
            ),
            (
                [
                    d.d2,
                    d.lfd,
                    d.mean,
                    d.mean_per_spacing,
                    d.mean_at_most,
                    d.mean_per_triangle,
                    d.largest,
                    d.largest_per_spacing,
                    d.largest_per_triangle,
                    d.vertices_per_edge,
                    d.split_vertices_per_edge,
                    d.deleted,
                    d.added,
                    d.moved,
                    d.geometry,
                ]
                .iter()
                .all(|x| (0.0..=10.0).contains(x))
                    && (1..=1000).contains(&d.candidates),
                "similarity.duplicates",
                "thresholds must be in [0, 10] and candidates in 1..=1000",
            ),
            (
                (0.0..=1.0).contains(&self.ecc_weight),
                "similarity.ecc_weight",
                "must be in [0, 1]",
            ),
            (
                [self.penalty_power, h.penalty_power]
                    .iter()
                    .all(|p| (0.0..=4.0).contains(p)),
                "similarity.penalty_power",
                "must be in [0, 4], also the hybrid's",
            ),
            (
                parts
                    .iter()
                    .all(|t| t.weight >= 0.0 && t.weight.is_finite()),
                "similarity.hybrid",
                "weights must be finite and not negative",
            ),
            (
                parts.iter().all(|t| t.scale > 0.0 && t.scale.is_finite())
                    && parts.iter().any(|t| t.weight > 0.0),
                "similarity.hybrid",
                "scales must be positive and finite, and one weight positive",
            ),
        ]
    }
}

/// The thresholds of the near-duplicate check (`crate::duplicate`), chosen with `salient eval
/// duplicates` on the tuning halves of both shared collections (`docs/results/duplicates/`).
/// Ranking parameters: changing them never makes a signature stale.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DuplicateParams {
    /// Candidates are within this global D2 distance (the `d2` method's) …
    pub d2: f64,
    /// … and this light field distance (the `lfd` method's) of each other: every disguised
    /// copy of the tuning halves, of every family, was within 0.085 and 0.026 (CAPOD clustered).
    pub lfd: f64,
    /// At most this many candidates for one upload, nearest first.
    pub candidates: usize,
    /// `same_shape` when, aligned, each surface's samples lie on average within this many RMS
    /// radii of the other surface, or within `mean_per_spacing` typical triangle sizes of the
    /// coarser mesh if that is more (a remeshing moves a coarse surface more) but never more
    /// than `mean_at_most` (boxy low-poly models have large triangles that remeshing hardly
    /// moves), or within `mean_per_triangle` sizes of the coarser mesh's triangles where each
    /// sample lies (a simplification moves the surface in proportion to the triangles it
    /// leaves there, large or small: `crate::duplicate::Distances`) …
    pub mean: f64,
    pub mean_per_spacing: f64,
    pub mean_at_most: f64,
    pub mean_per_triangle: f64,
    /// … and none farther than `largest` RMS radii or `largest_per_spacing` typical triangle
    /// sizes, or else `largest_per_triangle` sizes of the triangles where they lie: another
    /// pose of a model moves a limb far, however small its triangles …
    pub largest: f64,
    pub largest_per_spacing: f64,
    pub largest_per_triangle: f64,
    /// … and nine in ten of the coarser mesh's vertices within this many of their own edge
    /// lengths of the finer surface, fitted onto it (`crate::duplicate::Shape`): a
    /// simplification keeps or places its vertices on the surface, whichever simplifier made
    /// it, while a morph of one mesh (the same faces, some vertices moved) or a smoothing
    /// moves them off it by more than the surfaces' limits tell.
    pub vertices_per_edge: f64,
    /// A copy whose mesh is the other's triangles each split in four is the same asset only
    /// when every vertex of the coarser lies within this many of its edge lengths of the finer
    /// surface, fitted onto it: a split that kept the surface (midpoint subdivision: ~1e-6 on
    /// generated shapes) and not a smoothing one (Loop's: 0.15–0.24 at the farthest vertex,
    /// though nine in ten lie within `vertices_per_edge`).
    pub split_vertices_per_edge: f64,
    /// A simplification may delete small connected pieces whole (an edge collapse takes an
    /// isolated triangle away: CAPOD's trees lose leaves). For a copy all of whose vertices
    /// lie within `vertices_per_edge`, the finer mesh's samples on small pieces beyond the
    /// largest distance are left out of the limits above, when they are at most this share
    /// of its surface.
    pub deleted: f64,
    /// A coarser mesh that is the finer's own triangles (a sub-mesh, `crate::duplicate::Shape`)
    /// is the same asset only when it lacks at most this share of the finer's area: the slivers
    /// and loose triangles a cleanup removes, not parts another design adds (CAPOD's airplane
    /// m48 is m47 and 4 % more surface).
    pub added: f64,
    /// One mesh with its vertices edited (the same triangles, vertex for vertex) is the same
    /// asset only when no vertex moved farther than this many of its edge lengths once all are
    /// fitted: float precision and quantisation move them far less, a morph or a moved part more.
    pub moved: f64,
    /// `identical_geometry` when the welded meshes have the same counts and every vertex lies
    /// within this many RMS radii of the other surface, unrotated.
    pub geometry: f64,
}

impl Default for DuplicateParams {
    fn default() -> Self {
        Self {
            d2: 0.1,
            lfd: 0.03,
            candidates: 32,
            mean: 0.006,
            mean_per_spacing: 0.2,
            mean_at_most: 0.02,
            mean_per_triangle: 0.1,
            largest: 0.08,
            largest_per_spacing: 1.0,
            largest_per_triangle: 1.5,
            vertices_per_edge: 0.105,
            split_vertices_per_edge: 0.01,
            deleted: 0.06,
            added: 0.01,
            moved: 0.05,
            geometry: 1e-4,
        }
    }
}

impl DuplicateParams {
    /// The surfaces' mean and largest distance allowed between two meshes in RMS radii, the
    /// coarser of typical triangle size `spacing` (RMS radii).
    pub fn surface_limits(&self, spacing: f64) -> (f64, f64) {
        (
            self.mean
                .max((self.mean_per_spacing * spacing).min(self.mean_at_most)),
            self.largest.max(self.largest_per_spacing * spacing),
        )
    }
}

/// How a part is searched for (`crate::partial`). Ranking parameters: changing them never
/// makes a stored signature stale.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PartialParams {
    /// The sizes a part may have in its whole model: its largest distance from its own
    /// centroid over the model's (SPEC §1.4's normalising radius). SPEC §1.4 scales every mesh
    /// to the unit sphere, which magnifies a part against its source, so the part is described
    /// at each of these sizes ([`Params::at_scale`]) and a model ranks by the best.
    pub scales: Vec<f64>,
    /// How many models the part is registered into ([`crate::partial::Probe::residual`]),
    /// which then rank first by how well it lies on their surface: the models nearest it by
    /// their stored patches, and as many of the feature fit's best among models whose
    /// patches are not made yet ([`crate::rank::Query::Part`]); 0 ranks by the
    /// feature fit alone. Each costs a registration (and, when the model's surface is not
    /// cached, its preparation).
    pub verified: usize,
}

impl PartialParams {
    /// Sizes a part may be described at: below 0.2 the default `D_g` would outgrow the
    /// validated range, and a part is at most as large as its model.
    pub const RANGE: std::ops::RangeInclusive<f64> = 0.2..=1.0;
    /// At most this many sizes: each is an extraction of the part.
    pub const MAX_SCALES: usize = 8;
    /// At most this many verified models: each is a registration.
    pub const MAX_VERIFIED: usize = 100;

    /// The sizes to describe a part at: the one the caller knows, else [`Self::scales`].
    pub fn sizes(&self, known: Option<f64>) -> Vec<f64> {
        known.map_or_else(|| self.scales.clone(), |r| vec![r])
    }
}

impl Default for PartialParams {
    fn default() -> Self {
        Self {
            scales: vec![0.25, 0.35, 0.5, 0.7],
            verified: 50,
        }
    }
}

/// One part of the `hybrid` distance: it adds `weight · d / scale`. The scale is fixed (a
/// typical distance of the part, chosen with the weights), so a hybrid distance depends only
/// on the two models, never on what else is stored, and lower bounds add up.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Term {
    pub weight: f64,
    pub scale: f64,
}

/// Weights and scales of the `hybrid` method (SPEC §9), chosen by `salient eval tune` on the
/// tuning halves of both shared collections (`docs/results/tune/`). Ranking parameters:
/// changing them never makes a signature stale.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HybridParams {
    pub ecc: Term,
    pub d2: Term,
    pub lfd: Term,
    pub geodesic: Term,
    /// The count penalty's power in the ECC part (see [`SimilarityParams::penalty_power`]).
    pub penalty_power: f64,
}

impl Default for HybridParams {
    fn default() -> Self {
        Self {
            ecc: Term {
                weight: 0.25,
                scale: 0.27367162493563657,
            },
            d2: Term {
                weight: 0.0,
                scale: 0.14292362285777926,
            },
            lfd: Term {
                weight: 0.55,
                scale: 0.0426318082788671,
            },
            geodesic: Term {
                weight: 0.2,
                scale: 0.020201022503897548,
            },
            penalty_power: 0.0,
        }
    }
}

impl HybridParams {
    /// The terms in the order of [`crate::rank::PARTS`].
    pub fn terms(&self) -> [Term; 4] {
        [self.ecc, self.d2, self.lfd, self.geodesic]
    }

    /// The terms to set, in the same order.
    pub fn terms_mut(&mut self) -> [&mut Term; 4] {
        [
            &mut self.ecc,
            &mut self.d2,
            &mut self.lfd,
            &mut self.geodesic,
        ]
    }
}

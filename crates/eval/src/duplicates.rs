//! `salient eval duplicates`: how well the library-wide near-duplicate search
//! ([`salient_core::duplicate`]) finds disguised copies, and how rarely it takes another model of
//! the same class for one (`docs/results/duplicates/`). Every model of a collection (or of one
//! of its halves, [`super::study::halves`]) gets one copy of each family of disguises
//! ([`Disguise`], made by [`super::disguise`]): re-exported, re-triangulated, simplified by
//! three kinds of simplifier, subdivided linearly — each expected to be found — and Loop or
//! Catmull–Clark subdivided, a smoothed asset expected *not* to be. Each copy is also rotated, scaled by 25.4
//! or 0.1, moved and written in another format.
//!
//! Copies are written as files and read back, as an upload would be. The search then runs as
//! the service runs it: candidate pairs from the global descriptors, each verified on the
//! meshes, groups from the verified links. Each family is measured on its own: the models with
//! only that family's copies mixed in (the candidate filter is pairwise, so one search over
//! every file serves every family). A pair of files counts as found at an evidence level when
//! both are in one group at that level; the true pairs are the files of one source model.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::time::Instant;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use super::disguise::{self, Indexed};
use super::report::{score, write, write_json, Table};
use super::robustness::random_rotation;
use super::study::Half;
use super::{LabelledCollection, Progress};
use salient_core::duplicate::{groups, judge, Deviation, Evidence, Link, Reach, Shape, Verdict};
use salient_core::mesh::load::NoResources;
use salient_core::mesh::weld::weld;
use salient_core::mesh::write::Export;
use salient_core::mesh::{load_bytes, load_path, RawMesh};
use salient_core::params::{DuplicateParams, Limits, Params};
use salient_core::pipeline::compute_global;
use salient_core::rank::{distance, Index, Method};

/// Lower-case hex SHA-256 of a file's bytes.
fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    hex::encode(sha2::Sha256::digest(bytes))
}
use salient_core::Result;

/// How a copy was disguised: a family of tools ([`super::disguise`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Disguise {
    /// Another format (float32 for STL and GLB), other units, moved; not rotated.
    Reexported,
    /// The same vertices, quads' diagonals flipped.
    Retriangulated,
    /// meshoptimizer's edge collapse to 40–60 % of the welded vertices (a subset of them).
    EdgeCollapse,
    /// Garland–Heckbert quadric collapse with optimal placement, to 40–60 %.
    Quadric,
    /// Forstmann's fast quadric simplification (pyfqmr, fast_simplification), to 40–60 % of
    /// the triangles: thin parts and small pieces collapse.
    FastQuadric,
    /// Vertex clustering on a grid, to 40–60 %.
    Clustered,
    /// Every triangle split in four at its edges' midpoints.
    Midpoint,
    /// One step of Loop's smoothing subdivision: another asset.
    Loop,
    /// One step of Catmull–Clark's, its quads triangulated: another asset.
    CatmullClark,
}

impl Disguise {
    pub const ALL: [Disguise; 9] = [
        Disguise::Reexported,
        Disguise::Retriangulated,
        Disguise::EdgeCollapse,
        Disguise::Quadric,
        Disguise::FastQuadric,
        Disguise::Clustered,
        Disguise::Midpoint,
        Disguise::Loop,
        Disguise::CatmullClark,
    ];

    /// The weakest evidence a copy so disguised should be found with (stronger is right
    /// too); `None` for another asset. A linear subdivision leaves every vertex of each mesh
    /// on the other's surface: `identical_geometry`. A re-triangulation keeps the vertices
    /// but moves the surface between them a little, and the frame with it.
    fn expected(self) -> Option<Evidence> {
        match self {
            Disguise::Reexported | Disguise::Midpoint => Some(Evidence::IdenticalGeometry),
            Disguise::Retriangulated
            | Disguise::EdgeCollapse
            | Disguise::Quadric
            | Disguise::FastQuadric
            | Disguise::Clustered => Some(Evidence::SameShape),
            Disguise::Loop | Disguise::CatmullClark => None,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Disguise::Reexported => "reexported",
            Disguise::Retriangulated => "retriangulated",
            Disguise::EdgeCollapse => "edge_collapse",
            Disguise::Quadric => "quadric",
            Disguise::FastQuadric => "fast_quadric",
            Disguise::Clustered => "clustered",
            Disguise::Midpoint => "midpoint",
            Disguise::Loop => "loop",
            Disguise::CatmullClark => "catmull_clark",
        }
    }

    /// The copy of a welded mesh, before it is moved; `fraction` of its vertices kept by
    /// the simplifiers (of its triangles by the fast quadric one, which counts those).
    fn make(self, welded: &salient_core::mesh::weld::Welded, fraction: f64) -> Indexed {
        let (p, t) = (&welded.positions[..], &welded.triangles[..]);
        let target = ((p.len() as f64 * fraction) as usize).max(4);
        match self {
            Disguise::Reexported => (p.to_vec(), t.to_vec()),
            Disguise::Retriangulated => disguise::retriangulated(p, t),
            Disguise::EdgeCollapse => disguise::edge_collapse(p, t, target),
            Disguise::Quadric => disguise::quadric(p, t, target),
            Disguise::FastQuadric => {
                disguise::fast_quadric(p, t, ((t.len() as f64 * fraction) as usize).max(4))
            }
            Disguise::Clustered => disguise::clustered(p, t, target),
            Disguise::Midpoint => disguise::midpoint(p, t),
            Disguise::Loop => disguise::loop_subdivided(p, t),
            Disguise::CatmullClark => disguise::catmull_clark(p, t),
        }
    }
}

/// A file of the mixed collection: a model, or a disguised copy of one.
struct File {
    name: String,
    source: usize,
    /// The source of the first model of its design ([`SAME_DESIGN`]): files of one design
    /// and different sources are a `same_shape` pair.
    design: usize,
    class: String,
    disguise: Option<Disguise>,
    /// A copy's area over its model's, both as made ([`DAMAGED`]); 1 for a model.
    area_kept: f64,
    raw: RawMesh,
}

impl File {
    /// The evidence this file should be found with beside its source; `None` for another
    /// asset made from it.
    fn expected(&self) -> Option<Evidence> {
        self.disguise
            .map_or(Some(Evidence::IdenticalFile), Disguise::expected)
    }
}

/// What the search found, per family of disguises.
#[derive(Debug, Clone, Serialize)]
pub struct DuplicatesReport {
    pub collection: String,
    pub half: String,
    pub models: usize,
    pub copies: usize,
    pub params: DuplicateParams,
    /// Candidate pairs verified on the meshes (pairs of copies of two families left out).
    pub verified: usize,
    /// Models of the collection whose files are byte-identical: one model for the measures.
    pub identical_in_collection: Vec<(String, String)>,
    /// Models of the collection that are one design tessellated twice ([`SAME_DESIGN`]):
    /// a `same_shape` pair for the measures.
    pub same_design_in_collection: Vec<(String, String)>,
    pub families: Vec<Family>,
    /// Verified links between files that are not one asset (false positives), and their
    /// classes.
    pub false_links: Vec<FalseLink>,
    /// The 99th percentile of the aligned distances, in triangle sizes, of every candidate
    /// pair of different models (of one design too, [`SAME_DESIGN`]).
    pub negatives_local_p99: Distribution,
    /// The [`HARDEST`] of those pairs, nearest the reach first, with their aligned deviation:
    /// how far the hardest negatives stay from the `same_shape` thresholds.
    pub negatives: Vec<Aligned>,
    /// How well each global descriptor's distance separates copies from other models, over
    /// every pair of files: what a candidate filter can use.
    pub filters: Vec<Filter>,
    pub seconds: Seconds,
}

/// One descriptor distance as a candidate filter.
#[derive(Debug, Clone, Serialize)]
pub struct Filter {
    pub method: String,
    /// The largest distance between files of one model (copies expected to be found).
    pub copies_max: f64,
    /// Pairs of files of different models, and how many are within `copies_max`.
    pub others: usize,
    pub others_within: usize,
}

/// Pairs found at one evidence level.
#[derive(Debug, Clone, Serialize)]
pub struct Level {
    pub min_evidence: Evidence,
    pub true_pairs: usize,
    pub found_pairs: usize,
    pub correct: usize,
    pub precision: f64,
    pub recall: f64,
}

/// One family of disguises: the models with only its copies mixed in, and each copy against
/// its own model, verified directly (whether or not it was a candidate).
#[derive(Debug, Clone, Serialize)]
pub struct Family {
    pub disguise: Disguise,
    /// What its copies should be found with (`null`: another asset, never to be linked).
    pub expected: Option<Evidence>,
    pub copies: usize,
    /// Pairs found in the mixed collection at `identical_geometry`, `same_shape` and
    /// `mirrored`.
    pub levels: Vec<Level>,
    /// Copies that passed the candidate filter with their model.
    pub candidates: usize,
    /// Evidence found between copy and model, by name (`none` when not a duplicate).
    pub evidence: BTreeMap<String, usize>,
    /// The copies' share of their model's welded vertices.
    pub vertices_kept: Distribution,
    /// The copies' area over their model's, as made (before they are moved).
    pub area_kept: Distribution,
    /// Copies that kept less than [`DAMAGED`] of their model's area, and the evidence each
    /// was found with (`none` when not a duplicate): counted in the measures like every copy.
    pub damaged: Vec<Damaged>,
    /// D2 distances between copy and model.
    pub d2: Distribution,
    /// The 99th percentile of the aligned distances, in RMS radii and in triangle sizes
    /// ([`salient_core::duplicate::Distances`]).
    pub aligned: Distribution,
    pub aligned_local: Distribution,
    /// The 90th percentile of the coarser file's vertices' distances, in edge lengths.
    pub vertices: Distribution,
    /// Copies whose verdict with their model depends on which comes first (each is verified
    /// both ways): the service caches a verdict by the unordered pair, so any is a defect.
    pub one_way: Vec<String>,
    /// Every copy, farthest from its model first.
    pub worst: Vec<Aligned>,
}

/// A copy its simplifier damaged ([`DAMAGED`]), and the evidence it was found with.
#[derive(Debug, Clone, Serialize)]
pub struct Damaged {
    pub copy: String,
    pub found: &'static str,
}

/// Two files, their aligned deviation and the coarser one's typical triangle size (RMS
/// radii): what a verdict is judged on, for choosing thresholds.
#[derive(Debug, Clone, Serialize)]
pub struct Aligned {
    pub a: String,
    pub b: String,
    /// `identical_geometry` passed (no alignment needed).
    pub identical: bool,
    /// The pair passed the candidate filter.
    pub candidate: bool,
    pub deviation: Deviation,
    pub spacing: f64,
}

/// A pair verified as the service verifies it, with what the verdict was judged on.
struct Measured {
    verdict: Option<Verdict>,
    identical: bool,
    deviation: Deviation,
    spacing: f64,
}

fn measure(x: &Shape, y: &Shape, p: &DuplicateParams) -> Measured {
    // Every pair's vertices measured, for choosing thresholds.
    let spacing = x.coarser(y);
    let alignment = x.align(y, Reach::new(p, spacing), |_| true);
    let geometry = x.geometry_deviation(y, p.geometry);
    Measured {
        verdict: judge((geometry, x.split_of(y)), |_, _| alignment, spacing, p),
        identical: geometry.is_some(),
        deviation: alignment.rotated,
        spacing,
    }
}

/// A copy verified against its model alone (copy first), and what else the family's table
/// says of it.
struct Checked<'a> {
    measured: Measured,
    /// D2 distance to the model, and the copy's share of the model's welded vertices.
    d2: f64,
    kept: f64,
    area_kept: f64,
    name: &'a str,
    /// The pair passed the candidate filter.
    candidate: bool,
    /// Verified model first, the evidence differs.
    one_way: bool,
}

#[derive(Debug, Clone, Serialize)]
pub struct FalseLink {
    pub a: String,
    pub b: String,
    pub same_class: bool,
    pub evidence: Evidence,
    pub score: f64,
}

/// The median, 95th percentile and largest of some values (smallest too, for negatives).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Distribution {
    pub count: usize,
    pub min: f64,
    pub median: f64,
    pub p95: f64,
    pub max: f64,
}

impl Distribution {
    fn of(mut values: Vec<f64>) -> Self {
        if values.is_empty() {
            return Self::default();
        }
        values.sort_by(f64::total_cmp);
        let at = |q: f64| values[((values.len() - 1) as f64 * q).round() as usize];
        Self {
            count: values.len(),
            min: values[0],
            median: at(0.5),
            p95: at(0.95),
            max: values[values.len() - 1],
        }
    }
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct Seconds {
    /// Making and reading back the copies.
    pub copies: f64,
    /// D2 signatures and verification shapes of every file.
    pub describe: f64,
    /// Candidate pairs and their verification.
    pub search: f64,
}

/// Runs the benchmark on `half` of `collection`. Deterministic: copies are seeded by model.
pub fn run(
    collection: &LabelledCollection,
    half: Half,
    params: &Params,
    limits: &Limits,
    progress: &dyn Progress,
) -> Result<DuplicatesReport> {
    let chosen = half.models(collection);
    let p = &params.similarity.duplicates;

    let clock = Instant::now();
    progress.start("copies", chosen.len());
    let mut files: Vec<File> = chosen
        .par_iter()
        .map(|&i| {
            let model = &collection.models[i];
            let files = disguised(
                i,
                &model.id,
                &model.class,
                &load_path(&model.path, limits)?,
                params,
                limits,
            );
            progress.advance(&model.id);
            files
        })
        .collect::<Result<Vec<_>>>()?
        .into_iter()
        .flatten()
        .collect();
    progress.finish();
    let identical_in_collection = one_source_per_content(collection, &mut files)?;
    let same_design_in_collection = one_design(collection, &mut files);
    let copies_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    progress.start("describe", files.len());
    let described = files
        .par_iter()
        .map(|f| {
            let described = (
                compute_global(&f.raw, params)?,
                Shape::new(&f.raw, params.mesh.weld_tolerance)?,
            );
            progress.advance(&f.name);
            Ok(described)
        })
        .collect::<Result<Vec<_>>>()?;
    progress.finish();
    let mut index = Index::new(params.similarity.clone());
    for (f, (signature, _)) in files.iter().zip(&described) {
        index
            .insert(f.name.as_str(), signature)
            .map_err(|e| salient_core::Error::Io {
                path: std::env::temp_dir(),
                source: e,
            })?;
    }
    let describe_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let number: HashMap<&str, usize> = files
        .iter()
        .enumerate()
        .map(|(i, f)| (f.name.as_str(), i))
        .collect();
    // Two copies of different families are never in one mixed collection.
    let apart =
        |a: &File, b: &File| matches!((a.disguise, b.disguise), (Some(x), Some(y)) if x != y);
    let pairs: Vec<(usize, usize)> = index
        .near_pairs(p.d2, p.lfd)
        .map_err(|e| salient_core::Error::Io {
            path: std::env::temp_dir(),
            source: e,
        })?
        .iter()
        .map(|(a, b)| (number[&**a], number[&**b]))
        .filter(|&(a, b)| !apart(&files[a], &files[b]))
        .collect();
    progress.start("verify", pairs.len());
    let measured: Vec<(usize, usize, Measured)> = pairs
        .par_iter()
        .map(|&(i, j)| {
            progress.advance(&files[i].name);
            (i, j, measure(&described[i].1, &described[j].1, p))
        })
        .collect();
    progress.finish();
    let search_seconds = clock.elapsed().as_secs_f64();

    let links: Vec<Link<usize>> = measured
        .iter()
        .filter_map(|&(a, b, ref m)| {
            Some(Link {
                a,
                b,
                verdict: m.verdict?,
            })
        })
        .collect();
    let false_links = links
        .iter()
        .filter(|l| expected(&files, l.a, l.b).is_none())
        .map(|l| FalseLink {
            a: files[l.a].name.clone(),
            b: files[l.b].name.clone(),
            same_class: files[l.a].class == files[l.b].class,
            evidence: l.verdict.evidence,
            score: l.verdict.score,
        })
        .collect();
    let filters = [Method::D2, Method::Lfd, Method::Geodesic]
        .into_iter()
        .map(|method| {
            let all: Vec<(bool, f64)> = (0..files.len())
                .into_par_iter()
                .flat_map_iter(|a| {
                    let described = &described;
                    let files = &files;
                    (a + 1..files.len())
                        .filter(move |&b| !apart(&files[a], &files[b]))
                        .filter(move |&b| {
                            files[a].source != files[b].source || expected(files, a, b).is_some()
                        })
                        .map(move |b| {
                            let d = distance(
                                method,
                                &described[a].0,
                                &described[b].0,
                                &params.similarity,
                            );
                            (files[a].source == files[b].source, d)
                        })
                })
                .collect();
            let copies_max = all.iter().filter(|x| x.0).map(|x| x.1).fold(0.0, f64::max);
            Filter {
                method: method.to_string(),
                copies_max,
                others: all.iter().filter(|x| !x.0).count(),
                others_within: all.iter().filter(|x| !x.0 && x.1 <= copies_max).count(),
            }
        })
        .collect();
    let mut negatives: Vec<Aligned> = measured
        .iter()
        .filter(|m| files[m.0].source != files[m.1].source)
        .map(|(a, b, m)| Aligned {
            a: files[*a].name.clone(),
            b: files[*b].name.clone(),
            identical: m.identical,
            candidate: true,
            deviation: m.deviation,
            spacing: m.spacing,
        })
        .collect();
    let negatives_local_p99 = Distribution::of(
        negatives
            .iter()
            .map(|a| a.deviation.surfaces.local.p99)
            .collect(),
    );
    negatives.sort_by(|x, y| {
        let key = |a: &Aligned| a.deviation.surfaces.reached.max;
        key(x).total_cmp(&key(y))
    });
    negatives.truncate(HARDEST);
    let candidate: std::collections::HashSet<(usize, usize)> = pairs.iter().copied().collect();
    let original: HashMap<usize, usize> = files
        .iter()
        .enumerate()
        .rev()
        .filter(|(_, f)| f.disguise.is_none())
        .map(|(i, f)| (f.source, i))
        .collect();
    let families = Disguise::ALL
        .into_iter()
        .map(|disguise| {
            let members: Vec<usize> = (0..files.len())
                .filter(|&i| files[i].disguise.is_none_or(|d| d == disguise))
                .collect();
            let levels = [
                Evidence::IdenticalGeometry,
                Evidence::SameShape,
                Evidence::Mirrored,
            ]
            .into_iter()
            .map(|min| level(&files, &members, &links, min))
            .collect();
            let checked: Vec<Checked> = files
                .par_iter()
                .enumerate()
                .filter(|(_, f)| f.disguise == Some(disguise))
                .map(|(c, f)| {
                    // The source's first model (byte-identical models share a source).
                    let o = original[&f.source];
                    let pair = (o.min(c), o.max(c));
                    let d2 = salient_core::descriptor::histogram_l1(
                        &described[o].0.d2,
                        &described[c].0.d2,
                    );
                    let kept = described[c].1.vertices() as f64 / described[o].1.vertices() as f64;
                    let forth = measure(&described[c].1, &described[o].1, p);
                    let back = measure(&described[o].1, &described[c].1, p);
                    let evidence = |m: &Measured| m.verdict.map(|v| v.evidence);
                    Checked {
                        one_way: evidence(&forth) != evidence(&back),
                        measured: forth,
                        d2,
                        kept,
                        area_kept: f.area_kept,
                        name: f.name.as_str(),
                        candidate: candidate.contains(&pair),
                    }
                })
                .collect();
            let mut evidence = BTreeMap::new();
            for c in &checked {
                let name = c.measured.verdict.map_or("none", |v| v.evidence.as_str());
                *evidence.entry(name.to_string()).or_insert(0) += 1;
            }
            let of = |f: &dyn Fn(&Deviation) -> f64| {
                Distribution::of(checked.iter().map(|c| f(&c.measured.deviation)).collect())
            };
            let mut worst: Vec<Aligned> = checked
                .iter()
                .map(|c| Aligned {
                    a: c.name.to_string(),
                    b: files[original[&files[number[c.name]].source]].name.clone(),
                    identical: c.measured.identical,
                    candidate: c.candidate,
                    deviation: c.measured.deviation,
                    spacing: c.measured.spacing,
                })
                .collect();
            worst.sort_by(|x, y| {
                let key = |a: &Aligned| a.deviation.surfaces.local.p99;
                key(y).total_cmp(&key(x))
            });
            Family {
                disguise,
                expected: disguise.expected(),
                copies: checked.len(),
                levels,
                candidates: checked.iter().filter(|c| c.candidate).count(),
                evidence,
                vertices_kept: Distribution::of(checked.iter().map(|c| c.kept).collect()),
                area_kept: Distribution::of(checked.iter().map(|c| c.area_kept).collect()),
                damaged: checked
                    .iter()
                    .filter(|c| c.area_kept < DAMAGED)
                    .map(|c| Damaged {
                        copy: c.name.to_string(),
                        found: c.measured.verdict.map_or("none", |v| v.evidence.as_str()),
                    })
                    .collect(),
                d2: Distribution::of(checked.iter().map(|c| c.d2).collect()),
                aligned: of(&|d| d.surfaces.absolute.p99),
                aligned_local: of(&|d| d.surfaces.local.p99),
                vertices: of(&|d| d.vertices.p90),
                one_way: checked
                    .iter()
                    .filter(|c| c.one_way)
                    .map(|c| c.name.to_string())
                    .collect(),
                worst,
            }
        })
        .collect();
    Ok(DuplicatesReport {
        collection: collection.root.display().to_string(),
        half: format!("{half:?}").to_lowercase(),
        models: chosen_count(&files),
        copies: files.iter().filter(|f| f.disguise.is_some()).count(),
        params: p.clone(),
        verified: pairs.len(),
        identical_in_collection,
        same_design_in_collection,
        families,
        false_links,
        negatives_local_p99,
        negatives,
        filters,
        seconds: Seconds {
            copies: copies_seconds,
            describe: describe_seconds,
            search: search_seconds,
        },
    })
}

/// A copy with less than this share of its model's area left was damaged by its simplifier,
/// not only re-tessellated: fast quadric halvings of CAPOD's trees, of its ~360-vertex pianos
/// and of guitar m119 at 40 % keep 0.21–0.7 of the area (pyfqmr 0.3.0 the same) and cut parts
/// away that lie 0.35 RMS radii from the model, as far as a morph's (the test
/// `duplicates::a_low_poly_piano_halved_…`). Listed beside the measures, never left out of
/// them. Not a verdict: an edge collapse deletes up to 35 % of a tree's leaves and a quadric
/// collapse 28 %, and some of those copies are found (CAPOD's tuning and held-out halves,
/// stop 57); smoothing shrinks trees and desktop computers to 0.67.
const DAMAGED: f64 = 0.75;

/// Hard negatives kept in the report: every candidate pair's deviation would make it tens of
/// megabytes.
const HARDEST: usize = 300;

/// The evidence files `a` and `b` should be linked by, if they are one asset: files of one
/// model by the weaker of their disguises' (`None` when either is another asset, unless both
/// are its copies by one disguise), files of one design ([`SAME_DESIGN`]) by `same_shape`.
fn expected(files: &[File], a: usize, b: usize) -> Option<Evidence> {
    let (x, y) = (&files[a], &files[b]);
    if x.design != y.design {
        return None;
    }
    // Two copies made alike from one model (byte-identical models' Loop copies: CAPOD's
    // pianos m121 = m123) are one asset, whatever the family.
    if x.source == y.source && x.disguise.is_some() && x.disguise == y.disguise {
        return Some(Evidence::SameShape);
    }
    let weaker = x.expected()?.max(y.expected()?);
    Some(if x.source == y.source {
        weaker
    } else {
        weaker.max(Evidence::SameShape)
    })
}

/// Files whose models are byte-identical files of the collection (both shared collections
/// hold a few) take the first one's source: they are duplicates in fact.
fn one_source_per_content(
    collection: &LabelledCollection,
    files: &mut [File],
) -> Result<Vec<(String, String)>> {
    let mut first: HashMap<String, usize> = HashMap::new();
    let mut source = HashMap::new();
    let mut identical = Vec::new();
    for f in files.iter().filter(|f| f.disguise.is_none()) {
        let model = &collection.models[f.source];
        let hash = sha256_hex(&salient_core::collection::read(&model.path)?);
        let kept = *first.entry(hash).or_insert(f.source);
        if kept != f.source {
            identical.push((collection.models[kept].id.clone(), model.id.clone()));
        }
        source.insert(f.source, kept);
    }
    for f in files.iter_mut() {
        f.source = source[&f.source];
        f.design = f.source;
    }
    Ok(identical)
}

/// Models of the shared collections that are one design tessellated twice, not byte-identical
/// — with other vertex counts, one turned against the other — found by this benchmark and
/// confirmed by looking at both (`salient render`; not committed, SHREC'07 is academic-only).
/// The collection's labels take them for two shapes; they are a `same_shape` copy in fact.
const SAME_DESIGN: [(&str, &str); 2] = [
    ("glasses/41.off", "glasses/57.off"),
    ("glasses/50.off", "glasses/54.off"),
];

/// Files of models of one design ([`SAME_DESIGN`]) take the first one's design; the pairs
/// among the chosen models.
fn one_design(collection: &LabelledCollection, files: &mut [File]) -> Vec<(String, String)> {
    let source_of = |id: &str| {
        files
            .iter()
            .find(|f| f.disguise.is_none() && collection.models[f.source].id == id)
            .map(|f| f.source)
    };
    let pairs: Vec<(usize, usize)> = SAME_DESIGN
        .iter()
        .filter_map(|&(a, b)| Some((source_of(a)?, source_of(b)?)))
        .collect();
    for f in files.iter_mut() {
        if let Some(&(first, _)) = pairs.iter().find(|p| p.1 == f.source) {
            f.design = first;
        }
    }
    pairs
        .iter()
        .map(|&(a, b)| {
            (
                collection.models[a].id.clone(),
                collection.models[b].id.clone(),
            )
        })
        .collect()
}

fn chosen_count(files: &[File]) -> usize {
    files.iter().filter(|f| f.disguise.is_none()).count()
}

/// Precision and recall of the pairs of `members` grouped at `min` or stronger by the links
/// among them: right when one asset ([`expected`] at all), recalled when expected at `min`
/// or stronger.
fn level(files: &[File], members: &[usize], links: &[Link<usize>], min: Evidence) -> Level {
    let member: std::collections::HashSet<usize> = members.iter().copied().collect();
    let among: Vec<Link<usize>> = links
        .iter()
        .filter(|l| member.contains(&l.a) && member.contains(&l.b))
        .cloned()
        .collect();
    let is_true = |a: usize, b: usize| expected(files, a, b).is_some_and(|e| e <= min);
    // A pair found is right when it is one asset, whatever evidence it was expected with;
    // recall counts the pairs expected at `min`.
    let (mut found, mut correct, mut recalled) = (0, 0, 0);
    for g in groups(&among, min) {
        for (k, &a) in g.ids.iter().enumerate() {
            for &b in &g.ids[k + 1..] {
                found += 1;
                correct += usize::from(expected(files, a, b).is_some());
                recalled += usize::from(is_true(a, b));
            }
        }
    }
    let mut true_pairs = 0;
    for (k, &a) in members.iter().enumerate() {
        for &b in &members[k + 1..] {
            true_pairs += usize::from(is_true(a, b));
        }
    }
    let ratio = |x: usize, y: usize| if y == 0 { 1.0 } else { x as f64 / y as f64 };
    Level {
        min_evidence: min,
        true_pairs,
        found_pairs: found,
        correct,
        precision: ratio(correct, found),
        recall: ratio(recalled, true_pairs),
    }
}

/// A model and one copy of each family ([`Disguise::ALL`]), each moved (rotated too when
/// not expected `identical_geometry`), written as a file in turn of the formats and read back.
fn disguised(
    source: usize,
    name: &str,
    class: &str,
    raw: &RawMesh,
    params: &Params,
    limits: &Limits,
) -> Result<Vec<File>> {
    let mut rng = ChaCha8Rng::seed_from_u64(source as u64);
    let welded = weld(raw, params.mesh.weld_tolerance)?;
    let size = {
        let (lo, hi) = salient_core::mesh::weld::bounds(&welded.positions);
        lo.distance(hi)
    };
    let fraction = rng.gen_range(0.4..0.6);
    let mut files = vec![File {
        name: name.to_string(),
        source,
        design: source,
        class: class.to_string(),
        disguise: None,
        area_kept: 1.0,
        raw: raw.clone(),
    }];
    let area = disguise::area(&welded.positions, &welded.triangles);
    for (k, disguise) in Disguise::ALL.into_iter().enumerate() {
        let (positions, triangles) = disguise.make(&welded, fraction);
        let scale = if rng.gen_bool(0.5) { 25.4 } else { 0.1 };
        let rotation = if disguise.expected() == Some(Evidence::IdenticalGeometry) {
            glam::DQuat::IDENTITY
        } else {
            random_rotation(&mut rng)
        };
        let shift = DVec3::new(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        ) * size;
        let copy = RawMesh {
            positions: positions
                .iter()
                .map(|&p| rotation * (p * scale) + shift * scale)
                .collect(),
            triangles,
        };
        let export = Export::ALL[(source + k) % Export::ALL.len()];
        files.push(File {
            name: format!(
                "{name}#{}.{}",
                disguise.name(),
                export.name().replace(' ', "-")
            ),
            source,
            design: source,
            class: class.to_string(),
            disguise: Some(disguise),
            area_kept: disguise::area(&positions, &copy.triangles) / area,
            raw: load_bytes(&export.write(&copy), export.format(), &NoResources, limits)?,
        });
    }
    Ok(files)
}

impl DuplicatesReport {
    pub fn markdown(&self) -> String {
        let mut families = Table::new([
            "family",
            "expected",
            "copies",
            "`identical_geometry` P / R",
            "`same_shape` P / R",
            "pairs found / true (`same_shape`)",
        ]);
        for f in &self.families {
            let at = |min: Evidence| {
                f.levels
                    .iter()
                    .find(|l| l.min_evidence == min)
                    .expect("every level is measured")
            };
            let (geometry, shape) = (at(Evidence::IdenticalGeometry), at(Evidence::SameShape));
            families.row([
                f.disguise.name().to_string(),
                f.expected.map_or("none", Evidence::as_str).to_string(),
                f.copies.to_string(),
                format!("{} / {}", score(geometry.precision), score(geometry.recall)),
                format!("{} / {}", score(shape.precision), score(shape.recall)),
                format!("{} / {}", shape.found_pairs, shape.true_pairs),
            ]);
        }
        let mut copies = Table::new([
            "family",
            "vertices kept median",
            "area kept median / min",
            "damaged (area < 3/4): found / all",
            "candidates",
            "evidence found",
            "D2 median / max",
            "aligned p99, RMS radii: median / p95 / max",
            "aligned p99, triangle sizes: median / p95 / max",
            "vertices p90, edges: median / p95 / max",
            "verdict depends on the order",
        ]);
        let three = |d: &Distribution| format!("{:.4} / {:.4} / {:.4}", d.median, d.p95, d.max);
        for f in &self.families {
            copies.row([
                f.disguise.name().to_string(),
                format!("{:.2}", f.vertices_kept.median),
                format!("{:.2} / {:.2}", f.area_kept.median, f.area_kept.min),
                format!(
                    "{} / {}",
                    f.damaged.iter().filter(|d| d.found != "none").count(),
                    f.damaged.len()
                ),
                f.candidates.to_string(),
                f.evidence
                    .iter()
                    .map(|(k, v)| format!("{k} {v}"))
                    .collect::<Vec<_>>()
                    .join(", "),
                format!("{:.4} / {:.4}", f.d2.median, f.d2.max),
                three(&f.aligned),
                three(&f.aligned_local),
                three(&f.vertices),
                if f.one_way.is_empty() {
                    "none".to_string()
                } else {
                    f.one_way.join(", ")
                },
            ]);
        }
        let mut wrong = Table::new(["a", "b", "same class", "evidence", "score"]);
        for f in &self.false_links {
            wrong.row([
                f.a.clone(),
                f.b.clone(),
                f.same_class.to_string(),
                f.evidence.to_string(),
                format!("{:.3}", f.score),
            ]);
        }
        let mut filters = Table::new([
            "descriptor",
            "largest between copies",
            "other pairs within it",
            "of",
        ]);
        for f in &self.filters {
            filters.row([
                f.method.clone(),
                format!("{:.4}", f.copies_max),
                f.others_within.to_string(),
                f.others.to_string(),
            ]);
        }
        let n = &self.negatives_local_p99;
        let listed = |pairs: &[(String, String)], sign: &str| {
            if pairs.is_empty() {
                "none".to_string()
            } else {
                pairs
                    .iter()
                    .map(|(a, b)| format!("{a} {sign} {b}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        };
        format!(
            "# Near-duplicates: {} ({} half)\n\n{} models, each with one copy of each family \
             ({} copies), every family measured with only its copies mixed in. Thresholds \
             (`similarity.duplicates`): `{}`. {} candidate pairs verified. Byte-identical \
             models of the collection count as one model: {}; models of one design \
             (`SAME_DESIGN`), as a `same_shape` pair: {}.\n\n## Pairs found, per family\n\n{}\n\
             ## Each copy against its model\n\nVerified copy first, and model first for \
             the last column (a verdict is cached by the unordered pair, so it must not depend \
             on the order).\n\n{}\n## Candidate filters\n\n{}\n\
             ## Hard negatives\n\nCandidate pairs of different models, 99th percentile of the \
             aligned distances in triangle sizes: {} pairs, smallest {:.4}, median {:.4}.\n\n\
             False links:\n\n{}\nSeconds: copies {:.1}, signatures and shapes {:.1}, search {:.1}.\n",
            self.collection,
            self.half,
            self.models,
            self.copies,
            serde_json::to_string(&self.params).expect("parameters serialise"),
            self.verified,
            listed(&self.identical_in_collection, "="),
            listed(&self.same_design_in_collection, "~"),
            families.markdown(),
            copies.markdown(),
            filters.markdown(),
            n.count,
            n.min,
            n.median,
            if self.false_links.is_empty() {
                "none.\n".to_string()
            } else {
                wrong.markdown()
            },
            self.seconds.copies,
            self.seconds.describe,
            self.seconds.search,
        )
    }

    /// Writes `duplicates.json` and `duplicates.md` into `dir`.
    pub fn write(&self, dir: &Path) -> Result<()> {
        write_json(&dir.join("duplicates.json"), self)?;
        write(&dir.join("duplicates.md"), self.markdown())
    }
}

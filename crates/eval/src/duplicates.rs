//! `salient eval duplicates`: how well the library-wide near-duplicate search
//! ([`salient_core::duplicate`]) finds disguised copies, and how rarely it takes another model of
//! the same class for one (`docs/results/duplicates/`). Every model of a collection (or of one of its halves,
//! [`super::study::halves`]) gets two copies, mixed into it:
//! - **re-exported**: another file format (float32 for STL and GLB), scaled by 25.4 or 0.1 and
//!   moved — expected `identical_geometry`;
//! - **remeshed**: simplified to 40–60 % of its welded vertices, rotated at random, scaled and
//!   moved, in another format — expected `same_shape`.
//!
//! Copies are written as files and read back, as an upload would be. The search then runs as
//! the service runs it: candidate pairs from the D2 histograms, each verified on the meshes,
//! groups from the verified links. A pair of files counts as found at an evidence level when
//! both are in one group at that level; the true pairs are the files of one source model.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::time::Instant;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use super::report::{score, write, write_json, Table};
use super::robustness::random_rotation;
use super::study::Half;
use super::{LabelledCollection, Progress};
use salient_core::duplicate::{groups, judge, Deviation, Evidence, Link, Shape, Verdict};
use salient_core::mesh::load::NoResources;
use salient_core::mesh::simplify::simplify;
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

/// How a copy was disguised.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Disguise {
    Reexported,
    Remeshed,
}

impl Disguise {
    /// The evidence a copy so disguised should be found with.
    fn expected(self) -> Evidence {
        match self {
            Disguise::Reexported => Evidence::IdenticalGeometry,
            Disguise::Remeshed => Evidence::SameShape,
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
    raw: RawMesh,
}

/// What the search found, overall and per evidence level.
#[derive(Debug, Clone, Serialize)]
pub struct DuplicatesReport {
    pub collection: String,
    pub half: String,
    pub models: usize,
    pub copies: usize,
    pub params: DuplicateParams,
    /// Candidate pairs verified on the meshes.
    pub verified: usize,
    /// Models of the collection whose files are byte-identical: one model for the measures.
    pub identical_in_collection: Vec<(String, String)>,
    /// Models of the collection that are one design tessellated twice ([`SAME_DESIGN`]):
    /// a `same_shape` pair for the measures.
    pub same_design_in_collection: Vec<(String, String)>,
    pub levels: Vec<Level>,
    pub disguises: Vec<DisguiseResult>,
    /// Verified links between files of different models (false positives), and their
    /// classes.
    pub false_links: Vec<FalseLink>,
    /// Candidate pairs of different models and their aligned deviation (RMS radii): how far
    /// the hardest negatives stay from the `same_shape` threshold.
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
    /// The largest distance between files of one model.
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

/// Each copy against its own model, verified directly (whether or not it was a candidate).
#[derive(Debug, Clone, Serialize)]
pub struct DisguiseResult {
    pub disguise: Disguise,
    pub copies: usize,
    /// Copies that passed the candidate filter with their model.
    pub candidates: usize,
    /// Evidence found between copy and model, by name (`none` when not a duplicate).
    pub evidence: BTreeMap<String, usize>,
    /// D2 distances and aligned distances between copy and model.
    pub d2: Distribution,
    /// The 99th percentile of the aligned distances ([`Deviation`]).
    pub aligned: Distribution,
    /// The 90th percentile of the coarser file's vertices' distances ([`Deviation`]).
    pub vertices: Distribution,
    /// Every copy, farthest from its model first.
    pub worst: Vec<Aligned>,
}

/// Two files, their aligned deviation and the coarser one's triangle size (RMS radii).
#[derive(Debug, Clone, Serialize)]
pub struct Aligned {
    pub a: String,
    pub b: String,
    pub deviation: Deviation,
    pub spacing: f64,
}

/// A pair verified as the service verifies it, with what the verdict was judged on.
struct Measured {
    verdict: Option<Verdict>,
    deviation: Deviation,
    spacing: f64,
}

fn measure(x: &Shape, y: &Shape, p: &DuplicateParams) -> Measured {
    // Every pair's vertices measured, for choosing thresholds.
    let spacing = x.coarser(y);
    let alignment = x.align(y, p.surface_limits(spacing).1, |_| true);
    Measured {
        verdict: judge(
            x.geometry_deviation(y, p.geometry),
            |_, _| alignment,
            spacing,
            p,
        ),
        deviation: alignment.rotated,
        spacing,
    }
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
    let pairs = index
        .near_pairs(p.d2, p.lfd)
        .map_err(|e| salient_core::Error::Io {
            path: std::env::temp_dir(),
            source: e,
        })?;
    progress.start("verify", pairs.len());
    let measured: Vec<(usize, usize, Measured)> = pairs
        .par_iter()
        .map(|(a, b)| {
            let (i, j) = (number[&**a], number[&**b]);
            let (x, y) = (&described[i].1, &described[j].1);
            progress.advance(a);
            (i, j, measure(x, y, p))
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
    let same_design = |a: usize, b: usize| files[a].design == files[b].design;
    let levels = [
        Evidence::IdenticalGeometry,
        Evidence::SameShape,
        Evidence::Mirrored,
    ]
    .into_iter()
    .map(|min| level(&files, &links, min))
    .collect();
    let false_links = links
        .iter()
        .filter(|l| !same_design(l.a, l.b))
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
                    (a + 1..files.len()).map(move |b| {
                        let d =
                            distance(method, &described[a].0, &described[b].0, &params.similarity);
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
    let negatives: Vec<Aligned> = measured
        .iter()
        .filter(|m| !same_design(m.0, m.1))
        .map(|(a, b, m)| Aligned {
            a: files[*a].name.clone(),
            b: files[*b].name.clone(),
            deviation: m.deviation,
            spacing: m.spacing,
        })
        .collect();
    let candidate: std::collections::HashSet<(usize, usize)> = pairs
        .iter()
        .map(|(a, b)| (number[&**a], number[&**b]))
        .collect();
    let original: HashMap<usize, usize> = files
        .iter()
        .enumerate()
        .rev()
        .filter(|(_, f)| f.disguise.is_none())
        .map(|(i, f)| (f.source, i))
        .collect();
    let disguises = [Disguise::Reexported, Disguise::Remeshed]
        .into_iter()
        .map(|disguise| {
            let checked: Vec<(Measured, f64, &str, bool)> = files
                .par_iter()
                .enumerate()
                .filter(|(_, f)| f.disguise == Some(disguise))
                .map(|(c, f)| {
                    // The source's first model (byte-identical models share a source).
                    let o = original[&f.source];
                    let pair = if files[o].name < f.name {
                        (o, c)
                    } else {
                        (c, o)
                    };
                    let d2 = salient_core::descriptor::histogram_l1(
                        &described[o].0.d2,
                        &described[c].0.d2,
                    );
                    (
                        measure(&described[c].1, &described[o].1, p),
                        d2,
                        f.name.as_str(),
                        candidate.contains(&pair),
                    )
                })
                .collect();
            let mut evidence = BTreeMap::new();
            for (measured, ..) in &checked {
                let name = measured.verdict.map_or("none", |v| v.evidence.as_str());
                *evidence.entry(name.to_string()).or_insert(0) += 1;
            }
            DisguiseResult {
                disguise,
                copies: checked.len(),
                candidates: checked.iter().filter(|c| c.3).count(),
                evidence,
                d2: Distribution::of(checked.iter().map(|c| c.1).collect()),
                aligned: Distribution::of(
                    checked.iter().map(|c| c.0.deviation.surfaces.p99).collect(),
                ),
                vertices: Distribution::of(
                    checked.iter().map(|c| c.0.deviation.vertices.p90).collect(),
                ),
                worst: {
                    let mut worst: Vec<Aligned> = checked
                        .iter()
                        .map(|c| Aligned {
                            a: c.2.to_string(),
                            b: String::new(),
                            deviation: c.0.deviation,
                            spacing: c.0.spacing,
                        })
                        .collect();
                    worst.sort_by(|x, y| {
                        y.deviation
                            .surfaces
                            .p99
                            .total_cmp(&x.deviation.surfaces.p99)
                    });
                    worst
                },
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
        levels,
        disguises,
        false_links,
        negatives,
        filters,
        seconds: Seconds {
            copies: copies_seconds,
            describe: describe_seconds,
            search: search_seconds,
        },
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

/// Precision and recall of the pairs grouped at `min` or stronger. The true pairs at
/// `identical_geometry` are each model with its re-exported copy; below it, every two files
/// of one model, and of one design.
fn level(files: &[File], links: &[Link<usize>], min: Evidence) -> Level {
    let expected = |f: &File| {
        f.disguise
            .map_or(Evidence::IdenticalFile, Disguise::expected)
    };
    let is_true = |a: usize, b: usize| {
        let expected = if files[a].source == files[b].source {
            expected(&files[a]).max(expected(&files[b]))
        } else if files[a].design == files[b].design {
            Evidence::SameShape
        } else {
            return false;
        };
        expected <= min
    };
    let mut found = 0;
    let mut correct = 0;
    for g in groups(links, min) {
        for (k, &a) in g.ids.iter().enumerate() {
            for &b in &g.ids[k + 1..] {
                found += 1;
                correct += usize::from(is_true(a, b));
            }
        }
    }
    let mut true_pairs = 0;
    for a in 0..files.len() {
        for b in a + 1..files.len() {
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
        recall: ratio(correct, true_pairs),
    }
}

/// A model and its two disguised copies, each written as a file and read back.
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
    let exports = Export::ALL;
    let (first, second) = (exports[source % 4], exports[(source + 1) % 4]);
    let size = {
        let (lo, hi) = salient_core::mesh::weld::bounds(&welded.positions);
        lo.distance(hi)
    };
    let moved = |positions: &[DVec3], rotate: bool, rng: &mut ChaCha8Rng| {
        let scale = if rng.gen_bool(0.5) { 25.4 } else { 0.1 };
        let rotation = if rotate {
            random_rotation(rng)
        } else {
            glam::DQuat::IDENTITY
        };
        let shift = DVec3::new(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        ) * size;
        positions
            .iter()
            .map(|&p| rotation * (p * scale) + shift * scale)
            .collect::<Vec<_>>()
    };
    let reexported = RawMesh {
        positions: moved(&welded.positions, false, &mut rng),
        triangles: welded.triangles.clone(),
    };
    let fraction = rng.gen_range(0.4..0.6);
    let target = ((welded.positions.len() as f64 * fraction) as usize).max(4);
    let (positions, triangles) = simplify(&welded.positions, &welded.triangles, target)
        .unwrap_or_else(|| (welded.positions.clone(), welded.triangles.clone()));
    let remeshed = RawMesh {
        positions: moved(&positions, true, &mut rng),
        triangles,
    };
    let read_back = |mesh: &RawMesh, export: Export| {
        load_bytes(&export.write(mesh), export.format(), &NoResources, limits)
    };
    let file = |suffix: String, disguise, raw| File {
        name: format!("{name}{suffix}"),
        source,
        design: source,
        class: class.to_string(),
        disguise,
        raw,
    };
    Ok(vec![
        file(String::new(), None, raw.clone()),
        file(
            format!("#reexported.{}", first.name().replace(' ', "-")),
            Some(Disguise::Reexported),
            read_back(&reexported, first)?,
        ),
        file(
            format!("#remeshed.{}", second.name().replace(' ', "-")),
            Some(Disguise::Remeshed),
            read_back(&remeshed, second)?,
        ),
    ])
}

impl DuplicatesReport {
    pub fn markdown(&self) -> String {
        let mut levels = Table::new([
            "min evidence",
            "true pairs",
            "found",
            "correct",
            "precision",
            "recall",
        ]);
        for l in &self.levels {
            levels.row([
                l.min_evidence.to_string(),
                l.true_pairs.to_string(),
                l.found_pairs.to_string(),
                l.correct.to_string(),
                score(l.precision),
                score(l.recall),
            ]);
        }
        let mut disguises = Table::new([
            "copy",
            "copies",
            "candidates",
            "evidence found",
            "D2 median / max",
            "aligned median / p95 / max",
            "vertices median / p95 / max",
        ]);
        for d in &self.disguises {
            disguises.row([
                format!("{:?}", d.disguise).to_lowercase(),
                d.copies.to_string(),
                d.candidates.to_string(),
                d.evidence
                    .iter()
                    .map(|(k, v)| format!("{k} {v}"))
                    .collect::<Vec<_>>()
                    .join(", "),
                format!("{:.4} / {:.4}", d.d2.median, d.d2.max),
                format!(
                    "{:.4} / {:.4} / {:.4}",
                    d.aligned.median, d.aligned.p95, d.aligned.max
                ),
                format!(
                    "{:.4} / {:.4} / {:.4}",
                    d.vertices.median, d.vertices.p95, d.vertices.max
                ),
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
        let mut nearest: Vec<&Aligned> = self.negatives.iter().collect();
        nearest.sort_by(|x, y| {
            x.deviation
                .surfaces
                .p99
                .total_cmp(&y.deviation.surfaces.p99)
        });
        let n = Distribution::of(
            self.negatives
                .iter()
                .map(|a| a.deviation.surfaces.p99)
                .collect(),
        );
        format!(
            "# Near-duplicates: {} ({} half)\n\n{} models, each with a re-exported and a remeshed copy \
             ({} copies). Thresholds (`similarity.duplicates`): `{}`. {} candidate pairs verified. \
             Byte-identical models of the collection count as one model: {}; models of one design (`SAME_DESIGN`), as a `same_shape` pair: {}.\n\n## Pairs found\n\n{}\n## Each copy against its model\n\n{}\n\
             ## Candidate filters\n\n{}\n## Hard negatives\n\nCandidate pairs of different models, 99th percentile of the aligned distances (RMS radii): \
             {} pairs, smallest {:.4}, median {:.4}.\n\nFalse links:\n\n{}\n\
             Seconds: copies {:.1}, signatures and shapes {:.1}, search {:.1}.\n",
            self.collection,
            self.half,
            self.models,
            self.copies,
            serde_json::to_string(&self.params).expect("parameters serialise"),
            self.verified,
            if self.identical_in_collection.is_empty() {
                "none".to_string()
            } else {
                self.identical_in_collection.iter().map(|(a, b)| format!("{a} = {b}")).collect::<Vec<_>>().join(", ")
            },
            if self.same_design_in_collection.is_empty() {
                "none".to_string()
            } else {
                self.same_design_in_collection.iter().map(|(a, b)| format!("{a} ~ {b}")).collect::<Vec<_>>().join(", ")
            },
            levels.markdown(),
            disguises.markdown(),
            filters.markdown(),
            n.count,
            n.min,
            n.median,
            if self.false_links.is_empty() { "none.\n".to_string() } else { wrong.markdown() },
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

//! Leave-one-out retrieval over a labelled collection (SPEC §7, paper §6.2): every model
//! queries all the others, each method's full distance matrix is computed once (in
//! parallel), and each query's ranked list is scored with [`Scores`].

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;
use std::str::FromStr;
use std::time::Instant;

use rayon::prelude::*;
use serde::{Serialize, Serializer};

use super::metrics::{Scores, RECALL_LEVELS};
use super::report::{precision_recall_plot, score, write, write_json, Table};
use super::robustness::Perturbation;
use super::{LabelledCollection, Progress};
use salient_core::collection::{read, SignatureCache, Source};
use salient_core::mesh::load_path;
use salient_core::params::{Limits, Params, SimilarityParams};
use salient_core::pipeline::compute;
use salient_core::rank::{distance, Method};
use salient_core::signature::Signature;
use salient_core::Result;

/// A retrieval method as the evaluation names it: the parameters its signatures are
/// extracted with and the distance that ranks them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum EvalMethod {
    /// The service's default: the weighted sum of the ECC, D2 and LFD distances (SPEC §9).
    Hybrid,
    /// Salient features under the penalised EMD, with the given (default) parameters.
    Ecc,
    /// The global D2 baseline (SPEC §6), from the same signatures.
    D2,
    /// Salient features with [`Params::paper`]: the paper read literally.
    EccPaper,
    /// The Light Field Descriptor baseline (SPEC §6), from the same signatures.
    Lfd,
    /// The geodesic distance distributions, from the same signatures.
    Geodesic,
}

impl EvalMethod {
    pub const ALL: [EvalMethod; 6] = [
        EvalMethod::Hybrid,
        EvalMethod::Ecc,
        EvalMethod::D2,
        EvalMethod::EccPaper,
        EvalMethod::Lfd,
        EvalMethod::Geodesic,
    ];

    pub fn name(self) -> &'static str {
        match self {
            EvalMethod::Hybrid => "hybrid",
            EvalMethod::Ecc => "ecc",
            EvalMethod::D2 => "d2",
            EvalMethod::EccPaper => "ecc-paper",
            EvalMethod::Lfd => "lfd",
            EvalMethod::Geodesic => "geodesic",
        }
    }

    /// The extraction parameters: `base` (the user's, by default SPEC's), or the paper's.
    pub fn params(self, base: &Params) -> Params {
        match self {
            EvalMethod::EccPaper => Params::paper(),
            _ => base.clone(),
        }
    }

    /// The distance that ranks.
    pub fn rank(self) -> Method {
        match self {
            EvalMethod::Hybrid => Method::Hybrid,
            EvalMethod::Ecc | EvalMethod::EccPaper => Method::Ecc,
            EvalMethod::D2 => Method::D2,
            EvalMethod::Lfd => Method::Lfd,
            EvalMethod::Geodesic => Method::Geodesic,
        }
    }
}

impl fmt::Display for EvalMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for EvalMethod {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|m| m.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| {
                format!(
                    "unknown method `{s}` (expected hybrid, ecc, d2, ecc-paper, lfd or geodesic)"
                )
            })
    }
}

/// Distances between all models of a collection under one method, rows and columns in the
/// order of `ids`.
#[derive(Debug, Clone, PartialEq)]
pub struct DistanceMatrix {
    pub ids: Vec<String>,
    values: Vec<f64>,
}

impl DistanceMatrix {
    /// A matrix from its row-major values (`ids.len()²` of them).
    pub fn new(ids: Vec<String>, values: Vec<f64>) -> Self {
        assert_eq!(values.len(), ids.len() * ids.len(), "a square matrix");
        Self { ids, values }
    }

    /// All pairwise distances, each unordered pair once: both distances are symmetric (the
    /// EMD between equal total masses, the `max/min` penalty and the L1 distance all are).
    /// Rows run in parallel; `on_row` is called after each.
    pub fn compute(
        ids: Vec<String>,
        signatures: &[Signature],
        method: Method,
        params: &SimilarityParams,
        on_row: impl Fn() + Sync,
    ) -> Self {
        let n = signatures.len();
        assert_eq!(ids.len(), n, "one id per signature");
        let rows: Vec<Vec<f64>> = (0..n)
            .into_par_iter()
            .map(|i| {
                let row = (i + 1..n)
                    .map(|j| distance(method, &signatures[i], &signatures[j], params))
                    .collect();
                on_row();
                row
            })
            .collect();
        let mut values = vec![0.0; n * n];
        for (i, row) in rows.into_iter().enumerate() {
            for (j, d) in (i + 1..n).zip(row) {
                values[i * n + j] = d;
                values[j * n + i] = d;
            }
        }
        Self::new(ids, values)
    }

    pub fn len(&self) -> usize {
        self.ids.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    pub fn get(&self, i: usize, j: usize) -> f64 {
        self.values[i * self.len() + j]
    }

    /// `query`'s ranked list among `members` (itself left out): nearest first, ties broken
    /// by id as in [`salient_core::rank`].
    pub fn ranking(&self, query: usize, members: &[usize]) -> Vec<usize> {
        let mut others: Vec<usize> = members.iter().copied().filter(|&j| j != query).collect();
        others.sort_by(|&a, &b| {
            self.get(query, a)
                .total_cmp(&self.get(query, b))
                .then_with(|| self.ids[a].cmp(&self.ids[b]))
        });
        others
    }

    /// CSV with a header row of ids and one row per model, led by its id.
    pub fn to_csv(&self) -> String {
        let mut csv = String::from("id");
        for id in &self.ids {
            csv += &format!(",{id}");
        }
        csv.push('\n');
        for (i, id) in self.ids.iter().enumerate() {
            csv += id;
            for j in 0..self.len() {
                csv += &format!(",{:.7}", self.get(i, j));
            }
            csv.push('\n');
        }
        csv
    }
}

/// Scores of a method over a set of queries, overall and per class.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Evaluation {
    #[serde(flatten)]
    pub scores: Scores,
    pub per_class: BTreeMap<String, Scores>,
    /// Queries scored.
    pub queries: usize,
    /// Queries left out because their class has no other model.
    pub skipped_queries: usize,
    /// Each scored query's scores, in member order: two methods evaluated on the same members
    /// can be compared query by query.
    #[serde(skip)]
    pub per_query: Vec<Scores>,
}

/// Leave-one-out over `members` (indices into `matrix`, whose models have classes
/// `classes`): each member queries the other members.
pub fn evaluate(matrix: &DistanceMatrix, classes: &[&str], members: &[usize]) -> Evaluation {
    let mut per_query = Vec::new();
    let mut by_class: BTreeMap<&str, Vec<Scores>> = BTreeMap::new();
    for &q in members {
        let class = classes[q];
        let relevance: Vec<bool> = matrix
            .ranking(q, members)
            .into_iter()
            .map(|j| classes[j] == class)
            .collect();
        let relevant = relevance.iter().filter(|&&r| r).count();
        if let Some(scores) = Scores::of_query(&relevance, relevant) {
            by_class.entry(class).or_default().push(scores);
            per_query.push(scores);
        }
    }
    Evaluation {
        scores: Scores::mean(&per_query).unwrap_or_default(),
        per_class: by_class
            .iter()
            .filter_map(|(class, scores)| Some((class.to_string(), Scores::mean(scores)?)))
            .collect(),
        queries: per_query.len(),
        skipped_queries: members.len() - per_query.len(),
        per_query,
    }
}

/// How a collection's signatures were obtained.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ExtractionSummary {
    pub extracted: usize,
    pub cached: usize,
    /// Extraction time of all models as each signature recorded it (SPEC §4), whether it was
    /// extracted in this run or earlier: the cost of indexing the collection from scratch.
    pub extraction_seconds: f64,
    /// The slowest model's extraction, and its vertex count after preparation.
    pub slowest_seconds: f64,
    pub slowest_vertices: usize,
    /// Wall-clock time of this run's pass (cache reads and any extraction).
    pub wall_seconds: f64,
}

/// The signature of every model, in collection order, from `cache` or extracted with
/// `params`; of a perturbed copy of each model with `perturbation` (`cache` must then be one
/// for that perturbation alone: it is keyed by the original file).
pub fn signatures(
    collection: &LabelledCollection,
    cache: &SignatureCache,
    params: &Params,
    limits: &Limits,
    perturbation: Option<&Perturbation>,
    progress: &dyn Progress,
) -> Result<(Vec<Signature>, ExtractionSummary)> {
    let clock = Instant::now();
    let mut summary = ExtractionSummary::default();
    progress.start("signatures", collection.models.len());
    let mut signatures = Vec::with_capacity(collection.models.len());
    for model in &collection.models {
        let (signature, source) = match perturbation {
            None => cache.signature(&model.path, params, limits)?,
            Some(change) => {
                let bytes = read(&model.path)?;
                match cache.get(&bytes) {
                    Some(signature) => (signature, Source::Cached),
                    None => {
                        let raw = load_path(&model.path, limits)?;
                        let copy = change.apply(&raw, params, &model.id)?;
                        let signature = cache.put(&bytes, &compute(&copy, params)?)?;
                        (signature, Source::Extracted)
                    }
                }
            }
        };
        match source {
            Source::Cached => summary.cached += 1,
            Source::Extracted => summary.extracted += 1,
        }
        let stats = &signature.stats.extraction;
        summary.extraction_seconds += stats.total_seconds;
        if stats.total_seconds > summary.slowest_seconds {
            summary.slowest_seconds = stats.total_seconds;
            summary.slowest_vertices = stats.mesh.vertices;
        }
        signatures.push(signature);
        progress.advance(&model.id);
    }
    progress.finish();
    summary.wall_seconds = clock.elapsed().as_secs_f64();
    Ok((signatures, summary))
}

/// How many salient features a class's models have. The penalty of Eq. 13 multiplies the EMD
/// by the ratio of two models' counts, so a class whose counts spread widely looks unlike
/// itself.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FeatureCounts {
    pub mean: f64,
    pub sd: f64,
    pub min: usize,
    pub max: usize,
}

impl FeatureCounts {
    fn of(counts: &[usize]) -> Self {
        let n = counts.len().max(1) as f64;
        let mean = counts.iter().sum::<usize>() as f64 / n;
        let variance = counts
            .iter()
            .map(|&c| (c as f64 - mean).powi(2))
            .sum::<f64>()
            / n;
        Self {
            mean,
            sd: variance.sqrt(),
            min: counts.iter().copied().min().unwrap_or(0),
            max: counts.iter().copied().max().unwrap_or(0),
        }
    }
}

/// Feature counts per class, for methods that rank by salient features.
fn feature_counts(
    collection: &LabelledCollection,
    signatures: &[Signature],
) -> BTreeMap<String, FeatureCounts> {
    let mut counts: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for (model, signature) in collection.models.iter().zip(signatures) {
        counts
            .entry(model.class.clone())
            .or_default()
            .push(signature.features.len());
    }
    counts
        .into_iter()
        .map(|(class, c)| (class, FeatureCounts::of(&c)))
        .collect()
}

/// One method's results on a collection.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodResult {
    #[serde(skip)]
    pub method: EvalMethod,
    #[serde(flatten)]
    pub evaluation: Evaluation,
    /// Salient features per model, per class (methods that rank by them).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub features_per_class: BTreeMap<String, FeatureCounts>,
    pub params: Params,
    pub extraction: ExtractionSummary,
    /// Wall-clock seconds to fill the distance matrix.
    pub matrix_seconds: f64,
}

/// Everything `salient eval retrieval` reports.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RetrievalReport {
    pub collection: String,
    pub models: usize,
    pub classes: usize,
    pub class_sizes: BTreeMap<String, usize>,
    /// The change every model went through first (`--perturb`), if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub perturbation: Option<String>,
    /// Keyed by method name, in the order they were asked for.
    #[serde(serialize_with = "by_name")]
    pub methods: Vec<MethodResult>,
}

fn by_name<S: Serializer>(methods: &[MethodResult], serializer: S) -> Result<S::Ok, S::Error> {
    serializer.collect_map(methods.iter().map(|m| (m.method.name(), m)))
}

/// Evaluates `methods` on `collection` (or on its copy changed by `perturbation`):
/// signatures from the cache `cache_for` gives for each parameter set (methods that share
/// parameters share signatures), then each method's distance matrix and scores. Returns the
/// report and the matrices, in method order.
pub fn run(
    collection: &LabelledCollection,
    methods: &[EvalMethod],
    base: &Params,
    cache_for: impl Fn(&Params) -> SignatureCache,
    limits: &Limits,
    perturbation: Option<&Perturbation>,
    progress: &dyn Progress,
) -> Result<(RetrievalReport, Vec<DistanceMatrix>)> {
    let ids: Vec<String> = collection.models.iter().map(|m| m.id.clone()).collect();
    let classes = collection.classes();
    let everyone: Vec<usize> = (0..ids.len()).collect();
    let mut extracted: Vec<(Params, Vec<Signature>, ExtractionSummary)> = Vec::new();
    let mut results = Vec::new();
    let mut matrices = Vec::new();
    for &method in methods {
        let params = method.params(base);
        let index = match extracted.iter().position(|(p, _, _)| *p == params) {
            Some(index) => index,
            None => {
                let cache = cache_for(&params);
                let (signatures, summary) =
                    signatures(collection, &cache, &params, limits, perturbation, progress)?;
                extracted.push((params.clone(), signatures, summary));
                extracted.len() - 1
            }
        };
        let (_, signatures, summary) = &extracted[index];
        let clock = Instant::now();
        progress.start(method.name(), ids.len());
        let matrix = DistanceMatrix::compute(
            ids.clone(),
            signatures,
            method.rank(),
            &params.similarity,
            || progress.advance(""),
        );
        progress.finish();
        let matrix_seconds = clock.elapsed().as_secs_f64();
        let features_per_class = match method.rank() {
            Method::Ecc => feature_counts(collection, signatures),
            Method::Hybrid | Method::D2 | Method::Lfd | Method::Geodesic => BTreeMap::new(),
        };
        results.push(MethodResult {
            method,
            evaluation: evaluate(&matrix, &classes, &everyone),
            features_per_class,
            params,
            extraction: summary.clone(),
            matrix_seconds,
        });
        matrices.push(matrix);
    }
    let class_sizes = collection.class_sizes();
    Ok((
        RetrievalReport {
            collection: collection.root.display().to_string(),
            models: ids.len(),
            classes: class_sizes.len(),
            class_sizes,
            perturbation: perturbation.map(|p| p.name()),
            methods: results,
        },
        matrices,
    ))
}

impl RetrievalReport {
    /// The collection's folder name.
    fn name(&self) -> String {
        Path::new(&self.collection)
            .file_name()
            .map_or(self.collection.clone(), |n| {
                n.to_string_lossy().into_owned()
            })
    }

    /// Tables of the overall scores, the precision–recall points, per-class scores and
    /// costs, with the figure `pr.png` beside it.
    pub fn markdown(&self) -> String {
        let name = self.name();
        let mut text = format!(
            "# Retrieval on {name}\n\n{} models in {} classes; every model queries all the others \
             (leave-one-out, SPEC §7). Measures as in the Princeton Shape Benchmark: nearest \
             neighbour (NN), first and second tier (FT, ST), E-measure of the first 32, \
             normalised DCG, mean average precision; higher is better.\n\n",
            self.models, self.classes
        );
        if let Some(change) = &self.perturbation {
            text += &format!(
                "Every model was first changed (`--perturb`): **{change}**, Gaussian noise \
                 whose RMS length is that fraction of the bounding-box diagonal, seeded by \
                 model.\n\n"
            );
        }
        let mut overall = Table::new(["method", "NN", "FT", "ST", "E", "DCG", "mAP"]);
        for m in &self.methods {
            let measures = m.evaluation.scores.measures();
            overall.row(
                std::iter::once(m.method.name().to_string())
                    .chain(measures.iter().map(|&(_, x)| score(x))),
            );
        }
        text += &overall.markdown();
        text += "\n![precision-recall](pr.png)\n\n## Precision at recall 0, 0.1, …, 1\n\n";
        let mut pr = Table::new(
            std::iter::once("method".to_string())
                .chain((0..RECALL_LEVELS).map(|l| format!("{:.1}", l as f64 / 10.0))),
        );
        for m in &self.methods {
            pr.row(
                std::iter::once(m.method.name().to_string())
                    .chain(m.evaluation.scores.pr.iter().map(|&p| score(p))),
            );
        }
        text += &pr.markdown();
        for (measure, pick) in [
            ("mAP", (|s: &Scores| s.map) as fn(&Scores) -> f64),
            ("NN", |s: &Scores| s.nearest_neighbour),
            ("FT", |s: &Scores| s.first_tier),
        ] {
            text += &format!("\n## {measure} per class\n\n");
            let mut table = Table::new(
                ["class", "models"]
                    .into_iter()
                    .chain(self.methods.iter().map(|m| m.method.name())),
            );
            for (class, size) in &self.class_sizes {
                table.row([class.clone(), size.to_string()].into_iter().chain(
                    self.methods.iter().map(|m| {
                        m.evaluation
                            .per_class
                            .get(class)
                            .map_or("–".into(), |s| score(pick(s)))
                    }),
                ));
            }
            text += &table.markdown();
        }
        let featured: Vec<&MethodResult> = self
            .methods
            .iter()
            .filter(|m| !m.features_per_class.is_empty())
            .collect();
        if !featured.is_empty() {
            text += "\n## Salient features per model\n\nMean ± standard deviation (min–max) \
                     per class. The penalty of Eq. 13 multiplies the EMD by the ratio of two \
                     models' counts, so a class whose counts spread is hard to retrieve.\n\n";
            let mut table = Table::new(
                ["class"]
                    .into_iter()
                    .chain(featured.iter().map(|m| m.method.name())),
            );
            for class in self.class_sizes.keys() {
                table.row(
                    std::iter::once(class.clone()).chain(featured.iter().map(|m| {
                        m.features_per_class.get(class).map_or("–".into(), |c| {
                            format!("{:.1} ± {:.1} ({}–{})", c.mean, c.sd, c.min, c.max)
                        })
                    })),
                );
            }
            text += &table.markdown();
        }
        text += "\n## Cost\n\n";
        let mut cost = Table::new([
            "method",
            "extracted",
            "cached",
            "extraction s (all models)",
            "slowest model s (vertices)",
            "distance matrix s",
        ]);
        for m in &self.methods {
            let e = &m.extraction;
            cost.row([
                m.method.name().to_string(),
                e.extracted.to_string(),
                e.cached.to_string(),
                format!("{:.1}", e.extraction_seconds),
                format!("{:.2} ({})", e.slowest_seconds, e.slowest_vertices),
                format!("{:.2}", m.matrix_seconds),
            ]);
        }
        text += &cost.markdown();
        text += "\nExtraction seconds are those each signature recorded when it was made (2 \
                 worker threads here); the matrix time is this run's wall clock.\n";
        text
    }

    /// Writes `report.json`, `report.md`, `pr.png`, `pr.svg` and one
    /// `distances-METHOD.csv` per method into `dir`.
    pub fn write(&self, dir: &Path, matrices: &[DistanceMatrix]) -> Result<()> {
        write_json(&dir.join("report.json"), self)?;
        write(&dir.join("report.md"), self.markdown())?;
        let curves: Vec<(&str, [f64; RECALL_LEVELS])> = self
            .methods
            .iter()
            .map(|m| (m.method.name(), m.evaluation.scores.pr))
            .collect();
        precision_recall_plot(
            &format!("Precision–recall, {} ({} models)", self.name(), self.models),
            &curves,
            &dir.join("pr.png"),
            &dir.join("pr.svg"),
        )?;
        for (m, matrix) in self.methods.iter().zip(matrices) {
            write(
                &dir.join(format!("distances-{}.csv", m.method.name())),
                matrix.to_csv(),
            )?;
        }
        Ok(())
    }
}

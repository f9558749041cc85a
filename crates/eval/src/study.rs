//! The parameter study behind the defaults (SPEC §5: "tune `W` on the labelled set and record
//! the tuned value with its evidence"; `docs/results/study-*/`): `W`, the penalty, `K`, `flat_max`, `D_g` and
//! SPEC's three resolved rules varied one at a time around the defaults, scored by
//! leave-one-out retrieval with the ECC method.
//!
//! Against overfitting, each class's models are split in two halves (alternately, in id
//! order): a value is chosen on the tuning half and judged on the held-out half, each half
//! ranked only among itself; scores on the whole collection are reported too.
//!
//! Signatures are cached per parameter set. Settings that change only the similarity (`W`,
//! penalty) reuse the default signatures, and settings that leave the ECC unchanged (`K`)
//! reuse one extraction per model: only `flat_max` and `D_g` extract the collection again.

use std::path::Path;
use std::time::Instant;

use serde::Serialize;

use super::metrics::Scores;
use super::report::{score, write, write_json, Table};
use super::retrieval::{evaluate, DistanceMatrix};
use super::{LabelledCollection, Progress};
use salient_core::collection::{read, SignatureCache};
use salient_core::extraction::Extraction;
use salient_core::params::{CandidateRule, GeodesicRule, HeightRule, Limits, Params, RegionRule};
use salient_core::pipeline::{describe, extract_path};
use salient_core::rank::Method;
use salient_core::signature::Signature;
use salient_core::Result;

/// Held-out mAP a tuned value must gain over the default before the study recommends it,
/// at the least; the gain must also be twice its standard error.
pub const MIN_GAIN: f64 = 0.005;

/// One parameter changed from the base.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Change {
    /// `W` of the ground distance (SPEC §5).
    EccWeight(f64),
    Penalty(bool),
    /// `K` of k-means (SPEC §3.1).
    Clusters(usize),
    FlatMax(f64),
    /// `D_g` (SPEC §2).
    LocalSize(f64),
    Height(HeightRule),
    Candidates(CandidateRule),
    Regions(RegionRule),
    /// Local geodesics (SPEC §2.1, §9).
    Geodesic(GeodesicRule),
}

impl Change {
    pub fn parameter(self) -> &'static str {
        match self {
            Change::EccWeight(_) => "W",
            Change::Penalty(_) => "penalty",
            Change::Clusters(_) => "K",
            Change::FlatMax(_) => "flat_max",
            Change::LocalSize(_) => "D_g",
            Change::Height(_) => "height",
            Change::Candidates(_) => "candidates",
            Change::Regions(_) => "region_rule",
            Change::Geodesic(_) => "geodesic",
        }
    }

    pub fn value(self) -> String {
        match self {
            Change::EccWeight(x) | Change::FlatMax(x) | Change::LocalSize(x) => x.to_string(),
            Change::Penalty(on) => if on { "on" } else { "off" }.into(),
            Change::Clusters(k) => k.to_string(),
            Change::Height(rule) => format!("{rule:?}").to_lowercase(),
            Change::Candidates(rule) => format!("{rule:?}").to_lowercase(),
            Change::Regions(rule) => format!("{rule:?}").to_lowercase(),
            Change::Geodesic(GeodesicRule::Dijkstra) => "dijkstra".into(),
            Change::Geodesic(GeodesicRule::FastMarching) => "fast_marching".into(),
        }
    }

    pub fn apply(self, params: &mut Params) {
        match self {
            Change::EccWeight(w) => params.similarity.ecc_weight = w,
            Change::Penalty(on) => params.similarity.penalty = on,
            Change::Clusters(k) => params.salient.clusters = k,
            Change::FlatMax(x) => params.ecc.flat_max = x,
            Change::LocalSize(x) => params.ecc.local_size = x,
            Change::Height(rule) => params.ecc.height = rule,
            Change::Candidates(rule) => params.salient.candidates = rule,
            Change::Regions(rule) => params.salient.region_rule = rule,
            Change::Geodesic(rule) => params.ecc.geodesic = rule,
        }
    }
}

/// The alternatives tried: `W` ∈ {0, 0.25, 0.75, 1}, penalty off, `K` ∈ {3, 8}, `flat_max` ∈
/// {0.25, 1}, `D_g` ∈ {0.2, 0.3, 0.4}, and the paper's height, candidate and region rules
/// (`Params::paper`), and fast-marching geodesics, skipping any that `base` already has.
pub fn grid(base: &Params) -> Vec<Change> {
    let changes = [0.0, 0.25, 0.75, 1.0]
        .map(Change::EccWeight)
        .into_iter()
        .chain([
            Change::Penalty(false),
            Change::Clusters(3),
            Change::Clusters(8),
        ])
        .chain([0.25, 1.0].map(Change::FlatMax))
        .chain([0.2, 0.3, 0.4].map(Change::LocalSize))
        .chain([
            Change::Height(HeightRule::Paper),
            Change::Candidates(CandidateRule::Norm),
            Change::Regions(RegionRule::Area),
            Change::Geodesic(GeodesicRule::FastMarching),
        ]);
    changes.filter(|c| with(base, &[*c]) != *base).collect()
}

/// `base` with `changes` applied.
fn with(base: &Params, changes: &[Change]) -> Params {
    let mut params = base.clone();
    for c in changes {
        c.apply(&mut params);
    }
    params
}

/// Which of a collection's models take part in an evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Half {
    /// The half parameters are chosen on.
    Tuning,
    /// The half they are judged on.
    HeldOut,
    All,
}

impl Half {
    pub const ALL: [Half; 3] = [Half::Tuning, Half::HeldOut, Half::All];

    /// Its name on the command line and in reports.
    pub fn as_str(self) -> &'static str {
        match self {
            Half::Tuning => "tuning",
            Half::HeldOut => "held-out",
            Half::All => "all",
        }
    }

    /// The indices of this half's models ([`halves`]).
    pub fn models(self, collection: &LabelledCollection) -> Vec<usize> {
        let (tuning, held_out) = halves(collection);
        match self {
            Half::Tuning => tuning,
            Half::HeldOut => held_out,
            Half::All => (0..collection.models.len()).collect(),
        }
    }
}

/// Each class's models alternately into a tuning and a held-out half, in id order.
pub fn halves(collection: &LabelledCollection) -> (Vec<usize>, Vec<usize>) {
    let (mut tune, mut test) = (Vec::new(), Vec::new());
    let mut seen = std::collections::HashMap::<&str, usize>::new();
    for (i, model) in collection.models.iter().enumerate() {
        let count = seen.entry(model.class.as_str()).or_default();
        if count.is_multiple_of(2) {
            &mut tune
        } else {
            &mut test
        }
        .push(i);
        *count += 1;
    }
    (tune, test)
}

/// A setting's scores: the baseline (no change), one change, or the recommended changes
/// combined.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SettingResult {
    pub parameter: String,
    pub value: String,
    #[serde(skip)]
    pub changes: Vec<Change>,
    pub tune: Scores,
    pub held_out: Scores,
    pub all: Scores,
    /// Held-out mAP gain over the baseline, and its standard error over held-out queries
    /// (paired: the same queries under both settings).
    pub held_out_gain: f64,
    pub held_out_gain_se: f64,
    pub matrix_seconds: f64,
}

/// For one parameter, the value best on the tuning half and what it gains over the default.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Choice {
    pub parameter: &'static str,
    pub best_on_tune: String,
    /// mAP gains over the baseline (negative: worse).
    pub tune_gain: f64,
    pub held_out_gain: f64,
    pub held_out_gain_se: f64,
    pub all_gain: f64,
    /// Whether the held-out half confirms it: a gain of at least [`MIN_GAIN`] and two
    /// standard errors.
    pub recommended: bool,
}

/// Everything `salient eval study` reports.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StudyReport {
    pub collection: String,
    pub models: usize,
    pub tune_models: usize,
    pub held_out_models: usize,
    pub base: Params,
    /// The baseline, each change, and last (when anything was recommended) the recommended
    /// changes together.
    pub results: Vec<SettingResult>,
    pub choices: Vec<Choice>,
    /// Wall-clock seconds of the signature passes (extraction of what was not cached).
    pub signature_seconds: f64,
}

/// Runs the grid on `collection`, caching signatures in `cache_dir`.
pub fn run(
    collection: &LabelledCollection,
    base: &Params,
    cache_dir: &Path,
    limits: &Limits,
    progress: &dyn Progress,
) -> Result<StudyReport> {
    let mut settings = vec![Vec::new()];
    settings.extend(grid(base).into_iter().map(|c| vec![c]));
    let mut scorer = Scorer::new(collection, base, cache_dir, limits, progress);
    let sets: Vec<Params> = settings
        .iter()
        .map(|c| scorer.signature_params(c))
        .collect();
    scorer.prepare(&sets)?;
    let mut results = Vec::new();
    for changes in settings {
        results.push(scorer.score(changes)?);
    }
    let choices = choose(&results);
    let recommended: Vec<Change> = choices
        .iter()
        .filter(|c| c.recommended)
        .flat_map(|c| {
            results
                .iter()
                .find(|r| r.parameter == c.parameter && r.value == c.best_on_tune)
                .map(|r| r.changes[0])
        })
        .collect();
    if recommended.len() > 1 {
        results.push(scorer.score(recommended)?);
    }
    let (tune, held_out) = &scorer.halves;
    Ok(StudyReport {
        collection: collection.root.display().to_string(),
        models: collection.models.len(),
        tune_models: tune.len(),
        held_out_models: held_out.len(),
        base: base.clone(),
        results,
        choices,
        signature_seconds: scorer.signature_seconds,
    })
}

/// Scores settings on a collection's halves, extracting signatures as they are needed.
struct Scorer<'a> {
    collection: &'a LabelledCollection,
    base: &'a Params,
    cache_dir: &'a Path,
    limits: &'a Limits,
    progress: &'a dyn Progress,
    halves: (Vec<usize>, Vec<usize>),
    /// Signatures per parameter set (similarity parameters left at the base's: they do not
    /// change signatures).
    signatures: Vec<(Params, Vec<Signature>)>,
    /// The baseline's held-out per-query scores, for paired gains.
    baseline: Vec<Scores>,
    signature_seconds: f64,
}

impl<'a> Scorer<'a> {
    fn new(
        collection: &'a LabelledCollection,
        base: &'a Params,
        cache_dir: &'a Path,
        limits: &'a Limits,
        progress: &'a dyn Progress,
    ) -> Self {
        Self {
            collection,
            base,
            cache_dir,
            limits,
            progress,
            halves: halves(collection),
            signatures: Vec::new(),
            baseline: Vec::new(),
            signature_seconds: 0.0,
        }
    }

    /// The parameters of the signatures `changes` need: similarity parameters do not change
    /// signatures, so they stay at the base's.
    fn signature_params(&self, changes: &[Change]) -> Params {
        Params {
            similarity: self.base.similarity.clone(),
            ..with(self.base, changes)
        }
    }

    /// Extracts (or reads from the cache) the signature sets not yet at hand, all in one pass
    /// so that sets sharing their ECC share one ECC computation per model.
    fn prepare(&mut self, sets: &[Params]) -> Result<()> {
        let mut missing: Vec<Params> = Vec::new();
        for p in sets {
            if !missing.contains(p) && self.signatures.iter().all(|(q, _)| q != p) {
                missing.push(p.clone());
            }
        }
        if missing.is_empty() {
            return Ok(());
        }
        let clock = Instant::now();
        let extracted = signatures(
            self.collection,
            &missing,
            self.cache_dir,
            self.limits,
            self.progress,
        )?;
        self.signature_seconds += clock.elapsed().as_secs_f64();
        self.signatures.extend(missing.into_iter().zip(extracted));
        Ok(())
    }

    /// Scores `base` with `changes`; the first call must be the baseline (no changes).
    fn score(&mut self, changes: Vec<Change>) -> Result<SettingResult> {
        let params = with(self.base, &changes);
        let signature_params = self.signature_params(&changes);
        self.prepare(std::slice::from_ref(&signature_params))?;
        let (_, signatures) = self
            .signatures
            .iter()
            .find(|(p, _)| *p == signature_params)
            .expect("prepared above");

        let (parameter, value) = match changes.as_slice() {
            [] => (BASELINE.to_string(), "defaults".to_string()),
            [one] => (one.parameter().to_string(), one.value()),
            many => (
                COMBINED.to_string(),
                many.iter()
                    .map(|c| format!("{} {}", c.parameter(), c.value()))
                    .collect::<Vec<_>>()
                    .join(", "),
            ),
        };
        let clock = Instant::now();
        let ids: Vec<String> = self
            .collection
            .models
            .iter()
            .map(|m| m.id.clone())
            .collect();
        self.progress
            .start(&format!("{parameter} {value}"), ids.len());
        let matrix =
            DistanceMatrix::compute(ids, signatures, Method::Ecc, &params.similarity, || {
                self.progress.advance("")
            });
        self.progress.finish();
        let classes = self.collection.classes();
        let (tune, held_out) = &self.halves;
        let all: Vec<usize> = (0..matrix.len()).collect();
        let held = evaluate(&matrix, &classes, held_out);
        if changes.is_empty() {
            self.baseline = held.per_query.clone();
        }
        let (gain, se) = paired_gain(&self.baseline, &held.per_query);
        Ok(SettingResult {
            parameter,
            value,
            changes,
            tune: evaluate(&matrix, &classes, tune).scores,
            held_out: held.scores,
            all: evaluate(&matrix, &classes, &all).scores,
            held_out_gain: gain,
            held_out_gain_se: se,
            matrix_seconds: clock.elapsed().as_secs_f64(),
        })
    }
}

const BASELINE: &str = "baseline";
const COMBINED: &str = "combined";

/// Mean and standard error of the per-query average-precision differences `after − before`.
pub(super) fn paired_gain(before: &[Scores], after: &[Scores]) -> (f64, f64) {
    let differences: Vec<f64> = before
        .iter()
        .zip(after)
        .map(|(b, a)| a.map - b.map)
        .collect();
    let n = differences.len() as f64;
    if n < 2.0 {
        return (differences.first().copied().unwrap_or(0.0), 0.0);
    }
    let mean = differences.iter().sum::<f64>() / n;
    let variance = differences.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (variance / n).sqrt())
}

/// Per parameter, the value of best tuning-half mAP (the baseline's when none beats it).
fn choose(results: &[SettingResult]) -> Vec<Choice> {
    let baseline = &results[0];
    let mut parameters: Vec<&'static str> = Vec::new();
    for r in &results[1..] {
        let parameter = r.changes[0].parameter();
        if !parameters.contains(&parameter) {
            parameters.push(parameter);
        }
    }
    parameters
        .into_iter()
        .map(|parameter| {
            let best = results
                .iter()
                .filter(|r| r.changes.first().map(|c| c.parameter()) == Some(parameter))
                .chain([baseline])
                .max_by(|a, b| a.tune.map.total_cmp(&b.tune.map))
                .expect("the baseline is a candidate");
            let changed = best.parameter != BASELINE;
            Choice {
                parameter,
                best_on_tune: if changed {
                    best.value.clone()
                } else {
                    "default".into()
                },
                tune_gain: best.tune.map - baseline.tune.map,
                held_out_gain: best.held_out_gain,
                held_out_gain_se: best.held_out_gain_se,
                all_gain: best.all.map - baseline.all.map,
                recommended: changed
                    && best.held_out_gain >= MIN_GAIN.max(2.0 * best.held_out_gain_se),
            }
        })
        .collect()
}

/// The signatures of every model under each parameter set in `sets`, from the cache where
/// possible; a model's ECC is computed once for all sets that share mesh and ECC parameters.
fn signatures(
    collection: &LabelledCollection,
    sets: &[Params],
    cache_dir: &Path,
    limits: &Limits,
    progress: &dyn Progress,
) -> Result<Vec<Vec<Signature>>> {
    let caches: Vec<SignatureCache> = sets
        .iter()
        .map(|p| SignatureCache::new(cache_dir, p))
        .collect();
    let mut out = vec![Vec::with_capacity(collection.models.len()); sets.len()];
    progress.start("signatures", collection.models.len());
    for model in &collection.models {
        let bytes = read(&model.path)?;
        let mut extractions: Vec<(&Params, Extraction)> = Vec::new();
        for ((params, cache), signatures) in sets.iter().zip(&caches).zip(&mut out) {
            let signature = match cache.get(&bytes) {
                Some(signature) => signature,
                None => {
                    let same_ecc = |p: &Params| p.mesh == params.mesh && p.ecc == params.ecc;
                    let index = match extractions.iter().position(|(p, _)| same_ecc(p)) {
                        Some(index) => index,
                        None => {
                            extractions.push((params, extract_path(&model.path, params, limits)?));
                            extractions.len() - 1
                        }
                    };
                    cache.put(&bytes, &describe(&extractions[index].1, params))?
                }
            };
            signatures.push(signature);
        }
        progress.advance(&model.id);
    }
    progress.finish();
    Ok(out)
}

impl StudyReport {
    /// The grid's scores and the choice per parameter.
    pub fn markdown(&self) -> String {
        let mut results = Table::new([
            "parameter",
            "value",
            "tune mAP",
            "held-out mAP",
            "held-out ΔmAP ± SE",
            "held-out NN",
            "held-out FT",
            "all NN",
            "all FT",
            "all mAP",
        ]);
        for r in &self.results {
            results.row([
                r.parameter.clone(),
                r.value.clone(),
                score(r.tune.map),
                score(r.held_out.map),
                format!("{:+.3} ± {:.3}", r.held_out_gain, r.held_out_gain_se),
                score(r.held_out.nearest_neighbour),
                score(r.held_out.first_tier),
                score(r.all.nearest_neighbour),
                score(r.all.first_tier),
                score(r.all.map),
            ]);
        }
        let mut choices = Table::new([
            "parameter",
            "best on tuning half",
            "tune ΔmAP",
            "held-out ΔmAP ± SE",
            "all ΔmAP",
            "recommended",
        ]);
        for c in &self.choices {
            choices.row([
                c.parameter.to_string(),
                c.best_on_tune.clone(),
                format!("{:+.3}", c.tune_gain),
                format!("{:+.3} ± {:.3}", c.held_out_gain, c.held_out_gain_se),
                format!("{:+.3}", c.all_gain),
                if c.recommended { "yes" } else { "no" }.to_string(),
            ]);
        }
        format!(
            "# Parameter study on {}\n\n{} models: {} to tune, {} held out (each class split \
             alternately in id order; each half ranked only among itself). One parameter \
             varied at a time around the defaults (`W` = {}, penalty {}, `K` = {}, \
             `flat_max` = {}, `D_g` = {}); ECC method, leave-one-out.\n\n{}\n## Choice per \
             parameter\n\nThe value of best tuning-half mAP, and what it gains over the \
             defaults. Recommended only when the held-out half gains at least {MIN_GAIN} mAP and two \
             standard errors of the paired per-query differences. The last row of the table \
             above, when present, has all recommended changes together.\n\n{}",
            self.collection,
            self.models,
            self.tune_models,
            self.held_out_models,
            self.base.similarity.ecc_weight,
            if self.base.similarity.penalty { "on" } else { "off" },
            self.base.salient.clusters,
            self.base.ecc.flat_max,
            self.base.ecc.local_size,
            results.markdown(),
            choices.markdown()
        )
    }

    /// Writes `study.json` and `study.md` into `dir`.
    pub fn write(&self, dir: &Path) -> Result<()> {
        write_json(&dir.join("study.json"), self)?;
        write(&dir.join("study.md"), self.markdown())
    }
}

//! The parameter study behind the defaults (SPEC §5: "tune `W` on the labelled set and record
//! the tuned value with its evidence"; issue #4): `W`, the penalty, `K`, `flat_max`, `D_g` and
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
use crate::collection::{read, SignatureCache};
use crate::extract::{extract_path, Extraction};
use crate::params::{CandidateRule, HeightRule, Limits, Params, RegionRule};
use crate::rank::Method;
use crate::signature::{describe, Signature};
use crate::Result;

/// Held-out mAP a tuned value must gain over the default before the study recommends it.
pub const MIN_GAIN: f64 = 0.005;

/// One point of the grid: `base` with one parameter changed (or none, for the baseline).
#[derive(Debug, Clone, PartialEq)]
pub struct Setting {
    pub parameter: &'static str,
    pub value: String,
    pub params: Params,
}

/// The baseline, then each parameter's alternatives: `W` ∈ {0, 0.25, 0.75, 1}, penalty off,
/// `K` ∈ {3, 8}, `flat_max` ∈ {0.25, 1}, `D_g` ∈ {0.2, 0.4}, and the paper's height,
/// candidate and region rules (values equal to `base`'s are skipped).
pub fn grid(base: &Params) -> Vec<Setting> {
    let mut settings = vec![Setting {
        parameter: BASELINE,
        value: "defaults".into(),
        params: base.clone(),
    }];
    let mut vary = |parameter: &'static str, value: String, change: &dyn Fn(&mut Params)| {
        let mut params = base.clone();
        change(&mut params);
        if params != *base {
            settings.push(Setting {
                parameter,
                value,
                params,
            });
        }
    };
    for w in [0.0, 0.25, 0.75, 1.0] {
        vary("W", w.to_string(), &|p| p.similarity.ecc_weight = w);
    }
    vary("penalty", "off".into(), &|p| p.similarity.penalty = false);
    for k in [3, 8] {
        vary("K", k.to_string(), &|p| p.salient.clusters = k);
    }
    for flat in [0.25, 1.0] {
        vary("flat_max", flat.to_string(), &|p| p.ecc.flat_max = flat);
    }
    for size in [0.2, 0.4] {
        vary("D_g", size.to_string(), &|p| p.ecc.local_size = size);
    }
    // SPEC's resolutions against the paper's literal reading, one at a time (see
    // `Params::paper`).
    vary("height", "paper".into(), &|p| {
        p.ecc.height = HeightRule::Paper
    });
    vary("candidates", "norm".into(), &|p| {
        p.salient.candidates = CandidateRule::Norm
    });
    vary("region_rule", "area".into(), &|p| {
        p.salient.region_rule = RegionRule::Area
    });
    settings
}

const BASELINE: &str = "baseline";

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

/// A setting's scores.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SettingResult {
    pub parameter: &'static str,
    pub value: String,
    pub tune: Scores,
    pub held_out: Scores,
    pub all: Scores,
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
    pub all_gain: f64,
    /// Whether the held-out half confirms it by at least [`MIN_GAIN`].
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
    pub results: Vec<SettingResult>,
    pub choices: Vec<Choice>,
    /// Wall-clock seconds of the signature pass (extraction of what was not cached).
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
    let settings = grid(base);
    // Signatures do not depend on the similarity parameters.
    let signature_params = |s: &Setting| Params {
        similarity: base.similarity.clone(),
        ..s.params.clone()
    };
    let mut sets: Vec<Params> = Vec::new();
    for s in &settings {
        let p = signature_params(s);
        if !sets.contains(&p) {
            sets.push(p);
        }
    }
    let clock = Instant::now();
    let signatures = signatures(collection, &sets, cache_dir, limits, progress)?;
    let signature_seconds = clock.elapsed().as_secs_f64();

    let ids: Vec<String> = collection.models.iter().map(|m| m.id.clone()).collect();
    let classes = collection.classes();
    let (tune, held_out) = halves(collection);
    let all: Vec<usize> = (0..ids.len()).collect();
    let mut results = Vec::new();
    for s in &settings {
        let set = sets
            .iter()
            .position(|p| *p == signature_params(s))
            .expect("every setting has its signature set");
        let clock = Instant::now();
        progress.start(&format!("{} {}", s.parameter, s.value), ids.len());
        let matrix = DistanceMatrix::compute(
            ids.clone(),
            &signatures[set],
            Method::Ecc,
            &s.params.similarity,
            || progress.advance(""),
        );
        progress.finish();
        results.push(SettingResult {
            parameter: s.parameter,
            value: s.value.clone(),
            tune: evaluate(&matrix, &classes, &tune).scores,
            held_out: evaluate(&matrix, &classes, &held_out).scores,
            all: evaluate(&matrix, &classes, &all).scores,
            matrix_seconds: clock.elapsed().as_secs_f64(),
        });
    }
    let choices = choose(&results);
    Ok(StudyReport {
        collection: collection.root.display().to_string(),
        models: ids.len(),
        tune_models: tune.len(),
        held_out_models: held_out.len(),
        base: base.clone(),
        results,
        choices,
        signature_seconds,
    })
}

/// Per parameter, the value of best tuning-half mAP (the baseline's when none beats it).
fn choose(results: &[SettingResult]) -> Vec<Choice> {
    let baseline = &results[0];
    let mut parameters: Vec<&'static str> = Vec::new();
    for r in &results[1..] {
        if !parameters.contains(&r.parameter) {
            parameters.push(r.parameter);
        }
    }
    parameters
        .into_iter()
        .map(|parameter| {
            let best = results
                .iter()
                .filter(|r| r.parameter == parameter)
                .chain([baseline])
                .max_by(|a, b| a.tune.map.total_cmp(&b.tune.map))
                .expect("the baseline is a candidate");
            let held_out_gain = best.held_out.map - baseline.held_out.map;
            Choice {
                parameter,
                best_on_tune: if best.parameter == BASELINE {
                    "default".into()
                } else {
                    best.value.clone()
                },
                tune_gain: best.tune.map - baseline.tune.map,
                held_out_gain,
                all_gain: best.all.map - baseline.all.map,
                recommended: best.parameter != BASELINE && held_out_gain >= MIN_GAIN,
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
            "held-out NN",
            "held-out FT",
            "all NN",
            "all FT",
            "all mAP",
        ]);
        for r in &self.results {
            results.row([
                r.parameter.to_string(),
                r.value.clone(),
                score(r.tune.map),
                score(r.held_out.map),
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
            "held-out ΔmAP",
            "all ΔmAP",
            "recommended",
        ]);
        for c in &self.choices {
            choices.row([
                c.parameter.to_string(),
                c.best_on_tune.clone(),
                format!("{:+.3}", c.tune_gain),
                format!("{:+.3}", c.held_out_gain),
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
             defaults. Recommended only when the held-out half gains at least {MIN_GAIN} mAP.\n\n{}",
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

//! Choosing the `hybrid` method's weights, scales and penalty power (SPEC §9; `docs/results/tune/`) on
//! the tuning halves of one or more labelled collections together, and judging the choice on
//! the held-out halves.
//!
//! - **Scales** are fixed, not learnt: each part's median distance over the pairs of the
//!   pooled tuning halves. They only make the weights readable (a weight of 1 is "as much as
//!   a typical distance of this part"); ranking depends on `weight / scale`.
//! - **Weights** and the ECC part's **penalty power** are searched on a grid (weights on the
//!   simplex in steps of [`WEIGHT_STEP`], powers [`POWERS`]), scoring the mean tuning-half mAP
//!   over the collections; each half is ranked only among itself, as in [`super::study`].
//! - **Overfitting** is judged on each held-out half: the setting tuned on the tuning half
//!   against the setting that half would choose for itself. The difference is what tuning on
//!   the wrong half costs (the "overfit gap").
//!
//! The part distances are computed once per collection (the ECC's EMD without penalty, with
//! the feature counts, so that each power is a multiplication); every setting fuses them with
//! [`salient_core::rank::fuse`], the function the service ranks with.

use std::collections::BTreeMap;
use std::path::Path;

use serde::Serialize;

use super::metrics::Scores;
use super::report::{score, write, write_json, Table};
use super::retrieval::{evaluate, signatures, DistanceMatrix, Evaluation};
use super::study::{halves, paired_gain};
use super::{LabelledCollection, Progress};
use salient_core::collection::SignatureCache;
use salient_core::params::{HybridParams, Limits, Params, SimilarityParams};
use salient_core::rank::{fuse, Method, PARTS};
use salient_core::Result;

/// Step of the weight grid on the simplex `Σ wᵢ = 1`.
pub const WEIGHT_STEP: f64 = 0.05;

/// Powers of the count penalty tried for the ECC part (1 is the paper's Eq. 13, 0 none).
pub const POWERS: [f64; 5] = [0.0, 0.25, 0.5, 0.75, 1.0];

/// One collection's part distances and halves.
struct Parts {
    name: String,
    classes: Vec<String>,
    ids: Vec<String>,
    /// EMD between salient features (Eq. 12, no penalty); infinite when a side has none.
    emd: DistanceMatrix,
    /// `max(m, n) / min(m, n)` of the feature counts, row-major.
    ratio: Vec<f64>,
    /// The other parts' distances, in [`PARTS`] order after the ECC.
    others: Vec<DistanceMatrix>,
    tune: Vec<usize>,
    held_out: Vec<usize>,
}

impl Parts {
    fn compute(
        collection: &LabelledCollection,
        params: &Params,
        cache: &SignatureCache,
        limits: &Limits,
        progress: &dyn Progress,
    ) -> Result<Self> {
        let (signatures, _) = signatures(collection, cache, params, limits, None, progress)?;
        let ids: Vec<String> = collection.models.iter().map(|m| m.id.clone()).collect();
        let unpenalised = SimilarityParams {
            penalty: false,
            ..params.similarity.clone()
        };
        let matrix = |method| {
            progress.start(&format!("{method}"), ids.len());
            let m = DistanceMatrix::compute(ids.clone(), &signatures, method, &unpenalised, || {
                progress.advance("")
            });
            progress.finish();
            m
        };
        let counts: Vec<f64> = signatures.iter().map(|s| s.features.len() as f64).collect();
        let ratio = counts
            .iter()
            .flat_map(|&m| counts.iter().map(move |&n| m.max(n) / m.min(n).max(1.0)))
            .collect();
        let (tune, held_out) = halves(collection);
        Ok(Self {
            name: collection_name(collection),
            classes: collection.models.iter().map(|m| m.class.clone()).collect(),
            emd: matrix(Method::Ecc),
            ratio,
            others: PARTS[1..].iter().map(|&m| matrix(m)).collect(),
            ids,
            tune,
            held_out,
        })
    }

    /// The part distances of `(i, j)`, the ECC's with the penalty to `power`.
    fn parts(&self, i: usize, j: usize, power: f64) -> [Option<f64>; 4] {
        let n = self.ids.len();
        let finite = |d: f64| d.is_finite().then_some(d);
        std::array::from_fn(|k| match k {
            0 => finite(self.emd.get(i, j) * self.ratio[i * n + j].powf(power)),
            _ => finite(self.others[k - 1].get(i, j)),
        })
    }

    /// The hybrid's distance matrix under `hybrid`.
    fn fused(&self, hybrid: &HybridParams) -> DistanceMatrix {
        let n = self.ids.len();
        let values = (0..n * n)
            .map(|k| fuse(hybrid, self.parts(k / n, k % n, hybrid.penalty_power)))
            .collect();
        DistanceMatrix::new(self.ids.clone(), values)
    }

    fn evaluate(&self, matrix: &DistanceMatrix, members: &[usize]) -> Evaluation {
        let classes: Vec<&str> = self.classes.iter().map(String::as_str).collect();
        evaluate(matrix, &classes, members)
    }

    /// Part `k`'s distances over the pairs within the tuning half.
    fn tuning_distances(&self, part: usize, power: f64) -> impl Iterator<Item = f64> + '_ {
        self.tune.iter().enumerate().flat_map(move |(a, &i)| {
            self.tune[a + 1..]
                .iter()
                .filter_map(move |&j| self.parts(i, j, power)[part])
        })
    }
}

fn collection_name(collection: &LabelledCollection) -> String {
    collection.root.file_name().map_or_else(
        || collection.root.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(1.0)
}

/// Every setting of the grid, scales as given.
fn grid(scales: &BTreeMap<String, [f64; 4]>) -> Vec<HybridParams> {
    let steps = (1.0 / WEIGHT_STEP).round() as usize;
    let mut weights: Vec<[usize; 4]> = Vec::new();
    for a in 0..=steps {
        for b in 0..=steps - a {
            for c in 0..=steps - a - b {
                weights.push([a, b, c, steps - a - b - c]);
            }
        }
    }
    let mut settings = Vec::new();
    for power in POWERS {
        let s = scales[&power.to_string()];
        for w in &weights {
            let mut hybrid = HybridParams {
                penalty_power: power,
                ..HybridParams::default()
            };
            for (k, term) in hybrid.terms_mut().into_iter().enumerate() {
                (term.weight, term.scale) = (w[k] as f64 / steps as f64, s[k]);
            }
            settings.push(hybrid);
        }
    }
    settings
}

/// A method's scores on one collection.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodScores {
    pub method: String,
    pub tune: Scores,
    pub held_out: Scores,
    /// Leave-one-out over the whole collection.
    pub all: Scores,
    /// mAP per class on the held-out half.
    pub held_out_per_class: BTreeMap<String, f64>,
}

/// What tuning found on one collection.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CollectionResult {
    pub collection: String,
    pub models: usize,
    pub tune_models: usize,
    pub held_out_models: usize,
    /// The tuned hybrid, then each single method.
    pub methods: Vec<MethodScores>,
    /// Held-out mAP gain of the hybrid over the best single method on that half, with the
    /// standard error of the paired per-query differences.
    pub best_single: String,
    pub held_out_gain: f64,
    pub held_out_gain_se: f64,
    /// The setting the held-out half would choose for itself, and its held-out mAP.
    pub self_tuned: HybridParams,
    pub self_tuned_held_out_map: f64,
    /// `self_tuned_held_out_map` minus the tuned hybrid's held-out mAP.
    pub overfit_gap: f64,
}

/// Everything `salient eval tune` reports.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TuneReport {
    /// Per penalty power, the scales of the parts ([`PARTS`]).
    pub scales: BTreeMap<String, [f64; 4]>,
    pub settings_tried: usize,
    /// The chosen setting: best mean tuning-half mAP over the collections.
    pub chosen: HybridParams,
    pub chosen_tune_map: f64,
    /// The ten best settings on the tuning halves, with their mean tuning-half mAP.
    pub runners_up: Vec<(HybridParams, f64)>,
    pub collections: Vec<CollectionResult>,
}

/// Tunes the hybrid on `collections` (signatures from `cache_for(collection)`).
pub fn run(
    collections: &[LabelledCollection],
    params: &Params,
    cache_for: impl Fn(&LabelledCollection) -> SignatureCache,
    limits: &Limits,
    progress: &dyn Progress,
) -> Result<TuneReport> {
    let parts: Vec<Parts> = collections
        .iter()
        .map(|c| Parts::compute(c, params, &cache_for(c), limits, progress))
        .collect::<Result<_>>()?;
    let scales: BTreeMap<String, [f64; 4]> = POWERS
        .iter()
        .map(|&power| {
            let scale = |k: usize| {
                median(
                    parts
                        .iter()
                        .flat_map(|p| p.tuning_distances(k, power))
                        .collect(),
                )
            };
            (power.to_string(), std::array::from_fn(scale))
        })
        .collect();
    let settings = grid(&scales);
    progress.start("settings", settings.len());
    // Per setting, per collection: (tuning-half mAP, held-out mAP).
    let scored: Vec<Vec<(f64, f64)>> = settings
        .iter()
        .map(|hybrid| {
            let row = parts
                .iter()
                .map(|p| {
                    let m = p.fused(hybrid);
                    (
                        p.evaluate(&m, &p.tune).scores.map,
                        p.evaluate(&m, &p.held_out).scores.map,
                    )
                })
                .collect();
            progress.advance("");
            row
        })
        .collect();
    progress.finish();
    let mean_tune = |row: &[(f64, f64)]| row.iter().map(|s| s.0).sum::<f64>() / row.len() as f64;
    let mut order: Vec<usize> = (0..settings.len()).collect();
    // Best first; among equals the earlier in grid order (lower power first).
    order.sort_by(|&a, &b| mean_tune(&scored[b]).total_cmp(&mean_tune(&scored[a])));
    let chosen = settings[order[0]].clone();

    let single = |method: Method| {
        let mut hybrid = chosen.clone();
        for (term, part) in hybrid.terms_mut().into_iter().zip(PARTS) {
            term.weight = if part == method { 1.0 } else { 0.0 };
        }
        hybrid.penalty_power = params.similarity.penalty_power;
        hybrid
    };
    let results = parts
        .iter()
        .enumerate()
        .map(|(c, p)| {
            let self_best = (0..settings.len())
                .max_by(|&a, &b| scored[a][c].1.total_cmp(&scored[b][c].1).then(b.cmp(&a)))
                .expect("a grid");
            let method = |name: &str, hybrid: &HybridParams| {
                let m = p.fused(hybrid);
                let held = p.evaluate(&m, &p.held_out);
                let scores = MethodScores {
                    method: name.to_string(),
                    tune: p.evaluate(&m, &p.tune).scores,
                    held_out: held.scores,
                    all: p.evaluate(&m, &(0..p.ids.len()).collect::<Vec<_>>()).scores,
                    held_out_per_class: held
                        .per_class
                        .iter()
                        .map(|(class, s)| (class.clone(), s.map))
                        .collect(),
                };
                (scores, held.per_query)
            };
            let (hybrid, hybrid_queries) = method("hybrid", &chosen);
            let singles: Vec<_> = PARTS
                .iter()
                .map(|&m| method(&m.to_string(), &single(m)))
                .collect();
            let (best, best_queries) = singles
                .iter()
                .max_by(|a, b| a.0.held_out.map.total_cmp(&b.0.held_out.map))
                .expect("four parts");
            let (gain, se) = paired_gain(best_queries, &hybrid_queries);
            CollectionResult {
                collection: p.name.clone(),
                models: p.ids.len(),
                tune_models: p.tune.len(),
                held_out_models: p.held_out.len(),
                best_single: best.method.clone(),
                held_out_gain: gain,
                held_out_gain_se: se,
                self_tuned: settings[self_best].clone(),
                self_tuned_held_out_map: scored[self_best][c].1,
                overfit_gap: scored[self_best][c].1 - hybrid.held_out.map,
                methods: std::iter::once(hybrid)
                    .chain(singles.into_iter().map(|(s, _)| s))
                    .collect(),
            }
        })
        .collect();
    Ok(TuneReport {
        scales,
        settings_tried: settings.len(),
        chosen_tune_map: mean_tune(&scored[order[0]]),
        runners_up: order
            .iter()
            .take(10)
            .map(|&i| (settings[i].clone(), mean_tune(&scored[i])))
            .collect(),
        chosen,
        collections: results,
    })
}

fn setting(h: &HybridParams) -> String {
    let weights: Vec<String> = PARTS
        .iter()
        .zip(h.terms())
        .map(|(m, t)| format!("{m} {:.2}", t.weight))
        .collect();
    format!("{}; penalty power {}", weights.join(", "), h.penalty_power)
}

impl TuneReport {
    /// The chosen setting as a parameter file (`--params`, or the server's configuration).
    pub fn params(&self) -> serde_json::Value {
        serde_json::json!({ "similarity": { "hybrid": self.chosen } })
    }

    pub fn markdown(&self) -> String {
        let mut text = format!(
            "# Tuning the hybrid\n\nThe `hybrid` distance is `Σ wᵢ · dᵢ / sᵢ` over the ECC \
             (penalised EMD), D2, LFD and geodesic distances (SPEC §9). Scales `sᵢ` are each part's \
             median distance over the pairs of the pooled tuning halves; weights (a simplex \
             grid in steps of {WEIGHT_STEP}) and the ECC part's penalty power ({:?}) are \
             chosen by the mean tuning-half mAP over {} collection(s): {} settings. Each \
             class is split alternately in id order; each half is ranked only among itself.\n\n\
             **Chosen:** {} (tuning-half mAP {}), i.e. `{}`.\n\n",
            POWERS,
            self.collections.len(),
            self.settings_tried,
            setting(&self.chosen),
            score(self.chosen_tune_map),
            serde_json::to_string(&self.params()).expect("serialisable"),
        );
        let mut scales = Table::new(
            std::iter::once("penalty power".to_string())
                .chain(PARTS.iter().map(|m| format!("{m} scale"))),
        );
        for (power, s) in &self.scales {
            scales.row(std::iter::once(power.clone()).chain(s.iter().map(|x| format!("{x:.4}"))));
        }
        text += &scales.markdown();
        text += "\n## The ten best settings on the tuning halves\n\n";
        let mut top = Table::new(["setting", "mean tuning-half mAP"]);
        for (h, m) in &self.runners_up {
            top.row([setting(h), score(*m)]);
        }
        text += &top.markdown();
        for c in &self.collections {
            text += &format!(
                "\n## {}\n\n{} models: {} to tune, {} held out. The hybrid against each single \
                 method (the ECC with the configured penalty) on each half and on the whole \
                 collection (leave-one-out).\n\n",
                c.collection, c.models, c.tune_models, c.held_out_models
            );
            let mut table = Table::new(
                ["method", "half"]
                    .into_iter()
                    .chain(["NN", "FT", "ST", "E", "DCG", "mAP"]),
            );
            for m in &c.methods {
                for (half, s) in [
                    ("tune", &m.tune),
                    ("held out", &m.held_out),
                    ("all", &m.all),
                ] {
                    table.row(
                        [m.method.clone(), half.to_string()]
                            .into_iter()
                            .chain(s.measures().iter().map(|&(_, x)| score(x))),
                    );
                }
            }
            text += &table.markdown();
            text += &format!(
                "\nHeld-out mAP, hybrid minus the best single method ({}): {:+.3} ± {:.3} \
                 (paired standard error). **Overfit gap**: the held-out half tuned on itself \
                 ({}) reaches mAP {}, {:+.3} over the hybrid tuned on the other half.\n\n\
                 Held-out mAP per class:\n\n",
                c.best_single,
                c.held_out_gain,
                c.held_out_gain_se,
                setting(&c.self_tuned),
                score(c.self_tuned_held_out_map),
                c.overfit_gap
            );
            let mut classes = Table::new(
                std::iter::once("class").chain(c.methods.iter().map(|m| m.method.as_str())),
            );
            for class in c.methods[0].held_out_per_class.keys() {
                classes.row(
                    std::iter::once(class.clone())
                        .chain(c.methods.iter().map(|m| score(m.held_out_per_class[class]))),
                );
            }
            text += &classes.markdown();
        }
        text
    }

    /// Writes `tune.json`, `tune.md` and `params.json` (the chosen setting) into `dir`.
    pub fn write(&self, dir: &Path) -> Result<()> {
        write_json(&dir.join("tune.json"), self)?;
        write_json(&dir.join("params.json"), &self.params())?;
        write(&dir.join("tune.md"), self.markdown())
    }
}

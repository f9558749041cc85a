//! Retrieval measures of one query's ranked list, as defined by the Princeton Shape Benchmark
//! (P. Shilane, P. Min, M. Kazhdan, T. Funkhouser, "The Princeton Shape Benchmark", SMI 2004,
//! §4) and reported by the SHREC contests (e.g. Giorgi, Biasotti, Paraboschi, "SHREC:
//! Watertight Models Track", 2007), plus the 11-point interpolated precision–recall curve of
//! TREC (Manning, Raghavan, Schütze, *Introduction to Information Retrieval*, §8.4) that the
//! paper plots in Fig. 14.
//!
//! A query's class has `C` models; the `C − 1` others are its relevant results. The query
//! itself is never in its list (leave-one-out, SPEC §7).

use serde::{Deserialize, Serialize};

/// Results the E-measure looks at: "the first 32 retrieved models", chosen in the PSB because
/// a results page shows about that many.
pub const E_MEASURE_DEPTH: usize = 32;

/// Recall levels 0, 0.1, …, 1 of the precision–recall curve.
pub const RECALL_LEVELS: usize = 11;

/// The measures of one query, or their mean over queries. All lie in [0, 1], higher is
/// better.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Scores {
    /// Nearest neighbour: whether the first result is relevant.
    #[serde(rename = "NN")]
    pub nearest_neighbour: f64,
    /// First tier: the fraction of relevant models among the first `C − 1` results.
    #[serde(rename = "FT")]
    pub first_tier: f64,
    /// Second tier: relevant models among the first `2(C − 1)` results, over `C − 1`.
    #[serde(rename = "ST")]
    pub second_tier: f64,
    /// E-measure of the first [`E_MEASURE_DEPTH`] results: `2 / (1/P + 1/R)`, 0 when none
    /// is relevant.
    #[serde(rename = "E")]
    pub e_measure: f64,
    /// Discounted cumulative gain, `G_1 + Σ_{i≥2} G_i / log₂ i` with `G_i` = 1 for a relevant
    /// result, divided by its ideal value `1 + Σ_{j=2}^{C−1} 1 / log₂ j`.
    #[serde(rename = "DCG")]
    pub dcg: f64,
    /// Average precision (mean of the precision at the rank of each relevant model), or its
    /// mean over queries.
    #[serde(rename = "mAP")]
    pub map: f64,
    /// Interpolated precision at recall 0, 0.1, …, 1: the largest precision at any recall
    /// at least that level.
    pub pr: [f64; RECALL_LEVELS],
}

impl Scores {
    /// The measures of one ranked list: `relevance[k]` says whether the result at rank `k + 1`
    /// is of the query's class, and `relevant` (`C − 1`) how many such models exist. `None`
    /// when there are none (a class of one model): every measure would be 0/0.
    pub fn of_query(relevance: &[bool], relevant: usize) -> Option<Self> {
        if relevant == 0 {
            return None;
        }
        let hits_within = |depth: usize| relevance.iter().take(depth).filter(|&&r| r).count();
        let r = relevant as f64;
        let (mut hits, mut dcg, mut precision_sum) = (0, 0.0, 0.0);
        let mut pr = [0.0; RECALL_LEVELS];
        for rank in (1..=relevance.len()).filter(|&k| relevance[k - 1]) {
            hits += 1;
            let precision = hits as f64 / rank as f64;
            precision_sum += precision;
            dcg += if rank == 1 {
                1.0
            } else {
                1.0 / (rank as f64).log2()
            };
            // Recall hits / relevant reaches level j / 10: interpolate downwards.
            for (level, p) in pr.iter_mut().enumerate() {
                if hits * (RECALL_LEVELS - 1) >= level * relevant {
                    *p = f64::max(*p, precision);
                }
            }
        }
        let ideal = 1.0 + (2..=relevant).map(|j| 1.0 / (j as f64).log2()).sum::<f64>();
        Some(Self {
            nearest_neighbour: if relevance.first() == Some(&true) {
                1.0
            } else {
                0.0
            },
            first_tier: hits_within(relevant) as f64 / r,
            second_tier: hits_within(2 * relevant) as f64 / r,
            // 2 / (1/P + 1/R) with P = h/32 and R = h/(C − 1).
            e_measure: 2.0 * hits_within(E_MEASURE_DEPTH) as f64
                / (E_MEASURE_DEPTH + relevant) as f64,
            dcg: dcg / ideal,
            map: precision_sum / r,
            pr,
        })
    }

    /// The mean of each measure over `scores` (every query weighs the same, as in the PSB);
    /// `None` for no scores.
    pub fn mean<'a>(scores: impl IntoIterator<Item = &'a Scores>) -> Option<Self> {
        let mut sum = Self::default();
        let mut count = 0;
        for s in scores {
            count += 1;
            sum.nearest_neighbour += s.nearest_neighbour;
            sum.first_tier += s.first_tier;
            sum.second_tier += s.second_tier;
            sum.e_measure += s.e_measure;
            sum.dcg += s.dcg;
            sum.map += s.map;
            for (a, b) in sum.pr.iter_mut().zip(&s.pr) {
                *a += b;
            }
        }
        if count == 0 {
            return None;
        }
        let n = count as f64;
        Some(Self {
            nearest_neighbour: sum.nearest_neighbour / n,
            first_tier: sum.first_tier / n,
            second_tier: sum.second_tier / n,
            e_measure: sum.e_measure / n,
            dcg: sum.dcg / n,
            map: sum.map / n,
            pr: sum.pr.map(|p| p / n),
        })
    }

    /// The six scalar measures with their report names, in the order reports show them.
    pub fn measures(&self) -> [(&'static str, f64); 6] {
        [
            ("NN", self.nearest_neighbour),
            ("FT", self.first_tier),
            ("ST", self.second_tier),
            ("E", self.e_measure),
            ("DCG", self.dcg),
            ("mAP", self.map),
        ]
    }
}

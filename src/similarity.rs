//! Comparing two signatures (SPEC §5, paper §5): the ground distance between two salient
//! features, the EMD between the feature sets with equal weights, the `max(m,n)/min(m,n)`
//! penalty; the global D2 distance of the baseline (SPEC §6); and a cheap lower bound on the
//! penalised EMD that lets a search skip most of a collection.

use serde::{Deserialize, Serialize};

use crate::descriptor::histogram_l1;
use crate::emd::emd_uniform;
use crate::params::SimilarityParams;
use crate::signature::{Feature, Signature};

/// The result of comparing two signatures by their salient features.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Similarity {
    /// `SIM(P, Q)` of Eq. 13 (just the EMD when the penalty is off). Lower is more similar.
    pub sim: f64,
    pub emd: f64,
    /// Feature counts of the two signatures.
    pub m: usize,
    pub n: usize,
}

/// Ground distance (Eq. 11): `W · ‖α_p − α_q‖₂ / √N + (1 − W) · ½‖h_p − h_q‖₁`.
pub fn ground_distance(p: &Feature, q: &Feature, w: f64) -> f64 {
    let ecc = rms(&p.ecc, &q.ecc);
    w * ecc + (1.0 - w) * histogram_l1(&p.d2, &q.d2)
}

/// `‖a − b‖₂ / √len`.
fn rms(a: &[f64], b: &[f64]) -> f64 {
    let sum: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    (sum / a.len().max(1) as f64).sqrt()
}

/// `max(m, n) / min(m, n)` when enabled, else 1 (Eq. 13).
pub fn penalty(m: usize, n: usize, params: &SimilarityParams) -> f64 {
    if params.penalty {
        m.max(n) as f64 / m.min(n).max(1) as f64
    } else {
        1.0
    }
}

/// `SIM(P, Q)` by exact EMD over the features, each of weight `1/m` resp. `1/n` (Eq. 12).
pub fn compare(p: &Signature, q: &Signature, params: &SimilarityParams) -> Similarity {
    let (m, n) = (p.features.len(), q.features.len());
    let emd = if m == 0 || n == 0 {
        f64::INFINITY
    } else {
        emd_uniform(m, n, |i, j| {
            ground_distance(&p.features[i], &q.features[j], params.ecc_weight)
        })
    };
    Similarity {
        sim: penalty(m, n, params) * emd,
        emd,
        m,
        n,
    }
}

/// The baseline's distance: half the L1 distance of the global D2 histograms (SPEC §6).
pub fn d2_distance(p: &Signature, q: &Signature) -> f64 {
    histogram_l1(&p.d2, &q.d2)
}

/// Feature means of a signature, for [`lower_bound`].
#[derive(Debug, Clone, PartialEq)]
pub struct Centroid {
    ecc: Vec<f64>,
    d2: Vec<f64>,
    count: usize,
}

impl Centroid {
    pub fn of(signature: &Signature) -> Self {
        let count = signature.features.len();
        let mean = |get: fn(&Feature) -> &[f64]| {
            let len = signature.features.first().map_or(0, |f| get(f).len());
            let mut sum = vec![0.0; len];
            for f in &signature.features {
                for (s, x) in sum.iter_mut().zip(get(f)) {
                    *s += x;
                }
            }
            sum.into_iter().map(|s| s / count.max(1) as f64).collect()
        };
        Self {
            ecc: mean(|f| &f.ecc),
            d2: mean(|f| &f.d2),
            count,
        }
    }
}

/// A lower bound on [`compare`]'s `sim` (Rubner et al. 2000, §4.2): the ground distance is a
/// norm of the feature difference (a weighted sum of an L2 and an L1 norm on separate parts),
/// and both sides carry the same total mass, so by convexity
/// `EMD(P, Q) = Σ f_ij d(p_i − q_j) ≥ d(Σ f_ij (p_i − q_j)) = d(mean P − mean Q)`. The penalty
/// multiplies both sides.
pub fn lower_bound(p: &Centroid, q: &Centroid, params: &SimilarityParams) -> f64 {
    let w = params.ecc_weight;
    let d = w * rms(&p.ecc, &q.ecc) + (1.0 - w) * histogram_l1(&p.d2, &q.d2);
    penalty(p.count, q.count, params) * d
}

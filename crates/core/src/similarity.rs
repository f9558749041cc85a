//! Comparing two signatures (SPEC §5, paper §5): the ground distance between two salient
//! features, the EMD between the feature sets with equal weights, the `max(m,n)/min(m,n)`
//! penalty; the global D2 distance of the baseline (SPEC §6); and a cheap lower bound on the
//! penalised EMD that lets a search skip most of a collection.

use serde::{Deserialize, Serialize};

use crate::descriptor::{lane_sum, Span};
use crate::emd::{emd_flows, emd_matrix};
use crate::params::SimilarityParams;
use crate::signature::{quantise, Feature, Signature, BIN_SCALE};

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

/// A model's salient features as they are compared: ECC values in single precision and region
/// D2 bins as fractions of 65 535, the precision they are stored in ([`crate::signature`]),
/// each kind in one array. A fresh extraction and its stored copy compare alike, and an index
/// of 100 000 models holds a quarter of what `Vec<Feature>` took (positions, regions and
/// per-feature allocations are left with the signature).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Features {
    count: usize,
    /// `count` rows of ECC values.
    ecc: Box<[f32]>,
    /// `count` rows of region D2 bins, each `round(65 535 · bin)`.
    d2: Box<[u16]>,
}

impl Features {
    pub fn of(features: &[Feature]) -> Self {
        Self {
            count: features.len(),
            ecc: features
                .iter()
                .flat_map(|f| f.ecc.iter().map(|&a| a as f32))
                .collect(),
            d2: features.iter().flat_map(|f| quantise(&f.d2)).collect(),
        }
    }

    /// The features from their rows as [`Features::rows`] gives them; `None` when an array
    /// is not `count` rows of one length.
    pub(crate) fn from_rows(count: usize, ecc: Vec<f32>, d2: Vec<u16>) -> Option<Self> {
        let rows = |len: usize| match count {
            0 => len == 0,
            n => len.is_multiple_of(n),
        };
        (rows(ecc.len()) && rows(d2.len())).then(|| Self {
            count,
            ecc: ecc.into(),
            d2: d2.into(),
        })
    }

    /// The count, the ECC values and the region D2 bins, row after row.
    pub(crate) fn rows(&self) -> (usize, &[f32], &[u16]) {
        (self.count, &self.ecc, &self.d2)
    }

    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Each feature's ECC values and region bins, the rows' lengths divided out once rather
    /// than per row (a cost matrix walks these for every pair of features).
    fn each(&self) -> impl Iterator<Item = (&[f32], &[u16])> {
        // A feature has ECC values and bins (the parameters' checks); without features both
        // arrays are empty and `max(1)` only keeps `chunks_exact` from a zero length.
        let row = |len: usize| (len / self.count.max(1)).max(1);
        let ecc = self.ecc.chunks_exact(row(self.ecc.len()));
        ecc.zip(self.d2.chunks_exact(row(self.d2.len())))
    }
}

/// Ground distance (Eq. 11) between feature `i` of `p` and `j` of `q`:
/// `W · ‖α_p − α_q‖₂ / √N + (1 − W) · ½‖h_p − h_q‖₁`.
fn ground_distance(p: (&[f32], &[u16]), q: (&[f32], &[u16]), w: f64) -> f64 {
    let ecc = rms(p.0, q.0);
    w * ecc + (1.0 - w) * bins_l1(p.1, q.1) / BIN_SCALE
}

/// [`crate::descriptor::histogram_l1`] of two histograms stored as `u16` fractions, summed in
/// integers: every partial sum in f64 was an exact integer too, so the value is the same bit
/// for bit, and the loop vectorises (the ground distances of an exact EMD were a seventh of a
/// ranking).
fn bins_l1(a: &[u16], b: &[u16]) -> f64 {
    // At most 65 535 a bin: u32 holds 65 536 bins' worth.
    let sum: u32 = a
        .iter()
        .zip(b)
        .map(|(&x, &y)| u32::from(x.abs_diff(y)))
        .sum();
    f64::from(sum) / 2.0
}

/// `‖a − b‖₂ / √len`, summed in f64.
fn rms<T: Copy + Into<f64>>(a: &[T], b: &[T]) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .map(|(&x, &y)| (x.into() - y.into()).powi(2))
        .sum();
    (sum / a.len().max(1) as f64).sqrt()
}

/// `max(m, n) / min(m, n)` when enabled (Eq. 13), raised to `penalty_power`; else 1.
pub fn penalty(m: usize, n: usize, params: &SimilarityParams) -> f64 {
    if !params.penalty || params.penalty_power == 0.0 {
        return 1.0;
    }
    let ratio = m.max(n) as f64 / m.min(n).max(1) as f64;
    if params.penalty_power == 1.0 {
        ratio
    } else {
        ratio.powf(params.penalty_power)
    }
}

/// `SIM(P, Q)` by exact EMD over the features, each of weight `1/m` resp. `1/n` (Eq. 12).
pub fn compare(p: &Signature, q: &Signature, params: &SimilarityParams) -> Similarity {
    let (p, q) = (Features::of(&p.features), Features::of(&q.features));
    compare_costs(&CostMatrix::new(&p, &q, params), params)
}

/// Ground distances between every feature of `P` (rows) and of `Q` (columns).
#[derive(Debug, Clone, PartialEq)]
pub struct CostMatrix {
    m: usize,
    n: usize,
    cost: Vec<f64>,
}

impl Similarity {
    /// `SIM` of the same EMD under other parameters' count penalty (Eq. 13): the ECC method
    /// and the hybrid's ECC part differ only there ([`SimilarityParams::hybrid_ecc`]).
    pub fn penalised(&self, params: &SimilarityParams) -> f64 {
        penalty(self.m, self.n, params) * self.emd
    }
}

impl CostMatrix {
    /// Eq. 13 from the EMD of these features.
    fn similarity(&self, emd: f64, params: &SimilarityParams) -> Similarity {
        Similarity {
            sim: penalty(self.m, self.n, params) * emd,
            emd,
            m: self.m,
            n: self.n,
        }
    }

    pub fn new(p: &Features, q: &Features, params: &SimilarityParams) -> Self {
        let (m, n) = (p.len(), q.len());
        let cost = p
            .each()
            .flat_map(|a| {
                q.each()
                    .map(move |b| ground_distance(a, b, params.ecc_weight))
            })
            .collect();
        Self { m, n, cost }
    }

    /// A lower bound on [`compare_costs`]'s `sim` that drops one side's constraints: every
    /// unit of `P`'s mass travels at least to its nearest feature of `Q`, and vice versa
    /// (Pele and Werman 2008 call it the relaxed EMD). Cheaper than the EMD once the costs are
    /// known, and much tighter than the centroid bound.
    pub fn relaxed_bound(&self, params: &SimilarityParams) -> f64 {
        let (m, n) = (self.m, self.n);
        if m == 0 || n == 0 {
            return f64::INFINITY;
        }
        let rows = self.nearest_bound();
        let columns: f64 = (0..n)
            .map(|j| {
                (0..m)
                    .map(|i| self.cost[i * n + j])
                    .fold(f64::INFINITY, f64::min)
            })
            .sum::<f64>()
            / n as f64;
        penalty(m, n, params) * rows.max(columns)
    }

    /// Each of `P`'s features at its nearest of `Q`, mean over `P`: the cost of moving `P`'s
    /// mass with `Q`'s capacities ignored, so a lower bound on [`part_in`] (and one half of
    /// [`CostMatrix::relaxed_bound`]).
    pub fn nearest_bound(&self) -> f64 {
        if self.m == 0 || self.n == 0 {
            return f64::INFINITY;
        }
        self.cost
            .chunks_exact(self.n)
            .map(|row| row.iter().copied().fold(f64::INFINITY, f64::min))
            .sum::<f64>()
            / self.m as f64
    }
}

/// How far part `P` is from being a part of model `Q` (`crate::partial`): each of `P`'s `m` features
/// carries mass `1/m`, all of it moves, and each of `Q`'s `n` features takes at most
/// `1/min(m, n)` — as much as one of `P`'s while `Q` has features enough, so `Q`'s surplus
/// (the rest of the model) stays unmatched at no cost, and no count penalty. With Eq. 12's
/// weights `1/n` on `Q`, a part would have to match the whole model. When `n < m` this is the
/// plain EMD. Infinite when either side has no features.
pub fn part_in(costs: &CostMatrix) -> f64 {
    let (m, n) = (costs.m, costs.n);
    if m == 0 || n == 0 {
        return f64::INFINITY;
    }
    if n <= m {
        return emd_matrix(&vec![n as u64; m], &vec![m as u64; n], &costs.cost);
    }
    // One unit per feature of `P` and of `Q`, and a free source of the `n − m` units `Q`
    // does not take from `P`: a balanced problem over `n` units, of which `P` moves `m`.
    let mut cost = costs.cost.clone();
    cost.extend(std::iter::repeat_n(0.0, n));
    let mut supply = vec![1; m];
    supply.push((n - m) as u64);
    emd_matrix(&supply, &vec![1; n], &cost) * n as f64 / m as f64
}

/// A lower bound on [`part_in`] from the summaries' projections: every unit of `part`'s mass
/// moves at least to the nearest of `model`'s features along each 1-Lipschitz projection
/// (see [`lower_bound`]). Both summaries must have been built with the same `W`.
pub fn part_bound(part: &Summary, model: &Summary) -> f64 {
    if part.count == 0 || model.count == 0 {
        return f64::INFINITY;
    }
    part.projections()
        .zip(model.projections())
        .map(|(a, b)| nearest_1d(a, b))
        .fold(0.0, f64::max)
}

/// Mean over `a` of the distance to the nearest value of `b`, both sorted: one merge.
fn nearest_1d(a: &[f64], b: &[f64]) -> f64 {
    let mut j = 0;
    let total: f64 = a
        .iter()
        .map(|&x| {
            while j + 1 < b.len() && b[j + 1] <= x {
                j += 1;
            }
            let below = (x - b[j]).abs();
            b.get(j + 1).map_or(below, |&y| below.min((y - x).abs()))
        })
        .sum();
    total / a.len() as f64
}

/// [`compare`] from precomputed ground distances.
pub fn compare_costs(costs: &CostMatrix, params: &SimilarityParams) -> Similarity {
    let (m, n) = (costs.m, costs.n);
    let emd = if m == 0 || n == 0 {
        f64::INFINITY
    } else {
        emd_matrix(&vec![n as u64; m], &vec![m as u64; n], &costs.cost)
    };
    costs.similarity(emd, params)
}

/// Which salient feature of `P` was matched to which of `Q`: one flow of the optimal EMD
/// plan (Eq. 9), its mass (the masses sum to 1) and its ground distance (Eq. 11).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Match {
    pub p: usize,
    pub q: usize,
    pub mass: f64,
    pub ground_distance: f64,
}

/// [`compare`] and the matches behind it, for explaining a result. No matches when either
/// side has no features.
pub fn explain(
    p: &Signature,
    q: &Signature,
    params: &SimilarityParams,
) -> (Similarity, Vec<Match>) {
    explain_features(
        &Features::of(&p.features),
        &Features::of(&q.features),
        params,
    )
}

/// [`explain`] of features in their compared form.
pub fn explain_features(
    p: &Features,
    q: &Features,
    params: &SimilarityParams,
) -> (Similarity, Vec<Match>) {
    let costs = CostMatrix::new(p, q, params);
    let (m, n) = (costs.m, costs.n);
    if m == 0 || n == 0 {
        return (costs.similarity(f64::INFINITY, params), Vec::new());
    }
    let (emd, flows) = emd_flows(&vec![n as u64; m], &vec![m as u64; n], &costs.cost);
    let matches = flows
        .into_iter()
        .map(|f| Match {
            p: f.from,
            q: f.to,
            mass: f.mass,
            ground_distance: costs.cost[f.from * n + f.to],
        })
        .collect();
    (costs.similarity(emd, params), matches)
}

/// What [`lower_bound`] needs of a signature beside its [`Features::centroid`], computed once
/// per stored model: per projection (four) the features' scalar projections, sorted, in one
/// allocation.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Summary {
    count: usize,
    values: Box<[f64]>,
}

/// Projections a [`Summary`] keeps per feature: [`projections`]' three and their sum.
const PROJECTIONS: usize = 4;

impl Summary {
    /// Salient features summarised.
    pub fn features(&self) -> usize {
        self.count
    }

    fn projections(&self) -> impl Iterator<Item = &[f64]> {
        self.values.chunks_exact(self.count.max(1))
    }
}

/// A model's feature means in single precision, ECC then region D2, and its feature count
/// ([`Features::centroid`]): the half of [`lower_bound`] a first pass over every entry can
/// afford ([`centroid_bound`]).
pub type Centroid<'a> = (&'a [f32], &'a [f32], usize);

impl Features {
    /// The feature means, ECC then region D2 (summed in double precision, kept in single:
    /// an index keeps them for every entry).
    pub fn centroid(&self) -> (Vec<f32>, Vec<f32>) {
        let single = |v: Vec<f64>| v.into_iter().map(|x| x as f32).collect();
        (
            single(mean(self, |f| f.0, 1.0)),
            single(mean(self, |f| f.1, BIN_SCALE)),
        )
    }
}

/// Absolute slack of [`centroid_bound`] for its single-precision means: each mean is off by
/// at most ~6e-8 of its value (ECC values are a few radians, D2 bins at most 1), so 64 bins
/// and 10 waves of such errors stay far below it.
const CENTROID_SLACK: f64 = 1e-5;

/// The centroid half of [`lower_bound`], less [`CENTROID_SLACK`] for its single-precision
/// means.
pub fn centroid_bound(p: Centroid, q: Centroid, params: &SimilarityParams) -> f64 {
    let sums = (lane_sum(p.0, q.0, SQUARED), lane_sum(p.1, q.1, ABSOLUTE));
    centroid_of(p, sums, q.2, params)
}

/// Never above [`centroid_bound`] of `p` and any centroid in the boxes `spans` (ECC, region
/// D2) whose count is in `counts`: the sums are [`Span::lane_sum`]'s, and the penalty,
/// growing with the counts' ratio (its power is never negative), is the nearest count's.
pub fn centroid_span_bound(
    p: Centroid,
    (ecc, d2): (&Span, &Span),
    (least, greatest): (usize, usize),
    params: &SimilarityParams,
) -> f64 {
    let sums = (ecc.lane_sum(p.0, SQUARED), d2.lane_sum(p.1, ABSOLUTE));
    centroid_of(p, sums, p.2.max(least).min(greatest), params)
}

const SQUARED: fn(f32, f32) -> f32 = |a, b| (a - b) * (a - b);
const ABSOLUTE: fn(f32, f32) -> f32 = |a, b| (a - b).abs();

/// [`centroid_bound`] from its sums of squared ECC and absolute D2 differences, and the
/// other side's count.
fn centroid_of(p: Centroid, (ecc, d2): (f64, f64), count: usize, params: &SimilarityParams) -> f64 {
    let w = params.ecc_weight;
    let ecc = (ecc / p.0.len().max(1) as f64).sqrt();
    let d2 = d2 / 2.0;
    let centroid = w * ecc + (1.0 - w) * d2 - CENTROID_SLACK;
    penalty(p.2, count, params) * centroid.max(0.0)
}

/// Scalar projections of a feature, each 1-Lipschitz for the ground distance before its weight
/// is applied: `|u·Δα| ≤ ‖Δα‖₂` for a unit `u` (scaled by `1/√N` like `d_ECC`), and
/// `½|c·Δh| ≤ ½‖Δh‖₁` for `|c_k| ≤ 1`. Mean ECC, ECC slope across the waves, and mean D2 distance
/// (bin centres mapped to [-1, 1]).
fn projections((ecc, d2): (&[f32], &[u16])) -> [(f64, f64); 3] {
    let n = ecc.len().max(1) as f64;
    let mean = ecc.iter().map(|&a| a as f64).sum::<f64>() / n; // u = 1/√N: (u·α)/√N = mean
    let centre = (n - 1.0) / 2.0;
    let spread = (0..ecc.len())
        .map(|i| (i as f64 - centre).powi(2))
        .sum::<f64>()
        .sqrt()
        .max(1e-12);
    let slope = ecc
        .iter()
        .enumerate()
        .map(|(i, &a)| (i as f64 - centre) / spread * a as f64)
        .sum::<f64>()
        / n.sqrt();
    let bins = d2.len().max(1) as f64;
    let distance = d2
        .iter()
        .enumerate()
        .map(|(k, &h)| (2.0 * k as f64 + 1.0 - bins) / bins * (h as f64 / BIN_SCALE))
        .sum::<f64>()
        / 2.0;
    // (ECC part, D2 part) of each projection; the weight W combines them at query time.
    [(mean, 0.0), (slope, 0.0), (0.0, distance)]
}

impl Summary {
    pub fn of(features: &Features, params: &SimilarityParams) -> Self {
        let count = features.len();
        let w = params.ecc_weight;
        let per_feature: Vec<[(f64, f64); 3]> = features.each().map(projections).collect();
        let mut projected: Vec<Vec<f64>> = (0..3)
            .map(|k| {
                per_feature
                    .iter()
                    .map(|p| w * p[k].0 + (1.0 - w) * p[k].1)
                    .collect()
            })
            .collect();
        // Mean ECC and mean D2 distance together: d ≥ |Δφ_ecc| + |Δφ_d2| ≥ |Δ(φ_ecc + φ_d2)|.
        projected.push(
            per_feature
                .iter()
                .map(|p| w * p[0].0 + (1.0 - w) * p[2].1)
                .collect(),
        );
        for values in &mut projected {
            values.sort_by(f64::total_cmp);
        }
        debug_assert_eq!(projected.len(), PROJECTIONS);
        Self {
            count,
            values: projected.into_iter().flatten().collect(),
        }
    }
}

/// The mean over `features` of one of their vectors, each value divided by `unit`.
fn mean<'a, T: Copy + Into<f64> + 'a>(
    features: &'a Features,
    get: impl Fn((&'a [f32], &'a [u16])) -> &'a [T],
    unit: f64,
) -> Vec<f64> {
    let len = features.each().next().map_or(0, |f| get(f).len());
    let mut sum = vec![0.0; len];
    for f in features.each() {
        for (s, &x) in sum.iter_mut().zip(get(f)) {
            *s += x.into();
        }
    }
    sum.into_iter()
        .map(|s| s / unit / features.len().max(1) as f64)
        .collect()
}

/// A lower bound on [`compare`]'s `sim`, from two facts about the EMD with equal total masses
/// (Rubner et al. 2000, §4.2; Villani, *Optimal Transport*, ch. 6):
/// - the ground distance is a norm of the feature difference (a weighted sum of an L2 and an L1
///   norm on separate parts), so by convexity
///   `EMD(P, Q) = Σ f_ij d(p_i − q_j) ≥ d(Σ f_ij (p_i − q_j)) = d(mean P − mean Q)`;
/// - mapping features through a 1-Lipschitz scalar projection cannot increase the EMD, and in
///   one dimension the EMD is exact in O(m + n) from sorted values.
///
/// The larger of these, times the penalty (which multiplies both sides); the first from
/// single-precision means ([`centroid_bound`]). Both summaries must have been built with the
/// same `W` as `params`.
pub fn lower_bound(
    p: (&Summary, Centroid),
    q: (&Summary, Centroid),
    params: &SimilarityParams,
) -> f64 {
    let projected =
        p.0.projections()
            .zip(q.0.projections())
            .map(|(a, b)| emd_1d(a, b))
            .fold(0.0, f64::max);
    centroid_bound(p.1, q.1, params).max(penalty(p.0.count, q.0.count, params) * projected)
}

/// EMD between two sorted samples on the line with uniform weights: the area between their
/// quantile functions, walked breakpoint by breakpoint (integer arithmetic on `i·n` vs `j·m`
/// keeps the breakpoints exact).
fn emd_1d(a: &[f64], b: &[f64]) -> f64 {
    let (m, n) = (a.len(), b.len());
    if m == 0 || n == 0 {
        return 0.0;
    }
    let (mut i, mut j, mut t, mut total) = (0, 0, 0usize, 0.0);
    while i < m && j < n {
        let (next_a, next_b) = ((i + 1) * n, (j + 1) * m);
        let next = next_a.min(next_b);
        total += (next - t) as f64 * (a[i] - b[j]).abs();
        t = next;
        if next_a == next {
            i += 1;
        }
        if next_b == next {
            j += 1;
        }
    }
    total / (m * n) as f64
}

#[cfg(test)]
mod tests {
    use super::{emd_1d, nearest_1d};

    #[test]
    fn nearest_by_hand() {
        assert_eq!(nearest_1d(&[0.0], &[1.0]), 1.0);
        // 0 → 0, 1.4 → 2 (0.6), 5 → 2 (3).
        assert!((nearest_1d(&[0.0, 1.4, 5.0], &[-1.0, 0.0, 2.0]) - 3.6 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn one_dimensional_emd_by_hand() {
        assert_eq!(emd_1d(&[0.0], &[1.0]), 1.0);
        assert_eq!(emd_1d(&[0.0, 1.0], &[0.0, 1.0]), 0.0);
        // Half the mass moves 1, the other half 0: 0.5.
        assert_eq!(emd_1d(&[0.0, 1.0], &[1.0]), 0.5);
        // Quantiles 1/3 and 2/3 against 1/2: |0−0|·1/3 + |1−0|·1/6 + |1−2|·1/6 + |2−2|·1/3.
        assert!((emd_1d(&[0.0, 1.0, 2.0], &[0.0, 2.0]) - 1.0 / 3.0).abs() < 1e-12);
    }
}

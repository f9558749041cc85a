//! Ranking a collection against a query (SPEC §5): every entry by distance ascending, ties
//! broken by id, the top `k` returned.
//!
//! For the ECC method most entries never need their EMD solved: the centroid lower bound
//! ([`crate::similarity::lower_bound`]) is computed for all, entries are visited in order of
//! their bound, and the visit stops once the next bound exceeds the k-th best distance found.
//! Because the bound never exceeds the true distance, this returns exactly the top `k` of a
//! full scan. The LFD method is ranked the same way with its own bound
//! ([`crate::descriptor::lfd::LfdSummary`]), and the hybrid with the weighted sum of its
//! parts' bounds ([`fuse`]).

use std::fmt;
use std::str::FromStr;
use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::descriptor::geodesic::Cumulative;
use crate::descriptor::lfd::LfdSummary;
use crate::descriptor::{GeodesicDescriptor, LightFieldDescriptor};
use crate::params::{HybridParams, SimilarityParams};
use crate::signature::Signature;
use crate::similarity::{compare, compare_costs, d2_distance, lower_bound, CostMatrix, Summary};

/// How two models are compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// The default: a weighted sum of the other methods' distances, each divided by a fixed
    /// scale (SPEC §9, [`fuse`]).
    #[default]
    Hybrid,
    /// Salient ECC + region D2 features under the penalised EMD (SPEC §5).
    Ecc,
    /// The global D2 shape distribution baseline (SPEC §6).
    D2,
    /// The Light Field Descriptor baseline (SPEC §6).
    Lfd,
    /// The geodesic distance distributions ([`crate::descriptor::GeodesicDescriptor`]).
    Geodesic,
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Method::Hybrid => "hybrid",
            Method::Ecc => "ecc",
            Method::D2 => "d2",
            Method::Lfd => "lfd",
            Method::Geodesic => "geodesic",
        })
    }
}

impl FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Method::ALL
            .into_iter()
            .find(|m| m.to_string().eq_ignore_ascii_case(s))
            .ok_or_else(|| {
                format!("unknown method `{s}` (expected hybrid, ecc, d2, lfd or geodesic)")
            })
    }
}

/// Distance between two signatures under `method`; infinite for [`Method::Lfd`] when either
/// signature predates the light field descriptor (see [`Method::comparable`]).
pub fn distance(method: Method, p: &Signature, q: &Signature, params: &SimilarityParams) -> f64 {
    match method {
        Method::Hybrid => fuse(&params.hybrid, hybrid_parts(p, q, params)),
        Method::Ecc => compare(p, q, params).sim,
        Method::D2 => d2_distance(p, q),
        Method::Lfd => lfd_distance(p, q).unwrap_or(f64::INFINITY),
        Method::Geodesic => geodesic_distance(p, q).unwrap_or(f64::INFINITY),
    }
}

/// The hybrid's parts, in the order of [`fuse`]'s arguments.
pub const PARTS: [Method; 4] = [Method::Ecc, Method::D2, Method::Lfd, Method::Geodesic];

/// The hybrid's part distances ([`PARTS`]): `None` for a part one side lacks or the hybrid
/// does not weigh.
pub fn hybrid_parts(p: &Signature, q: &Signature, params: &SimilarityParams) -> [Option<f64>; 4] {
    let h = &params.hybrid;
    let ecc =
        (h.ecc.weight > 0.0 && has_features(p, q)).then(|| compare(p, q, &params.hybrid_ecc()).sim);
    [
        ecc,
        Some(d2_distance(p, q)),
        hybrid_lfd(h, p, q),
        geodesic_distance(p, q),
    ]
}

/// Whether both signatures have salient features, without which the EMD is undefined.
fn has_features(p: &Signature, q: &Signature) -> bool {
    !p.features.is_empty() && !q.features.is_empty()
}

/// The geodesic distance when both have the descriptor.
fn geodesic_distance(p: &Signature, q: &Signature) -> Option<f64> {
    Some(p.geodesic.as_ref()?.distance(q.geodesic.as_ref()?))
}

/// The LFD distance when both have the descriptor.
fn lfd_distance(p: &Signature, q: &Signature) -> Option<f64> {
    Some(p.lfd.as_ref()?.distance(q.lfd.as_ref()?))
}

/// The LFD part of the hybrid, computed only when it weighs anything.
fn hybrid_lfd(h: &HybridParams, p: &Signature, q: &Signature) -> Option<f64> {
    (h.lfd.weight > 0.0).then(|| lfd_distance(p, q)).flatten()
}

/// The hybrid distance `Σ wᵢ · dᵢ / sᵢ` over the [`PARTS`] (SPEC §9), from each
/// part's distance, or from a lower bound of each: the sum grows with every part, so bounds
/// of the parts make a bound of the sum. A part missing on either side (`None`) is left out
/// and the others are scaled up to the full weight, so a model stored before a descriptor
/// existed is still ranked, on what it has (responses count such models as `partial`).
pub fn fuse(h: &HybridParams, parts: [Option<f64>; 4]) -> f64 {
    let terms = contributions(h, parts);
    if terms.iter().all(Option::is_none) {
        return f64::INFINITY;
    }
    terms.into_iter().flatten().sum()
}

/// Each part's term of [`fuse`]'s sum ([`PARTS`]), `None` for a part left out: what a
/// result's explanation shows.
pub fn contributions(h: &HybridParams, parts: [Option<f64>; 4]) -> [Option<f64>; 4] {
    let terms = h.terms();
    let weighed = |k: usize| terms[k].weight > 0.0;
    let total: f64 = (0..4)
        .filter(|&k| weighed(k))
        .map(|k| terms[k].weight)
        .sum();
    let used: f64 = (0..4)
        .filter(|&k| weighed(k) && parts[k].is_some())
        .map(|k| terms[k].weight)
        .sum();
    std::array::from_fn(|k| {
        let d = parts[k].filter(|_| weighed(k))?;
        Some(terms[k].weight * d / terms[k].scale * (total / used))
    })
}

impl Method {
    pub const ALL: [Method; 5] = [
        Method::Hybrid,
        Method::Ecc,
        Method::D2,
        Method::Lfd,
        Method::Geodesic,
    ];

    /// Whether `signature` holds what this method compares.
    pub fn comparable(self, signature: &Signature) -> bool {
        match self {
            Method::Lfd => signature.lfd.is_some(),
            Method::Geodesic => signature.geodesic.is_some(),
            Method::Hybrid | Method::Ecc | Method::D2 => true,
        }
    }

    /// Whether this method compares salient features, so that a query needs its ECC
    /// ([`crate::pipeline::Extent`]): the ECC method, and the hybrid while its ECC part
    /// weighs anything.
    pub fn compares_features(self, params: &SimilarityParams) -> bool {
        match self {
            Method::Ecc => true,
            Method::Hybrid => params.hybrid.ecc.weight > 0.0,
            Method::D2 | Method::Lfd | Method::Geodesic => false,
        }
    }

    /// Whether `signature` holds every part this method weighs; a comparable signature
    /// that is not complete is ranked on part of the distance (see [`fuse`]).
    pub fn complete(self, signature: &Signature) -> bool {
        match self {
            Method::Hybrid => PARTS.iter().all(|m| m.comparable(signature)),
            _ => self.comparable(signature),
        }
    }
}

/// One ranked result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Hit {
    pub id: String,
    pub distance: f64,
}

/// The top `k` and how much work finding them took.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Ranking {
    pub hits: Vec<Hit>,
    /// Entries whose exact distance was computed.
    pub evaluated: usize,
    /// Entries rejected by a lower bound without solving their EMD.
    pub pruned: usize,
}

/// An in-memory collection of signatures with what ranking precomputes for each.
///
/// Summaries for the lower bound depend on the ground-distance weight `W`, so an index is
/// built for one [`SimilarityParams`]. Cloning is cheap (entries are shared, the id map is
/// persistent), so the service publishes a changed copy instead of locking.
#[derive(Debug, Clone)]
pub struct Index {
    params: SimilarityParams,
    entries: Vec<Arc<Entry>>,
    position: imbl::HashMap<Arc<str>, usize>,
}

#[derive(Debug)]
struct Entry {
    id: Arc<str>,
    signature: Arc<Signature>,
    summary: Summary,
    /// The LFD bound's side of this model and the geodesic descriptor as it is compared, kept
    /// beside the entry: both run for every entry of a hybrid ranking.
    lfd: Option<LfdSummary>,
    geodesic: Option<Cumulative>,
}

/// Entries whose exact distances are computed together (in parallel) between bound checks.
const BATCH: usize = 64;

/// Entries put in bound order at a time by the pruned ranking (a multiple of [`BATCH`]).
const SORTED: usize = 16 * BATCH;

impl Index {
    pub fn new(params: SimilarityParams) -> Self {
        Self {
            params,
            entries: Vec::new(),
            position: imbl::HashMap::new(),
        }
    }

    /// Adds an entry, replacing one with the same id.
    pub fn insert(&mut self, id: impl Into<Arc<str>>, signature: impl Into<Arc<Signature>>) {
        let (id, signature) = (id.into(), signature.into());
        let summary = Summary::of(&signature, &self.params);
        let entry = Arc::new(Entry {
            id: id.clone(),
            lfd: signature.lfd.as_ref().map(LightFieldDescriptor::summary),
            geodesic: signature
                .geodesic
                .as_ref()
                .map(GeodesicDescriptor::cumulative),
            signature,
            summary,
        });
        match self.position.get(&id) {
            Some(&i) => self.entries[i] = entry,
            None => {
                self.position.insert(id, self.entries.len());
                self.entries.push(entry);
            }
        }
    }

    /// Removes an entry; returns whether it was there.
    pub fn remove(&mut self, id: &str) -> bool {
        let Some(i) = self.position.remove(id) else {
            return false;
        };
        self.entries.swap_remove(i);
        if let Some(moved) = self.entries.get(i) {
            self.position.insert(moved.id.clone(), i);
        }
        true
    }

    /// The signature stored under `id`.
    pub fn get(&self, id: &str) -> Option<&Arc<Signature>> {
        self.position.get(id).map(|&i| &self.entries[i].signature)
    }

    /// The parameters the index compares with.
    pub fn params(&self) -> &SimilarityParams {
        &self.params
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The `k` entries nearest to `query`, nearest first, ties by id.
    pub fn search(&self, query: &Signature, k: usize, method: Method) -> Ranking {
        self.search_where(query, k, method, &|_| true)
    }

    /// [`Index::search`] over the entries whose id `keep` accepts (a tag filter, or "not the
    /// query itself"). Entries left out count neither as evaluated nor as pruned.
    pub fn search_where(
        &self,
        query: &Signature,
        k: usize,
        method: Method,
        keep: &(dyn Fn(&str) -> bool + Sync),
    ) -> Ranking {
        match method {
            Method::Hybrid => self.search_hybrid(query, k, keep),
            Method::Ecc => self.search_ecc(query, k, keep),
            Method::Lfd => self.search_lfd(query, k, keep),
            // A histogram distance costs less than any bound would.
            Method::D2 | Method::Geodesic => self.exhaustive(query, k, method, &self.params, keep),
        }
    }

    /// Entries `keep` accepts that `method` cannot compare (see [`Method::comparable`]): they
    /// are left out of its rankings until re-extracted, and responses say how many.
    pub fn incomparable(&self, method: Method, keep: &(dyn Fn(&str) -> bool + Sync)) -> usize {
        self.entries
            .iter()
            .filter(|e| !method.comparable(&e.signature) && keep(&e.id))
            .count()
    }

    /// Entries `keep` accepts that `method` ranks on part of its distance only (see
    /// [`Method::complete`]); they are re-extracted in the background, and responses say how
    /// many.
    pub fn partial(&self, method: Method, keep: &(dyn Fn(&str) -> bool + Sync)) -> usize {
        self.entries
            .iter()
            .filter(|e| {
                method.comparable(&e.signature) && !method.complete(&e.signature) && keep(&e.id)
            })
            .count()
    }

    /// [`Index::search_where`] with other similarity parameters than the index was built for
    /// (a query-time `W`): the bounds' summaries do not hold for them, so this ranks
    /// exhaustively unless the parameters are the index's own.
    pub fn search_with(
        &self,
        query: &Signature,
        k: usize,
        method: Method,
        params: &SimilarityParams,
        keep: &(dyn Fn(&str) -> bool + Sync),
    ) -> Ranking {
        if matches!(method, Method::D2 | Method::Lfd | Method::Geodesic) || *params == self.params {
            return self.search_where(query, k, method, keep);
        }
        self.exhaustive(query, k, method, params, keep)
    }

    /// Every entry's exact distance, no pruning: the reference the pruned search must match.
    /// Entries the method cannot compare (see [`Method::comparable`]) are left out.
    pub fn search_exhaustive(&self, query: &Signature, k: usize, method: Method) -> Ranking {
        self.exhaustive(query, k, method, &self.params, &|_| true)
    }

    fn exhaustive(
        &self,
        query: &Signature,
        k: usize,
        method: Method,
        params: &SimilarityParams,
        keep: &(dyn Fn(&str) -> bool + Sync),
    ) -> Ranking {
        let mut scored: Vec<(f64, usize)> = self
            .entries
            .par_iter()
            .enumerate()
            .filter(|(_, e)| keep(&e.id) && method.comparable(&e.signature))
            .map(|(i, e)| (distance(method, query, &e.signature, params), i))
            .collect();
        let evaluated = scored.len();
        let top = self.smallest(&mut scored, k);
        Ranking {
            hits: top
                .iter()
                .map(|&(distance, i)| Hit {
                    id: self.entries[i].id.to_string(),
                    distance,
                })
                .collect(),
            evaluated,
            pruned: 0,
        }
    }

    /// SPEC §5 ranking with the ECC bounds: the centroid/projection bound for every entry,
    /// then the relaxed-EMD bound from the cost matrix, which the exact EMD reuses.
    fn search_ecc(
        &self,
        query: &Signature,
        k: usize,
        keep: &(dyn Fn(&str) -> bool + Sync),
    ) -> Ranking {
        let params = &self.params;
        let summary = Summary::of(query, params);
        self.pruned(
            k,
            |e| keep(&e.id),
            |e| lower_bound(&summary, &e.summary, params),
            |e, kth| {
                let costs = CostMatrix::new(query, &e.signature, params);
                (costs.relaxed_bound(params) <= kth).then(|| compare_costs(&costs, params).sim)
            },
        )
    }

    /// The hybrid's ranking: each entry's bound is the fused bounds of its parts (the ECC's
    /// centroid/projection bound, the exact D2 and geodesic distances, which cost less than a
    /// bound, and the LFD's bound); an entry past the bound is rejected by the fused
    /// relaxed-EMD bound before its EMD is solved.
    fn search_hybrid(
        &self,
        query: &Signature,
        k: usize,
        keep: &(dyn Fn(&str) -> bool + Sync),
    ) -> Ranking {
        let h = &self.params.hybrid;
        // The summaries depend on `W` only, which the hybrid's ECC part shares.
        let params = &self.params.hybrid_ecc();
        let summary = Summary::of(query, params);
        let lfd_summary = query.lfd.as_ref().map(|d| d.summary());
        let lfd_bound = |e: &Entry| match (&lfd_summary, &e.lfd) {
            (Some(q), Some(s)) if h.lfd.weight > 0.0 => Some(q.lower_bound(s)),
            _ => None,
        };
        // Left out (as `fuse` would leave it) when it weighs nothing, as in the defaults.
        let d2 = |e: &Entry| (h.d2.weight > 0.0).then(|| d2_distance(query, &e.signature));
        let query_geodesic = query.geodesic.as_ref().map(GeodesicDescriptor::cumulative);
        let geodesic = |e: &Entry| Some(query_geodesic.as_ref()?.distance(e.geodesic.as_ref()?));
        // From the entry's summary, not its signature: this runs for every entry, and the
        // signature is another cache miss away.
        let with_ecc = |e: &Entry| {
            h.ecc.weight > 0.0 && !query.features.is_empty() && e.summary.features() > 0
        };
        // Cheapest first: the relaxed EMD with the LFD's bound, then with its distance
        // (~50 µs), and only then the EMD itself.
        let exact = |e: &Entry, kth: f64| {
            let (d2, geodesic) = (d2(e), geodesic(e));
            let costs = with_ecc(e).then(|| CostMatrix::new(query, &e.signature, params));
            let relaxed = costs.as_ref().map(|c| c.relaxed_bound(params));
            if fuse(h, [relaxed, d2, lfd_bound(e), geodesic]) > kth {
                return None;
            }
            let lfd = hybrid_lfd(h, query, &e.signature);
            if fuse(h, [relaxed, d2, lfd, geodesic]) > kth {
                return None;
            }
            let ecc = costs.map(|c| compare_costs(&c, params).sim);
            Some(fuse(h, [ecc, d2, lfd, geodesic]))
        };

        // The ECC bound costs about as much as the other parts' together, so it is computed
        // only for entries that a coarse bound (the ECC part at 0, which `fuse` keeps a lower
        // bound) does not reject against the k-th distance among the k entries of least
        // coarse bound: a real k-th distance, so never below the true one.
        let coarse = |e: &Entry| {
            let ecc = with_ecc(e).then_some(0.0);
            fuse(h, [ecc, d2(e), lfd_bound(e), geodesic(e)])
        };
        let mut coarse_order: Vec<(f64, usize)> = self
            .entries
            .par_iter()
            .enumerate()
            .filter(|(_, e)| keep(&e.id))
            .map(|(i, e)| (coarse(e), i))
            .collect();
        let mut seeds: Vec<f64> = self
            .smallest(&mut coarse_order, k)
            .par_iter()
            .filter_map(|&(_, i)| exact(&self.entries[i], f64::INFINITY))
            .collect();
        seeds.sort_by(f64::total_cmp);
        let kth = seeds
            .get(k.wrapping_sub(1))
            .copied()
            .unwrap_or(f64::INFINITY);
        let order: Vec<(f64, usize)> = coarse_order
            .par_iter()
            .filter(|(bound, _)| *bound <= kth)
            .map(|&(_, i)| {
                let e = &self.entries[i];
                let ecc = with_ecc(e).then(|| lower_bound(&summary, &e.summary, params));
                (fuse(h, [ecc, d2(e), lfd_bound(e), geodesic(e)]), i)
            })
            .collect();
        let rejected = coarse_order.len() - order.len();
        self.refine(k, order, rejected, exact)
    }

    /// Light field ranking with [`crate::descriptor::lfd::LfdSummary::lower_bound`]; entries without a descriptor are
    /// left out (see [`Method::comparable`]), and a query without one ranks nothing.
    fn search_lfd(
        &self,
        query: &Signature,
        k: usize,
        keep: &(dyn Fn(&str) -> bool + Sync),
    ) -> Ranking {
        let Some(query) = &query.lfd else {
            // Nothing to compare with: no entry is ranked (callers check `comparable`).
            return Ranking {
                hits: Vec::new(),
                evaluated: 0,
                pruned: 0,
            };
        };
        let summary = query.summary();
        fn descriptor(e: &Entry) -> &LightFieldDescriptor {
            e.signature.lfd.as_ref().expect("kept entries have one")
        }
        self.pruned(
            k,
            |e| keep(&e.id) && e.lfd.is_some(),
            |e| summary.lower_bound(e.lfd.as_ref().expect("kept entries have one")),
            |e, _| Some(query.distance(descriptor(e))),
        )
    }

    /// Top `k` of the entries `keep` accepts, visiting them in order of `bound` (a lower bound
    /// on the distance) and stopping once the next bound exceeds the k-th best distance;
    /// `exact(entry, kth)` is the distance, or `None` when it can tell cheaply that it exceeds
    /// `kth`. The result equals a full scan's.
    fn pruned(
        &self,
        k: usize,
        keep: impl Fn(&Entry) -> bool + Sync,
        bound: impl Fn(&Entry) -> f64 + Sync,
        exact: impl Fn(&Entry, f64) -> Option<f64> + Sync,
    ) -> Ranking {
        let order: Vec<(f64, usize)> = self
            .entries
            .par_iter()
            .enumerate()
            .filter(|(_, e)| keep(e))
            .map(|(i, e)| (bound(e), i))
            .collect();
        self.refine(k, order, 0, exact)
    }

    /// The visit of [`Index::pruned`]: `order` holds each candidate's lower bound and entry;
    /// `rejected` more entries were already rejected by a bound (they count as pruned).
    fn refine(
        &self,
        k: usize,
        mut order: Vec<(f64, usize)>,
        rejected: usize,
        exact: impl Fn(&Entry, f64) -> Option<f64> + Sync,
    ) -> Ranking {
        if k == 0 {
            return Ranking {
                hits: Vec::new(),
                evaluated: 0,
                pruned: rejected + order.len(),
            };
        }
        let mut best: Vec<Hit> = Vec::with_capacity(k + BATCH);
        let (mut evaluated, mut visited, mut sorted) = (0, 0, 0);
        while visited < order.len() {
            // Only the visited prefix needs sorting, and the visit rarely goes far: sort a
            // chunk at a time, each the smallest of what is left.
            if visited == sorted {
                sorted += self.smallest(&mut order[sorted..], SORTED).len();
            }
            let batch = &order[visited..(visited + BATCH).min(sorted)];
            visited += batch.len();
            // An entry whose bound equals the k-th distance may still tie with it and win by
            // id, so only a strictly larger bound is rejected.
            let kth = if best.len() >= k {
                best[k - 1].distance
            } else {
                f64::INFINITY
            };
            let live: Vec<usize> = batch
                .iter()
                .take_while(|(b, _)| *b <= kth)
                .map(|&(_, i)| i)
                .collect();
            if live.is_empty() {
                break;
            }
            let solved: Vec<Hit> = live
                .par_iter()
                .filter_map(|&i| {
                    let entry = &self.entries[i];
                    exact(entry, kth).map(|distance| Hit {
                        id: entry.id.to_string(),
                        distance,
                    })
                })
                .collect();
            evaluated += solved.len();
            best.extend(solved);
            sort_hits(&mut best);
            best.truncate(k);
            if live.len() < batch.len() {
                break;
            }
        }
        Ranking {
            hits: best,
            evaluated,
            pruned: rejected + order.len() - evaluated,
        }
    }

    /// Moves the `k` smallest of `scored` (by score, ties by id) to its front, sorted, and
    /// returns them: a selection then a sort of `k`, not a sort of all.
    fn smallest<'a>(&self, scored: &'a mut [(f64, usize)], k: usize) -> &'a [(f64, usize)] {
        let order = |a: &(f64, usize), b: &(f64, usize)| {
            a.0.total_cmp(&b.0)
                .then_with(|| self.entries[a.1].id.cmp(&self.entries[b.1].id))
        };
        let k = k.min(scored.len());
        if k < scored.len() && k > 0 {
            scored.select_nth_unstable_by(k - 1, order);
        }
        scored[..k].sort_unstable_by(order);
        &scored[..k]
    }
}

fn sort_hits(hits: &mut [Hit]) {
    hits.sort_by(|a, b| {
        a.distance
            .total_cmp(&b.distance)
            .then_with(|| a.id.cmp(&b.id))
    });
}

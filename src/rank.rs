//! Ranking a collection against a query (SPEC §5): every entry by distance ascending, ties
//! broken by id, the top `k` returned.
//!
//! For the ECC method most entries never need their EMD solved: the centroid lower bound
//! ([`crate::similarity::lower_bound`]) is computed for all, entries are visited in order of
//! their bound, and the visit stops once the next bound exceeds the k-th best distance found.
//! Because the bound never exceeds the true distance, this returns exactly the top `k` of a
//! full scan. The LFD method is ranked the same way with its own bound
//! ([`crate::descriptor::lfd::LfdSummary`]).

use std::fmt;
use std::str::FromStr;
use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::descriptor::LightFieldDescriptor;
use crate::params::SimilarityParams;
use crate::signature::Signature;
use crate::similarity::{compare, compare_costs, d2_distance, lower_bound, CostMatrix, Summary};

/// How two models are compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Salient ECC + region D2 features under the penalised EMD (SPEC §5).
    #[default]
    Ecc,
    /// The global D2 shape distribution baseline (SPEC §6).
    D2,
    /// The Light Field Descriptor baseline (SPEC §6).
    Lfd,
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Method::Ecc => "ecc",
            Method::D2 => "d2",
            Method::Lfd => "lfd",
        })
    }
}

impl FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "ecc" => Ok(Method::Ecc),
            "d2" => Ok(Method::D2),
            "lfd" => Ok(Method::Lfd),
            other => Err(format!(
                "unknown method `{other}` (expected ecc, d2 or lfd)"
            )),
        }
    }
}

/// Distance between two signatures under `method`; infinite for [`Method::Lfd`] when either
/// signature predates the light field descriptor (see [`Method::comparable`]).
pub fn distance(method: Method, p: &Signature, q: &Signature, params: &SimilarityParams) -> f64 {
    match method {
        Method::Ecc => compare(p, q, params).sim,
        Method::D2 => d2_distance(p, q),
        Method::Lfd => match (&p.lfd, &q.lfd) {
            (Some(a), Some(b)) => a.distance(b),
            _ => f64::INFINITY,
        },
    }
}

impl Method {
    pub const ALL: [Method; 3] = [Method::Ecc, Method::D2, Method::Lfd];

    /// Whether `signature` holds what this method compares.
    pub fn comparable(self, signature: &Signature) -> bool {
        self != Method::Lfd || signature.lfd.is_some()
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
}

/// Entries whose exact distances are computed together (in parallel) between bound checks.
const BATCH: usize = 64;

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
            Method::Ecc => self.search_ecc(query, k, keep),
            Method::Lfd => self.search_lfd(query, k, keep),
            // A D2 distance costs less than any bound would.
            Method::D2 => self.exhaustive(query, k, method, &self.params, keep),
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
        if method != Method::Ecc || *params == self.params {
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
        let mut hits: Vec<Hit> = self
            .entries
            .par_iter()
            .filter(|e| keep(&e.id) && method.comparable(&e.signature))
            .map(|e| Hit {
                id: e.id.to_string(),
                distance: distance(method, query, &e.signature, params),
            })
            .collect();
        let evaluated = hits.len();
        sort_hits(&mut hits);
        hits.truncate(k);
        Ranking {
            hits,
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
        // The summaries are recomputed rather than kept: 900 bytes an entry would cost more
        // memory than the 4 500 additions cost time (the bound is ~3 % of a distance).
        self.pruned(
            k,
            |e| keep(&e.id) && e.signature.lfd.is_some(),
            |e| summary.lower_bound(&descriptor(e).summary()),
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
        if k == 0 {
            return Ranking {
                hits: Vec::new(),
                evaluated: 0,
                pruned: self.entries.len(),
            };
        }
        let mut order: Vec<(f64, usize)> = self
            .entries
            .par_iter()
            .enumerate()
            .filter(|(_, e)| keep(e))
            .map(|(i, e)| (bound(e), i))
            .collect();
        order.par_sort_unstable_by(|a, b| {
            a.0.total_cmp(&b.0)
                .then_with(|| self.entries[a.1].id.cmp(&self.entries[b.1].id))
        });

        let mut best: Vec<Hit> = Vec::with_capacity(k + BATCH);
        let mut evaluated = 0;
        for batch in order.chunks(BATCH) {
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
            pruned: order.len() - evaluated,
        }
    }
}

fn sort_hits(hits: &mut [Hit]) {
    hits.sort_by(|a, b| {
        a.distance
            .total_cmp(&b.distance)
            .then_with(|| a.id.cmp(&b.id))
    });
}

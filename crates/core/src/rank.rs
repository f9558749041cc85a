//! Ranking a collection against a query (SPEC §5): every entry by distance ascending, ties
//! broken by id, the top `k` returned.
//!
//! Most entries never need their exact distance: entries are visited in order of a lower
//! bound (for the ECC method the centroid/projection bound of
//! [`crate::similarity::lower_bound`]), and the visit stops once the next bound exceeds the
//! k-th best distance found. Because a bound never exceeds the true distance, this returns
//! exactly the top `k` of a full scan. A cheaper bound filters first ([`Index::cascade`]):
//! computed for every entry (the ECC's centroid in single precision, the LFD's
//! [`crate::descriptor::lfd::LfdSketch`]) and compared with the k-th distance among the
//! entries it ranks first, it leaves the tighter bounds to a few. The hybrid's bounds are the
//! weighted sums of its parts' ([`fuse`]). Entries are kept by column in chunks ([`columns`]),
//! so that a pass over all of them streams through memory; the light field descriptors, read
//! only for the few candidates the bounds leave, are kept in a file (`rank/shelf.rs`).

use std::collections::HashSet;
use std::fmt;
use std::io;
use std::path::PathBuf;
use std::str::FromStr;
use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::descriptor::geodesic::Cumulative;
use crate::descriptor::lfd::LfdQuery;
use crate::descriptor::{histogram_l1, GeodesicDescriptor, LightFieldDescriptor};
use crate::params::{HybridParams, SimilarityParams};
use crate::partial::{Fit, Part};
use crate::signature::Signature;
use crate::similarity::{
    centroid_bound, centroid_span_bound, compare_costs, explain_features, lower_bound, CostMatrix,
    Features, Match, Summary,
};

mod arrange;
mod columns;
pub mod compact;
mod shelf;
pub mod vectors;

pub use columns::Row;
use columns::{BlockSpan, BLOCK};
use columns::{Columns, Entry};
pub use shelf::Fetch;
use shelf::Place;

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
/// signature predates the light field descriptor (see [`Method::ranks`]).
pub fn distance(method: Method, p: &Signature, q: &Signature, params: &SimilarityParams) -> f64 {
    let (p, q) = (Prepared::of(p), Prepared::of(q));
    compared_distance(method, p.compared(), q.compared(), params)
}

/// The hybrid's parts, in the order of [`fuse`]'s arguments.
pub const PARTS: [Method; 4] = [Method::Ecc, Method::D2, Method::Lfd, Method::Geodesic];

/// The hybrid's part distances ([`PARTS`]): `None` for a part one side lacks or the hybrid
/// does not weigh.
pub fn hybrid_parts(p: &Signature, q: &Signature, params: &SimilarityParams) -> [Option<f64>; 4] {
    let (p, q) = (Prepared::of(p), Prepared::of(q));
    parts(p.compared(), q.compared(), params)
}

/// Why `q` is at its distance from `p`: what a result's explanation shows.
#[derive(Debug, Clone, PartialEq)]
pub struct Explanation {
    /// The distance by each method that can compare the two, in [`Method::ALL`]'s order.
    pub distances: Vec<(Method, f64)>,
    /// The hybrid's terms ([`contributions`] of its [`PARTS`]).
    pub contributions: [Option<f64>; 4],
    /// The optimal EMD plan between the salient features (paper Eq. 9).
    pub matches: Vec<Match>,
}

/// The [`Explanation`] of `q`'s distance from `p`, the salient features' EMD solved once: the
/// ECC method and the hybrid's ECC part differ only by the count penalty applied to it.
pub fn explain(p: &Signature, q: &Signature, params: &SimilarityParams) -> Explanation {
    let (prepared_p, prepared_q) = (Prepared::of(p), Prepared::of(q));
    let (cp, cq) = (prepared_p.compared(), prepared_q.compared());
    let (ecc, matches) = explain_features(cp.features, cq.features, params);
    let parts = parts_with(cp, cq, params, || ecc.penalised(&params.hybrid_ecc()));
    let distance = |method: Method| match method {
        Method::Hybrid => fuse(&params.hybrid, parts),
        Method::Ecc => ecc.sim,
        other => PARTS
            .iter()
            .position(|&m| m == other)
            .and_then(|k| parts[k])
            .unwrap_or_else(|| compared_distance(other, cp, cq, params)),
    };
    Explanation {
        distances: Method::ALL
            .into_iter()
            .filter(|m| m.ranks(p) && m.ranks(q))
            .map(|m| (m, distance(m)))
            .collect(),
        contributions: contributions(&params.hybrid, parts),
        matches,
    }
}

/// What the methods compare of one model, borrowed from an index entry or from a
/// [`Prepared`] signature: one implementation of each distance serves both.
#[derive(Clone, Copy)]
struct Compared<'a> {
    features: &'a Features,
    d2: &'a [f32],
    lfd: Option<&'a LightFieldDescriptor>,
    geodesic: Option<&'a Cumulative>,
}

/// A signature with the forms of its descriptors that the methods compare.
struct Prepared<'a> {
    signature: &'a Signature,
    features: Features,
    geodesic: Option<Cumulative>,
}

impl<'a> Prepared<'a> {
    fn of(signature: &'a Signature) -> Self {
        Self {
            signature,
            features: Features::of(&signature.features),
            geodesic: signature
                .geodesic
                .as_ref()
                .map(GeodesicDescriptor::cumulative),
        }
    }

    fn compared(&self) -> Compared<'_> {
        Compared {
            features: &self.features,
            d2: &self.signature.d2,
            lfd: self.signature.lfd.as_ref(),
            geodesic: self.geodesic.as_ref(),
        }
    }
}

fn compared_distance(method: Method, p: Compared, q: Compared, params: &SimilarityParams) -> f64 {
    match method {
        Method::Hybrid => fuse(&params.hybrid, parts(p, q, params)),
        Method::Ecc => ecc_distance(p, q, params),
        Method::D2 => histogram_l1(p.d2, q.d2),
        Method::Lfd => lfd_distance(p, q).unwrap_or(f64::INFINITY),
        Method::Geodesic => geodesic_distance(p, q).unwrap_or(f64::INFINITY),
    }
}

fn parts(p: Compared, q: Compared, params: &SimilarityParams) -> [Option<f64>; 4] {
    parts_with(p, q, params, || ecc_distance(p, q, &params.hybrid_ecc()))
}

/// [`parts`] with the ECC part's distance from `ecc`, called only when the hybrid weighs it.
fn parts_with(
    p: Compared,
    q: Compared,
    params: &SimilarityParams,
    ecc: impl FnOnce() -> f64,
) -> [Option<f64>; 4] {
    let h = &params.hybrid;
    let ecc = (h.ecc.weight > 0.0 && !p.features.is_empty() && !q.features.is_empty()).then(ecc);
    let lfd = (h.lfd.weight > 0.0).then(|| lfd_distance(p, q)).flatten();
    [
        ecc,
        Some(histogram_l1(p.d2, q.d2)),
        lfd,
        geodesic_distance(p, q),
    ]
}

/// SPEC §5's `SIM(P, Q)`.
fn ecc_distance(p: Compared, q: Compared, params: &SimilarityParams) -> f64 {
    compare_costs(&CostMatrix::new(p.features, q.features, params), params).sim
}

/// The geodesic distance when both have the descriptor.
fn geodesic_distance(p: Compared, q: Compared) -> Option<f64> {
    Some(p.geodesic?.distance(q.geodesic?))
}

/// The LFD distance when both have the descriptor.
fn lfd_distance(p: Compared, q: Compared) -> Option<f64> {
    Some(p.lfd?.distance(q.lfd?))
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

/// A lower bound on [`fuse`] of any parts that agree with `parts` where these are present:
/// the terms of the present parts before [`fuse`] scales them up for the missing ones (never
/// down), each as [`contributions`] computes it, so also in floating point.
fn least_sum(h: &HybridParams, parts: [Option<f64>; 4]) -> f64 {
    let terms = h.terms();
    (0..4)
        .filter(|&k| terms[k].weight > 0.0)
        .filter_map(|k| Some(terms[k].weight * parts[k]? / terms[k].scale))
        .sum()
}

/// The largest value of part `k` for which [`fuse`] of `parts` with part `k` present stays
/// within `kth`, with a margin for rounding: a cutoff for computing that part that never
/// rejects an entry the sum itself would keep (the caller still compares the sum).
fn part_limit(h: &HybridParams, mut parts: [Option<f64>; 4], k: usize, kth: f64) -> f64 {
    parts[k] = Some(0.0);
    let base = fuse(h, parts);
    parts[k] = Some(1.0);
    let slope = fuse(h, parts) - base;
    if slope <= 0.0 || !kth.is_finite() {
        return f64::INFINITY;
    }
    (kth - base) / slope * (1.0 + 1e-9) + 1e-12
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

    /// Whether this method can rank a model that holds `held`: one that lacks the method's
    /// descriptor is left out of its rankings until it is re-extracted.
    pub fn ranks(self, held: impl Into<Held>) -> bool {
        let held = held.into();
        match self {
            Method::Lfd => held.lfd,
            Method::Geodesic => held.geodesic,
            Method::Hybrid | Method::Ecc | Method::D2 => true,
        }
    }

    /// Whether this method ranks a model that holds `held` on all of its distance; one it
    /// [`Method::ranks`] but not fully is ranked on part of it (see [`fuse`]).
    pub fn ranks_fully(self, held: impl Into<Held>) -> bool {
        let held = held.into();
        match self {
            Method::Hybrid => PARTS.iter().all(|m| m.ranks(held)),
            _ => self.ranks(held),
        }
    }

    /// Whether this method compares salient features, so that a query needs its ECC
    /// ([`crate::pipeline::Extent`]): the ECC method, and the hybrid while its ECC part
    /// weighs anything.
    pub fn needs_features(self, params: &SimilarityParams) -> bool {
        match self {
            Method::Ecc => true,
            Method::Hybrid => params.hybrid.ecc.weight > 0.0,
            Method::D2 | Method::Lfd | Method::Geodesic => false,
        }
    }
}

/// Which of the descriptors a signature may lack a model holds: what decides whether a
/// method can rank it ([`Method::ranks`]), read from its signature or from the index's columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Held {
    pub lfd: bool,
    pub geodesic: bool,
}

impl From<&Signature> for Held {
    fn from(signature: &Signature) -> Self {
        Self {
            lfd: signature.lfd.is_some(),
            geodesic: signature.geodesic.is_some(),
        }
    }
}

/// The entries a ranking considers: every entry but `without` (the model that `similar` asks
/// about, found once by id rather than compared with every entry's) that `keep` accepts (a
/// tag filter; every entry when `None`).
#[derive(Clone, Copy, Default)]
pub struct Scope<'a> {
    pub without: Option<&'a str>,
    pub keep: Option<&'a (dyn Fn(&str) -> bool + Sync)>,
}

/// One ranked result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Hit {
    pub id: String,
    pub distance: f64,
    /// For a part ([`Query::Part`]): the size it fitted this model at, its radius over the
    /// model's ([`crate::params::PartialParams::scales`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub part_scale: Option<f64>,
}

/// The top `k` and how much work finding them took.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Ranking {
    pub hits: Vec<Hit>,
    /// Entries whose exact distance was computed.
    pub evaluated: usize,
    /// Entries rejected by a lower bound without solving their EMD.
    pub pruned: usize,
    /// For a part ([`Query::Part`]): how many of the first hits are the candidates to verify
    /// by registering the part into them; 0 otherwise.
    #[serde(default)]
    pub candidates: usize,
}

/// What a caller asks of an index (as qdrant's `VectorIndex::search(query, filter, top,
/// params)`): the `k` entries in `scope` nearest a query, within `within`. Explanations are
/// not asked here: they need the stored signatures, which an index does not hold
/// ([`explain`] makes them from the hits).
#[derive(Clone, Copy)]
pub struct Request<'a> {
    pub query: Query<'a>,
    pub k: usize,
    pub scope: Scope<'a>,
    /// Only hits at most this far (infinite: the `k` nearest whatever their distance).
    pub within: f64,
    /// For a model: every entry's exact distance, no pruning, the reference a pruned ranking
    /// must match.
    pub exhaustive: bool,
}

/// What is searched with.
#[derive(Clone, Copy)]
pub enum Query<'a> {
    /// A whole model, compared by `method`; `params` other than the index's own (a query-time
    /// `W`) rank without the bounds, whose summaries were made for the index's.
    Model {
        signature: &'a Signature,
        method: Method,
        params: Option<&'a SimilarityParams>,
    },
    /// A piece of a model ([`crate::partial`]): the models that contain it. `nearest` are the
    /// models nearest the part by their stored patches, nearest first, of which `verified`
    /// become candidates to verify ([`crate::part_search::search`]).
    Part {
        part: &'a Part,
        nearest: &'a [(f64, String)],
        verified: usize,
    },
}

impl<'a> Request<'a> {
    /// The `k` models nearest `signature` by `method`, over every entry.
    pub fn model(signature: &'a Signature, method: Method, k: usize) -> Self {
        Self::of(
            Query::Model {
                signature,
                method,
                params: None,
            },
            k,
        )
    }

    /// The `k` models that best contain `part`, the first of those nearest it by their stored
    /// patches verified ([`Query::Part`]).
    pub fn part(part: &'a Part, nearest: &'a [(f64, String)], verified: usize, k: usize) -> Self {
        Self::of(
            Query::Part {
                part,
                nearest,
                verified,
            },
            k,
        )
    }

    fn of(query: Query<'a>, k: usize) -> Self {
        Self {
            query,
            k,
            scope: Scope::default(),
            within: f64::INFINITY,
            exhaustive: false,
        }
    }

    /// Over the entries in `scope` only.
    pub fn scope(self, scope: Scope<'a>) -> Self {
        Self { scope, ..self }
    }

    /// Only hits at most `distance` away.
    pub fn within(self, distance: f64) -> Self {
        Self {
            within: distance,
            ..self
        }
    }

    /// Without pruning ([`Request::exhaustive`]).
    pub fn exhaustive(self) -> Self {
        Self {
            exhaustive: true,
            ..self
        }
    }

    /// A model compared under `params` rather than the index's own.
    pub fn params(self, params: &'a SimilarityParams) -> Self {
        let query = match self.query {
            Query::Model {
                signature, method, ..
            } => Query::Model {
                signature,
                method,
                params: Some(params),
            },
            part => part,
        };
        Self { query, ..self }
    }
}

/// The entries in a scope that a method cannot rank (`left_out`, until re-extracted) or ranks
/// on part of its distance only (`partial`, see [`fuse`]): what responses report.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Coverage {
    pub left_out: usize,
    pub partial: usize,
}

/// An index of models that answers [`Request`]s: [`Index`] in memory, or one kept elsewhere.
pub trait Search {
    /// The hits of `request`, nearest first, ties by id.
    fn search(&self, request: &Request) -> io::Result<Ranking>;

    /// How many entries in `scope` `method` leaves out or ranks on part of its distance.
    fn coverage(&self, method: Method, scope: &Scope) -> Coverage;
}

/// What ranking compares of each model of a collection, with what it precomputes for its
/// bounds; the signatures themselves stay in the store.
///
/// Summaries for the lower bound depend on the ground-distance weight `W`, so an index is
/// built for one [`SimilarityParams`]. Cloning is cheap (entries are shared, the id map is
/// persistent), so the service publishes a changed copy instead of locking.
#[derive(Debug, Clone)]
pub struct Index {
    params: SimilarityParams,
    entries: Columns,
    position: imbl::HashMap<Arc<str>, usize>,
    /// Where the entries' light field descriptors are kept ([`shelf`]).
    shelf: Arc<Place>,
}

thread_local! {
    /// [`Index::cascade`]'s buffer of first-pass bounds, kept by each ranking thread between
    /// rankings. Taken, not borrowed: a ranking nested in another on the same thread (work
    /// stealing) finds it empty and allocates its own.
    static COARSE: std::cell::Cell<Vec<(f64, usize)>> = const { std::cell::Cell::new(Vec::new()) };
}

/// Entries whose exact distances are computed together (in parallel) between bound checks.
const BATCH: usize = 64;

/// Entries put in bound order at a time by the pruned ranking (a multiple of [`BATCH`]).
const SORTED: usize = 16 * BATCH;

/// Entries per result that [`Index::cascade`] with blocks bounds first, from the blocks of
/// least bound, for its first k-th distance.
const SEEDING: usize = 4;

/// No block bound ([`Index::cascade`]): for the rankings whose first bound has none.
const NO_BLOCKS: Option<fn(&BlockSpan) -> f64> = None;

impl Index {
    /// An index whose light field descriptors are shelved in the system's temporary
    /// directory.
    pub fn new(params: SimilarityParams) -> Self {
        Self::shelved_in(params, std::env::temp_dir())
    }

    /// An index whose light field descriptors are shelved in a file in `dir` (`rank/shelf.rs`),
    /// created with the first: a directory on disk, not a memory file system, for their
    /// pages to be reclaimable.
    pub fn shelved_in(params: SimilarityParams, dir: PathBuf) -> Self {
        Self::new_in(params, Place::new(dir))
    }

    fn new_in(params: SimilarityParams, place: Place) -> Self {
        Self {
            params,
            entries: Columns::default(),
            position: imbl::HashMap::new(),
            shelf: Arc::new(place),
        }
    }

    /// An index whose light field descriptors are kept away and fetched by `fetch` when a
    /// ranking needs them, a batch at a time: for a ranking of a first stage's candidates
    /// given in their [`compact`] form (#40), of which the bounds reject most. Rankings only:
    /// [`Index::near_pairs`] reads descriptors one pair at a time and fails on it.
    pub fn away(params: SimilarityParams, fetch: Fetch) -> Self {
        Self::new_in(params, Place::away(fetch))
    }

    /// What the index keeps of `signature` ([`Index::put`]): what ranking compares, in the
    /// form it compares it ([`Features`]), the light field descriptor shelved. What only a
    /// response shows (positions, statistics) stays in the store. Fails only if the shelf
    /// cannot be written.
    pub fn row(&self, id: impl Into<Arc<str>>, signature: &Signature) -> io::Result<Row> {
        let id = id.into();
        let light_field = signature
            .lfd
            .as_ref()
            .map(|d| io::Result::Ok((self.shelf.put(&id, d)?, d.summary())))
            .transpose()?;
        Ok(Row::new(id, signature, light_field, &self.params))
    }

    /// [`Index::row`] from a model's [`compact`] form, for an index whose descriptors are
    /// kept away ([`Index::away`]).
    pub fn compact_row(&self, id: impl Into<Arc<str>>, bytes: &[u8]) -> crate::Result<Row> {
        let id = id.into();
        let compact = compact::read(bytes)?;
        let light_field = (compact.lfd.is_some())
            .then(|| (self.shelf.away_slot(&id)).expect("an index made by Index::away"));
        Ok(Row::compact(id, compact, light_field, &self.params))
    }

    /// [`Index::row`], then [`Index::put`].
    pub fn insert(&mut self, id: impl Into<Arc<str>>, signature: &Signature) -> io::Result<()> {
        let row = self.row(id, signature)?;
        self.put(row);
        Ok(())
    }

    /// Adds an entry made by this index's [`Index::row`] (or a copy's), replacing one with
    /// the same id.
    pub fn put(&mut self, row: Row) {
        match self.position.get(row.id()) {
            Some(&i) => self.entries.set(i, row),
            None => {
                self.position.insert(row.id().clone(), self.entries.len());
                self.entries.push(row);
            }
        }
    }

    /// Puts entries near each other by the hybrid's first bound in the same blocks
    /// ([`arrange`]), which a hybrid ranking then rejects a block at a time: for after a
    /// start's load, whose order (by id) says nothing of the shapes. Entries added later go at
    /// the end, in blocks of their own; rankings are the same in any order.
    pub fn arrange(&mut self) {
        let order = arrange::order(&self.entries, &self.params);
        self.entries.permute(&order);
        // In place: a new map would leave the old one's memory to the allocator.
        for e in self.entries.iter() {
            if let Some(position) = self.position.get_mut(e.id()) {
                *position = e.number();
            }
        }
    }

    /// Removes an entry; returns whether it was there.
    pub fn remove(&mut self, id: &str) -> bool {
        let Some(i) = self.position.remove(id) else {
            return false;
        };
        if let Some(moved) = self.entries.swap_remove(i) {
            self.position.insert(moved, i);
        }
        true
    }

    /// Whether the index holds an entry `id`.
    pub fn contains(&self, id: &str) -> bool {
        self.position.contains_key(id)
    }

    /// The parameters the index compares with.
    pub fn params(&self) -> &SimilarityParams {
        &self.params
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.len() == 0
    }

    /// Every pair of entries within `d2` of each other by the `d2` method's distance and
    /// within `lfd` by the `lfd` method's (an entry without a light field descriptor passes
    /// on D2 alone), each pair once with its ids in order: the candidates of a library-wide
    /// duplicate search ([`crate::duplicate`]) without comparing every pair. The D2 bins cover
    /// [0, 2], so a histogram's mean moves by at most twice the distance (`|Σ (cᵢ − 1)(pᵢ −
    /// qᵢ)| ≤ Σ |pᵢ − qᵢ|`): sorted by mean, an entry meets only those whose mean is within
    /// `2 · d2`. The LFD's in-memory bounds go before its exact distance, read from the shelf.
    pub fn near_pairs(&self, d2: f64, lfd: f64) -> io::Result<Vec<(Arc<str>, Arc<str>)>> {
        let mean = |h: &[f32]| {
            let width = 2.0 / h.len() as f64;
            h.iter()
                .enumerate()
                .map(|(i, &p)| (i as f64 + 0.5) * width * f64::from(p))
                .sum::<f64>()
        };
        let mut order: Vec<(f64, Entry)> = self.entries.iter().map(|e| (mean(e.d2()), e)).collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0).then_with(|| a.1.id().cmp(b.1.id())));
        // Stored histograms are rounded to 1/65 535 a bin: a little slack keeps the bound safe.
        let window = 2.0 * d2 + 1e-3;
        let near_light_fields = |a: Entry, b: Entry| -> io::Result<bool> {
            let (Some(sa), Some(sb), Some(ua), Some(ub)) =
                (a.sketch(), b.sketch(), a.lfd(), b.lfd())
            else {
                return Ok(true);
            };
            if sa.lower_bound(sb) > lfd || ua.lower_bound(ub) > lfd {
                return Ok(false);
            }
            Ok(match (a.light_field()?, b.light_field()?) {
                (Some(x), Some(y)) => x.distance(&y) <= lfd,
                _ => true,
            })
        };
        let mut pairs = order
            .par_iter()
            .enumerate()
            .map(|(i, &(m, a))| {
                let mut near = Vec::new();
                for &(_, b) in order[i + 1..].iter().take_while(|(n, _)| n - m <= window) {
                    if histogram_l1(a.d2(), b.d2()) <= d2 && near_light_fields(a, b)? {
                        let (x, y) = if a.id() < b.id() { (a, b) } else { (b, a) };
                        near.push((x.id().clone(), y.id().clone()));
                    }
                }
                Ok(near)
            })
            .collect::<io::Result<Vec<_>>>()?
            .concat();
        pairs.sort();
        Ok(pairs)
    }

    /// Whether an entry is in `scope`.
    fn admits<'s>(&'s self, scope: &'s Scope<'s>) -> impl Fn(Entry) -> bool + Sync + 's {
        let without = scope.without.and_then(|id| self.position.get(id).copied());
        move |e: Entry| Some(e.number()) != without && scope.keep.is_none_or(|keep| keep(e.id()))
    }

    /// The `k` entries in `scope` nearest `query` by `method` under `params`. Entries left out
    /// count neither as evaluated nor as pruned.
    fn search_model(
        &self,
        query: &Signature,
        k: usize,
        method: Method,
        params: &SimilarityParams,
        scope: &Scope,
    ) -> io::Result<Ranking> {
        // The bounds' summaries hold for the index's parameters only; the histogram methods
        // and the LFD compare nothing that depends on them.
        let own =
            matches!(method, Method::D2 | Method::Lfd | Method::Geodesic) || *params == self.params;
        match method {
            _ if !own => self.exhaustive(query, k, method, params, scope),
            Method::Hybrid => self.search_hybrid(query, k, scope),
            Method::Ecc => self.search_ecc(query, k, scope),
            Method::Lfd => self.search_lfd(query, k, scope),
            // A histogram distance costs less than any bound would.
            Method::D2 | Method::Geodesic => self.exhaustive(query, k, method, &self.params, scope),
        }
    }

    fn exhaustive(
        &self,
        query: &Signature,
        k: usize,
        method: Method,
        params: &SimilarityParams,
        scope: &Scope,
    ) -> io::Result<Ranking> {
        let query = Prepared::of(query);
        // A read from the shelf per entry: only for a method that weighs the LFD.
        let reads_light_field = match method {
            Method::Lfd => true,
            Method::Hybrid => params.hybrid.lfd.weight > 0.0,
            Method::Ecc | Method::D2 | Method::Geodesic => false,
        };
        let distance = |e: Entry| -> io::Result<f64> {
            let lfd = if reads_light_field {
                e.light_field()?
            } else {
                None
            };
            let entry = e.compared(lfd.as_ref());
            Ok(compared_distance(method, query.compared(), entry, params))
        };
        let admits = self.admits(scope);
        let ranked: Vec<usize> = (self.entries.par_entries())
            .filter(|&e| admits(e) && e.ranks(method))
            .map(|e| e.number())
            .collect();
        let mut scored = self.solve(&ranked, |e| Ok((distance(e)?, e.number())))?;
        let evaluated = scored.len();
        let top = self.smallest(&mut scored, k);
        Ok(Ranking {
            hits: top
                .iter()
                .map(|&(distance, i)| Hit {
                    id: self.entries.get(i).id().to_string(),
                    distance,
                    part_scale: None,
                })
                .collect(),
            evaluated,
            pruned: 0,
            candidates: 0,
        })
    }

    /// SPEC §5 ranking with the ECC bounds: the centroid/projection bound for every entry,
    /// then the relaxed-EMD bound from the cost matrix, which the exact EMD reuses.
    fn search_ecc(&self, query: &Signature, k: usize, scope: &Scope) -> io::Result<Ranking> {
        let params = &self.params;
        let features = Features::of(&query.features);
        let summary = Summary::of(&features, params);
        let centroid = features.centroid();
        let centroid = (&centroid.0[..], &centroid.1[..], summary.features());
        self.cascade(
            k,
            self.admits(scope),
            (
                |e, _| centroid_bound(centroid, e.centroid(), params),
                NO_BLOCKS,
            ),
            |e, _| {
                Some(lower_bound(
                    (&summary, centroid),
                    (e.summary(), e.centroid()),
                    params,
                ))
            },
            |e, kth| {
                let costs = CostMatrix::new(&features, e.features(), params);
                Ok((costs.relaxed_bound(params) <= kth).then(|| compare_costs(&costs, params).sim))
            },
        )
    }

    /// The hybrid's ranking: each entry's bound is the fused bounds of its parts (the ECC's
    /// centroid/projection bound, the exact D2 and geodesic distances, which cost less than a
    /// bound, and the LFD's bound), coarse then fine ([`Index::cascade`]); an entry past the
    /// bound is rejected by the fused relaxed-EMD bound before its EMD is solved, and its LFD
    /// distance stops at the most the k-th distance leaves it ([`part_limit`]).
    fn search_hybrid(&self, query: &Signature, k: usize, scope: &Scope) -> io::Result<Ranking> {
        let h = &self.params.hybrid;
        // The summaries depend on `W` only, which the hybrid's ECC part shares.
        let params = &self.params.hybrid_ecc();
        let prepared = Prepared::of(query);
        let summary = Summary::of(&prepared.features, params);
        let lfd_query = query.lfd.as_ref().map(|d| (d.sketch(), LfdQuery::new(d)));
        let lfd_sketch = |e: Entry| match (&lfd_query, e.sketch()) {
            (Some((q, _)), Some(s)) if h.lfd.weight > 0.0 => Some(q.lower_bound(s)),
            _ => None,
        };
        let lfd_bound = |e: Entry| match (&lfd_query, e.lfd()) {
            (Some((_, q)), Some(s)) if h.lfd.weight > 0.0 => Some(q.summary().lower_bound(s)),
            _ => None,
        };
        // `None` past `cutoff`.
        let lfd_exact = |e: Entry, cutoff: f64| match &lfd_query {
            Some((_, query)) => lfd_within(query, e, cutoff),
            None => Ok(None),
        };
        // Left out (as `fuse` would leave it) when it weighs nothing, as in the defaults.
        let d2 = |e: Entry| (h.d2.weight > 0.0).then(|| histogram_l1(&query.d2, e.d2()));
        let geodesic = |e: Entry| Some(prepared.geodesic.as_ref()?.distance(e.geodesic()?));
        // From the entry's summary, not its signature: this runs for every entry, and the
        // signature is another cache miss away.
        let with_ecc_query = h.ecc.weight > 0.0 && !query.features.is_empty();
        let with_ecc = |e: Entry| with_ecc_query && e.summary().features() > 0;
        // The first pass, over every entry, takes the cheap halves of the bounds: the ECC's
        // centroid bound in single precision and the LFD's sketch.
        let centroid = prepared.features.centroid();
        let centroid = (&centroid.0[..], &centroid.1[..], summary.features());
        // The geodesic and ECC parts first: past `limit` together, most entries need no LFD
        // sketch (a quarter of the pass's reads).
        let coarse = |e: Entry, limit: f64| {
            let geodesic = geodesic(e);
            let least = least_sum(h, [None, None, None, geodesic]);
            if least > limit {
                return least;
            }
            let ecc = with_ecc(e).then(|| centroid_bound(centroid, e.centroid(), params));
            let least = least_sum(h, [ecc, None, None, geodesic]);
            if least > limit {
                return least;
            }
            fuse(h, [ecc, d2(e), lfd_sketch(e), geodesic])
        };
        // The same parts' bounds over a block's boxes: only parts every entry of the block
        // has, unscaled (`least_sum`), so never above the first bound of any of them.
        let block = |b: &BlockSpan| {
            let geodesic =
                (prepared.geodesic.as_ref().zip(b.geodesic())).map(|(q, span)| q.distance_to(span));
            let ecc = b
                .centroid()
                .filter(|_| with_ecc_query)
                .map(|(spans, counts)| centroid_span_bound(centroid, spans, counts, params));
            let lfd = match (&lfd_query, b.sketch()) {
                (Some((q, _)), Some(span)) if h.lfd.weight > 0.0 => Some(q.span_bound(span)),
                _ => None,
            };
            least_sum(h, [ecc, None, lfd, geodesic])
        };
        // The LFD's summary bound with the ECC's centroid bound orders the visit; the ECC's
        // projection bound waits for the visit, which stops long before most of the entries
        // the first pass leaves (~1 000 of 100 000 for a stored model's copies).
        let fine = |e: Entry, kth: f64| {
            let ecc = with_ecc(e).then(|| centroid_bound(centroid, e.centroid(), params));
            let bound = fuse(h, [ecc, d2(e), lfd_bound(e), geodesic(e)]);
            (bound <= kth).then_some(bound)
        };
        // Cheapest first: the ECC's projection bound, the relaxed EMD, both with the LFD's
        // bound, then with its distance (~50 µs), and only then the EMD itself.
        let exact = |e: Entry, kth: f64| {
            let (d2, lfd_bound, geodesic) = (d2(e), lfd_bound(e), geodesic(e));
            let projected = with_ecc(e)
                .then(|| lower_bound((&summary, centroid), (e.summary(), e.centroid()), params));
            if fuse(h, [projected, d2, lfd_bound, geodesic]) > kth {
                return Ok(None);
            }
            let costs =
                with_ecc(e).then(|| CostMatrix::new(&prepared.features, e.features(), params));
            let relaxed = costs.as_ref().map(|c| c.relaxed_bound(params));
            if fuse(h, [relaxed, d2, lfd_bound, geodesic]) > kth {
                return Ok(None);
            }
            let lfd = match lfd_bound {
                // The LFD distance stops early past the most it may be within the k-th.
                Some(_) => {
                    let cutoff = part_limit(h, [relaxed, d2, None, geodesic], 2, kth);
                    match lfd_exact(e, cutoff)? {
                        Some(lfd) => Some(lfd),
                        None => return Ok(None),
                    }
                }
                None => None,
            };
            if fuse(h, [relaxed, d2, lfd, geodesic]) > kth {
                return Ok(None);
            }
            let ecc = costs.map(|c| compare_costs(&c, params).sim);
            Ok(Some(fuse(h, [ecc, d2, lfd, geodesic])))
        };
        self.cascade(k, self.admits(scope), (coarse, Some(block)), fine, exact)
    }

    /// What `mode=partial` ranks (its one rule, served and evaluated): first the candidates to
    /// verify — the `verified` models nearest the part by their stored patches (`nearest`,
    /// nearest first, [`crate::descriptor::patch::Packed`]), then the fit's best `verified` of
    /// the models without patches (a library whose patches are still being made) — then the
    /// `k` entries in `scope` that best contain `part` ([`crate::partial`]), best first. Each
    /// hit has the size the part fitted it at; entries without salient features are left out.
    /// The fit is pruned by [`Part::bound`] like the other methods: the same top `k` as a full
    /// scan.
    fn search_part(
        &self,
        part: &Part,
        k: usize,
        scope: &Scope,
        nearest: &[(f64, String)],
        verified: usize,
    ) -> io::Result<Ranking> {
        let params = &self.params;
        let admits = self.admits(scope);
        let fitted = |e: Entry| admits(e) && e.summary().features() > 0;
        let fit = self.cascade(
            k.max(verified),
            fitted,
            (|e, _| part.bound(e.summary()), NO_BLOCKS),
            // The first bound is the only one; it orders the visit.
            |_, _| Some(0.0),
            |e, kth| Ok(part.fit(e.features(), params, kth).map(|f| f.distance)),
        )?;
        let fit_of = |id: &str| {
            let e = self.entries.get(*self.position.get(id)?);
            fitted(e).then(|| part.fit(e.features(), params, f64::INFINITY))?
        };
        // The patches' nearest that the part fits, then the fit's best of the models without
        // patches: each once, verified; then the rest of the fit's ranking.
        let patched: HashSet<&str> = nearest.iter().map(|(_, id)| id.as_str()).collect();
        let mut chosen: Vec<(&str, Fit)> = nearest
            .iter()
            .filter_map(|(_, id)| Some((id.as_str(), fit_of(id)?)))
            .take(verified)
            .collect();
        let unpatched = fit.hits.iter().take(verified).map(|h| h.id.as_str());
        chosen.extend(
            unpatched
                .filter(|id| !patched.contains(id))
                .filter_map(|id| Some((id, fit_of(id)?))),
        );
        let candidates = chosen.len();
        // Fits the cascade did not compute: the patches' choices outside its ranking.
        let ranked: HashSet<&str> = fit.hits.iter().map(|h| h.id.as_str()).collect();
        let fitted_here = chosen.iter().filter(|(id, _)| !ranked.contains(id)).count();
        let taken: HashSet<&str> = chosen.iter().map(|&(id, _)| id).collect();
        let rest: Vec<(&str, Fit)> = fit
            .hits
            .iter()
            .filter(|h| !taken.contains(h.id.as_str()))
            .filter_map(|h| Some((h.id.as_str(), fit_of(&h.id)?)))
            .collect();
        chosen.extend(rest);
        Ok(Ranking {
            hits: chosen
                .iter()
                .map(|&(id, f)| Hit {
                    id: id.to_string(),
                    distance: f.distance,
                    part_scale: Some(f.scale),
                })
                .collect(),
            evaluated: fit.evaluated + fitted_here,
            pruned: fit.pruned,
            candidates,
        })
    }

    /// Light field ranking with [`crate::descriptor::lfd::LfdSummary::lower_bound`]; entries without a descriptor are
    /// left out (see [`Method::ranks`]), and a query without one ranks nothing.
    fn search_lfd(&self, query: &Signature, k: usize, scope: &Scope) -> io::Result<Ranking> {
        let Some(query) = &query.lfd else {
            // Nothing to compare with: no entry is ranked (callers check [`Method::ranks`]).
            return Ok(Ranking::default());
        };
        let (sketch, prepared) = (query.sketch(), LfdQuery::new(query));
        const KEPT: &str = "kept entries have one";
        let admits = self.admits(scope);
        self.cascade(
            k,
            |e| admits(e) && e.ranks(Method::Lfd),
            (
                |e, _| sketch.lower_bound(e.sketch().expect(KEPT)),
                NO_BLOCKS,
            ),
            |e, _| Some(prepared.summary().lower_bound(e.lfd().expect(KEPT))),
            |e, kth| lfd_within(&prepared, e, kth),
        )
    }

    /// Top `k` of the entries `keep` accepts, with two lower bounds on the distance: `coarse`,
    /// cheap, for every entry; the exact distances of the `k` entries of least coarse bound,
    /// a real k-th distance and so never below the true one, reject most entries;
    /// `fine(entry, kth)`, tighter and costlier, orders the others for the visit, or is `None`
    /// when it can tell cheaply that the entry is past `kth`. The result equals a full scan's.
    ///
    /// `coarse(entry, limit)` may stop early and return any value above `limit` once its
    /// bound is past it. With `block`, a bound never above `coarse(entry, ∞)` of any entry of
    /// a block ([`BlockSpan`]), a first look at the blocks of least bound finds a real k-th distance
    /// before the pass over all entries, which is then its limit: the blocks past it are
    /// passed over whole, and most other entries stop at their cheapest parts (the hybrid's
    /// first pass was ~70 % of a `similar` ranking).
    fn cascade(
        &self,
        k: usize,
        keep: impl Fn(Entry) -> bool + Sync,
        (coarse, block): (
            impl Fn(Entry, f64) -> f64 + Sync,
            Option<impl Fn(&BlockSpan) -> f64 + Sync>,
        ),
        fine: impl Fn(Entry, f64) -> Option<f64> + Sync,
        exact: impl Fn(Entry, f64) -> io::Result<Option<f64>> + Sync,
    ) -> io::Result<Ranking> {
        // Every entry's bound, written in place into this thread's buffer: with a fresh
        // vector a query (1.6 MB at 100 000 entries), gathered from an unindexed parallel
        // collect, zeroing its new pages alone was ~13 % of a `similar` ranking's profile.
        let mut coarse_order = COARSE.take();
        let mut solved: Vec<(usize, Option<f64>)> = Vec::new();
        let solve = |solved: &mut Vec<(usize, Option<f64>)>, seeds: &[usize]| -> io::Result<()> {
            let fresh: Vec<usize> = seeds
                .iter()
                .copied()
                .filter(|i| !solved.iter().any(|(j, _)| j == i))
                .collect();
            let distances = self.solve(&fresh, |e| exact(e, f64::INFINITY))?;
            solved.extend(fresh.into_iter().zip(distances));
            Ok(())
        };
        let kth_of = |solved: &[(usize, Option<f64>)]| {
            let mut best: Vec<Hit> = solved
                .iter()
                .filter_map(|&(i, distance)| {
                    Some(Hit {
                        id: self.entries.get(i).id().to_string(),
                        distance: distance?,
                        part_scale: None,
                    })
                })
                .collect();
            sort_hits(&mut best);
            let kth = best
                .get(k.wrapping_sub(1))
                .map_or(f64::INFINITY, |hit| hit.distance);
            (best, kth)
        };
        let seeds_of = |order: &mut [(f64, usize)]| -> Vec<usize> {
            self.smallest(order, k).iter().map(|&(_, i)| i).collect()
        };
        // With blocks: every block's bound, and a real k-th distance from the entries of the
        // blocks of least bound, which hold the query's nearest more often than not (the
        // entries arranged, [`Index::arrange`]); the blocks past it are passed over.
        let (limit, past) = match &block {
            Some(block) if k > 0 => {
                let mut blocks: Vec<(f64, usize)> = (0..self.entries.blocks())
                    .into_par_iter()
                    .map(|b| (block(self.entries.span(b)), b))
                    .collect();
                blocks.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                coarse_order.clear();
                for &(_, b) in &blocks {
                    if coarse_order.len() >= SEEDING * k {
                        break;
                    }
                    let entries = b * BLOCK..((b + 1) * BLOCK).min(self.entries.len());
                    coarse_order.extend(
                        entries
                            .map(|i| (self.entries.get(i), i))
                            .filter(|&(e, _)| keep(e))
                            .map(|(e, i)| (coarse(e, f64::INFINITY), i)),
                    );
                }
                solve(&mut solved, &seeds_of(&mut coarse_order))?;
                let kth = kth_of(&solved).1;
                let mut past = vec![false; blocks.len()];
                for (bound, b) in blocks {
                    past[b] = bound > kth;
                }
                (kth, past)
            }
            _ => (f64::INFINITY, Vec::new()),
        };
        // The first bounds of every entry in `keep`, stopping past `limit`; an entry of a block
        // past it is past it too.
        (0..self.entries.len())
            .into_par_iter()
            .map(|i| {
                let e = self.entries.get(i);
                let bound = match keep(e) {
                    false => f64::NAN,
                    true if past.get(i / BLOCK) == Some(&true) => f64::INFINITY,
                    true => coarse(e, limit),
                };
                (bound, i)
            })
            .collect_into_vec(&mut coarse_order);
        coarse_order.retain(|(bound, _)| !bound.is_nan());
        let admitted = coarse_order.len();
        // Past a real k-th distance: never in the top `k`, not even by a tie.
        coarse_order.retain(|&(bound, _)| bound <= limit);
        let seeds = seeds_of(&mut coarse_order);
        solve(&mut solved, &seeds)?;
        let (best, kth) = kth_of(&solved);
        // The solved entries are known: the visit starts from them, with their k-th distance.
        let order: Vec<(f64, usize)> = coarse_order
            .par_iter()
            .filter(|(bound, i)| *bound <= kth && !solved.iter().any(|(j, _)| j == i))
            .filter_map(|&(bound, i)| Some((fine(self.entries.get(i), kth)?.max(bound), i)))
            .collect();
        COARSE.set(coarse_order);
        let seeded = solved.iter().filter(|(_, d)| d.is_some()).count();
        self.fetch_ahead(&order)?;
        let (hits, visited) = self.refine(k, order, best, exact)?;
        let evaluated = seeded + visited;
        Ok(Ranking {
            hits,
            evaluated,
            pruned: admitted - evaluated,
            candidates: 0,
        })
    }

    /// The visit of [`Index::cascade`]: `order` holds each candidate's lower bound and entry,
    /// `best` the hits found before it, sorted. Returns the top `k` and how many entries the
    /// visit solved.
    fn refine(
        &self,
        k: usize,
        mut order: Vec<(f64, usize)>,
        mut best: Vec<Hit>,
        exact: impl Fn(Entry, f64) -> io::Result<Option<f64>> + Sync,
    ) -> io::Result<(Vec<Hit>, usize)> {
        best.truncate(k);
        if k == 0 {
            return Ok((best, 0));
        }
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
            let solved = self.solve(&live, |entry| {
                Ok(exact(entry, kth)?.map(|distance| Hit {
                    id: entry.id().to_string(),
                    distance,
                    part_scale: None,
                }))
            })?;
            let solved: Vec<Hit> = solved.into_iter().flatten().collect();
            evaluated += solved.len();
            best.extend(solved);
            sort_hits(&mut best);
            best.truncate(k);
            if live.len() < batch.len() {
                break;
            }
        }
        Ok((best, evaluated))
    }

    /// With descriptors kept away ([`Index::away`]), fetches those of every entry a visit may
    /// read (`order`: each within the k-th distance by its bounds) in one round trip, before
    /// the visit: a round trip per batch of the visit cost more, on a loaded database, than
    /// the descriptors it then did not fetch (the load bench: 2 to 8 trips a ranking).
    fn fetch_ahead(&self, order: &[(f64, usize)]) -> io::Result<()> {
        if !self.shelf.is_away() {
            return Ok(());
        }
        self.shelf
            .fetch(order.iter().map(|&(_, i)| self.entries.get(i).id()))
    }

    /// `exact` of each of `entries`, in parallel. With descriptors kept away ([`Index::away`]),
    /// the entries whose distance needed one not yet fetched ([`shelf::is_away`]) are solved
    /// again once those are fetched, in one round trip: a batch's bounds reject most entries
    /// before their descriptor is read, so only the few they leave are fetched.
    fn solve<T: Send>(
        &self,
        entries: &[usize],
        exact: impl Fn(Entry) -> io::Result<T> + Sync,
    ) -> io::Result<Vec<T>> {
        let first: Vec<io::Result<T>> = entries
            .par_iter()
            .map(|&i| exact(self.entries.get(i)))
            .collect();
        let away: Vec<usize> = (entries.iter().zip(&first))
            .filter(|(_, r)| r.as_ref().is_err_and(shelf::is_away))
            .map(|(&i, _)| i)
            .collect();
        if away.is_empty() {
            return first.into_iter().collect();
        }
        self.shelf
            .fetch(away.iter().map(|&i| self.entries.get(i).id()))?;
        let again: Vec<T> = away
            .par_iter()
            .map(|&i| exact(self.entries.get(i)))
            .collect::<io::Result<_>>()?;
        let mut again = again.into_iter();
        first
            .into_iter()
            .map(|r| match r {
                Err(e) if shelf::is_away(&e) => Ok(again.next().expect("one for each")),
                r => r,
            })
            .collect()
    }

    /// Moves the `k` smallest of `scored` (by score, ties by id) to its front, sorted, and
    /// returns them: a selection then a sort of `k`, not a sort of all.
    fn smallest<'a>(&self, scored: &'a mut [(f64, usize)], k: usize) -> &'a [(f64, usize)] {
        let order = |a: &(f64, usize), b: &(f64, usize)| {
            a.0.total_cmp(&b.0)
                .then_with(|| self.entries.get(a.1).id().cmp(self.entries.get(b.1).id()))
        };
        let k = k.min(scored.len());
        if k < scored.len() && k > 0 {
            scored.select_nth_unstable_by(k - 1, order);
        }
        scored[..k].sort_unstable_by(order);
        &scored[..k]
    }
}

impl Search for Index {
    fn search(&self, request: &Request) -> io::Result<Ranking> {
        let Request {
            query,
            k,
            ref scope,
            within,
            exhaustive,
        } = *request;
        let mut ranking = match query {
            Query::Model {
                signature,
                method,
                params,
            } => {
                let params = params.unwrap_or(&self.params);
                if exhaustive {
                    self.exhaustive(signature, k, method, params, scope)?
                } else {
                    self.search_model(signature, k, method, params, scope)?
                }
            }
            Query::Part {
                part,
                nearest,
                verified,
            } => self.search_part(part, k, scope, nearest, verified)?,
        };
        ranking.hits.retain(|h| h.distance <= within);
        ranking.candidates = ranking.candidates.min(ranking.hits.len());
        Ok(ranking)
    }

    fn coverage(&self, method: Method, scope: &Scope) -> Coverage {
        let admits = self.admits(scope);
        let (mut left_out, mut partial) = (0, 0);
        for e in self.entries.iter().filter(|&e| admits(e)) {
            if !e.ranks(method) {
                left_out += 1;
            } else if !e.ranks_fully(method) {
                partial += 1;
            }
        }
        Coverage { left_out, partial }
    }
}

/// The LFD distance from `query` to `e`, or `None` past `cutoff` or without a descriptor. The
/// descriptor is read from the shelf only when `e`'s summary leaves some light-field pair
/// within the cutoff.
fn lfd_within(query: &LfdQuery, e: Entry, cutoff: f64) -> io::Result<Option<f64>> {
    let Some(pairs) = e.lfd().and_then(|theirs| query.pairs(theirs, cutoff)) else {
        return Ok(None);
    };
    Ok(e.light_field()?.and_then(|d| query.distance(pairs, &d)))
}

fn sort_hits(hits: &mut [Hit]) {
    hits.sort_by(|a, b| {
        a.distance
            .total_cmp(&b.distance)
            .then_with(|| a.id.cmp(&b.id))
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::emd::SOLVED;
    use crate::params::Params;
    use crate::signature::Feature;

    fn signature(features: usize, shift: f64) -> Signature {
        let feature = |i: usize| Feature {
            vertex: i as u32,
            position: [i as f64, shift, 0.0],
            position_normalized: [0.0; 3],
            ecc: (0..10)
                .map(|j| 1.0 + shift * (i + j) as f64 / 10.0)
                .collect(),
            d2: (0..8).map(|j| if j == i % 8 { 1.0 } else { 0.0 }).collect(),
            region_size: 0.3,
            region_area: 0.1,
        };
        Signature {
            mesh_hash: Default::default(),
            features: (0..features).map(feature).collect(),
            d2: vec![0.25; 4],
            lfd: None,
            geodesic: None,
            params: Params::default(),
            stats: Default::default(),
        }
    }

    #[test]
    fn an_explanation_solves_the_features_emd_once_and_agrees_with_the_distances() {
        let (p, q) = (signature(3, 0.0), signature(5, 0.4));
        let params = SimilarityParams::default();
        let solved = SOLVED.with(|n| n.get());
        let explained = explain(&p, &q, &params);
        assert_eq!(SOLVED.with(|n| n.get()) - solved, 1);
        assert!(!explained.matches.is_empty());
        for (method, d) in &explained.distances {
            assert_eq!(*d, distance(*method, &p, &q, &params), "{method}");
        }
        assert_eq!(
            explained.contributions,
            contributions(&params.hybrid, hybrid_parts(&p, &q, &params))
        );
    }
}

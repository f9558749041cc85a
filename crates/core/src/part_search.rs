//! The one partial search: what `POST /v1/search?mode=partial`, `salient search --partial` and
//! `salient eval partial` all run. Where the stored models' patches and surfaces come from is
//! the caller's ([`Library`]): the service's store, a folder's cache, the evaluation's memory.

use std::sync::Arc;

use rayon::prelude::*;

use crate::descriptor::patch::{Packed, PackedPiece};
use crate::mesh::RawMesh;
use crate::params::Params;
use crate::partial::{Part, Probe, Registration, Target};
use crate::rank::{Request, Scope, Search};

/// What a partial search verifies against.
pub trait Library: Sync {
    type Error: Send;

    /// Every model with stored patches, with the distance of its nearest patch of each
    /// radius to `piece` ([`Packed::nearest`]), in any order. A model without patches yet is
    /// left to the fit.
    fn nearest(&self, piece: &PackedPiece) -> Result<Vec<(Vec<f64>, String)>, Self::Error>;

    /// Model `id` as parts are registered into it; `None` when it is gone or can no longer
    /// be prepared (it is then ranked by the fit, unverified).
    fn target(&self, id: &str) -> Result<Option<Arc<Target>>, Self::Error>;
}

/// A part as searched: its salient features at each size and its probe.
pub struct PartQuery {
    pub part: Part,
    /// `None` for a part without area: it is ranked by the fit alone.
    pub probe: Option<Probe>,
}

impl PartQuery {
    /// The part `raw` described at each of `scales` ([`Part::extract`]).
    pub fn extract(raw: &RawMesh, params: &Params, scales: &[f64]) -> crate::Result<Self> {
        Ok(Self {
            part: Part::extract(raw, params, scales, &params.similarity)?,
            probe: Probe::new(raw),
        })
    }
}

/// One result of a partial search.
#[derive(Debug, Clone, PartialEq)]
pub struct PartHit {
    pub id: String,
    /// The salient-feature fit ([`Part::fit`]).
    pub distance: f64,
    /// The size the part fitted this model at.
    pub part_scale: Option<f64>,
    /// Where the part lies in this model and how far it stays from its surface there
    /// ([`Probe::register`]), for the models verified.
    pub registration: Option<Registration>,
}

impl PartHit {
    pub fn residual(&self) -> Option<f64> {
        self.registration.map(|r| r.residual)
    }
}

/// What a partial search found and what it cost.
#[derive(Debug, Clone, Default)]
pub struct PartRanking {
    pub hits: Vec<PartHit>,
    /// Models whose fit was solved, and rejected by its bound.
    pub evaluated: usize,
    pub pruned: usize,
    /// Models the part was registered into.
    pub verified: usize,
}

/// Why a partial search failed: the index, or the caller's library.
#[derive(Debug, thiserror::Error)]
pub enum SearchError<E> {
    #[error("the ranking index: {0}")]
    Index(#[source] std::io::Error),
    #[error(transparent)]
    Library(E),
}

/// The `k` models that best contain `query`, in `scope`: the `verified` models nearest it by
/// their stored patches (that the part fits at all) registered and ranked by residual
/// ([`by_residual`]), then the rest by the fit ([`crate::rank::Query::Part`]).
/// Registrations run in parallel on the current rayon pool; the result does not depend on it.
pub fn search<L: Library>(
    query: &PartQuery,
    index: &(impl Search + ?Sized),
    scope: Scope,
    library: &L,
    verified: usize,
    k: usize,
) -> Result<PartRanking, SearchError<L::Error>> {
    let nearest = match &query.probe {
        Some(probe) => candidates(
            library
                .nearest(&Packed::piece(probe.description()))
                .map_err(SearchError::Library)?,
        ),
        None => Vec::new(),
    };
    let ranking = index
        .search(&Request::part(&query.part, &nearest, verified, k).scope(scope))
        .map_err(SearchError::Index)?;
    let candidates = match &query.probe {
        Some(_) => ranking.candidates,
        None => 0,
    };
    let registrations: Vec<Option<Registration>> = ranking.hits[..candidates]
        .par_iter()
        .map(|hit| {
            let target = library.target(&hit.id).map_err(SearchError::Library)?;
            let probe = query.probe.as_ref().expect("candidates only with a probe");
            Ok(target.and_then(|t| probe.register(&t)))
        })
        .collect::<Result<_, _>>()?;
    let mut hits: Vec<PartHit> = ranking
        .hits
        .into_iter()
        .zip(registrations.into_iter().chain(std::iter::repeat(None)))
        .map(|(hit, registration)| PartHit {
            id: hit.id,
            distance: hit.distance,
            part_scale: hit.part_scale,
            registration,
        })
        .collect();
    by_residual(&mut hits[..candidates], PartHit::residual);
    hits.truncate(k);
    Ok(PartRanking {
        hits,
        evaluated: ranking.evaluated,
        pruned: ranking.pruned,
        verified: candidates,
    })
}

/// The order a partial search takes its candidates in ([`crate::rank::Query::Part`]), from
/// each model's nearest patch of each radius to the part ([`Packed::nearest`]): the model
/// nearest by the smallest pieces, then the one nearest by the next radius, and so on in
/// turn, each model once (ties by id); each with its nearest patch of any radius.
///
/// Why in turn: a part's size in its model is not known, and a large piece matches a small
/// part's generic surface too well, so the nearest piece of any radius lets one size crowd
/// out the others. On the tuning halves (`docs/results/partial/`, every model ranked by its
/// patches alone), for parts of 15 % of the surface, the source was among the 50 nearest for
/// 0.44 of SHREC'07's parts by the nearest piece of any radius and 0.60 in turn (one radius
/// of 0.4: 0.58).
pub fn candidates<S: Ord>(models: Vec<(Vec<f64>, S)>) -> Vec<(f64, S)> {
    // At least one order, so that every model is taken even without distances.
    let radii = models
        .iter()
        .map(|(d, _)| d.len())
        .max()
        .unwrap_or(0)
        .max(1);
    let at = |d: &[f64], r: usize| d.get(r).copied().unwrap_or(f64::INFINITY);
    let orders: Vec<Vec<usize>> = (0..radii)
        .map(|r| {
            let mut order: Vec<usize> = (0..models.len()).collect();
            order.sort_by(|&a, &b| {
                let (a, b) = (&models[a], &models[b]);
                at(&a.0, r)
                    .total_cmp(&at(&b.0, r))
                    .then_with(|| a.1.cmp(&b.1))
            });
            order
        })
        .collect();
    let mut taken = vec![false; models.len()];
    let mut turn: Vec<usize> = Vec::with_capacity(models.len());
    let mut heads = vec![0; radii];
    while turn.len() < models.len() {
        for (order, head) in orders.iter().zip(&mut heads) {
            while *head < order.len() && taken[order[*head]] {
                *head += 1;
            }
            if let Some(&i) = order.get(*head) {
                taken[i] = true;
                turn.push(i);
            }
        }
    }
    let mut models: Vec<Option<(Vec<f64>, S)>> = models.into_iter().map(Some).collect();
    turn.into_iter()
        .map(|i| {
            let (d, id) = models[i].take().expect("each once");
            (d.into_iter().fold(f64::INFINITY, f64::min), id)
        })
        .collect()
}

/// Re-ranks the verified head of a part's fit ranking by residual ([`Probe::residual`]),
/// lower first; entries without one (not registered: deleted meanwhile, or degenerate) go
/// after them, and ties keep the fit's order.
fn by_residual<T>(verified: &mut [T], residual: impl Fn(&T) -> Option<f64>) {
    let key = |t: &T| {
        residual(t)
            .filter(|r| r.is_finite())
            .unwrap_or(f64::INFINITY)
    };
    verified.sort_by(|a, b| key(a).total_cmp(&key(b)));
}

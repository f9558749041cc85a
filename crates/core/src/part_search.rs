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

    /// Every model with stored patches, at the distance of its nearest patch to `piece`
    /// ([`Packed::nearest`]), in any order. A model without patches yet is left to the fit.
    fn nearest(&self, piece: &PackedPiece) -> Result<Vec<(f64, String)>, Self::Error>;

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
        Some(probe) => nearest_first(
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

/// Models by the distance of a part to their stored patches ([`Packed::nearest`]), nearest
/// first, ties by id: the order a partial search takes its candidates in
/// ([`crate::rank::Query::Part`]).
fn nearest_first<S: Ord>(mut models: Vec<(f64, S)>) -> Vec<(f64, S)> {
    models.sort_by(|a, b| a.0.total_cmp(&b.0).then_with(|| a.1.cmp(&b.1)));
    models
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

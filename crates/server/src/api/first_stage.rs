//! Rankings with their first stage in the database (`--index pgvector`, #40): pgvector's
//! HNSW index finds about the `k × first_stage_oversampling` models nearest the query by
//! their vectors ([`salient_core::rank::vectors`], one per model, pooled: as good as one per
//! light field in `benches/first_stage.rs`, at a tenth of the rows), with their compact forms
//! ([`salient_core::rank::compact`]) in the same round trip, and this replica ranks those by
//! their exact distance under any method. The vectors are the hybrid's, so the other
//! methods' first stage is the hybrid's too. Approximate, and said so in the response: a
//! model the first stage misses is not ranked. Nothing per model stays in the replica's
//! memory but its record.

use std::cell::Cell;
use std::io;
use std::sync::Arc;

use rayon::prelude::*;

use super::catalog::Snapshot;
use super::config::{Config, FirstStageKind};
use super::App;
use crate::store::{Candidate, Kept, PostgresStore, Store, StoreError, VectorSpec};
use salient_core::descriptor::lfd::{LightFieldDescriptor, PACKED};
use salient_core::params::{Params, SimilarityParams};
use salient_core::rank::vectors::{self, Layout};
use salient_core::rank::{
    compact, Coverage, Fetch, Index, Method, Query, Ranking, Request, Row, Scope, Search,
};
use salient_core::signature::Signature;

/// What the first stage keeps: 1 the vectors alone, 2 with a compact form made of the
/// signature's sections, 3 with the compact form in the index's own layout, 4 with the light
/// field packed too. Rows made with another form carry another key and are made again.
const FORM: u32 = 4;

/// How the store makes the vectors: the pooled rows under the ranking parameters `params`
/// name, which a change of the weights they depend on (the hybrid's and `W`) makes again.
pub fn spec(params: &Params) -> VectorSpec {
    let similarity = params.similarity.clone();
    let key = serde_json::to_string(&(similarity.ecc_weight, &similarity.hybrid, FORM))
        .expect("parameters serialise");
    VectorSpec {
        dimensions: vectors::dimensions(params),
        key,
        vector: Arc::new(move |bytes| {
            let signature = Signature::from_bytes(bytes).ok()?;
            Some(Kept {
                vector: vector(&signature, &similarity)?,
                compact: compact::of(&signature),
                light_field: signature.lfd.as_ref()?.packed().to_vec(),
            })
        }),
    }
}

/// The PostgreSQL store at `url` for a replica of `config`: keeping the first stage when its
/// `index` ranks with it, and also when the database has one, so that the models this
/// replica writes are not missing from the other replicas' first stage.
pub fn open_store(url: &str, config: &Config) -> Result<PostgresStore, StoreError> {
    let store = PostgresStore::open(url)?;
    if config.index == FirstStageKind::Pgvector || store.has_first_stage()? {
        store.with_first_stage(spec(&config.params))
    } else {
        Ok(store)
    }
}

fn vector(signature: &Signature, params: &SimilarityParams) -> Option<Vec<f32>> {
    vectors::rows(signature, params, Layout::Pooled)?.pop()
}

/// Whether the first stage can rank with `signature`: it has the descriptors the vectors are
/// made of (a stored model made before one existed has not, until re-extracted).
pub fn ranks(signature: &Signature) -> bool {
    signature.lfd.is_some() && signature.geodesic.is_some()
}

/// The index a ranking on a snapshot of the catalogue searches: the snapshot's own, in
/// memory, or the first stage in the database.
pub enum Searcher<'a> {
    Memory(&'a Index),
    Database(InDatabase<'a>),
}

impl<'a> Searcher<'a> {
    /// The index of `snapshot` for a ranking of the models with `tag`.
    pub fn of(app: &'a App, snapshot: &'a Snapshot, tag: Option<&'a str>) -> Self {
        if snapshot.in_memory() {
            Searcher::Memory(&snapshot.index)
        } else {
            Searcher::Database(InDatabase {
                app,
                snapshot,
                tag,
                first_stage_ms: Cell::new(0.0),
            })
        }
    }

    /// Whether a ranking may miss a model nearer than those it returns.
    pub fn approximate(&self) -> bool {
        matches!(self, Searcher::Database(_))
    }

    /// The time the last search spent in the database.
    pub fn first_stage_ms(&self) -> Option<f64> {
        match self {
            Searcher::Memory(_) => None,
            Searcher::Database(d) => Some(d.first_stage_ms.get()),
        }
    }
}

impl Search for Searcher<'_> {
    fn search(&self, request: &Request) -> io::Result<Ranking> {
        match self {
            Searcher::Memory(index) => index.search(request),
            Searcher::Database(d) => d.search(request),
        }
    }

    fn coverage(&self, method: Method, scope: &Scope) -> Coverage {
        match self {
            Searcher::Memory(index) => index.coverage(method, scope),
            Searcher::Database(d) => d.coverage(method, scope),
        }
    }
}

/// The first stage in the database as an index (`--index pgvector`): a request's candidates
/// come from the store — a whole model's, about the `k × first_stage_oversampling` nearest
/// by their vectors, with their compact forms; a part's, the models its stored patches name
/// (none while the patches are still to be made) — and an index of their own ranks them as
/// the in-memory index ranks all models: the bounds first, then the exact distances of those
/// they leave, whose light fields come packed in a second round trip. Approximate: a model
/// the first stage misses is not ranked.
pub struct InDatabase<'a> {
    app: &'a App,
    snapshot: &'a Snapshot,
    /// The tag the first stage filters by, as the request's scope does.
    tag: Option<&'a str>,
    first_stage_ms: Cell<f64>,
}

impl Search for InDatabase<'_> {
    fn search(&self, request: &Request) -> io::Result<Ranking> {
        let (config, store) = (&self.app.config, &self.app.store);
        let stage = store.first_stage().expect("checked at start");
        let clock = std::time::Instant::now();
        let candidates = match request.query {
            Query::Model { signature, .. } => {
                let Some(vector) = vector(signature, &config.params.similarity) else {
                    return Err(io::Error::new(
                        io::ErrorKind::InvalidInput,
                        "a query without the first stage's descriptors",
                    ));
                };
                let count = request
                    .k
                    .saturating_mul(config.first_stage_oversampling)
                    .min(config.first_stage_max_candidates)
                    .max(request.k);
                stage.nearest(&vector, count, self.tag, request.scope.without)
            }
            Query::Part { nearest, .. } => {
                let ids: Vec<&str> = nearest.iter().map(|(_, id)| id.as_str()).collect();
                stage.compacts(&ids)
            }
        }
        .map_err(io::Error::other)?;
        self.first_stage_ms.set(clock.elapsed().as_secs_f64() * 1e3);
        let mut index = Index::away(
            config.params.similarity.clone(),
            light_fields(store.clone()),
        );
        // A compact form this release cannot read is a candidate left out, as a model
        // without a vector is.
        let rows: Vec<Row> = candidates
            .par_iter()
            .filter_map(|Candidate { id, compact }| {
                let row = index.compact_row(id.as_str(), compact);
                if row.is_err() {
                    tracing::warn!(%id, "a first-stage candidate's compact form is unreadable");
                }
                row.ok()
            })
            .collect();
        for row in rows {
            index.put(row);
        }
        index.search(request)
    }

    fn coverage(&self, _: Method, scope: &Scope) -> Coverage {
        self.snapshot.unranked(scope)
    }
}

/// The second round of a ranking: the light field descriptors of the candidates whose bounds
/// do not reject them, packed: unpacking one is a copy, where decoding its stored signature
/// costs ~38 µs, and a ranking of a thousand candidates reads ~900 (`benches/rank.rs`,
/// `SALIENT_RANK_FIRST_STAGE`: 31 against 64 ms a ranking on one thread).
fn light_fields(store: Arc<dyn Store>) -> Fetch {
    Arc::new(move |ids: &[Arc<str>]| {
        let ids: Vec<&str> = ids.iter().map(|id| &**id).collect();
        let stage = store.first_stage().expect("checked at start");
        let packed = stage.light_fields(&ids).map_err(io::Error::other)?;
        Ok(packed
            .into_iter()
            .filter_map(|(id, bytes)| {
                let Ok(packed) = <&[u8; PACKED]>::try_from(bytes.as_slice()) else {
                    tracing::warn!(%id, "a first-stage light field of another size");
                    return None;
                };
                Some((
                    Arc::from(id.as_str()),
                    LightFieldDescriptor::unpacked(packed),
                ))
            })
            .collect())
    })
}

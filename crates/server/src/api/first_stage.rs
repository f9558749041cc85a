//! The hybrid's rankings with their first stage in the database (`--index pgvector`, #40):
//! pgvector's HNSW index finds about the `k × first_stage_oversampling` models nearest the
//! query by their vectors ([`salient_core::rank::vectors`], one per model, pooled: as good as
//! one per light field in `benches/first_stage.rs`, at a tenth of the rows), with their
//! compact forms ([`salient_core::rank::compact`]) in the same round trip, and this replica
//! ranks those by their exact distance: the bounds first, then the distances of the few they
//! leave, whose light field descriptors come in batches from their stored signatures.
//! Approximate, and said so in the response: a model the first stage misses is not ranked.

use std::sync::Arc;

use rayon::prelude::*;

use super::config::{Config, FirstStageKind};
use super::error::AppError;
use super::App;
use crate::store::{Candidate, Kept, PostgresStore, Store, StoreError, VectorSpec};
use salient_core::params::{Params, SimilarityParams};
use salient_core::rank::vectors::{self, Layout};
use salient_core::rank::{compact, Fetch, Hit, Index, Method, Request, Row, Search};
use salient_core::signature::Signature;

/// What the first stage keeps: 1 the vectors alone, 2 with a compact form made of the
/// signature's sections, 3 with the compact form in the index's own layout. Rows made with
/// another form carry another key and are made again.
const FORM: u32 = 3;

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

/// A ranking of the first stage's candidates.
pub struct Ranked {
    pub hits: Vec<Hit>,
    /// Candidates whose exact distance was computed, and those rejected by a bound.
    pub evaluated: usize,
    pub pruned: usize,
    /// Time in the database.
    pub first_stage_ms: f64,
}

/// The `k` models nearest `query` by the hybrid distance among the first stage's candidates
/// that have `tag`, `without` left out; `None` for a query without a vector (a stored model
/// made before a descriptor existed), which the caller ranks on the exact index.
pub async fn rank(
    app: &Arc<App>,
    query: Arc<Signature>,
    k: usize,
    tag: Option<String>,
    without: Option<String>,
) -> Result<Option<Ranked>, AppError> {
    let params = app.config.params.similarity.clone();
    let Some(vector) = vector(&query, &params) else {
        return Ok(None);
    };
    let config = &app.config;
    let count = k
        .saturating_mul(config.first_stage_oversampling)
        .min(config.first_stage_max_candidates)
        .max(k);
    let clock = std::time::Instant::now();
    let candidates = app
        .with_store(move |store| {
            let stage = store.first_stage().expect("checked at start");
            stage.nearest(&vector, count, tag.as_deref(), without.as_deref())
        })
        .await?;
    let first_stage_ms = clock.elapsed().as_secs_f64() * 1e3;
    let fetch = light_fields(app.store.clone());
    let turn = app.rankers.turn().await;
    tokio::task::spawn_blocking(move || {
        turn.install(|| {
            // The candidates ranked as the in-memory index ranks all models: bounds first,
            // the exact distance of the few they cannot reject. A compact form this release
            // cannot read is a candidate left out, as a model without a vector is.
            let mut index = Index::away(params, fetch);
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
            let ranking = index
                .search(&Request::model(&query, Method::Hybrid, k))
                .map_err(AppError::index)?;
            Ok(Some(Ranked {
                hits: ranking.hits,
                evaluated: ranking.evaluated,
                pruned: ranking.pruned,
                first_stage_ms,
            }))
        })
    })
    .await
    .map_err(|e| AppError::Internal(format!("ranking failed: {e}")))?
}

/// The second round of a ranking: the light field descriptors of the candidates whose bounds
/// do not reject them, from their stored signatures.
fn light_fields(store: Arc<dyn Store>) -> Fetch {
    Arc::new(move |ids: &[Arc<str>]| {
        let ids: Vec<&str> = ids.iter().map(|id| &**id).collect();
        let stage = store.first_stage().expect("checked at start");
        let signatures = stage.signatures(&ids).map_err(std::io::Error::other)?;
        Ok(signatures
            .into_iter()
            .filter_map(|(id, bytes)| {
                let lfd = Signature::from_bytes(&bytes).ok()?.lfd?;
                Some((Arc::from(id.as_str()), lfd))
            })
            .collect())
    })
}

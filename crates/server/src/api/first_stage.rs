//! The hybrid's rankings with their first stage in the database (`--index pgvector`, #40):
//! pgvector's HNSW index finds about the `k × first_stage_oversampling` models nearest the
//! query by their vectors ([`salient_core::rank::vectors`], one per model, pooled: as good as
//! one per light field in `benches/first_stage.rs`, at a tenth of the rows), with their
//! signatures in the same round trip, and this replica ranks those by their exact distance.
//! Approximate, and said so in the response: a model the first stage misses is not ranked.

use std::sync::Arc;

use rayon::prelude::*;

use super::error::AppError;
use super::App;
use crate::store::{Candidate, VectorSpec};
use salient_core::params::{Params, SimilarityParams};
use salient_core::rank::vectors::{self, Layout};
use salient_core::rank::{distance, Hit, Method};
use salient_core::signature::Signature;

/// How the store makes the vectors: the pooled rows under the ranking parameters `params`
/// name, which a change of weights makes again.
pub fn spec(params: &Params) -> VectorSpec {
    let similarity = params.similarity.clone();
    let key = serde_json::to_string(&similarity.hybrid).expect("parameters serialise");
    VectorSpec {
        dimensions: vectors::dimensions(params),
        key,
        vector: Arc::new(move |bytes| {
            let signature = Signature::from_bytes(bytes).ok()?;
            vector(&signature, &similarity)
        }),
    }
}

fn vector(signature: &Signature, params: &SimilarityParams) -> Option<Vec<f32>> {
    vectors::rows(signature, params, Layout::Pooled)?.pop()
}

/// A ranking of the first stage's candidates.
pub struct Ranked {
    pub hits: Vec<Hit>,
    /// Candidates whose exact distance was computed.
    pub evaluated: usize,
}

/// The `k` models nearest `query` by the hybrid distance among the first stage's candidates
/// that have `tag`, `without` left out.
pub async fn rank(
    app: &Arc<App>,
    query: Arc<Signature>,
    k: usize,
    tag: Option<String>,
    without: Option<String>,
) -> Result<Ranked, AppError> {
    let params = app.config.params.similarity.clone();
    let Some(vector) = vector(&query, &params) else {
        // A query is extracted today: it has every descriptor.
        return Err(AppError::Internal(
            "a query without a first-stage vector".into(),
        ));
    };
    let config = &app.config;
    let count = k
        .saturating_mul(config.first_stage_oversampling)
        .min(config.first_stage_max_candidates)
        .max(k);
    let candidates = app
        .with_store(move |store| {
            let stage = store.first_stage().expect("checked at start");
            stage.nearest(&vector, count, tag.as_deref(), without.as_deref())
        })
        .await?;
    let app = app.clone();
    let turn = app.rankers.turn().await;
    tokio::task::spawn_blocking(move || {
        turn.install(|| {
            let mut scored: Vec<Hit> = candidates
                .par_iter()
                .filter_map(|Candidate { id, signature }| {
                    let signature = Signature::from_bytes(signature).ok()?;
                    Some(Hit {
                        id: id.to_string(),
                        distance: distance(Method::Hybrid, &query, &signature, &params),
                        part_scale: None,
                    })
                })
                .collect();
            let evaluated = scored.len();
            scored.sort_by(|a, b| a.distance.total_cmp(&b.distance).then(a.id.cmp(&b.id)));
            scored.truncate(k);
            Ranked {
                hits: scored,
                evaluated,
            }
        })
    })
    .await
    .map_err(|e| AppError::Internal(format!("ranking failed: {e}")))
}

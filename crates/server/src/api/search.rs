//! Similarity search by upload and by stored model, and extraction without storing.

use std::sync::Arc;
use std::time::Instant;

use axum::extract::State;
use axum::Json;
use serde::{Deserialize, Serialize};

use super::error::{AppError, ErrorBody};
use super::first_stage::{self, Searcher};
use super::models::no_model;
use super::request::{AppPath, AppQuery, ModelPath};
use super::upload::MeshUpload;
use super::{App, AppState, Snapshot};
use crate::model::ModelId;
use crate::model::Upload;
use crate::store::Derived;
use salient_core::descriptor::patch::{Packed, PackedPiece};
use salient_core::mesh::load_bytes;
use salient_core::params::SimilarityParams;
use salient_core::part_search::{self, PartQuery, SearchError};
use salient_core::partial::Target;
use salient_core::pipeline::Extent;
use salient_core::rank::{explain, Coverage, Hit, Method, Request, Scope, Search, PARTS};
use salient_core::signature::Signature;

/// Query of the search endpoints.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct SearchQuery {
    /// Number of results (default 10; at most the server's `max_k`, 1000 by default).
    #[param(minimum = 1)]
    pub k: Option<usize>,
    /// `hybrid` (default: the other methods' distances, weighted), `ecc` (salient features,
    /// penalised EMD), `d2` (global shape distribution), `lfd` (Light Field Descriptor) or
    /// `geodesic` (geodesic distance distributions).
    #[param(value_type = Option<String>, pattern = "^(hybrid|ecc|d2|lfd|geodesic)$")]
    pub method: Option<Method>,
    /// Weight `W` of the ECC distance against the region D2 distance, in [0, 1]. A value other
    /// than the configured one ranks without the bound-based pruning, so it is slower.
    #[param(minimum = 0.0, maximum = 1.0)]
    pub w: Option<f64>,
    /// Only models with this tag.
    pub tag: Option<String>,
    /// Explain each result: its distance by every method, and which salient features of the
    /// query the EMD matched to which of the result's (default false).
    pub explain: Option<bool>,
    /// `whole` (default): the upload is a model. `partial` (`POST /v1/search` only): the
    /// upload is a piece of one — cut from it, with an open boundary — and the results are
    /// the models with a part like it: first those it was registered into (the nearest by
    /// their stored patch descriptors, `similarity.partial.verified` of them), by how well
    /// it lies on their surface, then the others by how well all of its salient features
    /// fit among theirs. `method` and `w` do not apply; `explain` gives where the part lies in
    /// each model it was registered into (`placement`).
    #[param(value_type = Option<String>, pattern = "^(whole|partial)$")]
    pub mode: Option<SearchMode>,
    /// With `mode=partial`: the part's size in its model, when known (its largest distance
    /// from its own centroid over the model's, in [0.2, 1]). Default: each of the
    /// configured sizes (`similarity.partial.scales`) is tried, and a model ranks by the best.
    #[param(minimum = 0.2, maximum = 1.0)]
    pub part_scale: Option<f64>,
}

/// What an uploaded query is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum SearchMode {
    /// A whole model.
    #[default]
    Whole,
    /// A piece of a model ([`salient_core::partial`]).
    Partial,
}

/// A size a part was described at (`mode=partial`).
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PartSize {
    /// The part's radius over the model's.
    pub scale: f64,
    /// Its salient features at that size.
    pub features: usize,
}

/// One ranked model.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SearchHit {
    pub rank: usize,
    pub id: String,
    pub name: Option<String>,
    pub tags: Vec<String>,
    pub class: Option<String>,
    /// Lower is more similar: the weighted sum of the parts' distances, each divided by its
    /// scale (`hybrid`), `SIM` of SPEC §5 (`ecc`), or the D2, LFD or geodesic distance.
    pub distance: f64,
    /// With `mode=partial`: the size (part radius over model radius) the part fitted this
    /// model at.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub part_scale: Option<f64>,
    /// With `mode=partial`, for the models the part was registered into (those nearest it by
    /// their stored patches, `similarity.partial.verified` of them): how far the part's
    /// surface stays from this model's once registered into it, in units of the part's size
    /// there. Near 0 for the model the part was cut from; these models rank first, by it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub residual: Option<f64>,
    /// With `mode=partial&explain=true`, for the models the part was registered into: where
    /// it lies in this model, the 4 × 4 matrix (column-major, as glTF's `matrix`) taking the
    /// part's coordinates as uploaded to this model's as stored (a rotation, a uniform scale
    /// and a shift).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(min_items = 16, max_items = 16)]
    pub placement: Option<[f64; 16]>,
    /// With `explain=true`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub explanation: Option<Explanation>,
}

/// Why a model ranked where it did.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Explanation {
    /// The distance by each method that can compare the two (`hybrid`, `ecc`, `d2`, `lfd`,
    /// `geodesic`).
    pub distances: std::collections::BTreeMap<String, f64>,
    /// Each weighed part's term of the hybrid distance (`ecc`, `d2`, `lfd`, `geodesic`:
    /// weight × distance / scale); they sum to `distances.hybrid`. A part of weight 0, or one
    /// left out (a descriptor one side lacks), is missing.
    pub contributions: std::collections::BTreeMap<String, f64>,
    /// The optimal EMD plan between the salient features (paper Eq. 9): each flow from a
    /// query feature to a result feature.
    pub matches: Vec<FeatureMatch>,
}

/// One flow of the EMD between the query's and a result's salient features.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct FeatureMatch {
    /// Index of the query's feature (its order in the query's signature and preview).
    pub query: usize,
    /// Index of the result's feature.
    pub result: usize,
    /// Share of the total mass moved (the masses of a result sum to 1).
    pub mass: f64,
    /// Ground distance of the two features (Eq. 11).
    pub ground_distance: f64,
    /// The two salient points, each in its own model's coordinates.
    pub query_position: [f64; 3],
    pub result_position: [f64; 3],
}

/// The query's salient features, with `explain=true`.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct QueryFeatures {
    pub features: Vec<QueryFeature>,
}

/// A salient feature of the query.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct QueryFeature {
    /// The salient point, in the query's own coordinates.
    pub position: [f64; 3],
    /// Geodesic radius of its region, normalised units (SPEC §3.3).
    pub region_size: f64,
}

/// Milliseconds spent on each part of the request.
#[derive(Debug, Default, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Timings {
    pub extract_ms: f64,
    pub search_ms: f64,
    /// With `--index pgvector`: the part of `search_ms` spent in the database, finding the
    /// candidates and reading their signatures.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub first_stage_ms: Option<f64>,
    pub total_ms: f64,
}

/// A ranked list.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SearchResponse {
    /// The method ranked by; `ecc` under `mode=partial` (salient features only).
    #[schema(value_type = String)]
    pub method: Method,
    /// What the upload was searched as: `whole`, or `partial` (a piece of a model).
    pub mode: SearchMode,
    pub k: usize,
    pub results: Vec<SearchHit>,
    /// Whether a model nearer than these results may be missing from them: the hybrid's
    /// rankings with their first stage in the database (`--index pgvector`) are approximate
    /// (recall in README, "Scaling past one machine"); the others are exact.
    pub approximate: bool,
    /// Models whose exact distance was computed, and models rejected by a lower bound.
    pub evaluated: usize,
    pub pruned: usize,
    /// Models left out because their stored signature lacks what the method compares; they
    /// are being re-extracted (`GET /v1/admin/reindex`), and join the rankings when done.
    pub left_out: usize,
    /// Models ranked on part of the `hybrid` distance, because their stored signature lacks
    /// one of its descriptors (the others count for it until they are re-extracted).
    pub partial: usize,
    /// Salient features of the query; 0 under `d2`, `lfd` and `geodesic`, which compare none:
    /// an uploaded query's ECC is not computed for them.
    pub query_features: usize,
    /// With `explain=true`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub query: Option<QueryFeatures>,
    /// With `mode=partial`: the sizes the part was described at.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub part_sizes: Option<Vec<PartSize>>,
    pub timings: Timings,
}

/// The explanation of `result`'s distance from `query` ([`salient_core::rank::explain`]).
fn explanation(query: &Signature, result: &Signature, params: &SimilarityParams) -> Explanation {
    let explained = explain(query, result, params);
    Explanation {
        distances: explained
            .distances
            .into_iter()
            .map(|(m, d)| (m.to_string(), d))
            .collect(),
        contributions: PARTS
            .into_iter()
            .zip(explained.contributions)
            .filter_map(|(m, c)| Some((m.to_string(), c?)))
            .collect(),
        matches: explained
            .matches
            .into_iter()
            .map(|m| FeatureMatch {
                query: m.p,
                result: m.q,
                mass: m.mass,
                ground_distance: m.ground_distance,
                query_position: query.features[m.p].position,
                result_position: result.features[m.q].position,
            })
            .collect(),
    }
}

/// The `k` a query asks for, within the server's limit.
fn requested_k(app: &AppState, q: &SearchQuery) -> Result<usize, AppError> {
    let k = q.k.unwrap_or(10);
    if k == 0 || k > app.config.max_k {
        return Err(AppError::bad_request(
            "invalid_query",
            format!("k must be between 1 and {}", app.config.max_k),
        ));
    }
    Ok(k)
}

/// Whether a model has `tag` (every model when there is none).
fn tagged<'a>(catalog: &'a Snapshot, tag: &'a Option<String>) -> impl Fn(&str) -> bool + Sync + 'a {
    move |id: &str| {
        tag.as_ref()
            .is_none_or(|t| catalog.records.get(id).is_some_and(|r| r.tags.contains(t)))
    }
}

/// The models a ranking considers: those with `tag` ([`tagged`]), `without` left out.
fn scope<'a>(
    tag: &Option<String>,
    tagged: &'a (dyn Fn(&str) -> bool + Sync),
    without: Option<&'a str>,
) -> Scope<'a> {
    Scope {
        without,
        keep: tag.is_some().then_some(tagged),
    }
}

/// A whole model's ranking as a response reports it.
struct Ranked {
    results: Vec<SearchHit>,
    evaluated: usize,
    pruned: usize,
    left_out: usize,
    partial: usize,
    approximate: bool,
    first_stage_ms: Option<f64>,
}

/// Ranked hits with what the catalogue records of each.
fn search_hits(catalog: &Snapshot, hits: Vec<Hit>) -> Vec<SearchHit> {
    hits.into_iter()
        .enumerate()
        .map(|(i, hit)| {
            let record = catalog.records.get(hit.id.as_str());
            SearchHit {
                explanation: None,
                part_scale: hit.part_scale,
                residual: None,
                placement: None,
                rank: i + 1,
                name: record.and_then(|r| r.name.clone()),
                tags: record.map(|r| r.tags.clone()).unwrap_or_default(),
                class: record.and_then(|r| r.class.clone()),
                id: hit.id,
                distance: hit.distance,
            }
        })
        .collect()
}

/// Search with a part (`mode=partial`): the part described at each size on the extraction
/// pool, then [`part_search::search`] over the catalogue's snapshot and the stored patches.
async fn search_part(
    app: &AppState,
    q: SearchQuery,
    upload: Upload,
    clock: Instant,
) -> Result<Json<SearchResponse>, AppError> {
    if q.method.is_some() || q.w.is_some() {
        return Err(AppError::bad_request(
            "invalid_query",
            "method and w do not apply to mode=partial",
        ));
    }
    let explain = q.explain.unwrap_or(false);
    let k = requested_k(app, &q)?;
    let scales = app.config.params.similarity.partial.sizes(q.part_scale);
    let params = app.config.params.clone();
    let limits = app.config.limits;
    let query = app
        .pool
        .run(move || {
            let raw = load_bytes(&upload.mesh, upload.format, &upload.resources, &limits)?;
            PartQuery::extract(&raw, &params, &scales)
        })
        .await??;
    let extract_ms = clock.elapsed().as_secs_f64() * 1e3;
    let search_clock = Instant::now();
    let worker = app.0.clone();
    let tag = q.tag;
    let verified = app.config.params.similarity.partial.verified;
    // On the extraction pool, not the rankers: its registrations are as heavy as an
    // extraction, and are bounded by the same queue and time limit.
    let (query, mut results, ranking, approximate) = app
        .pool
        .run(move || {
            let catalog = worker.catalog.snapshot();
            let tagged = tagged(&catalog, &tag);
            let scope = scope(&tag, &tagged, None);
            let library = Stored {
                app: &worker,
                catalog: &catalog,
            };
            let index = Searcher::of(&worker, &catalog, tag.as_deref());
            let ranking = part_search::search(&query, &index, scope, &library, verified, k)
                .map_err(|e| match e {
                    SearchError::Index(e) => AppError::index(e),
                    SearchError::Library(e) => e,
                })?;
            let hits = ranking.hits.iter().map(|h| Hit {
                id: h.id.clone(),
                distance: h.distance,
                part_scale: h.part_scale,
            });
            let mut results = search_hits(&catalog, hits.collect());
            for (result, hit) in results.iter_mut().zip(&ranking.hits) {
                result.residual = hit.residual();
                if explain {
                    result.placement = hit.registration.map(|r| r.placement.to_cols_array());
                }
            }
            let approximate = index.approximate();
            Ok::<_, AppError>((query, results, ranking, approximate))
        })
        .await??;
    for (i, hit) in results.iter_mut().enumerate() {
        hit.rank = i + 1;
    }
    let search_seconds = search_clock.elapsed().as_secs_f64();
    app.metrics.search_seconds.observe(search_seconds);
    let part_sizes: Vec<PartSize> = query
        .part
        .sizes()
        .map(|(scale, features)| PartSize { scale, features })
        .collect();
    Ok(Json(SearchResponse {
        method: Method::Ecc,
        mode: SearchMode::Partial,
        k,
        results,
        approximate,
        evaluated: ranking.evaluated,
        pruned: ranking.pruned,
        left_out: 0,
        partial: 0,
        query_features: part_sizes.iter().map(|s| s.features).max().unwrap_or(0),
        query: None,
        part_sizes: Some(part_sizes),
        timings: Timings {
            extract_ms,
            search_ms: search_seconds * 1e3,
            first_stage_ms: None,
            total_ms: clock.elapsed().as_secs_f64() * 1e3,
        },
    }))
}

/// The stored models as partial search verifies against them: their patches in the store
/// ([`Derived::Patches`] of today's layout), their uploads prepared as targets.
struct Stored<'a> {
    app: &'a App,
    catalog: &'a Snapshot,
}

impl part_search::Library for Stored<'_> {
    type Error = AppError;

    fn nearest(&self, piece: &PackedPiece) -> Result<Vec<(Vec<f64>, String)>, AppError> {
        let mut nearest = Vec::new();
        for entry in self.app.store.all_derived(Derived::Patches) {
            let (id, bytes) = entry?;
            if let Some(packed) = Packed::from_bytes(&bytes) {
                nearest.push((packed.nearest(piece), id.to_string()));
            }
        }
        Ok(nearest)
    }

    /// Kept while recently used, by content hash.
    fn target(&self, id: &str) -> Result<Option<Arc<Target>>, AppError> {
        let Some(record) = self.catalog.records.get(id) else {
            return Ok(None);
        };
        let hash = &record.content_hash;
        let targets = &self.app.verifier.targets;
        if let Some(target) = targets.lock().expect("never poisoned").get(hash) {
            return Ok(Some(target.clone()));
        }
        let Some(upload) = self.app.store.upload(id)? else {
            return Ok(None);
        };
        // A stored model that no longer loads or prepares (limits lowered since it was
        // added) is left unverified rather than failing the search.
        let config = &self.app.config;
        let Ok(target) = load_bytes(
            &upload.mesh,
            upload.format,
            &upload.resources,
            &config.limits,
        )
        .and_then(|raw| Target::new(&raw, &config.params.mesh)) else {
            return Ok(None);
        };
        let target = Arc::new(target);
        targets
            .lock()
            .expect("never poisoned")
            .put(hash.to_string(), target.clone());
        Ok(Some(target))
    }
}

/// A whole-model ranking's options, checked before anything is extracted or read: a bad
/// query costs no extraction.
struct WholeQuery {
    k: usize,
    method: Method,
    params: SimilarityParams,
    explain: bool,
    tag: Option<String>,
}

impl WholeQuery {
    fn of(app: &AppState, q: SearchQuery) -> Result<Self, AppError> {
        let k = requested_k(app, &q)?;
        let mut params = app.config.params.similarity.clone();
        if let Some(w) = q.w {
            if !(0.0..=1.0).contains(&w) {
                return Err(AppError::bad_request(
                    "invalid_query",
                    "w must be in [0, 1]",
                ));
            }
            params.ecc_weight = w;
        }
        Ok(Self {
            k,
            method: q.method.unwrap_or_default(),
            params,
            explain: q.explain.unwrap_or(false),
            tag: q.tag,
        })
    }
}

/// Ranks the catalog against `query` off the async threads.
async fn rank(
    app: &AppState,
    query: Arc<Signature>,
    q: WholeQuery,
    exclude: Option<ModelId>,
    clock: Instant,
    extract_ms: f64,
) -> Result<Json<SearchResponse>, AppError> {
    let WholeQuery {
        k,
        method,
        params,
        explain: explain_hits,
        tag,
    } = q;
    let search_clock = Instant::now();
    let query_features = query.features.len();
    let query_description = explain_hits.then(|| QueryFeatures {
        features: query
            .features
            .iter()
            .map(|f| QueryFeature {
                position: f.position,
                region_size: f.region_size,
            })
            .collect(),
    });
    let explained = explain_hits.then(|| (query.clone(), params.clone()));
    let snapshot = app.catalog.snapshot();
    if !snapshot.in_memory() && !first_stage::ranks(&query) {
        return Err(AppError::Conflict(
            "this model's signature lacks the descriptors the first stage in the database ranks \
             by (it was made by an earlier release): re-extract it (POST /v1/reindex)"
                .to_string(),
        ));
    }
    drop(snapshot);
    let worker = app.0.clone();
    let results = app
        .read_catalog(move |catalog| {
            let tagged = tagged(catalog, &tag);
            let scope = scope(&tag, &tagged, exclude.as_ref().map(ModelId::as_str));
            let index = Searcher::of(&worker, catalog, tag.as_deref());
            let ranking = index.search(
                &Request::model(&query, method, k)
                    .params(&params)
                    .scope(scope),
            )?;
            let Coverage { left_out, partial } = index.coverage(method, &scope);
            let results = search_hits(catalog, ranking.hits);
            Ok(Ranked {
                results,
                evaluated: ranking.evaluated,
                pruned: ranking.pruned,
                left_out,
                partial,
                approximate: index.approximate(),
                first_stage_ms: index.first_stage_ms(),
            })
        })
        .await?
        .map_err(AppError::index)?;
    let search_seconds = search_clock.elapsed().as_secs_f64();
    app.metrics.search_seconds.observe(search_seconds);
    let Ranked {
        mut results,
        evaluated,
        pruned,
        left_out,
        partial,
        approximate,
        first_stage_ms,
    } = results;
    if let Some((query, params)) = explained {
        // What an explanation shows (feature positions, every method's distance) is read
        // from the store: the index keeps only what ranking compares. A model deleted since
        // the ranking has none.
        let ids: Vec<String> = results.iter().map(|r| r.id.clone()).collect();
        let explanations = app
            .with_store(move |store| {
                ids.iter()
                    .map(|id| {
                        let stored = store.decoded_signature(id)?;
                        Ok(stored.map(|result| explanation(&query, &result, &params)))
                    })
                    .collect::<Result<Vec<_>, _>>()
            })
            .await?;
        for (result, explanation) in results.iter_mut().zip(explanations) {
            result.explanation = explanation;
        }
    }
    Ok(Json(SearchResponse {
        method,
        mode: SearchMode::Whole,
        k,
        results,
        approximate,
        evaluated,
        pruned,
        left_out,
        partial,
        query_features,
        query: query_description,
        part_sizes: None,
        timings: Timings {
            extract_ms,
            search_ms: search_seconds * 1e3,
            first_stage_ms,
            total_ms: clock.elapsed().as_secs_f64() * 1e3,
        },
    }))
}

/// Search by upload: the stored models most similar to the uploaded mesh.
#[utoipa::path(
    post,
    path = "/v1/search",
    tag = "search",
    params(SearchQuery),
    responses(
        (status = 200, description = "Ranked models", body = SearchResponse),
        (status = 400, description = "Bad query or mesh file", body = ErrorBody),
        (status = 413, description = "Body or mesh over the limits", body = ErrorBody),
        (status = 415, description = "Unsupported format", body = ErrorBody),
        (status = 422, description = "Unusable mesh", body = ErrorBody),
        (status = 503, description = "Extraction queue full or time limit reached", body = ErrorBody)
    )
)]
pub async fn search(
    State(app): State<AppState>,
    AppQuery(q): AppQuery<SearchQuery>,
    upload: MeshUpload,
) -> Result<Json<SearchResponse>, AppError> {
    let clock = Instant::now();
    if q.mode == Some(SearchMode::Partial) {
        return search_part(&app, q, upload.upload, clock).await;
    }
    if q.part_scale.is_some() {
        return Err(AppError::bad_request(
            "invalid_query",
            "part_scale applies to mode=partial only",
        ));
    }
    let q = WholeQuery::of(&app, q)?;
    // A method that compares no salient features (and no explanation, which shows every
    // method's distance) needs no ECC of the upload: most of an extraction's cost.
    let extent = if q.explain || q.method.needs_features(&app.config.params.similarity) {
        Extent::Full
    } else {
        Extent::Global
    };
    let signature = app.extract_query(Arc::new(upload.upload), extent).await?;
    let extract_ms = clock.elapsed().as_secs_f64() * 1e3;
    rank(&app, signature, q, None, clock, extract_ms).await
}

/// The stored models most similar to a stored model (itself left out).
#[utoipa::path(
    get,
    path = "/v1/models/{id}/similar",
    tag = "search",
    params(ModelPath, SearchQuery),
    responses(
        (status = 200, description = "Ranked models", body = SearchResponse),
        (status = 400, description = "Bad id or query", body = ErrorBody),
        (status = 404, description = "No such model", body = ErrorBody),
        (status = 409, description = "The model's stored signature lacks the method's descriptor, or (with the first stage in the database) one its vectors are made of; it is being re-extracted", body = ErrorBody)
    )
)]
pub async fn similar(
    State(app): State<AppState>,
    AppPath(path): AppPath<ModelPath>,
    AppQuery(q): AppQuery<SearchQuery>,
) -> Result<Json<SearchResponse>, AppError> {
    let id = path.id()?;
    if q.mode == Some(SearchMode::Partial) || q.part_scale.is_some() {
        return Err(AppError::bad_request(
            "invalid_query",
            "a stored model is a whole model: mode=partial applies to POST /v1/search",
        ));
    }
    let q = WholeQuery::of(&app, q)?;
    let clock = Instant::now();
    let signature = app
        .stored_signature(&id)
        .await?
        .map(Arc::new)
        .ok_or_else(|| no_model(&id))?;
    let method = q.method;
    if !method.ranks(&*signature) {
        return Err(AppError::Conflict(format!(
            "model {:?} was stored without the {method} descriptor; it is re-extracted in the background (see GET /v1/admin/reindex; POST it to start)",
            id.as_str()
        )));
    }
    rank(&app, signature, q, Some(id), clock, 0.0).await
}

/// The signature of an uploaded mesh, stored nowhere.
#[utoipa::path(
    post,
    path = "/v1/extract",
    tag = "search",
    responses(
        (status = 200, description = "The signature (see `salient extract --json`)", body = Object),
        (status = 400, description = "Bad mesh file", body = ErrorBody),
        (status = 413, description = "Body or mesh over the limits", body = ErrorBody),
        (status = 415, description = "Unsupported format", body = ErrorBody),
        (status = 422, description = "Unusable mesh", body = ErrorBody),
        (status = 503, description = "Extraction queue full or time limit reached", body = ErrorBody)
    )
)]
pub async fn extract(
    State(app): State<AppState>,
    upload: MeshUpload,
) -> Result<Json<Signature>, AppError> {
    let signature = app
        .extract_query(Arc::new(upload.upload), Extent::Full)
        .await?;
    Ok(Json(Signature::clone(&signature)))
}

//! `/v1/duplicates`: near-duplicates of an upload, and groups of them over the library
//! ([`salient_core::duplicate`] decides; this module finds candidates in the catalogue, loads the
//! meshes to verify and pages the answer).
//!
//! Groups are computed when asked, from the current snapshot, in a stable order (by their
//! first id), so a page's `next` stays meaningful while models come and go: a group whose
//! first id is past the cursor is on a later page. Verdicts are remembered by the two
//! uploads' content hashes (a verdict depends only on the two files and the thresholds), so
//! the next pages, and the next listing after a few uploads, verify only new pairs. Pairs an
//! operator dismissed ([`super::dismissed`]) are never verified.

use std::collections::{BTreeMap, HashMap};
use std::num::NonZeroUsize;
use std::sync::{Arc, Mutex};

use axum::extract::State;
use axum::Json;
use serde::{Deserialize, Serialize};

use super::error::{AppError, ErrorBody};
use super::evidence::{DuplicateMatch, EvidenceSchema};
use super::first_stage::Searcher;
use super::request::{page_size, AppQuery};
use super::upload::MeshUpload;
use super::{App, AppState};
use crate::model::{ModelId, Upload};
use salient_core::duplicate::{groups, verify, Evidence, Link, Shape, Verdict};
use salient_core::mesh::load_bytes;
use salient_core::partial::Target;
use salient_core::pipeline::Extent;
use salient_core::rank::{Method, Request, Scope, Search};
use salient_core::signature::Signature;

/// Meshes kept ready for verification (a shape of 10 000 vertices takes ~1 MB) …
const SHAPES: NonZeroUsize = NonZeroUsize::new(64).expect("not zero");
/// … if they have at most this many vertices, so that the cache stays under ~1 GB.
const SHAPE_VERTICES: usize = 100_000;
/// Partial search's registration targets kept (under 1 MB each: a surface of at most
/// `mesh.max_vertices` and 192 patches).
const TARGETS: NonZeroUsize = NonZeroUsize::new(64).expect("not zero");
/// Verdicts remembered (~200 bytes each).
const VERDICTS: NonZeroUsize = NonZeroUsize::new(200_000).expect("not zero");

/// What verification remembers between requests.
pub struct Verifier {
    shapes: Mutex<lru::LruCache<String, Arc<Shape>>>,
    verdicts: Mutex<lru::LruCache<(String, String), Option<Verdict>>>,
    /// Stored models as partial search registers parts into them, by content hash.
    pub(super) targets: Mutex<lru::LruCache<String, Arc<Target>>>,
}

impl Default for Verifier {
    fn default() -> Self {
        Self {
            shapes: Mutex::new(lru::LruCache::new(SHAPES)),
            verdicts: Mutex::new(lru::LruCache::new(VERDICTS)),
            targets: Mutex::new(lru::LruCache::new(TARGETS)),
        }
    }
}

/// The stored models an upload duplicates, strongest evidence first.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CheckResponse {
    pub matches: Vec<DuplicateMatch>,
}

/// Query of `GET /v1/duplicates`.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct GroupsQuery {
    /// The weakest evidence that joins models into a group (default `same_shape`; `mirrored`
    /// adds mirror images).
    #[param(value_type = Option<String>, pattern = "^(identical_file|identical_geometry|same_shape|mirrored)$")]
    pub min_evidence: Option<Evidence>,
    /// Groups per page, 1–1000 (default 100).
    #[param(minimum = 1, maximum = 1000)]
    pub limit: Option<usize>,
    /// Return the groups whose first id is after this one (the `next` of the previous page).
    pub after: Option<String>,
}

/// Models that are one asset.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct DuplicateGroup {
    /// In id order.
    pub ids: Vec<String>,
    /// The weakest evidence the group needs to hold together.
    #[schema(value_type = EvidenceSchema)]
    pub evidence: Evidence,
    /// For each of `ids`, the best score of its links within the group.
    pub scores: Vec<f64>,
}

/// A page of groups.
#[derive(Debug, Serialize, Deserialize, utoipa::ToSchema)]
pub struct GroupPage {
    pub groups: Vec<DuplicateGroup>,
    /// Pass as `after` to get the next page; absent on the last page.
    pub next: Option<String>,
}

/// The stored models an uploaded mesh duplicates.
///
/// The same file (`identical_file`), the same mesh in another format, unit or place
/// (`identical_geometry`), the same surface rotated, rescaled or remeshed (`same_shape`), or
/// its mirror image (`mirrored`). Another model of the same kind, or another pose of the same
/// character, is not a duplicate.
#[utoipa::path(
    post,
    path = "/v1/duplicates/check",
    tag = "duplicates",
    responses(
        (status = 200, description = "Matches, strongest evidence first", body = CheckResponse),
        (status = 400, description = "Bad mesh file", body = ErrorBody),
        (status = 413, description = "Body or mesh over the limits", body = ErrorBody),
        (status = 415, description = "Unsupported format", body = ErrorBody),
        (status = 422, description = "Unusable mesh", body = ErrorBody),
        (status = 503, description = "Extraction queue full or time limit reached", body = ErrorBody)
    )
)]
pub async fn check_duplicates(
    State(app): State<AppState>,
    upload: MeshUpload,
) -> Result<Json<CheckResponse>, AppError> {
    let upload = Arc::new(upload.upload);
    let query = app.extract_query(upload.clone(), Extent::Global).await?;
    let matches = duplicates_of(&app, upload, query, None).await?;
    Ok(Json(CheckResponse { matches }))
}

/// Groups of stored models that are one asset, a page at a time.
///
/// Candidates come from the ranking index's descriptors and bounds, so not every pair is
/// compared; each is verified on the meshes.
#[utoipa::path(
    get,
    path = "/v1/duplicates",
    tag = "duplicates",
    params(GroupsQuery),
    responses(
        (status = 200, description = "A page of groups, in the order of their first ids", body = GroupPage),
        (status = 400, description = "Bad query", body = ErrorBody),
        (status = 409, description = "This replica ranks with its first stage in the database (`--index pgvector`), which does not compare every model with every other: ask a replica with the in-memory index", body = ErrorBody),
        (status = 503, description = "Verification queue full or time limit reached", body = ErrorBody)
    )
)]
pub async fn list_duplicates(
    State(app): State<AppState>,
    AppQuery(q): AppQuery<GroupsQuery>,
) -> Result<Json<GroupPage>, AppError> {
    let limit = page_size(q.limit)?;
    let min = q.min_evidence.unwrap_or(Evidence::SameShape);
    let p = app.config.params.similarity.duplicates.clone();
    if !app.catalog.snapshot().in_memory() {
        return Err(AppError::NotConfigured(
            "duplicate groups compare every stored model with the others, which needs the \
             in-memory index: ask a replica started with --index memory (a check of one \
             upload, POST /v1/duplicates/check, works here)"
                .to_string(),
        ));
    }
    let (candidates, records) = app
        .read_catalog(move |catalog| {
            let pairs = catalog.index.near_pairs(p.d2, p.lfd)?;
            let hashes: BTreeMap<String, String> = catalog
                .records
                .iter()
                .map(|(id, r)| (id.to_string(), r.content_hash.clone()))
                .collect();
            Ok::<_, std::io::Error>((pairs, hashes))
        })
        .await?
        .map_err(AppError::index)?;
    let mut same_file: HashMap<&str, Vec<&str>> = HashMap::new();
    for (id, hash) in &records {
        same_file.entry(hash).or_default().push(id);
    }
    let mut links: Vec<Link<String>> = same_file
        .values()
        .flat_map(|ids| {
            ids.iter().enumerate().flat_map(move |(k, a)| {
                ids[k + 1..].iter().map(move |b| Link {
                    a: a.to_string(),
                    b: b.to_string(),
                    verdict: Verdict::IDENTICAL_FILE,
                })
            })
        })
        .collect();
    let pairs: Vec<(String, String, String, String)> = candidates
        .into_iter()
        .filter_map(|(a, b)| {
            let (ha, hb) = (records.get(&*a)?, records.get(&*b)?);
            (ha != hb && !app.dismissed.contains(ha, hb))
                .then(|| (a.to_string(), b.to_string(), ha.clone(), hb.clone()))
        })
        .collect();
    let worker = app.0.clone();
    let verdicts = app
        .pool
        .run(move || {
            pairs
                .into_iter()
                .map(|(a, b, ha, hb)| {
                    let verdict = worker.verdict((&a, &ha), (&b, &hb), None)?;
                    Ok(verdict.map(|verdict| Link { a, b, verdict }))
                })
                .collect::<Result<Vec<_>, AppError>>()
        })
        .await??;
    links.extend(verdicts.into_iter().flatten());
    let after = q.after.unwrap_or_default();
    let mut page = groups(&links, min)
        .into_iter()
        .filter(|g| g.ids[0] > after)
        .map(|g| DuplicateGroup {
            ids: g.ids,
            evidence: g.evidence,
            scores: g.scores,
        });
    let groups: Vec<DuplicateGroup> = page.by_ref().take(limit).collect();
    let next = page.next().and(groups.last().map(|g| g.ids[0].clone()));
    Ok(Json(GroupPage { groups, next }))
}

/// The stored models (but `exclude`) that `upload`, whose signature is `query` (global
/// descriptors at least), duplicates, strongest evidence first, then best score, then id.
pub(super) async fn duplicates_of(
    app: &AppState,
    upload: Arc<Upload>,
    query: Arc<Signature>,
    exclude: Option<ModelId>,
) -> Result<Vec<DuplicateMatch>, AppError> {
    let p = app.config.params.similarity.duplicates.clone();
    let hash = upload.content_hash().to_string();
    let ranker = app.0.clone();
    let (same_file, mut candidates) = app
        .read_catalog(move |catalog| {
            let without = exclude.as_ref().map(ModelId::as_str);
            let same_file: Vec<String> = catalog
                .records
                .values()
                .filter(|r| r.content_hash == hash && Some(r.id.as_str()) != without)
                .map(|r| r.id.to_string())
                .collect();
            let scope = Scope {
                without,
                keep: None,
            };
            let ranking = Searcher::of(&ranker, catalog, None).search(
                &Request::model(&query, Method::Lfd, p.candidates)
                    .scope(scope)
                    .within(p.lfd),
            )?;
            let candidates: Vec<(String, String)> = ranking
                .hits
                .into_iter()
                .filter_map(|h| {
                    let record = catalog.records.get(h.id.as_str())?;
                    (record.content_hash != hash).then(|| (h.id, record.content_hash.clone()))
                })
                .collect();
            Ok::<_, std::io::Error>((same_file, candidates))
        })
        .await?
        .map_err(AppError::index)?;
    let hash = upload.content_hash();
    candidates.retain(|(_, their)| !app.dismissed.contains(hash, their));
    let worker = app.0.clone();
    let mut matches: Vec<DuplicateMatch> = same_file
        .into_iter()
        .map(|id| DuplicateMatch {
            id,
            evidence: Evidence::IdenticalFile,
            score: 1.0,
        })
        .collect();
    let verified = app
        .pool
        .run(move || {
            let hash = upload.content_hash().to_string();
            candidates
                .into_iter()
                .map(|(id, their)| {
                    let verdict = worker.verdict(("", &hash), (&id, &their), Some(&upload))?;
                    Ok(verdict.map(|v| DuplicateMatch {
                        id,
                        evidence: v.evidence,
                        score: v.score,
                    }))
                })
                .collect::<Result<Vec<_>, AppError>>()
        })
        .await??;
    matches.extend(verified.into_iter().flatten());
    matches.sort_by(|a, b| {
        (a.evidence, b.score, &a.id)
            .partial_cmp(&(b.evidence, a.score, &b.id))
            .expect("scores are finite")
    });
    Ok(matches)
}

impl App {
    /// The verdict on two models or uploads, each `(id, content hash)`; `upload` is the
    /// first's files when it is not stored. Remembered by the pair of hashes.
    fn verdict(
        &self,
        (a, ha): (&str, &str),
        (b, hb): (&str, &str),
        upload: Option<&Upload>,
    ) -> Result<Option<Verdict>, AppError> {
        let key = if ha < hb {
            (ha.to_string(), hb.to_string())
        } else {
            (hb.to_string(), ha.to_string())
        };
        let known = self
            .verifier
            .verdicts
            .lock()
            .expect("never poisoned")
            .get(&key)
            .copied();
        if let Some(verdict) = known {
            return Ok(verdict);
        }
        let first = match upload {
            Some(upload) => self.shape(ha, || Ok(Some(upload.clone())))?,
            None => self.shape(ha, || self.store.upload(a))?,
        };
        let second = self.shape(hb, || self.store.upload(b))?;
        let verdict = match (first, second) {
            (Some(x), Some(y)) => verify(&x, &y, &self.config.params.similarity.duplicates),
            // Deleted meanwhile: nothing to report, and nothing to remember.
            _ => return Ok(None),
        };
        self.verifier
            .verdicts
            .lock()
            .expect("never poisoned")
            .put(key, verdict);
        Ok(verdict)
    }

    /// The verification shape of the upload with content `hash`, from `load` if it is not
    /// kept; `None` if there is no such upload any more.
    fn shape(
        &self,
        hash: &str,
        load: impl FnOnce() -> Result<Option<Upload>, crate::store::StoreError>,
    ) -> Result<Option<Arc<Shape>>, AppError> {
        let kept = self
            .verifier
            .shapes
            .lock()
            .expect("never poisoned")
            .get(hash)
            .cloned();
        if let Some(shape) = kept {
            return Ok(Some(shape));
        }
        let Some(upload) = load()? else {
            return Ok(None);
        };
        let raw = load_bytes(
            &upload.mesh,
            upload.format,
            &upload.resources,
            &self.config.limits,
        )?;
        let shape = Arc::new(Shape::new(&raw, self.config.params.mesh.weld_tolerance)?);
        if shape.vertices() <= SHAPE_VERTICES {
            self.verifier
                .shapes
                .lock()
                .expect("never poisoned")
                .put(hash.to_string(), shape.clone());
        }
        Ok(Some(shape))
    }
}

//! Signature formats 1 and 2, as release 0.1.0 wrote them: read-only, and frozen.
//!
//! Those formats were positional `postcard` with the parameters and statistics embedded, so
//! they can only be read with the struct layouts of that release. The layouts are copied
//! here and must never change; each decoded value is turned into today's type through its
//! JSON form (the field names are the same), so fields added since take their defaults.
//! `tests/fixtures/golden/` holds bytes written by that release, which guard this file.

use serde::{Deserialize, Serialize};

use super::{dequantise, Feature, MeshHash, Signature, StoredFeature};
use crate::descriptor::LightFieldDescriptor;
use crate::{Error, Result};

/// Decodes the body (after magic and version) of a format-1 or format-2 signature.
pub(super) fn decode(format: u16, body: &[u8]) -> Result<Signature> {
    let corrupt = |message: String| Error::CorruptSignature { message };
    let (stored, rest): (Stored, _) =
        postcard::take_from_bytes(body).map_err(|e| corrupt(e.to_string()))?;
    let lfd: Option<LightFieldDescriptor> = match format {
        1 if rest.is_empty() => None,
        1 => return Err(corrupt("bytes after the record".into())),
        _ => postcard::from_bytes(rest).map_err(|e| corrupt(e.to_string()))?,
    };
    let mesh_hash: [u8; 32] = stored
        .mesh_hash
        .as_slice()
        .try_into()
        .map_err(|_| corrupt("mesh hash is not 32 bytes".into()))?;
    Ok(Signature {
        mesh_hash: MeshHash(mesh_hash),
        features: stored.features.into_iter().map(Feature::from).collect(),
        d2: dequantise(&stored.d2),
        lfd,
        geodesic: None,
        params: upgrade(format, &stored.params)?,
        stats: upgrade(format, &stored.stats)?,
    })
}

/// Today's type of a frozen value, through their shared JSON form.
fn upgrade<T: serde::de::DeserializeOwned>(format: u16, frozen: &impl Serialize) -> Result<T> {
    serde_json::to_value(frozen)
        .and_then(serde_json::from_value)
        .map_err(|e| Error::CorruptSignature {
            message: format!("format {format} parameters or statistics: {e}"),
        })
}

#[derive(Serialize, Deserialize)]
struct Stored {
    mesh_hash: Vec<u8>,
    features: Vec<StoredFeature>,
    d2: Vec<u16>,
    params: Params,
    stats: SignatureStats,
}

#[derive(Serialize, Deserialize)]
struct Params {
    version: u32,
    mesh: MeshParams,
    ecc: EccParams,
    salient: SalientParams,
    d2: D2Params,
    similarity: SimilarityParams,
}

#[derive(Serialize, Deserialize)]
struct MeshParams {
    weld_tolerance: f64,
    max_vertices: usize,
}

#[derive(Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
enum HeightRule {
    Axial,
    Paper,
}

#[derive(Serialize, Deserialize)]
struct EccParams {
    local_size: f64,
    waves: usize,
    flat_max: f64,
    height: HeightRule,
}

#[derive(Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
enum CandidateRule {
    Mean,
    Norm,
}

#[derive(Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
enum RegionRule {
    Size,
    Area,
}

#[derive(Serialize, Deserialize)]
struct SalientParams {
    clusters: usize,
    seed: u64,
    restarts: usize,
    candidates: CandidateRule,
    suppression_distance: f64,
    region_rule: RegionRule,
    min_region_ratio: f64,
    max_features: usize,
}

#[derive(Serialize, Deserialize)]
struct D2Params {
    samples: usize,
    bins: usize,
}

#[derive(Serialize, Deserialize)]
struct SimilarityParams {
    ecc_weight: f64,
    penalty: bool,
}

#[derive(Serialize, Deserialize)]
struct SignatureStats {
    extraction: ExtractionStats,
    salient: SalientStats,
    salient_seconds: f64,
    d2_seconds: f64,
}

#[derive(Serialize, Deserialize)]
struct ExtractionStats {
    load_seconds: f64,
    mesh: PrepareStats,
    topology_seconds: f64,
    mean_edge_length: f64,
    ecc: EccStats,
    total_seconds: f64,
}

#[derive(Serialize, Deserialize)]
struct PrepareStats {
    input_vertices: usize,
    input_triangles: usize,
    welded_vertices: usize,
    degenerate_triangles_removed: usize,
    duplicate_triangles_removed: usize,
    orientation: OrientStats,
    simplified: bool,
    vertices: usize,
    triangles: usize,
    weld_seconds: f64,
    orient_seconds: f64,
    simplify_seconds: f64,
    normalise_seconds: f64,
}

#[derive(Serialize, Deserialize)]
struct OrientStats {
    components: usize,
    closed_components: usize,
    flipped_triangles: usize,
    non_orientable_components: usize,
}

#[derive(Serialize, Deserialize)]
struct EccStats {
    vertices: usize,
    complete: usize,
    shrunk: usize,
    wave1_invalid: usize,
    first_defect: DefectCounts,
    accepted_invalid_waves: usize,
    geodesic_seconds: f64,
    waves_seconds: f64,
    cone_seconds: f64,
    wall_seconds: f64,
    threads: usize,
}

#[derive(Serialize, Deserialize)]
struct DefectCounts {
    missing: usize,
    branching: usize,
    open: usize,
    too_few_points: usize,
    not_flat: usize,
}

#[derive(Serialize, Deserialize)]
struct SalientStats {
    kmeans_iterations: usize,
    candidates: usize,
    after_suppression: usize,
    small_regions_dropped: usize,
    capped: usize,
    fallback: bool,
}

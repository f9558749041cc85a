//! The pipeline, in one place: load → prepare (SPEC §1) → ECC of every vertex (§2) →
//! salient points and regions (§3) → their D2 histograms and the global descriptors (§4, §6)
//! → a [`Signature`], with the statistics and per-stage timings every extraction reports.
//! Callers that need only the first stages (pictures, the parameter study) stop at
//! [`extract`] and go on with [`describe`].

use std::borrow::Cow;

use std::path::Path;
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use sha2::{Digest, Sha256};

use crate::descriptor::{d2_histogram, GeodesicDescriptor, LightFieldDescriptor};
use crate::ecc;
use crate::extraction::{Extraction, ExtractionStats};
use crate::mesh::{self, Format, PreparedMesh, RawMesh, Resources, Topology};
use crate::params::{Limits, Params};
use crate::preview::Preview;
use crate::salient;
use crate::signature::{Feature, MeshHash, Signature, SignatureStats};
use crate::Result;

/// Loads `path` (format from its extension, or sniffed) and extracts.
pub fn extract_path(path: &Path, params: &Params, limits: &Limits) -> Result<Extraction> {
    let clock = Instant::now();
    let raw = mesh::load_path(path, limits)?;
    let load_seconds = clock.elapsed().as_secs_f64();
    let mut extraction = extract(&raw, params)?;
    extraction.stats.load_seconds = load_seconds;
    extraction.stats.total_seconds += load_seconds;
    Ok(extraction)
}

/// Prepares `raw` (SPEC §1) and computes the ECC of every vertex (SPEC §2); given by value, the
/// loaded mesh is let go once welded.
pub fn extract<'a>(raw: impl Into<Cow<'a, RawMesh>>, params: &Params) -> Result<Extraction> {
    let clock = Instant::now();
    let (mesh, topology, mut stats) = prepare(raw, params)?;
    let ecc = ecc::compute(&mesh, &topology, &params.ecc);
    stats.ecc = ecc.stats.clone();
    stats.total_seconds = clock.elapsed().as_secs_f64();
    Ok(Extraction {
        mesh,
        topology,
        ecc,
        stats,
    })
}

/// How much of a signature to compute.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Extent {
    /// Everything: what is stored.
    Full,
    /// The global descriptors (D2, LFD, geodesic) without the ECC and the salient features:
    /// all that a query ranked by `d2`, `lfd` or `geodesic` compares, at a fraction of the
    /// cost.
    Global,
}

/// The signature of a mesh file (with its glTF resources), in its stored form: what a query
/// gets, so that it ranks exactly as the same model stored or searched offline.
pub fn signature_of_file(
    bytes: &[u8],
    format: Format,
    resources: &dyn Resources,
    (params, extent): (&Params, Extent),
    limits: &Limits,
) -> Result<Signature> {
    signature_of_mesh(
        mesh::load_bytes(bytes, format, resources, limits)?,
        (params, extent),
    )
}

/// [`signature_of_file`] of a loaded mesh, which is let go once welded.
pub fn signature_of_mesh(raw: RawMesh, (params, extent): (&Params, Extent)) -> Result<Signature> {
    let signature = match extent {
        Extent::Full => describe(&extract(raw, params)?, params),
        Extent::Global => compute_global(raw, params)?,
    };
    Signature::from_bytes(&signature.to_bytes())
}

/// The global descriptors of a loaded mesh ([`Extent::Global`]): no ECC, no features.
pub fn compute_global<'a>(raw: impl Into<Cow<'a, RawMesh>>, params: &Params) -> Result<Signature> {
    let (mesh, topology, stats) = prepare(raw, params)?;
    Ok(global_descriptors(&mesh, &topology, params, stats))
}

/// What every extraction starts with: the parameters checked, the mesh prepared (SPEC §1)
/// and its edge graph, with their statistics (no ECC yet).
fn prepare<'a>(
    raw: impl Into<Cow<'a, RawMesh>>,
    params: &Params,
) -> Result<(PreparedMesh, Topology, ExtractionStats)> {
    params.validate()?;
    let clock = Instant::now();
    let mesh = mesh::prepare(raw, &params.mesh)?;
    let topology_clock = Instant::now();
    let topology = Topology::new(&mesh.positions, &mesh.triangles);
    let stats = ExtractionStats {
        load_seconds: 0.0,
        mesh: mesh.stats.clone(),
        topology_seconds: topology_clock.elapsed().as_secs_f64(),
        mean_edge_length: topology.mean_edge_length(),
        ecc: Default::default(),
        total_seconds: clock.elapsed().as_secs_f64(),
    };
    Ok((mesh, topology, stats))
}

/// The preview (thumbnails, 3D view) of a mesh file whose features are known: it is prepared
/// again as they were found (`mesh` of the signature's parameters), and their regions regrown
/// (no ECC). No features give the plain mesh.
pub fn preview_of_file(
    bytes: &[u8],
    format: Format,
    resources: &dyn Resources,
    (params, features): (&Params, &[Feature]),
    limits: &Limits,
) -> Result<Preview> {
    let raw = mesh::load_bytes(bytes, format, resources, limits)?;
    let mesh = mesh::prepare(&raw, &params.mesh)?;
    let topology = Topology::new(&mesh.positions, &mesh.triangles);
    Ok(Preview::new(
        &mesh,
        &topology,
        features,
        params.ecc.geodesic,
    ))
}

/// Loads nothing: extracts the signature of an already loaded mesh.
pub fn compute(raw: &RawMesh, params: &Params) -> Result<Signature> {
    Ok(describe(&extract(raw, params)?, params))
}

/// Salient features and descriptors of an extraction (SPEC §3–4, §6).
pub fn describe(extraction: &Extraction, params: &Params) -> Signature {
    let global = global_descriptors(
        &extraction.mesh,
        &extraction.topology,
        params,
        extraction.stats.clone(),
    );
    with_features(global, extraction, params)
}

/// The salient features of a loaded mesh, no global descriptors: all that a part compares
/// ([`crate::partial`]).
pub fn compute_features(raw: &RawMesh, params: &Params) -> Result<Signature> {
    let extraction = extract(raw, params)?;
    let bare = bare(&extraction.mesh, params, extraction.stats.clone());
    Ok(with_features(bare, &extraction, params))
}

/// `signature` with the salient features of `extraction` (SPEC §3–4).
fn with_features(mut signature: Signature, extraction: &Extraction, params: &Params) -> Signature {
    let mesh = &extraction.mesh;
    let clock = Instant::now();
    let (points, salient_stats) = salient::detect(extraction, params);
    let salient_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let rng = |stream| histogram_rng(&signature.mesh_hash, stream);
    let d2 = &params.d2;
    let region_range = 2.0 * params.ecc.local_size;
    let features: Vec<Feature> = points
        .par_iter()
        .map(|point| {
            let v = point.vertex as usize;
            Feature {
                vertex: point.vertex,
                position: mesh.input_positions[v].to_array(),
                position_normalized: mesh.positions[v].to_array(),
                ecc: extraction.ecc.vector(v).to_vec(),
                d2: d2_histogram(
                    &point.region.triangles,
                    d2.samples,
                    d2.bins,
                    region_range,
                    &mut rng(point.vertex as u64),
                ),
                region_size: point.region_size,
                region_area: point.region.area,
            }
        })
        .collect();
    let region_seconds = clock.elapsed().as_secs_f64();
    signature.features = features;
    let stats = &mut signature.stats;
    stats.salient = salient_stats;
    stats.salient_seconds = salient_seconds;
    stats.d2_seconds += region_seconds;
    stats.extraction.total_seconds += salient_seconds + region_seconds;
    signature
}

/// One PRNG stream per histogram, all seeded from the mesh: the same mesh gives the same
/// samples on any machine and thread count (SPEC §4).
fn histogram_rng(hash: &MeshHash, stream: u64) -> ChaCha8Rng {
    let seed = u64::from_le_bytes(hash.0[..8].try_into().expect("a SHA-256 has 32 bytes"));
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(stream);
    rng
}

/// A signature of a prepared mesh with nothing described yet: its hash, parameters and
/// preparation statistics.
fn bare(mesh: &PreparedMesh, params: &Params, extraction: ExtractionStats) -> Signature {
    Signature {
        mesh_hash: mesh_hash(mesh),
        features: Vec::new(),
        d2: Vec::new(),
        lfd: None,
        geodesic: None,
        params: params.clone(),
        stats: SignatureStats {
            extraction,
            ..Default::default()
        },
    }
}

/// A signature with the global descriptors (D2, LFD, geodesic) of a prepared mesh and no
/// features yet.
fn global_descriptors(
    mesh: &PreparedMesh,
    topology: &Topology,
    params: &Params,
    extraction: ExtractionStats,
) -> Signature {
    let mut signature = bare(mesh, params, extraction);
    let clock = Instant::now();
    let whole: Vec<_> = mesh
        .triangles
        .iter()
        .map(|t| t.map(|v| mesh.positions[v as usize]))
        .collect();
    let d2 = &params.d2;
    signature.d2 = d2_histogram(
        &whole,
        d2.samples,
        d2.bins,
        2.0,
        &mut histogram_rng(&signature.mesh_hash, u64::MAX),
    );
    let d2_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    signature.lfd = Some(LightFieldDescriptor::compute(mesh));
    let lfd_seconds = clock.elapsed().as_secs_f64();
    let clock = Instant::now();
    signature.geodesic = Some(GeodesicDescriptor::compute(mesh, topology));
    let geodesic_seconds = clock.elapsed().as_secs_f64();

    let stats = &mut signature.stats;
    stats.d2_seconds = d2_seconds;
    stats.lfd_seconds = lfd_seconds;
    stats.geodesic_seconds = geodesic_seconds;
    stats.extraction.total_seconds += d2_seconds + lfd_seconds + geodesic_seconds;
    signature
}

/// SHA-256 over the prepared mesh's input-coordinate positions and triangles.
fn mesh_hash(mesh: &PreparedMesh) -> MeshHash {
    let mut hasher = Sha256::new();
    for p in &mesh.input_positions {
        for c in p.to_array() {
            hasher.update(c.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        for v in t {
            hasher.update(v.to_le_bytes());
        }
    }
    MeshHash(hasher.finalize().into())
}

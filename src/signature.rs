//! A model's signature (SPEC §4): its salient features — ECC vector and region D2 histogram
//! of each salient point — with positions, region sizes, the parameters that made it and
//! extraction statistics; plus the descriptors of the SPEC §6 baselines (global D2 histogram,
//! Light Field Descriptor), so that one stored record serves every method.
//!
//! Two encodings: JSON (serde, full precision) for people and tools, and a compact versioned
//! binary form for storage ([`Signature::to_bytes`]) that keeps ECC values as `f32` and
//! histogram bins as `u16` fractions of 65 535 (a quantisation step of 1.5e-5, far below the
//! Monte Carlo noise of a 2 000-sample D2). Format 2 appends the light field descriptor
//! (4.6 KB, already 8-bit) after the format-1 record, so format-1 signatures still read, as
//! signatures without one.

use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::descriptor::{d2_histogram, LightFieldDescriptor};
use crate::extract::{extract, Extraction, ExtractionStats};
use crate::mesh::{PreparedMesh, RawMesh};
use crate::params::Params;
use crate::salient::{self, SalientStats};
use crate::{Error, Result};

/// Version of the binary encoding; bumped when its layout changes. Format 1 (no light field
/// descriptor) is still read.
pub const SIGNATURE_FORMAT: u16 = 2;
const MAGIC: &[u8; 4] = b"SLSG";

/// One salient feature (Eq. 6: `SF = ECC + SD`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Feature {
    /// Index of the salient point among the prepared mesh's vertices.
    pub vertex: u32,
    /// Position in the input file's coordinates.
    pub position: [f64; 3],
    /// Position after normalisation into the unit sphere (SPEC §1.4).
    pub position_normalized: [f64; 3],
    /// ECC vector, radians (Eq. 5).
    pub ecc: Vec<f64>,
    /// D2 histogram of the salient region over `[0, 2·D_g]`, sum 1. Single precision: the
    /// bins are stored to 1/65 535 anyway, and an index of 100 000 models holds millions.
    pub d2: Vec<f32>,
    /// Final region size `D`, normalised units.
    pub region_size: f64,
    /// Area of the salient region, normalised units.
    pub region_area: f64,
}

/// Counts and timings of a whole extraction.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SignatureStats {
    pub extraction: ExtractionStats,
    pub salient: SalientStats,
    pub salient_seconds: f64,
    pub d2_seconds: f64,
}

/// Everything stored about a model's shape.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Signature {
    /// SHA-256 of the prepared mesh (positions and triangles): equal meshes, equal hash.
    pub mesh_hash: String,
    pub features: Vec<Feature>,
    /// Global D2 histogram of the whole normalised mesh over `[0, 2]` (SPEC §6).
    pub d2: Vec<f32>,
    /// Light Field Descriptor (SPEC §6); absent from signatures made before it existed
    /// (format 1), which `salient reindex` renews.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lfd: Option<LightFieldDescriptor>,
    pub params: Params,
    pub stats: SignatureStats,
}

/// Loads nothing: extracts the signature of an already loaded mesh.
pub fn compute(raw: &RawMesh, params: &Params) -> Result<Signature> {
    Ok(describe(&extract(raw, params)?, params))
}

/// Salient features and D2 histograms of an extraction (SPEC §3–4).
pub fn describe(extraction: &Extraction, params: &Params) -> Signature {
    let mesh = &extraction.mesh;
    let clock = Instant::now();
    let (points, salient_stats) = salient::detect(extraction, params);
    let salient_seconds = clock.elapsed().as_secs_f64();

    // One PRNG stream per histogram, all seeded from the mesh: the same mesh gives the same
    // samples on any machine and thread count (SPEC §4).
    let clock = Instant::now();
    let hash = mesh_hash(mesh);
    let seed = u64::from_le_bytes(hash[..8].try_into().expect("a SHA-256 has 32 bytes"));
    let rng = |stream: u64| {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(stream);
        rng
    };
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
    let whole: Vec<_> = mesh
        .triangles
        .iter()
        .map(|t| t.map(|v| mesh.positions[v as usize]))
        .collect();
    let global = d2_histogram(&whole, d2.samples, d2.bins, 2.0, &mut rng(u64::MAX));
    let d2_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let lfd = LightFieldDescriptor::compute(mesh);
    let lfd_seconds = clock.elapsed().as_secs_f64();

    let mut stats = SignatureStats {
        extraction: extraction.stats.clone(),
        salient: salient_stats,
        salient_seconds,
        d2_seconds,
    };
    stats.extraction.total_seconds += salient_seconds + d2_seconds + lfd_seconds;
    Signature {
        mesh_hash: hex(&hash),
        features,
        d2: global,
        lfd: Some(lfd),
        params: params.clone(),
        stats,
    }
}

/// SHA-256 over the prepared mesh's input-coordinate positions and triangles.
fn mesh_hash(mesh: &PreparedMesh) -> [u8; 32] {
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
    hasher.finalize().into()
}

/// Lower-case hexadecimal.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The binary record: quantised, and with the hash as raw bytes.
#[derive(Serialize, Deserialize)]
struct Stored {
    mesh_hash: Vec<u8>,
    features: Vec<StoredFeature>,
    d2: Vec<u16>,
    params: Params,
    stats: SignatureStats,
}

#[derive(Serialize, Deserialize)]
struct StoredFeature {
    vertex: u32,
    position: [f64; 3],
    position_normalized: [f32; 3],
    ecc: Vec<f32>,
    d2: Vec<u16>,
    region_size: f32,
    region_area: f32,
}

const BIN_SCALE: f64 = 65_535.0;

fn quantise(histogram: &[f32]) -> Vec<u16> {
    histogram
        .iter()
        .map(|&h| (h as f64 * BIN_SCALE).round().clamp(0.0, BIN_SCALE) as u16)
        .collect()
}

fn dequantise(histogram: &[u16]) -> Vec<f32> {
    histogram
        .iter()
        .map(|&h| (h as f64 / BIN_SCALE) as f32)
        .collect()
}

impl Signature {
    /// Compact, versioned binary form: `SLSG`, the format version (u16, little endian), the
    /// record in `postcard`, then the optional light field descriptor in `postcard`. Lossy as
    /// described in the module documentation.
    pub fn to_bytes(&self) -> Vec<u8> {
        let stored = Stored {
            mesh_hash: (0..self.mesh_hash.len() / 2)
                .filter_map(|i| u8::from_str_radix(&self.mesh_hash[2 * i..2 * i + 2], 16).ok())
                .collect(),
            features: self
                .features
                .iter()
                .map(|f| StoredFeature {
                    vertex: f.vertex,
                    position: f.position,
                    position_normalized: f.position_normalized.map(|c| c as f32),
                    ecc: f.ecc.iter().map(|&a| a as f32).collect(),
                    d2: quantise(&f.d2),
                    region_size: f.region_size as f32,
                    region_area: f.region_area as f32,
                })
                .collect(),
            d2: quantise(&self.d2),
            params: self.params.clone(),
            stats: self.stats.clone(),
        };
        let mut bytes = MAGIC.to_vec();
        bytes.extend(SIGNATURE_FORMAT.to_le_bytes());
        for part in [postcard::to_stdvec(&stored), postcard::to_stdvec(&self.lfd)] {
            bytes.extend(part.expect("serialising to memory cannot fail"));
        }
        bytes
    }

    /// Reads [`Signature::to_bytes`] output.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        let corrupt = |message: String| Error::CorruptSignature { message };
        if bytes.len() < 6 || &bytes[..4] != MAGIC {
            return Err(corrupt("not a salient signature (bad magic)".into()));
        }
        let format = u16::from_le_bytes([bytes[4], bytes[5]]);
        if !(1..=SIGNATURE_FORMAT).contains(&format) {
            return Err(Error::SignatureFormat {
                found: format,
                supported: SIGNATURE_FORMAT,
            });
        }
        let (stored, rest): (Stored, _) =
            postcard::take_from_bytes(&bytes[6..]).map_err(|e| corrupt(e.to_string()))?;
        let lfd = match format {
            1 if rest.is_empty() => None,
            1 => return Err(corrupt("bytes after the record".into())),
            _ => postcard::from_bytes(rest).map_err(|e| corrupt(e.to_string()))?,
        };
        Ok(Signature {
            mesh_hash: hex(&stored.mesh_hash),
            features: stored
                .features
                .into_iter()
                .map(|f| Feature {
                    vertex: f.vertex,
                    position: f.position,
                    position_normalized: f.position_normalized.map(f64::from),
                    ecc: f.ecc.into_iter().map(f64::from).collect(),
                    d2: dequantise(&f.d2),
                    region_size: f.region_size.into(),
                    region_area: f.region_area.into(),
                })
                .collect(),
            d2: dequantise(&stored.d2),
            lfd,
            params: stored.params,
            stats: stored.stats,
        })
    }
}

//! A model's signature (SPEC §4): its salient features — ECC vector and region D2 histogram
//! of each salient point — with positions, region sizes, the parameters that made it and
//! extraction statistics; plus the descriptors of the SPEC §6 baselines (global D2 histogram,
//! Light Field Descriptor), so that one stored record serves every method.
//!
//! Two encodings: JSON (serde, full precision) for people and tools, and a compact versioned
//! binary form for storage ([`Signature::to_bytes`]) that keeps ECC values as `f32` and
//! histogram bins as `u16` fractions of 65 535 (a quantisation step of 1.5e-5, far below the
//! Monte Carlo noise of a 2 000-sample D2).
//!
//! The binary form (format 3) is a list of tagged sections. What ranking reads (features,
//! histograms, descriptors) is positional `postcard`, compact and fixed: changing a section's
//! layout means a new tag or format and a store migration (`migrations/README.md`). The
//! parameters and statistics are JSON inside their sections, so fields added to them later
//! take their defaults in older signatures. A reader skips sections it does not know, and a
//! descriptor added later is a new section that older signatures simply lack (they are then
//! stale, see [`Signature::staleness`]). Formats 1 and 2 (release 0.1.0) still read.
//!
//! Format 4 is format 3's sections compressed with zstd against a fixed dictionary
//! ([`DICTIONARY`]): the parameters and statistics are mostly the same JSON keys and values in
//! every signature, so the dictionary holds a typical pair of them and they shrink to a few
//! dozen bytes; the light field's coefficients to about three quarters. Lossless: format 3 read
//! and written again as format 4 reads back the same signature. Format 3 still reads.

use serde::{Deserialize, Serialize};

use crate::descriptor::{GeodesicDescriptor, LightFieldDescriptor};
use crate::extraction::ExtractionStats;
use crate::params::Params;
use crate::salient::SalientStats;
use crate::{Error, Result};

mod legacy;

/// Version of the binary encoding: 4 is the sectioned form compressed, 3 the sectioned form;
/// 1 and 2 are read by `legacy`.
pub const SIGNATURE_FORMAT: u16 = 4;
const MAGIC: &[u8; 4] = b"SLSG";

/// Format 4's zstd dictionary (raw content: the parameters and statistics of one extraction,
/// as format 3 stores them). Every format-4 signature needs these exact bytes to be read, so
/// the file never changes (a test pins its hash); a better dictionary is a new format.
pub const DICTIONARY: &[u8] = include_bytes!("signature/dictionary-4.json");
/// The largest decompressed format-4 body read: far above any signature (a few kilobytes to
/// tens at the salient-point cap), so a corrupt or hostile length is refused, not allocated.
const MAX_BODY: usize = 4 << 20;
/// zstd's level for format 4: a signature is written once and read at every start.
const LEVEL: i32 = 19;

/// SHA-256 of a prepared mesh: 32 bytes in the binary form, lower-case hex in JSON.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct MeshHash(pub [u8; 32]);

impl From<[u8; 32]> for MeshHash {
    fn from(bytes: [u8; 32]) -> Self {
        Self(bytes)
    }
}

impl std::fmt::Display for MeshHash {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&hex::encode(self.0))
    }
}

impl Serialize for MeshHash {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(&self.to_string())
    }
}

impl<'de> Deserialize<'de> for MeshHash {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = String::deserialize(deserializer)?;
        let mut bytes = [0u8; 32];
        hex::decode_to_slice(&text, &mut bytes).map_err(serde::de::Error::custom)?;
        Ok(Self(bytes))
    }
}

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

/// Counts and timings of a whole extraction. Stored as JSON: fields added later take their
/// defaults in older signatures.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SignatureStats {
    pub extraction: ExtractionStats,
    pub salient: SalientStats,
    pub salient_seconds: f64,
    pub d2_seconds: f64,
    pub lfd_seconds: f64,
    pub geodesic_seconds: f64,
}

/// Everything stored about a model's shape.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Signature {
    /// SHA-256 of the prepared mesh (positions and triangles): equal meshes, equal hash.
    pub mesh_hash: MeshHash,
    pub features: Vec<Feature>,
    /// Global D2 histogram of the whole normalised mesh over `[0, 2]` (SPEC §6).
    pub d2: Vec<f32>,
    /// Light Field Descriptor (SPEC §6); absent from signatures made before it existed
    /// (format 1), which are therefore stale.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lfd: Option<LightFieldDescriptor>,
    /// Geodesic distance distributions ([`GeodesicDescriptor`]); absent from signatures made
    /// before it existed (release 0.2 and older), which are therefore stale.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geodesic: Option<GeodesicDescriptor>,
    pub params: Params,
    pub stats: SignatureStats,
}

/// Why a stored signature must be re-extracted. This is the one staleness rule: the service
/// applies it at start, to uploads of content already stored, and to pick what online
/// re-extraction renews; `salient reindex` applies it offline.
///
/// Only extraction parameters count ([`Params::same_extraction`]): ranking parameters
/// (weights, scales, thresholds, `W`, the penalty) are read from the configuration at query
/// time, so retuning them never makes a signature stale.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Staleness {
    /// Made with other extraction parameters, or by another version of the extraction.
    Parameters,
    /// Lacks a descriptor that this version computes.
    MissingDescriptor,
}

impl Signature {
    /// `None` if this signature is what extracting its mesh with `current` would give.
    pub fn staleness(&self, current: &Params) -> Option<Staleness> {
        if !self.params.same_extraction(current) {
            Some(Staleness::Parameters)
        } else if self.lfd.is_none() || self.geodesic.is_none() {
            Some(Staleness::MissingDescriptor)
        } else {
            None
        }
    }
}

/// Section tags of format 3. A tag's layout never changes; a new layout gets a new tag.
mod tag {
    /// [`super::Shape`], postcard.
    pub const SHAPE: u16 = 1;
    /// The light field descriptor, postcard.
    pub const LFD: u16 = 2;
    /// [`crate::Params`], JSON.
    pub const PARAMS: u16 = 3;
    /// [`super::SignatureStats`], JSON.
    pub const STATS: u16 = 4;
    /// [`super::StoredGeodesic`], postcard.
    pub const GEODESIC: u16 = 5;
}

#[derive(Serialize, Deserialize)]
struct Section {
    tag: u16,
    /// As bytes, not a sequence of `u8`: the same postcard encoding (a length, then the
    /// bytes), read in one copy instead of one visit per byte (a start reads every signature).
    #[serde(with = "serde_bytes")]
    bytes: Vec<u8>,
}

/// What ranking reads, quantised, with the hash as raw bytes.
#[derive(Serialize, Deserialize)]
struct Shape {
    mesh_hash: [u8; 32],
    features: Vec<StoredFeature>,
    d2: Vec<u16>,
}

/// The geodesic histograms, quantised like the D2 bins.
#[derive(Serialize, Deserialize)]
struct StoredGeodesic {
    distances: Vec<u16>,
    eccentricity: Vec<u16>,
}

/// A feature as stored: the same layout in formats 1, 2 and 3.
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

impl From<StoredFeature> for Feature {
    fn from(f: StoredFeature) -> Self {
        Feature {
            vertex: f.vertex,
            position: f.position,
            position_normalized: f.position_normalized.map(f64::from),
            ecc: f.ecc.into_iter().map(f64::from).collect(),
            d2: dequantise(&f.d2),
            region_size: f.region_size.into(),
            region_area: f.region_area.into(),
        }
    }
}

pub(crate) const BIN_SCALE: f64 = 65_535.0;

pub(crate) fn quantise(histogram: &[f32]) -> Vec<u16> {
    histogram
        .iter()
        .map(|&h| (h as f64 * BIN_SCALE).round().clamp(0.0, BIN_SCALE) as u16)
        .collect()
}

pub(crate) fn dequantise(histogram: &[u16]) -> Vec<f32> {
    histogram
        .iter()
        .map(|&h| (h as f64 / BIN_SCALE) as f32)
        .collect()
}

fn corrupt(message: impl ToString) -> Error {
    Error::CorruptSignature {
        message: message.to_string(),
    }
}

impl Signature {
    /// The binary form: `SLSG`, the format version (u16, little endian), then the sections
    /// in `postcard`. Lossy as described in the module documentation.
    pub fn to_bytes(&self) -> Vec<u8> {
        let shape = Shape {
            mesh_hash: self.mesh_hash.0,
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
        };
        let in_memory = "serialising to memory cannot fail";
        let mut sections = vec![Section {
            tag: tag::SHAPE,
            bytes: postcard::to_stdvec(&shape).expect(in_memory),
        }];
        if let Some(lfd) = &self.lfd {
            sections.push(Section {
                tag: tag::LFD,
                bytes: postcard::to_stdvec(lfd).expect(in_memory),
            });
        }
        if let Some(g) = &self.geodesic {
            let stored = StoredGeodesic {
                distances: quantise(&g.distances),
                eccentricity: quantise(&g.eccentricity),
            };
            sections.push(Section {
                tag: tag::GEODESIC,
                bytes: postcard::to_stdvec(&stored).expect(in_memory),
            });
        }
        sections.push(Section {
            tag: tag::PARAMS,
            bytes: serde_json::to_vec(&self.params).expect(in_memory),
        });
        sections.push(Section {
            tag: tag::STATS,
            bytes: serde_json::to_vec(&self.stats).expect(in_memory),
        });
        let body = postcard::to_stdvec(&sections).expect(in_memory);
        let mut bytes = MAGIC.to_vec();
        bytes.extend(SIGNATURE_FORMAT.to_le_bytes());
        bytes.extend(
            zstd::bulk::Compressor::with_dictionary(LEVEL, DICTIONARY)
                .and_then(|mut zstd| zstd.compress(&body))
                .expect("compressing in memory with a valid dictionary cannot fail"),
        );
        bytes
    }

    /// The binary format version of `bytes`, if they are a signature at all.
    pub fn format_of(bytes: &[u8]) -> Option<u16> {
        (bytes.len() >= 6 && &bytes[..4] == MAGIC).then(|| u16::from_le_bytes([bytes[4], bytes[5]]))
    }

    /// Reads [`Signature::to_bytes`] output, and formats 1 to 3.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        let format =
            Self::format_of(bytes).ok_or_else(|| corrupt("not a salient signature (bad magic)"))?;
        match format {
            1 | 2 => legacy::decode(format, &bytes[6..]),
            3 => Self::from_sections(&bytes[6..]),
            SIGNATURE_FORMAT => Self::from_sections(&decompress(&bytes[6..])?),
            found => Err(Error::SignatureFormat {
                found,
                supported: SIGNATURE_FORMAT,
            }),
        }
    }

    fn from_sections(body: &[u8]) -> Result<Self> {
        let sections: Vec<Section> = postcard::from_bytes(body).map_err(corrupt)?;
        let find = |wanted: u16| {
            sections
                .iter()
                .find(|s| s.tag == wanted)
                .map(|s| &s.bytes[..])
        };
        let required = |wanted: u16, name: &str| {
            find(wanted).ok_or_else(|| corrupt(format!("no {name} section")))
        };
        let shape: Shape = postcard::from_bytes(required(tag::SHAPE, "shape")?).map_err(corrupt)?;
        let lfd = find(tag::LFD)
            .map(postcard::from_bytes)
            .transpose()
            .map_err(corrupt)?;
        let geodesic = find(tag::GEODESIC)
            .map(postcard::from_bytes::<StoredGeodesic>)
            .transpose()
            .map_err(corrupt)?
            .map(|g| GeodesicDescriptor {
                distances: dequantise(&g.distances),
                eccentricity: dequantise(&g.eccentricity),
            });
        let params =
            serde_json::from_slice(required(tag::PARAMS, "parameters")?).map_err(corrupt)?;
        let stats = serde_json::from_slice(required(tag::STATS, "statistics")?).map_err(corrupt)?;
        Ok(Signature {
            mesh_hash: MeshHash(shape.mesh_hash),
            features: shape.features.into_iter().map(Feature::from).collect(),
            d2: dequantise(&shape.d2),
            lfd,
            geodesic,
            params,
            stats,
        })
    }
}

/// A format-4 body. The decompressor, which holds the loaded dictionary, is kept per thread:
/// a service reads every stored signature at start.
fn decompress(body: &[u8]) -> Result<Vec<u8>> {
    thread_local! {
        static ZSTD: std::cell::RefCell<Option<zstd::bulk::Decompressor<'static>>> =
            const { std::cell::RefCell::new(None) };
    }
    ZSTD.with_borrow_mut(|zstd| {
        let zstd = match zstd {
            Some(zstd) => zstd,
            None => {
                zstd.insert(zstd::bulk::Decompressor::with_dictionary(DICTIONARY).map_err(corrupt)?)
            }
        };
        zstd.decompress(body, MAX_BODY).map_err(corrupt)
    })
}

//! `salient`: content-based 3D model retrieval with extended cone-curvature (ECC) salient
//! features. The modules follow the method's pipeline (see `SPEC.md`):
//!
//! - [`mesh`]: load OBJ / glTF / OFF / PLY / STL, weld, orient, simplify, normalise (§1);
//! - [`geodesic`]: local Dijkstra geodesics bounded by `D_g` (§2.1);
//! - [`waves`]: geodesic iso-lines traced into closed loops, their validity (§2.2–2.3);
//! - [`ecc`]: the extended cone-curvature vector of every vertex (§2.4);
//! - [`salient`]: k-means candidates, non-maximum suppression, salient regions (§3);
//! - [`descriptor`]: D2 shape distributions of regions and whole meshes (§4, §6), and the
//!   Light Field Descriptor baseline (§6);
//! - [`pipeline`]: load → prepare → ECC → salient features → descriptors → signature, with
//!   statistics and timings;
//! - [`signature`]: a model's features, descriptors, parameters and statistics; JSON and the
//!   versioned binary form (§4), and the rule for when a stored one is stale;
//! - [`emd`]: exact Earth Mover's Distance by the transportation simplex (§5);
//! - [`similarity`]: ground distance, penalised EMD, D2 baseline distance, lower bound (§5–6);
//! - [`partial`]: a part of a model as a query: described at a few sizes, fitted into each
//!   model's features (issue #14);
//! - [`rank`]: top-k ranking of an in-memory collection with bound-based pruning;
//! - [`collection`]: mesh folders and a disk cache of their signatures;
//! - [`model`]: model ids, records and uploaded files (feature `server`);
//! - [`store`]: persistent models, signatures and original files: sled, or in memory
//!   (feature `server`);
//! - [`api`]: the HTTP service (SPEC §8), with online re-extraction (feature `server`);
//! - [`ingest`]: planning a bulk upload of a mesh folder to the service (`salient ingest`;
//!   feature `server`);
//! - [`eval`]: the evaluation protocol — retrieval measures, robustness, parameter study
//!   (§7; feature `eval`);
//! - [`preview`]: a compact display mesh of a model with its regions (thumbnails, 3D view);
//! - [`render`]: pictures of a mesh with its salient points and regions (paper Fig. 10),
//!   thumbnails and comparisons;
//! - [`raster`]: triangle scan conversion shared by pictures and silhouettes.

pub mod collection;
pub mod descriptor;
pub mod display;
pub mod duplicate;
pub mod ecc;
pub mod emd;
pub mod error;
pub mod extraction;
pub mod format;
pub mod geodesic;
pub mod mesh;
pub mod params;
pub mod partial;
pub mod pipeline;
pub mod preview;
pub mod rank;
pub mod raster;
pub mod register;
pub mod render;
pub mod salient;
pub mod signature;
pub mod similarity;
pub mod waves;

pub use error::{Error, Result};
pub use params::{
    CandidateRule, D2Params, EccParams, GeodesicRule, HeightRule, Limits, MeshParams, Params,
    RegionRule, SalientParams, SimilarityParams,
};
pub use signature::{Feature, Signature};

//! `salient-core`: content-based 3D model retrieval with extended cone-curvature (ECC)
//! salient features — the method, with no server, store or command line (the
//! `salient-server` and `salient-eval` crates and the `salient` binary build on it). The
//! modules follow the method's pipeline (SPEC §n is `docs/SPEC.md`):
//!
//! - [`format`]: the mesh file formats by name, extension and media type;
//! - [`mesh`]: load OBJ / glTF / OFF / PLY / STL, weld, orient, simplify, normalise, smooth
//!   (§1); cut a ball out of a mesh;
//! - [`geodesic`]: local Dijkstra geodesics bounded by `D_g` (§2.1);
//! - [`waves`]: geodesic iso-lines traced into closed loops, their validity (§2.2–2.3);
//! - [`ecc`]: the extended cone-curvature vector of every vertex (§2.4);
//! - [`extraction`]: a prepared mesh with the ECC of every vertex, and its statistics;
//! - [`salient`]: k-means candidates, non-maximum suppression, salient regions (§3);
//! - [`descriptor`]: D2 shape distributions of regions and whole meshes (§4, §6), the
//!   Light Field Descriptor (§6), geodesic distributions (§9), patch descriptors;
//! - [`pipeline`]: load → prepare → ECC → salient features → descriptors → signature, with
//!   statistics and timings;
//! - [`signature`]: a model's features, descriptors, parameters and statistics; JSON and the
//!   versioned binary form (§4), and the rule for when a stored one is stale;
//! - [`emd`]: exact Earth Mover's Distance by the transportation simplex (§5);
//! - [`similarity`]: ground distance, penalised EMD, D2 baseline distance, lower bound (§5–6);
//! - [`rank`]: the methods, the hybrid's fusion (§9), and top-k ranking of an in-memory
//!   collection with bound-based pruning behind one search entry ([`rank::Search`]);
//! - [`partial`]: a part of a model as a query: described at a few sizes, fitted into each
//!   model's features, registered into the nearest (`docs/results/partial/`);
//! - [`register`]: rigid registration of one surface into another (ICP);
//! - [`duplicate`]: near-duplicates and the evidence for them (`docs/results/duplicates/`);
//! - [`collection`]: mesh folders and a disk cache of their signatures;
//! - [`display`]: how a model is shown: its up axis, surface and region colours;
//! - [`preview`]: a compact display mesh of a model with its regions (thumbnails, 3D view);
//! - [`render`]: pictures of a mesh with its salient points and regions (paper Fig. 10),
//!   thumbnails and comparisons;
//! - [`raster`]: triangle scan conversion shared by pictures and silhouettes;
//! - [`params`]: every parameter with its default, versioned; [`error`]: the one error type.

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
pub mod part_search;
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

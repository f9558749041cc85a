//! `salient-server`: the HTTP retrieval service over the [`salient_core`] library (SPEC §8;
//! `openapi.yaml` is the contract).
//!
//! - [`model`]: model ids (the one id rule), records, uploaded files and their content hash;
//! - [`store`]: persistent models, signatures and original files: sled, or in memory; the
//!   migrations of `migrations/`;
//! - [`spool`]: large request bodies, in files while they are read;
//! - [`api`]: the service: handlers that translate, keys, the catalogue, the extraction and
//!   ranking pools, background re-extraction.

pub mod api;
pub mod model;
pub mod spool;
pub mod store;

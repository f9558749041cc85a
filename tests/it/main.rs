//! The integration tests, in one binary so that the suite links once (ripgrep's layout:
//! `autotests = false` and one `[[test]]` in `Cargo.toml`). Most API tests drive the router in
//! process ([`app`]); those that need a real process (start-up, signals, `kill -9`, the CLI)
//! run the binary on a loopback port ([`server`]).
//!
//! Support modules: [`app`] (in-process service), [`server`] (the real binary), [`shapes`]
//! (generated meshes with known answers), [`common`] (glTF writing, mesh helpers),
//! [`synthetic`] (signature collections for ranking and measures), [`stores`] (the stores an
//! API test runs over).

#[macro_use]
mod stores;
mod app;
mod common;
mod own_postgres;
mod server;
mod shapes;
mod synthetic;

mod api;
mod auth;
mod backup;
mod cli;
mod concurrency;
mod duplicates;
mod durability;
mod ecc;
mod emd;
mod eval;
mod eval_metrics;
mod geodesic;
mod golden;
mod ingest;
mod layout;
mod lfd;
mod load;
mod openapi;
mod partial;
mod pgvector;
mod previews;
mod rank;
mod reindex;
mod replicas;
mod signature;
mod store;
mod weld;

//! Subcommands of the `salient` binary. Each translates arguments into library calls and
//! results into output; the method itself lives in the library.

mod backup;
mod compare;
mod eval;
mod extract;
mod health;
mod ingest;
mod keys;
mod migrate;
mod reindex;
mod render;
mod search;
mod serve;

use std::path::PathBuf;

use anyhow::Context;
use clap::{Parser, Subcommand};

use salient_core::Params;

/// Content-based 3D model retrieval with extended cone-curvature salient features.
#[derive(Debug, Parser)]
#[command(name = "salient", version, about)]
pub struct Cli {
    /// Worker threads for extraction (default: one per core).
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Extract the signature of a mesh (OBJ, glTF/GLB, OFF, PLY, STL, 3MF, or a zip of one): a summary or JSON.
    Extract(extract::Args),
    /// Compare two models (meshes or signature JSON files) by their salient features.
    Compare(compare::Args),
    /// Rank the meshes of a folder by similarity to a query.
    Search(search::Args),
    /// Run the HTTP retrieval service on its store.
    Serve(Box<serve::Args>),
    /// Re-extract every stored model with the current parameters.
    Reindex(reindex::Args),
    /// Upload every mesh of a folder to a running service.
    Ingest(ingest::Args),
    /// Make API keys for the service.
    Keys(keys::Args),
    /// Check that a running service answers (exit code 0 if it does).
    Health(health::Args),
    /// Print the service's OpenAPI description (the committed `openapi.yaml`).
    Openapi,
    /// Evaluate the method (SPEC §7): retrieval measures, robustness, parameter study.
    Eval(eval::Args),
    /// Draw a mesh with its salient points and regions (PNG, three views).
    Render(render::Args),
    /// Ask a running service for a consistent snapshot of its sled store (its backup folder).
    Backup(backup::Args),
    /// Copy a backup (a store folder) into an empty store, sled or PostgreSQL, and check it.
    Restore(migrate::Args),
    /// Copy a whole catalogue into an empty store (sled to PostgreSQL or back) and check it.
    MigrateStore(migrate::Args),
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    if let Some(threads) = cli.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build_global()
            .context("cannot start the worker threads")?;
    }
    match cli.command {
        Command::Extract(args) => extract::run(args),
        Command::Compare(args) => compare::run(args),
        Command::Search(args) => search::run(args),
        Command::Serve(args) => serve::run(*args),
        Command::Reindex(args) => reindex::run(args),
        Command::Ingest(args) => ingest::run(args),
        Command::Keys(args) => keys::run(args),
        Command::Health(args) => health::run(args),
        Command::Openapi => {
            print!("{}", salient_server::api::openapi_yaml());
            Ok(())
        }
        Command::Eval(args) => eval::run(args),
        Command::Render(args) => render::run(args),
        Command::Backup(args) => backup::run(args),
        Command::Restore(args) | Command::MigrateStore(args) => migrate::run(args),
    }
}

/// Parameters from an optional JSON file (missing fields take the SPEC defaults).
fn load_params(path: Option<&PathBuf>) -> anyhow::Result<Params> {
    let Some(path) = path else {
        return Ok(Params::default());
    };
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read parameters {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("invalid parameters in {}", path.display()))
}

/// A value parser for a library enum named by `name`: its names are listed in `--help`, and
/// the libraries stay free of clap.
fn choice<T: Copy + Send + Sync + 'static>(
    all: &'static [T],
    name: fn(T) -> &'static str,
) -> impl clap::builder::TypedValueParser<Value = T> {
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(all.iter().map(|&v| name(v))).map(move |chosen| {
        *all.iter()
            .find(|&&v| name(v) == chosen)
            .expect("clap accepts only the possible values")
    })
}

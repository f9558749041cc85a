//! `salient migrate-store` and `salient restore`: copy a whole catalogue — models, their
//! files and signatures, derived caches, state — into an empty store, sled or PostgreSQL
//! either way, then check the copy model by model. `restore` is the same copy from a backup
//! folder (`salient backup`), named for what it is used for.

use std::sync::Arc;

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressStyle};

use salient_server::store::copy::{copy_all, differences};
use salient_server::store::{PostgresStore, SledStore, Store};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The store to copy: a folder (sled; stop the server on it first, sled locks it) or a
    /// PostgreSQL connection string. Give a connection string in the environment.
    #[arg(long, env = "SALIENT_FROM", hide_env_values = true)]
    from: String,
    /// The empty store to copy into: a folder (made if missing) or a PostgreSQL connection
    /// string (of a database that exists).
    #[arg(long, env = "SALIENT_TO", hide_env_values = true)]
    to: String,
}

/// A store named by a folder or a PostgreSQL connection string (`postgres://…`, or
/// `key=value` pairs). Neither is printed: a connection string may hold a password.
fn open(name: &str, which: &str) -> anyhow::Result<Arc<dyn Store>> {
    let postgres =
        name.starts_with("postgres://") || name.starts_with("postgresql://") || name.contains('=');
    Ok(if postgres {
        Arc::new(
            PostgresStore::open(name)
                .with_context(|| format!("cannot open the PostgreSQL store {which}"))?,
        )
    } else {
        Arc::new(
            SledStore::open(std::path::Path::new(name)).with_context(|| {
                format!("cannot open the store folder {which} (is a server running on it?)")
            })?,
        )
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let from = open(&args.from, "--from")?;
    let to = open(&args.to, "--to")?;
    // Listed, not counted: an error reading it is not an empty store.
    if !to.list(None, 1)?.is_empty() {
        bail!("the store --to already holds models: copy into an empty store");
    }
    let progress = ProgressBar::new(from.len() as u64).with_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} {msg}").expect("a valid template"),
    );
    let copied = copy_all(from.as_ref(), to.as_ref(), |id| {
        progress.inc(1);
        progress.set_message(id.to_string());
    })?;
    progress.finish_and_clear();
    let differ = differences(from.as_ref(), to.as_ref(), 10)?;
    if !differ.is_empty() {
        bail!(
            "the copy differs from the original (was a server writing to it?), e.g. {}",
            differ
                .iter()
                .map(|id| id.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    println!(
        "copied {} models, {} derived entries and {} state values; every model's record and signature checked",
        copied.models, copied.derived, copied.states
    );
    Ok(())
}

//! `salient reindex`: re-extract every stored model with the current parameters (after a
//! parameter change; the store schema itself is migrated at open).

use std::path::PathBuf;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};

use salient::mesh::load_bytes;
use salient::params::PARAMS_VERSION;
use salient::signature::compute;
use salient::store::{SledStore, Store};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder of the store (the server must be stopped: the store is locked while open).
    #[arg(long, env = "SALIENT_DATA", default_value = "salient-data")]
    data: PathBuf,
    /// Parameters as JSON (default: the SPEC defaults).
    #[arg(long)]
    params: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let params = super::load_params(args.params.as_ref())?;
    params.validate()?;
    let store = SledStore::open(&args.data).with_context(|| {
        format!(
            "cannot open the store in {} (is a server running on it?)",
            args.data.display()
        )
    })?;
    let records = store.list(None, usize::MAX)?;
    let progress = ProgressBar::new(records.len() as u64).with_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} {msg}").expect("a valid template"),
    );
    let limits = salient::Limits {
        max_input_vertices: usize::MAX,
        max_input_triangles: usize::MAX,
    };
    let mut failed = 0;
    for mut record in records {
        progress.set_message(record.id.clone());
        let upload = store
            .upload(&record.id)?
            .with_context(|| format!("model {} vanished", record.id))?;
        let extracted = load_bytes(&upload.mesh, upload.format, &upload.resources, &limits)
            .and_then(|raw| compute(&raw, &params));
        match extracted {
            Ok(signature) => {
                let stats = &signature.stats.extraction.mesh;
                record.vertices = stats.vertices;
                record.triangles = stats.triangles;
                record.features = signature.features.len();
                record.params_version = PARAMS_VERSION;
                record.updated_unix = std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0, |d| d.as_secs());
                store.put(&record, &signature.to_bytes(), &upload)?;
            }
            Err(error) => {
                failed += 1;
                progress.suspend(|| eprintln!("cannot re-extract {}: {error}", record.id));
            }
        }
        progress.inc(1);
    }
    progress.finish_and_clear();
    let total = store.len();
    println!("re-extracted {} of {total} models", total - failed);
    anyhow::ensure!(
        failed == 0,
        "{failed} models could not be re-extracted and keep their old signatures"
    );
    Ok(())
}

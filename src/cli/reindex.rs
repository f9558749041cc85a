//! `salient reindex`: re-extract the stale signatures of a store offline (the service does
//! the same online: `POST /v1/admin/reindex`). Which signatures are stale is the one rule of
//! `Signature::staleness`; the store schema itself is migrated at open.

use std::path::PathBuf;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};

use salient_core::pipeline::{signature_of_file, Extent};
use salient_core::signature::Signature;
use salient_core::Limits;
use salient_server::store::{SledStore, Store};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Folder of the store (the server must be stopped: the store is locked while open).
    #[arg(long, env = "SALIENT_DATA", default_value = "salient-data")]
    data: PathBuf,
    /// Parameters as JSON (default: the SPEC defaults).
    #[arg(long)]
    params: Option<PathBuf>,
    /// Re-extract every model, stale or not.
    #[arg(long)]
    all: bool,
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
    let (mut renewed, mut current, mut failed) = (0, 0, 0);
    for mut record in records {
        progress.inc(1);
        progress.set_message(record.id.to_string());
        let id = record.id.as_str();
        let stale = match store.signature(id)? {
            Some(bytes) => {
                Signature::from_bytes(&bytes).map_or(true, |s| s.staleness(&params).is_some())
            }
            None => true,
        };
        if !stale && !args.all {
            current += 1;
            continue;
        }
        let upload = store
            .upload(id)?
            .with_context(|| format!("model {id} vanished"))?;
        let extracted = signature_of_file(
            &upload.mesh,
            upload.format,
            &upload.resources,
            (&params, Extent::Full),
            &Limits::unlimited(),
        );
        match extracted {
            Ok(signature) => {
                record.describe(&signature);
                store.update_model(&record, &signature.to_bytes())?;
                renewed += 1;
            }
            Err(error) => {
                failed += 1;
                progress.suspend(|| eprintln!("cannot re-extract {id}: {error}"));
            }
        }
    }
    progress.finish_and_clear();
    println!(
        "re-extracted {renewed} of {} models ({current} were current)",
        store.len()
    );
    anyhow::ensure!(
        failed == 0,
        "{failed} models could not be re-extracted and keep their old signatures"
    );
    Ok(())
}

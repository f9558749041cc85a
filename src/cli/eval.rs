//! `salient eval retrieval|robustness|study`: the evaluation protocol of SPEC §7.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};

use salient::collection::SignatureCache;
use salient::eval::retrieval::{self, EvalMethod};
use salient::eval::{LabelledCollection, Progress};
use salient::{Limits, Params};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Leave-one-out retrieval over a labelled collection (CLASS/MODEL.ext or labels.tsv):
    /// NN, FT, ST, E, DCG, mAP and precision–recall per method.
    Retrieval(RetrievalArgs),
}

#[derive(Debug, clap::Args)]
struct RetrievalArgs {
    /// The labelled collection.
    dir: PathBuf,
    /// Methods to compare: ecc, d2, ecc-paper.
    #[arg(long, value_delimiter = ',', default_value = "ecc,d2,ecc-paper")]
    methods: Vec<EvalMethod>,
    /// Where report.json, report.md, pr.png, pr.svg and the distance matrices go.
    #[arg(long, default_value = "salient-report")]
    out: PathBuf,
    #[command(flatten)]
    common: Common,
}

/// Options shared by the subcommands that extract a collection.
#[derive(Debug, clap::Args)]
struct Common {
    /// Where signatures are cached (default: DIR/.salient-cache).
    #[arg(long)]
    cache_dir: Option<PathBuf>,
    /// Parameters as JSON for the default method (fields left out keep the SPEC defaults).
    #[arg(long)]
    params: Option<PathBuf>,
}

impl Common {
    fn cache(&self, collection: &Path, params: &Params) -> SignatureCache {
        match &self.cache_dir {
            Some(dir) => SignatureCache::new(dir, params),
            None => SignatureCache::beside(collection, params),
        }
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        Command::Retrieval(args) => retrieval(args),
    }
}

fn retrieval(args: RetrievalArgs) -> anyhow::Result<()> {
    let params = super::load_params(args.common.params.as_ref())?;
    params.validate()?;
    let collection = LabelledCollection::open(&args.dir)?;
    let (report, matrices) = retrieval::run(
        &collection,
        &args.methods,
        &params,
        |p| args.common.cache(&args.dir, p),
        &Limits::default(),
        &Bar::default(),
    )?;
    report
        .write(&args.out, &matrices)
        .with_context(|| format!("writing the report into {}", args.out.display()))?;
    println!("{} models, {} classes", report.models, report.classes);
    println!(
        "{:<10} {:>6} {:>6} {:>6} {:>6} {:>6} {:>6}",
        "method", "NN", "FT", "ST", "E", "DCG", "mAP"
    );
    for m in &report.methods {
        print!("{:<10}", m.method.name());
        for (_, x) in m.evaluation.scores.measures() {
            print!(" {x:>6.3}");
        }
        println!();
    }
    println!("report: {}", args.out.join("report.md").display());
    Ok(())
}

/// A progress bar on stderr, one per step.
#[derive(Default)]
struct Bar(Mutex<Option<ProgressBar>>);

impl Progress for Bar {
    fn start(&self, step: &str, total: usize) {
        let bar = ProgressBar::new(total as u64).with_style(
            ProgressStyle::with_template("{prefix:>12} {bar:40} {pos}/{len} {elapsed} {msg}")
                .expect("a valid template"),
        );
        bar.set_prefix(step.to_string());
        *self.0.lock().expect("no panic while holding the bar") = Some(bar);
    }

    fn advance(&self, item: &str) {
        if let Some(bar) = &*self.0.lock().expect("no panic while holding the bar") {
            bar.set_message(item.to_string());
            bar.inc(1);
        }
    }

    fn finish(&self) {
        if let Some(bar) = self
            .0
            .lock()
            .expect("no panic while holding the bar")
            .take()
        {
            bar.finish_with_message("done");
        }
    }
}

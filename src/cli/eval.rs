//! `salient eval retrieval|robustness|study`: the evaluation protocol of SPEC §7.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};

use salient_core::collection::{SignatureCache, CACHE_DIR};
use salient_core::mesh::load_path;
use salient_core::Limits;
use salient_eval::retrieval::{self, EvalMethod};
use salient_eval::robustness::Perturbation;
use salient_eval::{duplicates, partial, robustness, study, tune, LabelledCollection, Progress};

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
    /// Re-extract one mesh simplified, noisy and moved; count the salient points found again.
    Robustness(RobustnessArgs),
    /// Vary W, the penalty, K, flat_max and D_g one at a time; tune on half of each class,
    /// judge on the other half.
    Study(StudyArgs),
    /// Make one copy of every model of a half per family of disguises (re-exported in another
    /// format, unit and place; re-triangulated, simplified four ways, subdivided three ways;
    /// rotated and scaled), mix each family's copies into the half alone and measure how well
    /// the near-duplicate search links them: precision and recall per family and evidence
    /// level, and each copy verified against its model both ways.
    Duplicates(DuplicatesArgs),
    /// Cut parts from every model of a half (three balls of 30–50 % of its radius around
    /// random surface points, and one part each of 5, 15, 30 and 50 % of its surface) and
    /// search each against the whole collection as `mode=partial` serves it: how often its
    /// source ranks first and within the top 5, and its class first, per part size.
    Partial(PartialArgs),
    /// Choose the hybrid's weights, scales and penalty power on the tuning halves of the
    /// collections together; judge them on the held-out halves.
    Tune(TuneArgs),
}

#[derive(Debug, clap::Args)]
struct DuplicatesArgs {
    /// The labelled collection.
    dir: PathBuf,
    /// The models that take part: the tuning half (thresholds are chosen on it), the
    /// held-out half (they are judged on it) or all.
    #[arg(long, default_value = "held-out", value_parser = super::choice(&study::Half::ALL, study::Half::as_str))]
    half: study::Half,
    /// Where duplicates.json and duplicates.md go.
    #[arg(long, default_value = "salient-duplicates")]
    out: PathBuf,
    /// Parameters as JSON (`similarity.duplicates` holds the thresholds).
    #[arg(long)]
    params: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct PartialArgs {
    /// The labelled collection.
    dir: PathBuf,
    /// The models parts are cut from: the tuning half (the sizes are chosen on it), the
    /// held-out half (they are judged on it) or all. Every model is searched.
    #[arg(long, default_value = "held-out", value_parser = super::choice(&study::Half::ALL, study::Half::as_str))]
    half: study::Half,
    /// Where partial.json and partial.md go.
    #[arg(long, default_value = "salient-partial")]
    out: PathBuf,
    #[command(flatten)]
    common: Common,
}

#[derive(Debug, clap::Args)]
struct TuneArgs {
    /// The labelled collections.
    #[arg(required = true)]
    dirs: Vec<PathBuf>,
    /// Where tune.json, tune.md and params.json (the chosen setting) go.
    #[arg(long, default_value = "salient-tune")]
    out: PathBuf,
    /// Where signatures are cached: ROOT/NAME for each collection folder NAME (default:
    /// each collection's own .salient-cache).
    #[arg(long)]
    cache_dir: Option<PathBuf>,
    /// Parameters as JSON (fields left out keep the SPEC defaults).
    #[arg(long)]
    params: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct StudyArgs {
    /// The labelled collection.
    dir: PathBuf,
    /// Where study.json and study.md go.
    #[arg(long, default_value = "salient-study")]
    out: PathBuf,
    #[command(flatten)]
    common: Common,
}

#[derive(Debug, clap::Args)]
struct RobustnessArgs {
    /// The mesh file.
    mesh: PathBuf,
    /// Where robustness.json and robustness.md go.
    #[arg(long, default_value = "salient-robustness")]
    out: PathBuf,
    /// Seed of the noise and the motion.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Parameters as JSON (fields left out keep the SPEC defaults).
    #[arg(long)]
    params: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct RetrievalArgs {
    /// The labelled collection.
    dir: PathBuf,
    /// Methods to compare: hybrid (the default), ecc, d2, lfd (the paper's comparison,
    /// Fig. 14) and ecc-paper.
    #[arg(long, value_delimiter = ',', default_value = "hybrid,ecc,d2,lfd")]
    methods: Vec<EvalMethod>,
    /// Where report.json, report.md, pr.png, pr.svg and the distance matrices go.
    #[arg(long, default_value = "salient-report")]
    out: PathBuf,
    /// Evaluate a disguised copy of the collection: `noise=0.01` displaces every vertex by
    /// Gaussian noise of RMS length 1 % of the bounding-box diagonal (seeded by model).
    #[arg(long)]
    perturb: Option<Perturbation>,
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
    fn cache_dir(&self, collection: &Path) -> PathBuf {
        self.cache_dir
            .clone()
            .unwrap_or_else(|| collection.join(CACHE_DIR))
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        Command::Retrieval(args) => retrieval(args),
        Command::Robustness(args) => robustness(args),
        Command::Study(args) => study(args),
        Command::Tune(args) => tune(args),
        Command::Duplicates(args) => duplicates(args),
        Command::Partial(args) => partial(args),
    }
}

fn partial(args: PartialArgs) -> anyhow::Result<()> {
    let params = super::load_params(args.common.params.as_ref())?;
    params.validate()?;
    let collection = LabelledCollection::open(&args.dir)?;
    let report = partial::run(
        &collection,
        args.half,
        &params,
        &SignatureCache::new(args.common.cache_dir(&args.dir), &params),
        &Limits::default(),
        &Bar::default(),
    )?;
    written(&args.out, report.write(&args.out), report.markdown())
}

fn duplicates(args: DuplicatesArgs) -> anyhow::Result<()> {
    let params = super::load_params(args.params.as_ref())?;
    params.validate()?;
    let collection = LabelledCollection::open(&args.dir)?;
    let report = duplicates::run(
        &collection,
        args.half,
        &params,
        &Limits::default(),
        &Bar::default(),
    )?;
    written(&args.out, report.write(&args.out), report.markdown())
}

fn tune(args: TuneArgs) -> anyhow::Result<()> {
    let params = super::load_params(args.params.as_ref())?;
    params.validate()?;
    let collections = args
        .dirs
        .iter()
        .map(|dir| LabelledCollection::open(dir))
        .collect::<Result<Vec<_>, _>>()?;
    let cache_dir = |c: &LabelledCollection| match (&args.cache_dir, c.root.file_name()) {
        (Some(root), Some(name)) => root.join(name),
        _ => c.root.join(CACHE_DIR),
    };
    let report = tune::run(
        &collections,
        &params,
        |c| SignatureCache::new(cache_dir(c), &params),
        &Limits::default(),
        &Bar::default(),
    )?;
    written(&args.out, report.write(&args.out), report.markdown())
}

fn study(args: StudyArgs) -> anyhow::Result<()> {
    let params = super::load_params(args.common.params.as_ref())?;
    params.validate()?;
    let collection = LabelledCollection::open(&args.dir)?;
    let cache_dir = args.common.cache_dir(&args.dir);
    let report = study::run(
        &collection,
        &params,
        &cache_dir,
        &Limits::default(),
        &Bar::default(),
    )?;
    written(&args.out, report.write(&args.out), report.markdown())
}

fn robustness(args: RobustnessArgs) -> anyhow::Result<()> {
    let params = super::load_params(args.params.as_ref())?;
    let raw = load_path(&args.mesh, &Limits::default())
        .with_context(|| args.mesh.display().to_string())?;
    let report = robustness::run(&args.mesh.display().to_string(), &raw, &params, args.seed)
        .with_context(|| args.mesh.display().to_string())?;
    written(&args.out, report.write(&args.out), report.markdown())
}

fn retrieval(args: RetrievalArgs) -> anyhow::Result<()> {
    let params = super::load_params(args.common.params.as_ref())?;
    params.validate()?;
    let collection = LabelledCollection::open(&args.dir)?;
    let mut cache_dir = args.common.cache_dir(&args.dir);
    if let Some(change) = &args.perturb {
        cache_dir = cache_dir.join(change.name());
    }
    let (report, matrices) = retrieval::run(
        &collection,
        &args.methods,
        &params,
        |p| SignatureCache::new(&cache_dir, p),
        &Limits::default(),
        args.perturb.as_ref(),
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

/// The end of a report command: `result` of writing the report's files into `out`; then
/// the report on stdout.
fn written(out: &Path, result: salient_core::Result<()>, markdown: String) -> anyhow::Result<()> {
    result.with_context(|| format!("writing the report into {}", out.display()))?;
    print!("{markdown}");
    Ok(())
}

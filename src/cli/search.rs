//! `salient search QUERY COLLECTION_DIR [-k 10] [--method hybrid|ecc|d2|lfd] [--partial
//! [--part-scale R]] [--json]`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde::Serialize;

use salient_core::collection::{find_meshes, SignatureCache, Source};
use salient_core::descriptor::patch::PackedPiece;
use salient_core::mesh::load_path;
use salient_core::params::MeshParams;
use salient_core::part_search::{self, PartQuery, SearchError};
use salient_core::partial::Target;
use salient_core::rank::{Index, Method, Request, Scope, Search};
use salient_core::signature::Signature;
use salient_core::Limits;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The query: a mesh file, or a signature JSON written by `salient extract --json`.
    query: PathBuf,
    /// Folder of meshes to rank (searched recursively).
    collection: PathBuf,
    /// How many results.
    #[arg(short, default_value_t = 10)]
    k: usize,
    /// hybrid (the default: ECC, D2 and LFD distances fused), ecc (salient features,
    /// penalised EMD), d2 (global shape distribution baseline) or lfd (Light Field Descriptor
    /// baseline).
    #[arg(long)]
    method: Option<Method>,
    /// The query is a piece of a model (cut from it, with an open boundary): rank the models
    /// that contain a part like it (`salient_core::partial`), as the service does: the models
    /// nearest it by their patches (cached beside the signatures) verified by
    /// registration, then the rest by the salient-feature fit. `--method` does not apply.
    #[arg(long, conflicts_with = "method")]
    partial: bool,
    /// With --partial: the part's size in its model, when known (its radius over the model's,
    /// in [0.2, 1]); default: each of `similarity.partial.scales`.
    #[arg(long, requires = "partial")]
    part_scale: Option<f64>,
    /// Print JSON.
    #[arg(long)]
    json: bool,
    /// Parameters as JSON (fields left out keep the SPEC defaults).
    #[arg(long)]
    params: Option<PathBuf>,
    /// Where signatures are cached (default: COLLECTION/.salient-cache).
    #[arg(long)]
    cache_dir: Option<PathBuf>,
}

#[derive(Serialize)]
struct Output<'a> {
    query: &'a Path,
    method: Method,
    /// Whether the query was searched as a part (`--partial`).
    partial: bool,
    k: usize,
    results: Vec<Row>,
    collection: usize,
    extracted: usize,
    cached: usize,
    failed: Vec<Failure>,
    evaluated: usize,
    pruned: usize,
    index_seconds: f64,
    search_seconds: f64,
}

#[derive(Serialize)]
struct Row {
    rank: usize,
    id: String,
    distance: f64,
    /// With `--partial`: the size (part radius over model radius) it fitted this model at.
    #[serde(skip_serializing_if = "Option::is_none")]
    part_scale: Option<f64>,
    /// With `--partial`, for the verified models: the registration residual
    /// ([`salient_core::partial::Probe::residual`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    residual: Option<f64>,
}

/// What is searched for: a whole model, or a part of one.
enum Query {
    Whole(Box<Signature>),
    Part(Box<PartQuery>),
}

#[derive(Serialize)]
struct Failure {
    path: String,
    error: String,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let params = super::load_params(args.params.as_ref())?;
    params.validate()?;
    let cache = match &args.cache_dir {
        Some(dir) => SignatureCache::new(dir, &params),
        None => SignatureCache::beside(&args.collection, &params),
    };
    let limits = Limits::default();
    let files = find_meshes(&args.collection)?;
    let method = args.method.unwrap_or_default();
    let query = if args.partial {
        let scales = params.similarity.partial.sizes(args.part_scale);
        let raw =
            load_path(&args.query, &limits).with_context(|| args.query.display().to_string())?;
        Query::Part(Box::new(
            PartQuery::extract(&raw, &params, &scales)
                .with_context(|| args.query.display().to_string())?,
        ))
    } else if args
        .query
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        Query::Whole(Box::new(super::compare::signature_of(
            &args.query,
            &params,
        )?))
    } else {
        Query::Whole(Box::new(
            cache
                .signature(&args.query, &params, &limits)
                .with_context(|| args.query.display().to_string())?
                .0,
        ))
    };
    if let Query::Whole(signature) = &query {
        if !method.ranks(&**signature) {
            anyhow::bail!(
                "{}: the query signature has no {method} descriptor (made by an older salient); extract it again",
                args.query.display(),
            );
        }
    }

    let clock = Instant::now();
    let progress = ProgressBar::new(files.len() as u64).with_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} {msg}").expect("a valid template"),
    );
    let mut index = Index::new(params.similarity.clone());
    let (mut extracted, mut cached, mut failed) = (0, 0, Vec::new());
    let mut indexed = Vec::new();
    for path in &files {
        let id = path
            .strip_prefix(&args.collection)
            .unwrap_or(path)
            .display()
            .to_string();
        progress.set_message(id.clone());
        match cache.signature(path, &params, &limits) {
            Ok((signature, source)) => {
                match source {
                    Source::Cached => cached += 1,
                    Source::Extracted => extracted += 1,
                }
                index
                    .insert(id.clone(), &signature)
                    .context("cannot write the index's file in the temporary folder")?;
                indexed.push((id, path));
            }
            Err(error) => {
                progress.suspend(|| eprintln!("skipping {id}: {error}"));
                failed.push(Failure {
                    path: id,
                    error: error.to_string(),
                });
            }
        }
        progress.inc(1);
    }
    progress.finish_and_clear();
    let index_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let unreadable = "cannot read the index's file in the temporary folder";
    let (mut results, evaluated, pruned): (Vec<Row>, _, _) = match &query {
        Query::Whole(signature) => {
            let ranking = index
                .search(&Request::model(signature, method, args.k))
                .context(unreadable)?;
            let rows = ranking.hits.into_iter().map(|hit| Row {
                rank: 0,
                id: hit.id,
                distance: hit.distance,
                part_scale: None,
                residual: None,
            });
            (rows.collect(), ranking.evaluated, ranking.pruned)
        }
        Query::Part(part) => {
            let folder = Folder {
                root: &args.collection,
                indexed: &indexed,
                cache: &cache,
                limits: &limits,
                params: &params.mesh,
            };
            let verified = params.similarity.partial.verified;
            let ranking =
                part_search::search(part, &index, Scope::default(), &folder, verified, args.k)
                    .map_err(|e| match e {
                        SearchError::Index(e) => anyhow::Error::new(e).context(unreadable),
                        SearchError::Library(e) => e,
                    })?;
            let rows = ranking.hits.into_iter().map(|hit| Row {
                rank: 0,
                id: hit.id,
                distance: hit.distance,
                part_scale: hit.part_scale,
                residual: hit.registration.map(|r| r.residual),
            });
            (rows.collect(), ranking.evaluated, ranking.pruned)
        }
    };
    for (i, row) in results.iter_mut().enumerate() {
        row.rank = i + 1;
    }
    let search_seconds = clock.elapsed().as_secs_f64();
    if args.json {
        let output = Output {
            query: &args.query,
            method: if args.partial { Method::Ecc } else { method },
            partial: args.partial,
            k: args.k,
            results,
            collection: index.len(),
            extracted,
            cached,
            failed,
            evaluated,
            pruned,
            index_seconds,
            search_seconds,
        };
        println!("{}", serde_json::to_string(&output)?);
    } else {
        for r in &results {
            let residual = r
                .residual
                .map(|x| format!(", residual {x:.4}"))
                .unwrap_or_default();
            match r.part_scale {
                Some(scale) => println!(
                    "{:>4}  {:.6}  {}  (part at {scale}{residual})",
                    r.rank, r.distance, r.id
                ),
                None => println!("{:>4}  {:.6}  {}", r.rank, r.distance, r.id),
            }
        }
        eprintln!(
            "{} models ({extracted} extracted, {cached} cached, {} failed); search {:.1} ms, {} exact comparisons",
            index.len(),
            failed.len(),
            search_seconds * 1e3,
            evaluated
        );
    }
    Ok(())
}

/// The collection's meshes as partial search verifies against them: their patches from the
/// cache (made when missing), their files loaded and prepared as targets.
struct Folder<'a> {
    root: &'a Path,
    indexed: &'a [(String, &'a PathBuf)],
    cache: &'a SignatureCache,
    limits: &'a Limits,
    params: &'a MeshParams,
}

impl part_search::Library for Folder<'_> {
    type Error = anyhow::Error;

    fn nearest(&self, piece: &PackedPiece) -> anyhow::Result<Vec<(Vec<f64>, String)>> {
        Ok(self
            .indexed
            .par_iter()
            .filter_map(|(id, path)| {
                let packed = self.cache.patches(path, self.limits).ok()?;
                Some((packed.nearest(piece), id.clone()))
            })
            .collect())
    }

    fn target(&self, id: &str) -> anyhow::Result<Option<Arc<Target>>> {
        let path = self.root.join(id);
        let raw = load_path(&path, self.limits).with_context(|| path.display().to_string())?;
        let target = Target::new(&raw, self.params).with_context(|| path.display().to_string())?;
        Ok(Some(Arc::new(target)))
    }
}

//! `salient compare A B [--json]`: SIM between two meshes or signature JSON files.

use std::path::{Path, PathBuf};

use anyhow::Context;

use salient_core::pipeline::describe;
use salient_core::pipeline::extract_path;
use salient_core::similarity::compare;
use salient_core::{Limits, Params, Signature};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A mesh file, or a signature as written by `salient extract --json` (`.json`).
    a: PathBuf,
    /// The same for the other model.
    b: PathBuf,
    /// Print `{"sim", "emd", "m", "n"}` as JSON.
    #[arg(long)]
    json: bool,
    /// Parameters as JSON (extraction of meshes, and the similarity's `W` and penalty).
    #[arg(long)]
    params: Option<PathBuf>,
}

/// A signature from a `.json` file, or extracted from a mesh.
pub fn signature_of(path: &Path, params: &Params) -> anyhow::Result<Signature> {
    let is_json = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    if is_json {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        return serde_json::from_str(&text)
            .with_context(|| format!("{} is not a salient signature", path.display()));
    }
    let extraction = extract_path(path, params, &Limits::default())
        .with_context(|| path.display().to_string())?;
    Ok(describe(&extraction, params))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let params = super::load_params(args.params.as_ref())?;
    let (a, b) = (
        signature_of(&args.a, &params)?,
        signature_of(&args.b, &params)?,
    );
    let similarity = compare(&a, &b, &params.similarity);
    if args.json {
        println!("{}", serde_json::to_string(&similarity)?);
    } else {
        println!(
            "SIM {:.6} (EMD {:.6}, {} vs {} features)",
            similarity.sim, similarity.emd, similarity.m, similarity.n
        );
    }
    Ok(())
}

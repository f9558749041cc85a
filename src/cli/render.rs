//! `salient render MESH -o PICTURE.png`: the mesh with its salient points and regions.

use std::path::PathBuf;

use anyhow::Context;

use salient_core::pipeline::extract_path;
use salient_core::render::{render, save_png, Camera};
use salient_core::salient::detect;
use salient_core::Limits;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The mesh file.
    mesh: PathBuf,
    /// The PNG to write.
    #[arg(short, long)]
    output: PathBuf,
    /// Pixels per view (three views side by side).
    #[arg(long, default_value_t = 400)]
    size: u32,
    /// Extraction parameters as JSON (fields left out take the SPEC defaults).
    #[arg(long)]
    params: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        (16..=4096).contains(&args.size),
        "--size must be between 16 and 4096 pixels"
    );
    let params = super::load_params(args.params.as_ref())?;
    let extraction = extract_path(&args.mesh, &params, &Limits::default())
        .with_context(|| args.mesh.display().to_string())?;
    let (points, _) = detect(&extraction, &params);
    let picture = render(&extraction, &points, &Camera::around(), args.size);
    save_png(&picture, &args.output)?;
    println!(
        "{}: {} salient points, {}×{} pixels",
        args.output.display(),
        points.len(),
        picture.width(),
        picture.height()
    );
    Ok(())
}

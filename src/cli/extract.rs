//! `salient extract MESH [--json] [--per-vertex]`.

use std::io::Write;
use std::path::PathBuf;

use glam::DVec3;
use serde::Serialize;

use salient_core::pipeline::describe;
use salient_core::pipeline::extract_path;
use salient_core::{Limits, Signature};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The mesh file.
    mesh: PathBuf,
    /// Print JSON instead of a text summary.
    #[arg(long)]
    json: bool,
    /// With --json: include the welded positions, ECC vector and region size of every vertex.
    #[arg(long, requires = "json")]
    per_vertex: bool,
    /// Extraction parameters as JSON (fields left out take the SPEC defaults).
    #[arg(long)]
    params: Option<PathBuf>,
}

#[derive(Serialize)]
struct Output<'a> {
    #[serde(flatten)]
    signature: &'a Signature,
    #[serde(skip_serializing_if = "Option::is_none")]
    positions: Option<Vec<[f64; 3]>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    ecc: Option<Vec<&'a [f64]>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    region_size: Option<&'a [f64]>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let params = super::load_params(args.params.as_ref())?;
    let extraction = extract_path(&args.mesh, &params, &Limits::default())?;
    let signature = describe(&extraction, &params);
    let stats = &signature.stats.extraction;
    let mut out = std::io::stdout().lock();
    if args.json {
        let per_vertex = args.per_vertex;
        let output = Output {
            signature: &signature,
            positions: per_vertex.then(|| {
                extraction
                    .mesh
                    .input_positions
                    .iter()
                    .map(DVec3::to_array)
                    .collect()
            }),
            ecc: per_vertex.then(|| extraction.ecc.vectors().collect()),
            region_size: per_vertex.then_some(extraction.ecc.region_size.as_slice()),
        };
        serde_json::to_writer(&mut out, &output)?;
        writeln!(out)?;
        return Ok(());
    }
    let m = &stats.mesh;
    let e = &stats.ecc;
    writeln!(out, "{}", args.mesh.display())?;
    writeln!(
        out,
        "  mesh: {} vertices / {} triangles read, {} welded, {} used{}{}",
        m.input_vertices,
        m.input_triangles,
        m.welded_vertices,
        m.vertices,
        if m.simplified { " (simplified)" } else { "" },
        match m.denoising.iterations {
            0 => String::new(),
            n => format!(" (rough: smoothed, {n} passes)"),
        }
    )?;
    writeln!(
        out,
        "  waves: {} complete, {} shrunk, {} with wave 1 invalid (first invalid wave: {})",
        e.complete, e.shrunk, e.wave1_invalid, e.first_defect
    )?;
    let s = &signature.stats.salient;
    writeln!(
        out,
        "  salient: {} features ({} candidates, {} after suppression, {} small regions dropped{}{})",
        signature.features.len(),
        s.candidates,
        s.after_suppression,
        s.small_regions_dropped,
        if s.capped > 0 { format!(", {} over the cap", s.capped) } else { String::new() },
        if s.fallback { ", fallback point" } else { "" },
    )?;
    writeln!(
        out,
        "  time: {:.3} s total (load {:.3}, weld {:.3}, orient {:.3}, simplify {:.3}, topology {:.3}, ECC {:.3} wall on {} threads: geodesics {:.3}, waves {:.3}, cones {:.3} CPU s; salient {:.3}, D2 {:.3})",
        stats.total_seconds,
        stats.load_seconds,
        m.weld_seconds,
        m.orient_seconds,
        m.simplify_seconds,
        stats.topology_seconds,
        e.wall_seconds,
        e.threads,
        e.geodesic_seconds,
        e.waves_seconds,
        e.cone_seconds,
        signature.stats.salient_seconds,
        signature.stats.d2_seconds,
    )?;
    Ok(())
}

//! ECC extraction on a real ~15 000-vertex mesh (issue: under 2 s on 2 cores; the paper took
//! 405 s at 14 800 vertices) and its scaling over five sizes, with the per-stage split.
//!
//! `cargo bench --bench ecc`. The mesh is SHREC'07 teddy 171 (14 905 vertices) from
//! `../shared/data` (academic licence, not in this repository); set `SALIENT_BENCH_MESH` to
//! use another file.

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use salient_core::mesh::load_path;
use salient_core::pipeline::extract;
use salient_core::{Limits, Params};

fn mesh_path() -> PathBuf {
    std::env::var_os("SALIENT_BENCH_MESH").map_or_else(
        || {
            PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../shared/data/shrec07-watertight/teddy/171.off")
        },
        PathBuf::from,
    )
}

fn ecc_extraction(c: &mut Criterion) {
    let path = mesh_path();
    let raw = match load_path(&path, &Limits::default()) {
        Ok(raw) => raw,
        Err(e) => panic!("benchmark mesh {} unavailable: {e}", path.display()),
    };
    let mut group = c.benchmark_group("ecc_extraction");
    group.sample_size(10);
    for max_vertices in [3_000, 6_000, 9_000, 12_000, 20_000] {
        let mut params = Params::default();
        params.mesh.max_vertices = max_vertices;
        let once = extract(&raw, &params).expect("benchmark mesh extracts");
        let s = &once.stats;
        eprintln!(
            "{{\"vertices\": {}, \"total_s\": {:.3}, \"weld_s\": {:.3}, \"orient_s\": {:.3}, \"simplify_s\": {:.3}, \"topology_s\": {:.3}, \"ecc_wall_s\": {:.3}, \"geodesic_cpu_s\": {:.3}, \"waves_cpu_s\": {:.3}, \"cones_cpu_s\": {:.3}, \"threads\": {}}}",
            s.mesh.vertices,
            s.total_seconds,
            s.mesh.weld_seconds,
            s.mesh.orient_seconds,
            s.mesh.simplify_seconds,
            s.topology_seconds,
            s.ecc.wall_seconds,
            s.ecc.geodesic_seconds,
            s.ecc.waves_seconds,
            s.ecc.cone_seconds,
            s.ecc.threads
        );
        group.bench_with_input(
            BenchmarkId::from_parameter(s.mesh.vertices),
            &params,
            |b, params| b.iter(|| extract(&raw, params).expect("extracts")),
        );
    }
    group.finish();
}

criterion_group!(benches, ecc_extraction);
criterion_main!(benches);

//! The Light Field Descriptor baseline (SPEC §6): descriptor time per model at two sizes and
//! comparison time per pair of models.
//!
//! `cargo bench --bench lfd`. Meshes: the CAPOD horse fixture and SHREC'07 teddy 171 (14 905
//! vertices) from `../shared/data` (academic licence, not in this repository; set
//! `SALIENT_BENCH_MESH` to use another file).

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use salient::descriptor::LightFieldDescriptor;
use salient::mesh::{load_path, prepare, PreparedMesh};
use salient::{Limits, Params};

fn prepared(path: PathBuf) -> PreparedMesh {
    let raw = load_path(&path, &Limits::default())
        .unwrap_or_else(|e| panic!("benchmark mesh {} unavailable: {e}", path.display()));
    prepare(&raw, &Params::default().mesh).expect("benchmark mesh prepares")
}

fn meshes() -> Vec<PreparedMesh> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let big = std::env::var_os("SALIENT_BENCH_MESH").map_or_else(
        || root.join("../shared/data/shrec07-watertight/teddy/171.off"),
        PathBuf::from,
    );
    vec![
        prepared(root.join("tests/fixtures/capod_horse_m155.obj")),
        prepared(big),
    ]
}

fn descriptor(c: &mut Criterion) {
    let mut group = c.benchmark_group("lfd_descriptor");
    group.sample_size(10);
    for mesh in meshes() {
        group.bench_with_input(
            BenchmarkId::from_parameter(mesh.positions.len()),
            &mesh,
            |b, mesh| b.iter(|| LightFieldDescriptor::compute(mesh)),
        );
    }
    group.finish();
}

fn comparison(c: &mut Criterion) {
    let [a, b] = meshes()
        .iter()
        .map(LightFieldDescriptor::compute)
        .collect::<Vec<_>>()
        .try_into()
        .expect("two meshes");
    c.bench_function("lfd_distance_pair", |bench| bench.iter(|| a.distance(&b)));
    c.bench_function("lfd_distance_self", |bench| bench.iter(|| a.distance(&a)));
}

criterion_group!(benches, descriptor, comparison);
criterion_main!(benches);

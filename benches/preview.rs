//! What a thumbnail costs (SPEC §8): a model's preview made from its upload and signature
//! (the first request: load, prepare, regions regrown, decimation), then a 256-pixel
//! thumbnail from the cached preview (decode, draw, PNG), and the 3D view's GLB.
//!
//! `cargo bench --bench preview`. Mesh: CAPOD `dog/m104.obj` (8 289 vertices) from
//! `../shared/data` (CC BY 3.0, not in this repository; `SALIENT_BENCH_MESH` for another).

use std::collections::BTreeMap;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use salient_core::display::UpAxis;
use salient_core::mesh::{load_path, Format};
use salient_core::pipeline::{compute, preview_of_file};
use salient_core::preview::Preview;
use salient_core::render::{png, thumbnail};
use salient_core::{Limits, Params};

fn previews(c: &mut Criterion) {
    let path = std::env::var_os("SALIENT_BENCH_MESH").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/capod/dog/m104.obj"),
        PathBuf::from,
    );
    let bytes = std::fs::read(&path)
        .unwrap_or_else(|e| panic!("benchmark mesh {} unavailable: {e}", path.display()));
    let format = Format::from_path(&path).expect("a mesh file");
    let (params, limits) = (Params::default(), Limits::default());
    let raw = load_path(&path, &limits).expect("the benchmark mesh loads");
    let signature = compute(&raw, &params).expect("the benchmark mesh extracts");
    let no_resources = BTreeMap::<String, Vec<u8>>::new();
    let make = || {
        preview_of_file(
            &bytes,
            format,
            &no_resources,
            (&signature.params, &signature.features),
            &limits,
        )
        .expect("a preview")
    };
    let key = Preview::key("benchmark", &signature);
    let entry = make().to_cache_entry(&key);

    let mut group = c.benchmark_group("preview");
    group.sample_size(20);
    group.bench_function("cold (from the upload)", |b| b.iter(make));
    group.bench_function("thumbnail 256 from the cache", |b| {
        b.iter(|| {
            let preview = Preview::from_cache_entry(&entry, &key).expect("the entry");
            png(&thumbnail(&preview, 256, true, UpAxis::Y))
        })
    });
    let preview = make();
    group.bench_function("glb", |b| b.iter(|| preview.to_glb(UpAxis::Y)));
    group.finish();
    eprintln!(
        "preview of {}: {} vertices, {} triangles, {} features; cache entry {} bytes, GLB {} bytes",
        path.display(),
        preview.positions.len(),
        preview.triangles.len(),
        preview.points.len(),
        entry.len(),
        preview.to_glb(UpAxis::Y).len()
    );
}

criterion_group!(benches, previews);
criterion_main!(benches);

//! The Light Field Descriptor baseline (SPEC §6): descriptor time per model at two sizes,
//! comparison time per pair of models, and top-10 ranking over 100 000 descriptors.
//!
//! `cargo bench --bench lfd`. Meshes: the CAPOD horse fixture and SHREC'07 teddy 171 (14 905
//! vertices) from `../shared/data` (academic licence, not in this repository; set
//! `SALIENT_BENCH_MESH` to use another file). The ranking collection is made of the descriptors
//! of the CAPOD collection in `../shared/data/capod`, each copied ~550 times with every
//! coefficient moved by up to ±6 quantisation steps — 180 tight classes, a favourable case for
//! the pruning bound, so the report also gives the fraction pruned.

#[path = "../tests/it/synthetic.rs"]
mod synthetic;

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use salient_core::collection::find_meshes;
use salient_core::descriptor::lfd::{ImageFeatures, LIGHT_FIELDS};
use salient_core::descriptor::LightFieldDescriptor;
use salient_core::mesh::{load_path, prepare, PreparedMesh};
use salient_core::rank::{Index, Method, Request, Search};
use salient_core::{Limits, Params};

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

/// `d` with every coefficient moved by up to ±`steps`.
fn perturbed(d: &LightFieldDescriptor, steps: i32, rng: &mut ChaCha8Rng) -> LightFieldDescriptor {
    let images: Vec<ImageFeatures> = (0..LIGHT_FIELDS)
        .flat_map(|f| d.light_field(f).iter())
        .map(|image| {
            let bytes: Vec<u8> = image
                .coefficients()
                .iter()
                .map(|&c| (c as i32 + rng.gen_range(-steps..=steps)).clamp(0, 255) as u8)
                .collect();
            ImageFeatures::try_from(bytes).expect("45 coefficients")
        })
        .collect();
    LightFieldDescriptor::try_from(images).expect("100 images")
}

fn search_100k(c: &mut Criterion) {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/capod");
    let files = find_meshes(&dir)
        .unwrap_or_else(|e| panic!("benchmark collection {} unavailable: {e}", dir.display()));
    let params = Params::default();
    let real: Vec<LightFieldDescriptor> = files
        .par_iter()
        .filter_map(|path| {
            let raw = load_path(path, &Limits::default()).ok()?;
            Some(LightFieldDescriptor::compute(
                &prepare(&raw, &params.mesh).ok()?,
            ))
        })
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut index = Index::new(params.similarity.clone());
    for (i, (id, mut signature)) in synthetic::collection(100_000, 1000, 7)
        .into_iter()
        .enumerate()
    {
        signature.lfd = Some(perturbed(&real[i % real.len()], 6, &mut rng));
        index.insert(id, &signature).expect("shelved");
    }
    let queries: Vec<_> = synthetic::collection(20, 1000, 8)
        .into_iter()
        .enumerate()
        .map(|(i, (_, mut s))| {
            s.lfd = Some(perturbed(&real[(i * 7) % real.len()], 6, &mut rng));
            s
        })
        .collect();
    let (mut evaluated, mut pruned) = (0, 0);
    for q in &queries {
        let r = index
            .search(&Request::model(q, Method::Lfd, 10))
            .expect("ranks");
        evaluated += r.evaluated;
        pruned += r.pruned;
    }
    eprintln!(
        "{{\"lfd_top10_100k\": {{\"classes\": {}, \"evaluated_per_query\": {}, \"pruned_fraction\": {:.4}}}}}",
        real.len(),
        evaluated / queries.len(),
        pruned as f64 / (evaluated + pruned) as f64
    );
    let mut group = c.benchmark_group("lfd_search");
    group.sample_size(10);
    let mut next = queries.iter().cycle();
    group.bench_function("top10_of_100k", |b| {
        b.iter(|| {
            index.search(&Request::model(
                next.next().expect("cycles"),
                Method::Lfd,
                10,
            ))
        })
    });
    group.finish();
}

criterion_group!(benches, descriptor, comparison, search_100k);
criterion_main!(benches);

//! Similarity and ranking (issue targets: top-10 of 100 000 signatures in under 100 ms on
//! 2 cores). `cargo bench --bench rank`. Signatures are synthetic (tests/synthetic): class
//! prototypes of smooth ECC curves and unimodal region D2 histograms, members perturbed, with
//! light fields and geodesic histograms for the hybrid.

#[path = "../tests/it/synthetic.rs"]
mod synthetic;

use std::time::Instant;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use salient::rank::{Index, Method};
use salient::similarity::compare;
use salient::{Params, Signature};

/// A signature with exactly `n` features.
fn with_features(n: usize, seed: u64) -> Signature {
    let mut pool = synthetic::collection(64, 1, seed);
    let mut s = pool.pop().expect("one").1;
    let features: Vec<_> = pool
        .iter()
        .flat_map(|(_, p)| p.features.clone())
        .take(n)
        .collect();
    s.features = features;
    s
}

fn emd_solve(c: &mut Criterion) {
    let params = Params::default().similarity;
    let mut group = c.benchmark_group("sim_emd");
    for (m, n) in [(3, 3), (5, 5), (10, 10), (20, 20), (30, 30), (5, 12)] {
        let (p, q) = (with_features(m, 1), with_features(n, 2));
        group.bench_with_input(
            BenchmarkId::from_parameter(format!("{m}x{n}")),
            &(p, q),
            |b, (p, q)| b.iter(|| compare(p, q, &params)),
        );
    }
    group.finish();
}

fn search_100k(c: &mut Criterion) {
    let params = Params::default().similarity;
    let clock = Instant::now();
    // The last 20 members are held out as queries: new models of the stored classes.
    let mut collection = synthetic::collection(100_020, 1000, 7);
    synthetic::with_descriptors(&mut collection, 1000, 9);
    let queries = collection.split_off(100_000);
    let mut index = Index::new(params);
    for (id, s) in collection {
        index.insert(id, s);
    }
    eprintln!(
        "built a 100 000-entry index in {:.2} s",
        clock.elapsed().as_secs_f64()
    );
    for method in [Method::Ecc, Method::Hybrid] {
        let (mut evaluated, mut pruned) = (0, 0);
        for (_, q) in &queries {
            let r = index.search(q, 10, method);
            evaluated += r.evaluated;
            pruned += r.pruned;
        }
        eprintln!(
            "{method} top-10 over 100 000: {:.1} % pruned on average ({} exact distances per query)",
            100.0 * pruned as f64 / (pruned + evaluated) as f64,
            evaluated / queries.len()
        );
    }
    let mut group = c.benchmark_group("search_100k");
    group.sample_size(10);
    for method in [Method::Hybrid, Method::Ecc] {
        group.bench_function(format!("{method}_top10"), |b| {
            let mut i = 0;
            b.iter(|| {
                i = (i + 1) % queries.len();
                index.search(&queries[i].1, 10, method)
            })
        });
    }
    for method in [Method::D2, Method::Geodesic] {
        group.bench_function(format!("{method}_top10"), |b| {
            b.iter(|| index.search(&queries[0].1, 10, method))
        });
    }
    group.finish();
}

criterion_group!(benches, emd_solve, search_100k);
criterion_main!(benches);

//! Similarity and ranking (issue targets: top-10 of 100 000 signatures in under 100 ms on
//! 2 cores). `cargo bench --bench rank`. Signatures are synthetic (tests/synthetic): class
//! prototypes of smooth ECC curves and unimodal region D2 histograms, members perturbed, with
//! light fields and geodesic histograms for the hybrid.

#[path = "support/corpus.rs"]
mod corpus;
#[path = "../tests/it/synthetic.rs"]
mod synthetic;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Instant;

use rand::SeedableRng;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use salient_core::descriptor::lfd::LightFieldDescriptor;
use salient_core::rank::vectors::{self, Layout};
use salient_core::rank::{compact, Fetch, Index, Method, Request, Scope, Search};
use salient_core::similarity::compare;
use salient_core::{Params, Signature};

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
        index.insert(id, &s).expect("shelved");
    }
    eprintln!(
        "built a 100 000-entry index in {:.2} s",
        clock.elapsed().as_secs_f64()
    );
    for method in [Method::Ecc, Method::Hybrid] {
        let (mut evaluated, mut pruned) = (0, 0);
        for (_, q) in &queries {
            let r = index.search(&Request::model(q, method, 10)).expect("ranks");
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
                index
                    .search(&Request::model(&queries[i].1, method, 10))
                    .expect("ranks")
            })
        });
    }
    for method in [Method::D2, Method::Geodesic] {
        group.bench_function(format!("{method}_top10"), |b| {
            b.iter(|| {
                index
                    .search(&Request::model(&queries[0].1, method, 10))
                    .expect("ranks")
            })
        });
    }
    group.finish();
}

/// Resident memory of this process, MiB (Linux).
fn resident_mib() -> f64 {
    let statm = std::fs::read_to_string("/proc/self/statm").unwrap_or_default();
    let pages: f64 = statm
        .split_whitespace()
        .nth(1)
        .and_then(|p| p.parse().ok())
        .unwrap_or(f64::NAN);
    pages * 4096.0 / (1 << 20) as f64
}

/// The `p`-th percentile of `values` (sorted in place).
fn percentile(values: &mut [f64], p: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * p).round() as usize]
}

/// What a ranking with its first stage in the database (#40) pays a candidate for its row
/// from its compact form, against decoding its whole stored signature, on one thread.
fn candidate_rows(models: &[(usize, Signature)]) {
    let rounds = 20;
    let stored: Vec<Vec<u8>> = models.iter().map(|(_, s)| s.to_bytes()).collect();
    let compacts: Vec<Vec<u8>> = models.iter().map(|(_, s)| compact::of(s)).collect();
    let none: Fetch = Arc::new(|_: &[Arc<str>]| Ok(Vec::new()));
    let away = Index::away(Params::default().similarity, none);
    // µs per form of `read`, over `rounds` passes.
    let per_form = |forms: &[Vec<u8>], read: &dyn Fn(usize, &[u8])| {
        let clock = Instant::now();
        for (i, bytes) in forms.iter().cycle().take(rounds * forms.len()).enumerate() {
            read(i, bytes);
        }
        clock.elapsed().as_secs_f64() * 1e6 / (rounds * forms.len()) as f64
    };
    let compact_us = per_form(&compacts, &|i, bytes| {
        std::hint::black_box(away.compact_row(format!("m{i}"), bytes).expect("readable"));
    });
    let whole_us = per_form(&stored, &|_, bytes| {
        std::hint::black_box(Signature::from_bytes(bytes).expect("readable"));
    });
    let mean = |forms: &[Vec<u8>]| forms.iter().map(Vec::len).sum::<usize>() / forms.len();
    eprintln!(
        "a candidate's row: from its compact form {compact_us:.1} µs ({} bytes); decoding \
         its stored signature {whole_us:.1} µs ({} bytes)",
        mean(&compacts),
        mean(&stored)
    );
}

/// What a replica with its first stage in the database (#40) spends on one ranking, the
/// database left out: the `SALIENT_RANK_CANDIDATES` (1 000) models nearest each held-out query
/// by the first stage's vectors (exactly, as a perfect HNSW scan would give them) among
/// `size` perturbed copies, their rows made from their compact forms, then ranked with their
/// light field descriptors unpacked as the server's second round reads them. One thread, as a
/// ranking gets on two cores with two at once.
fn first_stage_rankings(
    sources: &[(usize, Signature)],
    held_out: &[(usize, Signature)],
    size: usize,
) {
    let params = Params::default().similarity;
    let candidates: usize = std::env::var("SALIENT_RANK_CANDIDATES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1000);
    let vector =
        |s: &Signature| vectors::rows(s, &params, Layout::Pooled).and_then(|mut v| v.pop());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let (mut kept, mut stored) = (Vec::with_capacity(size), Vec::with_capacity(size));
    for i in 0..size {
        let copy = corpus::perturbed(&sources[i % sources.len()].1, &mut rng, 0.15);
        let Some(v) = vector(&copy) else { continue };
        kept.push((format!("m{i:06}"), v, compact::of(&copy)));
        stored.push(copy.lfd.as_ref().expect("a vector needs one").packed());
    }
    let stored = Arc::new(stored);
    // Light fields read, over every query.
    let read = Arc::new(AtomicUsize::new(0));
    let fetch: Fetch = {
        let (stored, read) = (stored.clone(), read.clone());
        Arc::new(move |ids: &[Arc<str>]| {
            read.fetch_add(ids.len(), Ordering::Relaxed);
            Ok(ids
                .iter()
                .filter_map(|id| {
                    let i: usize = id[1..].parse().ok()?;
                    Some((id.clone(), LightFieldDescriptor::unpacked(&stored[i])))
                })
                .collect())
        })
    };
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a pool");
    let (mut rows_ms, mut rank_ms, mut exact) = (Vec::new(), Vec::new(), 0);
    for (_, query) in held_out {
        let Some(q) = vector(query) else { continue };
        let mut order: Vec<(f32, usize)> = kept
            .iter()
            .enumerate()
            .map(|(i, (_, v, _))| (v.iter().zip(&q).map(|(a, b)| (a - b).abs()).sum(), i))
            .collect();
        order.select_nth_unstable_by(candidates, |a, b| a.0.total_cmp(&b.0));
        let clock = Instant::now();
        let mut away = Index::away(params.clone(), fetch.clone());
        for &(_, i) in &order[..candidates] {
            let (id, _, form) = &kept[i];
            away.put(away.compact_row(id.as_str(), form).expect("readable"));
        }
        rows_ms.push(clock.elapsed().as_secs_f64() * 1e3);
        let clock = Instant::now();
        let ranking = one_thread
            .install(|| away.search(&Request::model(query, Method::Hybrid, 10)))
            .expect("ranks");
        rank_ms.push(clock.elapsed().as_secs_f64() * 1e3);
        exact += ranking.evaluated;
    }
    let queries = rank_ms.len().max(1);
    eprintln!(
        "first stage's {candidates} candidates of {size}: rows p50 {:.1} ms, ranking p50 {:.1} / \
         p99 {:.1} ms; a query reads {} light fields and solves {} exact distances",
        percentile(&mut rows_ms, 0.5),
        percentile(&mut rank_ms, 0.5),
        percentile(&mut rank_ms, 0.99),
        read.load(Ordering::Relaxed) / queries,
        exact / queries
    );
}

/// Ranking cost on **real signatures**: the load bench's base store (both shared collections
/// less every fifth model, extracted once by `cargo bench --bench load`) copied with every
/// descriptor perturbed into `SALIENT_RANK_MODELS` entries (100 000), ranked in process on one
/// thread: `similar` (a stored entry, itself left out) and held-out queries (every fifth base
/// model, whose copies are not stored). Prints one row per method.
fn real_signatures(_: &mut Criterion) {
    let base = corpus::base_store_path(true);
    if !base.with_extension("complete").exists() {
        eprintln!(
            "real signatures: {} not found (made by `cargo bench --bench load` with \
             ../shared/data); skipped",
            base.display()
        );
        return;
    }
    let size: usize = std::env::var("SALIENT_RANK_MODELS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(100_000);
    let models: Vec<Signature> = corpus::load_base(&base)
        .into_iter()
        .map(|(_, s, _)| s)
        .collect();
    let (held_out, sources): (Vec<_>, Vec<_>) = models
        .into_iter()
        .enumerate()
        .partition(|(i, _)| i % 5 == 4);
    candidate_rows(&sources);
    // `SALIENT_RANK_FIRST_STAGE=1`: the replica's side of a first stage in the database alone.
    if std::env::var("SALIENT_RANK_FIRST_STAGE").is_ok() {
        first_stage_rankings(&sources, &held_out, size);
        return;
    }
    let before = resident_mib();
    let clock = Instant::now();
    let mut index = Index::new(Params::default().similarity);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    // `similar` asks about stored entries: these, kept as they were inserted.
    let asked: Vec<usize> = (0..held_out.len()).map(|q| q * 997 % size).collect();
    let mut similar = Vec::new();
    for i in 0..size {
        let source = &sources[i % sources.len()].1;
        let (id, signature) = (
            format!("m{i:06}"),
            corpus::perturbed(source, &mut rng, 0.15),
        );
        index.insert(id.clone(), &signature).expect("shelved");
        if asked.contains(&i) {
            similar.push((Some(id), signature));
        }
    }
    // As the service does after loading its store.
    let arranging = Instant::now();
    index.arrange();
    eprintln!("arranged in {:.2} s", arranging.elapsed().as_secs_f64());
    eprintln!(
        "real signatures: {size} perturbed copies of {} models in {:.1} s, {:.0} MiB resident \
         for the index; {} held-out queries",
        sources.len(),
        clock.elapsed().as_secs_f64(),
        resident_mib() - before,
        held_out.len()
    );
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a pool");
    eprintln!("| method | queries | p50 ms | p99 ms | mean ms | exact per query |");
    eprintln!("|---|---|---:|---:|---:|---:|");
    // `SALIENT_RANK_METHODS=hybrid,lfd` narrows the table.
    let methods = corpus::methods_from_env("SALIENT_RANK_METHODS");
    for method in methods {
        /// Queries: the id left out of the ranking (a stored model's own), and the signature.
        type Queries<'a> = Vec<(Option<&'a str>, &'a Signature)>;
        let cases: [(&str, Queries); 2] = [
            (
                "similar",
                similar.iter().map(|(id, s)| (id.as_deref(), s)).collect(),
            ),
            (
                "held-out",
                held_out.iter().map(|(_, s)| (None, s)).collect(),
            ),
        ];
        for (what, queries) in cases {
            // `SALIENT_RANK_CASES=similar` likewise narrows the queries.
            if std::env::var("SALIENT_RANK_CASES").is_ok_and(|cases| !cases.contains(what)) {
                continue;
            }
            let (mut ms, mut exact) = (Vec::new(), 0);
            for (id, query) in &queries {
                let clock = Instant::now();
                let ranking = one_thread.install(|| {
                    index
                        .search(&Request::model(query, method, 10).scope(Scope {
                            without: *id,
                            keep: None,
                        }))
                        .expect("ranks")
                });
                ms.push(clock.elapsed().as_secs_f64() * 1e3);
                exact += ranking.evaluated;
            }
            let mean = ms.iter().sum::<f64>() / ms.len() as f64;
            eprintln!(
                "| {method} | {what} | {:.1} | {:.1} | {mean:.1} | {} |",
                percentile(&mut ms, 0.5),
                percentile(&mut ms, 0.99),
                exact / queries.len()
            );
        }
    }
}

criterion_group!(benches, emd_solve, search_100k);
criterion_group!(real, real_signatures);
criterion_main!(real, benches);

//! Load figures of the HTTP service (issue #5), against the real release binary on a loopback
//! port: ingest throughput of ~7 000-vertex meshes through `salient ingest`, then searches per
//! second and p50/p99 latency of `GET /v1/models/{id}/similar?k=10` and `POST /v1/search?k=10`
//! with 1 000 and 10 000 stored models, and the server's resident memory after loading them.
//!
//! `cargo bench --bench load` (a few minutes on 2 cores). `SALIENT_LOAD_SIZES=1000,10000` and
//! `SALIENT_LOAD_SECONDS=10` (per similar-search measurement) change the run.
//!
//! A bench target rather than a subcommand: it stays out of `cargo test` and of the shipped
//! binary, and cargo builds the server it starts in release mode. The meshes are generated
//! ("stars": UV spheres pushed out towards random tips). The large stores are filled through
//! the library (`Store::put`) with the signatures of the ingested meshes, each copy perturbed
//! so that no two stored models are equal, then served by a fresh server.

#[path = "../tests/it/server.rs"]
mod server;

use std::f64::consts::PI;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use salient::store::{SledStore, Store};
use salient::Signature;
use serde_json::Value;
use server::Server;

const BIN: &str = env!("CARGO_BIN_EXE_salient");
/// UV sphere resolution: 69 rings of 101 vertices and two poles, 6 971 vertices.
const RINGS: usize = 69;
const SEGMENTS: usize = 101;
/// Meshes ingested (and the distinct signatures the large stores are made of).
const MESHES: usize = 24;
/// Clients sending requests at once.
const CLIENTS: usize = 4;

/// A star mesh as OBJ text: a UV sphere of radius 0.5 pushed out towards `tips`.
fn star_obj(tips: &[DVec3], width: f64) -> String {
    let radius = |p: DVec3| {
        let bump: f64 = tips
            .iter()
            .map(|t| (-(p.angle_between(*t) / width).powi(2)).exp())
            .sum();
        0.5 + 0.8 * bump
    };
    let mut text = String::new();
    let mut vertex = |p: DVec3| text += &format!("v {} {} {}\n", p.x, p.y, p.z);
    vertex(DVec3::Z * radius(DVec3::Z));
    for r in 1..=RINGS {
        let theta = PI * r as f64 / (RINGS + 1) as f64;
        for s in 0..SEGMENTS {
            let phi = 2.0 * PI * s as f64 / SEGMENTS as f64;
            let p = DVec3::new(
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            );
            vertex(p * radius(p));
        }
    }
    vertex(-DVec3::Z * radius(-DVec3::Z));
    // 1-based OBJ indices: the north pole is 1, ring r (1-based) vertex s is 2 + (r-1)·S + s.
    let at = |r: usize, s: usize| 2 + (r - 1) * SEGMENTS + s % SEGMENTS;
    let south = 2 + RINGS * SEGMENTS;
    for s in 0..SEGMENTS {
        text += &format!("f 1 {} {}\n", at(1, s), at(1, s + 1));
        text += &format!("f {south} {} {}\n", at(RINGS, s + 1), at(RINGS, s));
        for r in 1..RINGS {
            let (a, b, c, d) = (at(r, s), at(r, s + 1), at(r + 1, s), at(r + 1, s + 1));
            text += &format!("f {a} {c} {d}\nf {a} {d} {b}\n");
        }
    }
    text
}

fn random_star(rng: &mut ChaCha8Rng) -> String {
    let tips: Vec<DVec3> = (0..rng.gen_range(2..9))
        .map(|_| {
            let (z, phi): (f64, f64) = (rng.gen_range(-1.0..1.0), rng.gen_range(0.0..2.0 * PI));
            let r = (1.0 - z * z).sqrt();
            DVec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect();
    star_obj(&tips, rng.gen_range(0.2..0.45))
}

/// Uploads/s of `salient ingest` with `concurrency` into an empty store.
fn ingest(meshes: &Path, concurrency: usize) -> f64 {
    let data = tempfile::tempdir().expect("a temporary folder");
    let server = Server::start(&data.path().join("store"), &[]);
    let out = Command::new(BIN)
        .arg("ingest")
        .arg(meshes)
        .args(["--server", &server.url, "--json", "--concurrency"])
        .arg(concurrency.to_string())
        .output()
        .expect("the client runs");
    let summary: Value = serde_json::from_slice(&out.stdout).expect("a JSON summary");
    assert_eq!(summary["added"], MESHES as u64, "{summary}");
    MESHES as f64 / summary["seconds"].as_f64().expect("seconds")
}

/// The signature with every ECC value and D2 bin scaled by up to ±`amount` (D2 renormalised)
/// and, as `tests/synthetic` does, sometimes a feature fewer: copies spread around their
/// original like the members of a class rather than piling up on it (which would let the
/// ranking's bounds prune almost everything).
fn perturbed(signature: &Signature, rng: &mut ChaCha8Rng, amount: f64) -> Signature {
    let mut s = signature.clone();
    if s.features.len() > 2 && rng.gen_bool(0.3) {
        let drop = rng.gen_range(0..s.features.len());
        s.features.remove(drop);
    }
    for f in &mut s.features {
        f.ecc
            .iter_mut()
            .for_each(|a| *a *= 1.0 + rng.gen_range(-amount..amount));
        jitter_histogram(&mut f.d2, rng, amount);
    }
    jitter_histogram(&mut s.d2, rng, amount);
    s
}

/// Each bin scaled by up to ±`amount`, then the histogram renormalised.
fn jitter_histogram(bins: &mut [f32], rng: &mut ChaCha8Rng, amount: f64) {
    for v in bins.iter_mut() {
        *v *= (1.0 + rng.gen_range(-amount..amount)) as f32;
    }
    let sum: f32 = bins.iter().sum();
    if sum > 0.0 {
        bins.iter_mut().for_each(|v| *v /= sum);
    }
}

/// Adds models `from..to` to the store at `data`, perturbed copies of the models of `base`.
fn fill(data: &Path, base: &Path, from: usize, to: usize) {
    let source = SledStore::open(base).expect("the ingested store");
    let models: Vec<_> = source
        .load_all()
        .map(|loaded| {
            let loaded = loaded.expect("loads");
            let upload = source
                .upload(loaded.record.id.as_str())
                .expect("reads")
                .expect("stored");
            let signature = Signature::from_bytes(&loaded.signature).expect("decodes");
            (loaded.record, signature, upload)
        })
        .collect();
    drop(source);
    let store = SledStore::open(data).expect("opens");
    let mut rng = ChaCha8Rng::seed_from_u64(from as u64);
    for i in from..to {
        let (record, signature, upload) = &models[i % models.len()];
        let mut record = record.clone();
        record.id = salient::model::ModelId::parse(&format!("m{i:05}")).expect("a valid id");
        record.tags = vec![format!("t{}", i % 10)];
        let bytes = perturbed(signature, &mut rng, 0.15).to_bytes();
        store.put(&record, &bytes, upload).expect("stores");
    }
}

/// Latencies of requests sent by `CLIENTS` clients in a closed loop, until `budget` has passed
/// or `limit` requests are done; the server's own `timings.search_ms` of each, and the models
/// whose exact distance it computed (the rest were pruned by a lower bound).
struct Run {
    latencies: Vec<Duration>,
    search_ms: Vec<f64>,
    evaluated: Vec<f64>,
    elapsed: Duration,
}

async fn closed_loop<F>(budget: Duration, limit: usize, request: F) -> Run
where
    F: Fn(usize) -> reqwest::RequestBuilder + Send + Sync + 'static,
{
    let request = Arc::new(request);
    let clock = Instant::now();
    let sent = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let mut clients = tokio::task::JoinSet::new();
    for _ in 0..CLIENTS {
        let (request, sent) = (request.clone(), sent.clone());
        clients.spawn(async move {
            let mut mine = Vec::new();
            loop {
                let n = sent.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                if n >= limit || clock.elapsed() > budget {
                    return mine;
                }
                let start = Instant::now();
                let response = request(n).send().await.expect("the server answers");
                assert!(response.status().is_success(), "{}", response.status());
                let body: Value = response.json().await.expect("JSON");
                mine.push((
                    start.elapsed(),
                    body["timings"]["search_ms"].as_f64(),
                    body["evaluated"].as_f64(),
                ));
            }
        });
    }
    let mut run = Run {
        latencies: Vec::new(),
        search_ms: Vec::new(),
        evaluated: Vec::new(),
        elapsed: Duration::ZERO,
    };
    while let Some(mine) = clients.join_next().await {
        for (latency, search_ms, evaluated) in mine.expect("a client task") {
            run.latencies.push(latency);
            run.search_ms.extend(search_ms);
            run.evaluated.extend(evaluated);
        }
    }
    run.elapsed = clock.elapsed();
    run
}

fn percentile_ms(values: &mut [f64], p: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * p).round() as usize]
}

fn report(models: usize, what: &str, mut run: Run) {
    let mut ms: Vec<f64> = run
        .latencies
        .iter()
        .map(|d| d.as_secs_f64() * 1e3)
        .collect();
    println!(
        "| {models} | {what} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.0} |",
        ms.len(),
        ms.len() as f64 / run.elapsed.as_secs_f64(),
        percentile_ms(&mut ms, 0.5),
        percentile_ms(&mut ms, 0.99),
        percentile_ms(&mut run.search_ms, 0.5),
        run.evaluated.iter().sum::<f64>() / run.evaluated.len() as f64,
    );
}

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let sizes: Vec<usize> = std::env::var("SALIENT_LOAD_SIZES")
        .unwrap_or_else(|_| "1000,10000".into())
        .split(',')
        .map(|s| s.trim().parse().expect("SALIENT_LOAD_SIZES: counts"))
        .collect();
    let budget = Duration::from_secs(env_or("SALIENT_LOAD_SECONDS", 10));
    let meshes = tempfile::tempdir().expect("a temporary folder");
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let queries: Vec<String> = (0..MESHES + 8).map(|_| random_star(&mut rng)).collect();
    for (i, obj) in queries[..MESHES].iter().enumerate() {
        std::fs::write(meshes.path().join(format!("star{i:02}.obj")), obj).expect("writes");
    }
    let horse = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/capod_horse_m155.obj"
    ))
    .expect("the fixture");

    println!("ingest of {MESHES} meshes of 6 971 vertices (salient ingest, empty store)\n");
    println!("| concurrency | uploads/s |\n|---|---|");
    for concurrency in [1, 2, 4] {
        println!(
            "| {concurrency} | {:.2} |",
            ingest(meshes.path(), concurrency)
        );
    }

    // The signatures the large stores are made of: one more ingest, kept.
    let base_dir = tempfile::tempdir().expect("a temporary folder");
    let base = base_dir.path().join("store");
    {
        let server = Server::start(&base, &[]);
        let status = Command::new(BIN)
            .arg("ingest")
            .arg(meshes.path())
            .args(["--server", &server.url])
            .stdout(Stdio::null())
            .status()
            .expect("the client runs");
        assert!(status.success());
    }

    println!(
        "\n{CLIENTS} clients in a closed loop; search_ms is the server's ranking time alone, \
         exact EMDs the models it did not prune\n"
    );
    println!(
        "| models | request (k = 10) | requests | req/s | p50 ms | p99 ms | search_ms p50 | exact EMDs |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let data_dir = tempfile::tempdir().expect("a temporary folder");
    let data = data_dir.path().join("store");
    let runtime = tokio::runtime::Runtime::new().expect("a runtime");
    // A stuck server fails the run instead of hanging it.
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(60))
        .build()
        .expect("a client");
    let mut stored = 0;
    for &size in &sizes {
        let clock = Instant::now();
        fill(&data, &base, stored, size);
        eprintln!(
            "filled {} models in {:.1} s",
            size - stored,
            clock.elapsed().as_secs_f64()
        );
        stored = size;
        let server = Server::start(&data, &[]);
        eprintln!(
            "server resident with {size} models: {:.0} MiB",
            server.resident_mib().unwrap_or(f64::NAN)
        );
        let url = server.url.clone();
        let (c, u) = (client.clone(), url.clone());
        let run = runtime.block_on(closed_loop(budget, usize::MAX, move |n| {
            let id = (n * 7919) % size;
            c.get(format!("{u}/v1/models/m{id:05}/similar?k=10"))
        }));
        report(size, "GET /v1/models/{id}/similar", run);
        let (c, u, body) = (client.clone(), url.clone(), horse.clone());
        let run = runtime.block_on(closed_loop(budget, usize::MAX, move |_| {
            c.post(format!("{u}/v1/search?k=10"))
                .header("content-type", "model/obj")
                .body(body.clone())
        }));
        report(size, "POST /v1/search, horse (346 vertices)", run);
        let (c, u, bodies) = (client.clone(), url, queries[MESHES..].to_vec());
        let run = runtime.block_on(closed_loop(budget * 3, 24, move |n| {
            c.post(format!("{u}/v1/search?k=10"))
                .header("content-type", "model/obj")
                .body(bodies[n % bodies.len()].clone())
        }));
        report(size, "POST /v1/search, star (6 971 vertices)", run);

        // Stored-model searches while an ingest keeps two extractions running: the figure an
        // asset library sees while it indexes uploads. New content per size (a comment line
        // changes the hash), so that nothing is skipped.
        let uploads = tempfile::tempdir().expect("a temporary folder");
        for (i, obj) in queries[MESHES..].iter().enumerate() {
            let text = format!("# {size}\n{obj}");
            std::fs::write(uploads.path().join(format!("new{i}.obj")), text).expect("writes");
        }
        let mut ingesting = Command::new(BIN)
            .arg("ingest")
            .arg(uploads.path())
            .args(["--server", &server.url, "--concurrency", "2"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("the client runs");
        std::thread::sleep(Duration::from_millis(500));
        let (c, u) = (client.clone(), server.url.clone());
        let run = runtime.block_on(closed_loop(budget, usize::MAX, move |n| {
            let id = (n * 7919) % size;
            c.get(format!("{u}/v1/models/m{id:05}/similar?k=10"))
        }));
        let _ = ingesting.kill();
        let _ = ingesting.wait();
        report(size, "GET /v1/models/{id}/similar during ingest", run);
    }
}

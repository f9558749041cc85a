//! `salient ingest` against the real server on a loopback port with a fresh store: a folder
//! goes in, a second run skips it, a corrupt file fails alone, and an overloaded server still
//! gets everything thanks to retries. Also `salient health`, the container's health check.

use crate::server;
use crate::shapes;

use std::path::Path;
use std::process::{Command, Output};

use glam::DMat4;
use salient_core::mesh::RawMesh;
use serde_json::Value;
use server::Server;

const BIN: &str = env!("CARGO_BIN_EXE_salient");

/// A server on a fresh store in `dir`.
fn serve(dir: &tempfile::TempDir, flags: &[&str]) -> Server {
    Server::start(&dir.path().join("store"), flags)
}

fn get(server: &Server, path: &str) -> String {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
        .block_on(async {
            reqwest::get(server.at(path))
                .await?
                .error_for_status()?
                .text()
                .await
        })
        .unwrap()
}

/// Every stored model, in id order.
fn models(server: &Server) -> Vec<Value> {
    let page: Value = serde_json::from_str(&get(server, "/v1/models?limit=1000")).unwrap();
    page["models"].as_array().unwrap().clone()
}

/// Writes `mesh` as OBJ at `path`, creating its folder.
fn write_obj(path: &Path, mesh: &RawMesh) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    shapes::write_obj(path, mesh);
}

fn copy_fixture(name: &str, to: &Path) {
    std::fs::create_dir_all(to.parent().unwrap()).unwrap();
    std::fs::write(to, server::fixture(name)).unwrap();
}

/// Runs `salient ingest DIR --server URL --json …`: the output and the parsed summary.
fn ingest(dir: &Path, server: &Server, flags: &[&str]) -> (Output, Value) {
    run_ingest(dir.as_os_str(), server, flags)
}

/// Runs `salient ingest --manifest FILE --server URL --json`.
fn ingest_manifest(manifest: &Path, server: &Server) -> (Output, Value) {
    run_ingest("--manifest".as_ref(), server, &[manifest.to_str().unwrap()])
}

fn run_ingest(first: &std::ffi::OsStr, server: &Server, flags: &[&str]) -> (Output, Value) {
    let out = Command::new(BIN)
        .arg("ingest")
        .arg(first)
        .args(flags)
        .args(["--server", &server.url, "--json"])
        .output()
        .expect("the client runs");
    let summary = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "no JSON summary ({e}); stdout {:?}, stderr {:?}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    });
    (out, summary)
}

fn counts(summary: &Value) -> [u64; 4] {
    ["files", "added", "skipped", "failed"].map(|k| summary[k].as_u64().unwrap())
}

#[test]
fn ingests_a_folder_then_skips_it() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    copy_fixture("capod_horse_m155.obj", &root.join("capod_horse_m155.obj"));
    copy_fixture("gltf_external/tetra.gltf", &root.join("gltf/tetra.gltf"));
    copy_fixture("gltf_external/tetra.bin", &root.join("gltf/tetra.bin"));
    write_obj(&root.join("shapes/sphere.obj"), &shapes::icosphere(3));
    write_obj(
        &root.join("shapes/star.obj"),
        &shapes::star(4, &shapes::five_tips()),
    );
    write_obj(&root.join("shapes/cone.obj"), &shapes::cone(0.5, 40, 48));
    let store = tempfile::tempdir().unwrap();
    let server = serve(&store, &[]);

    let (out, summary) = ingest(
        root,
        &server,
        &["--class-from-folder", "--tags", "test,bulk"],
    );
    assert!(out.status.success(), "{summary}");
    assert_eq!(counts(&summary), [5, 5, 0, 0], "{summary}");
    let before = models(&server);
    let listed: Vec<_> = before
        .iter()
        .map(|m| {
            (
                m["id"].as_str().unwrap(),
                m["name"].as_str().unwrap(),
                m["class"].as_str(),
            )
        })
        .collect();
    assert_eq!(
        listed,
        [
            ("capod_horse_m155", "capod_horse_m155", None),
            ("gltf-tetra", "tetra", Some("gltf")),
            ("shapes-cone", "cone", Some("shapes")),
            ("shapes-sphere", "sphere", Some("shapes")),
            ("shapes-star", "star", Some("shapes")),
        ]
    );
    assert!(before
        .iter()
        .all(|m| m["tags"] == serde_json::json!(["test", "bulk"])));
    assert_eq!(before[1]["format"], "gltf");
    assert_eq!(before[1]["resources"].as_object().unwrap().len(), 1);

    let (out, summary) = ingest(root, &server, &["--class-from-folder"]);
    assert!(out.status.success(), "{summary}");
    assert_eq!(counts(&summary), [5, 0, 5, 0], "{summary}");
    assert_eq!(models(&server), before, "a second run changes nothing");
}

#[test]
fn a_corrupt_file_fails_with_its_reason_while_the_rest_succeed() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    write_obj(&root.join("good.obj"), &shapes::icosphere(2));
    std::fs::write(
        root.join("broken.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
    )
    .unwrap();
    // A multi-file glTF without its buffer fails before anything is sent.
    copy_fixture("gltf_external/tetra.gltf", &root.join("lonely.gltf"));
    let store = tempfile::tempdir().unwrap();
    let server = serve(&store, &[]);

    let (out, summary) = ingest(root, &server, &[]);
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(counts(&summary), [3, 1, 0, 2], "{summary}");
    let failures = summary["failures"].as_array().unwrap();
    assert_eq!(failures[0]["path"], "broken.obj");
    assert_eq!(failures[0]["id"], "broken");
    let reason = failures[0]["reason"].as_str().unwrap();
    assert!(
        reason.starts_with("HTTP 400 bad_mesh:") && reason.contains("vertex 8"),
        "{reason}"
    );
    assert_eq!(failures[1]["path"], "lonely.gltf");
    assert!(
        failures[1]["reason"]
            .as_str()
            .unwrap()
            .contains("tetra.bin"),
        "{summary}"
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains("error: 2 of 3 files failed"));
    let ids: Vec<_> = models(&server).iter().map(|m| m["id"].clone()).collect();
    assert_eq!(ids, ["good"]);
}

#[test]
fn a_manifest_gives_the_librarys_ids_and_fields_and_updates_them_without_re_extraction() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    copy_fixture("capod_horse_m155.obj", &root.join("meshes/horse.obj"));
    copy_fixture("gltf_external/tetra.gltf", &root.join("meshes/tetra.gltf"));
    copy_fixture("gltf_external/tetra.bin", &root.join("meshes/tetra.bin"));
    let manifest = root.join("catalogue.jsonl");
    let write = |horse_tags: &str| {
        std::fs::write(
            &manifest,
            format!(
                r#"{{"path": "meshes/horse.obj", "id": "sku-1", "name": "Horse", "tags": [{horse_tags}], "class": "animal"}}

{{"path": "meshes/tetra.gltf", "id": "sku-2", "up": "z"}}
{{"path": "meshes/horse.obj", "id": "sku-3", "name": "Horse (copy)"}}
"#
            ),
        )
        .unwrap()
    };
    write(r#""farm""#);
    let store = tempfile::tempdir().unwrap();
    let server = serve(&store, &[]);

    let (out, summary) = ingest_manifest(&manifest, &server);
    assert!(out.status.success(), "{summary}");
    assert_eq!(
        counts(&summary),
        [3, 3, 0, 0],
        "a copy under its own id is added too"
    );
    let stored = models(&server);
    let fields: Vec<_> = stored
        .iter()
        .map(|m| {
            (
                m["id"].as_str().unwrap(),
                m["name"].as_str().unwrap(),
                m["tags"].clone(),
                m["class"].as_str(),
            )
        })
        .collect();
    assert_eq!(
        fields,
        [
            (
                "sku-1",
                "Horse",
                serde_json::json!(["farm"]),
                Some("animal")
            ),
            ("sku-2", "tetra", serde_json::json!([]), None),
            ("sku-3", "Horse (copy)", serde_json::json!([]), None),
        ]
    );
    assert_eq!(stored[1]["up"], "z", "the manifest's up axis");
    assert_eq!(stored[0]["up"], serde_json::Value::Null);

    // New tags for one model: it alone is updated, and not re-extracted.
    write(r#""farm", "brown""#);
    let (out, summary) = ingest_manifest(&manifest, &server);
    assert!(out.status.success(), "{summary}");
    assert_eq!(counts(&summary), [3, 0, 2, 0], "{summary}");
    assert_eq!(summary["updated"], 1);
    let after = models(&server);
    assert_eq!(after[0]["tags"], serde_json::json!(["farm", "brown"]));
    assert_eq!(after[0]["created_unix"], stored[0]["created_unix"]);
    let metrics = get(&server, "/metrics");
    let extractions = metrics
        .lines()
        .find(|l| l.starts_with("salient_extraction_seconds_count"))
        .unwrap();
    assert!(
        extractions.ends_with(" 3"),
        "three extractions in all: {extractions}"
    );

    // A bad line stops the run before anything is sent, naming the line.
    std::fs::write(
        &manifest,
        "{\"path\": \"meshes/horse.obj\", \"id\": \"sku-9\"}\n{\"path\": 7}\n",
    )
    .unwrap();
    let out = Command::new(BIN)
        .args([
            "ingest",
            "--manifest",
            manifest.to_str().unwrap(),
            "--server",
            &server.url,
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("catalogue.jsonl, line 2"), "{stderr}");
    assert_eq!(models(&server).len(), 3);
}

#[test]
fn an_overloaded_server_still_gets_everything() {
    let dir = tempfile::tempdir().unwrap();
    let star = shapes::star(4, &shapes::five_tips());
    for seed in 0..6 {
        let motion: DMat4 = shapes::random_motion(seed);
        write_obj(
            &dir.path().join(format!("star{seed}.obj")),
            &shapes::transformed(&star, motion),
        );
    }
    // One extraction at a time and no queue: concurrent uploads get 503 with Retry-After.
    let store = tempfile::tempdir().unwrap();
    let server = serve(&store, &["--workers", "1", "--queue-depth", "0"]);

    let (out, summary) = ingest(dir.path(), &server, &["--concurrency", "4"]);
    assert!(out.status.success(), "{summary}");
    assert_eq!(counts(&summary), [6, 6, 0, 0], "{summary}");
    assert!(summary["retries"].as_u64().unwrap() > 0, "{summary}");
    let metrics = get(&server, "/metrics");
    assert!(
        metrics.contains(r#"route="/v1/models",status="503""#),
        "the server did turn uploads away"
    );
    assert_eq!(models(&server).len(), 6);
}

#[test]
fn an_unreachable_server_ends_the_run_at_once() {
    let dir = tempfile::tempdir().unwrap();
    write_obj(&dir.path().join("a.obj"), &shapes::icosphere(1));
    // A port that was free a moment ago.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let out = Command::new(BIN)
        .arg("ingest")
        .arg(dir.path())
        .args([
            "--server",
            &format!("http://127.0.0.1:{port}"),
            "--attempts",
            "2",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("cannot reach the server"), "{stderr}");
    assert!(stderr.contains("gave up after 2 attempts"), "{stderr}");
}

#[test]
fn health_answers_for_a_running_server_only() {
    let store = tempfile::tempdir().unwrap();
    let server = serve(&store, &[]);
    let health = |args: &[&str], addr: Option<&str>| {
        let mut command = Command::new(BIN);
        command.arg("health").args(args).env_remove("SALIENT_ADDR");
        if let Some(addr) = addr {
            command.env("SALIENT_ADDR", addr);
        }
        command.output().unwrap()
    };
    let out = health(&[&server.url], None);
    assert!(out.status.success());
    assert_eq!(String::from_utf8_lossy(&out.stdout), "ok\n");
    // Without a URL it asks the address `serve` is configured with, as the container does;
    // an unspecified address is asked on the loopback.
    let port = server.url.rsplit(':').next().unwrap().to_string();
    assert!(health(&[], Some(&format!("0.0.0.0:{port}")))
        .status
        .success());
    drop(server);
    let out = health(&[], Some(&format!("127.0.0.1:{port}")));
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("does not answer"));
}

/// A library's files as they come: a zip of a `.gltf` with its buffer, a 3MF and compressed
/// glTF are ingested from a folder as any mesh file.
#[test]
fn ingests_zips_3mf_and_compressed_gltf() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    let read = server::fixture;
    let zipped = crate::common::zip(&[
        ("tetra/tetra.gltf", &read("gltf_external/tetra.gltf")),
        ("tetra/tetra.bin", &read("gltf_external/tetra.bin")),
    ]);
    std::fs::write(root.join("tetra.zip"), zipped).unwrap();
    copy_fixture("3mf/horse_two_items.3mf", &root.join("print.3mf"));
    copy_fixture("web/horse_draco.glb", &root.join("draco.glb"));
    let store = tempfile::tempdir().unwrap();
    let server = serve(&store, &[]);
    let (out, summary) = ingest(root, &server, &[]);
    assert!(out.status.success(), "{summary}");
    assert_eq!(counts(&summary), [3, 3, 0, 0], "{summary}");
    let formats: Vec<_> = models(&server)
        .iter()
        .map(|m| (m["name"].as_str().unwrap().to_string(), m["format"].clone()))
        .collect();
    assert_eq!(
        formats,
        [
            ("draco".into(), "glb".into()),
            ("print".into(), "3mf".into()),
            ("tetra".into(), "gltf".into()),
        ]
    );
}

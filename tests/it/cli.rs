//! The `salient` binary end to end: real files in, exact output shapes out.

use crate::shapes;

use std::process::{Command, Output};

use glam::{DMat4, DVec3};
use serde_json::Value;

fn salient(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_salient"))
        .args(args)
        .output()
        .expect("the binary runs")
}

#[test]
fn extract_json_per_vertex_reports_input_coordinates() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sphere.obj");
    // A sphere of radius 5 around (10, -3, 2): positions must come back in these coordinates.
    let motion = DMat4::from_scale_rotation_translation(
        DVec3::splat(5.0),
        Default::default(),
        DVec3::new(10.0, -3.0, 2.0),
    );
    let sphere = shapes::transformed(&shapes::icosphere(3), motion);
    shapes::write_obj(&path, &sphere);

    let out = salient(&["extract", path.to_str().unwrap(), "--json", "--per-vertex"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: Value = serde_json::from_slice(&out.stdout).unwrap();
    let positions = json["positions"].as_array().unwrap();
    let ecc = json["ecc"].as_array().unwrap();
    let region = json["region_size"].as_array().unwrap();
    assert_eq!(positions.len(), 642);
    assert_eq!(ecc.len(), positions.len());
    assert_eq!(region.len(), positions.len());
    for p in positions {
        let p: Vec<f64> = p
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        let r = DVec3::new(p[0], p[1], p[2]).distance(DVec3::new(10.0, -3.0, 2.0));
        assert!(
            (r - 5.0).abs() < 1e-5,
            "position {p:?} is not in input coordinates"
        );
    }
    for (alpha, size) in ecc.iter().zip(region) {
        let alpha = alpha.as_array().unwrap();
        assert_eq!(alpha.len(), 10);
        // A sphere is convex everywhere: every cone angle is positive.
        assert!(alpha.iter().all(|a| a.as_f64().unwrap() > 0.0));
        assert_eq!(
            size.as_f64(),
            Some(salient_core::Params::default().ecc.local_size)
        );
    }
    let stats = &json["stats"]["extraction"];
    assert_eq!(stats["mesh"]["input_vertices"], 642);
    assert_eq!(stats["mesh"]["welded_vertices"], 642);
    assert_eq!(stats["mesh"]["triangles"], 1280);
    assert_eq!(stats["mesh"]["simplified"], false);
    assert_eq!(stats["ecc"]["complete"], 642);
    assert_eq!(stats["ecc"]["wave1_invalid"], 0);
    // 642 Dijkstra runs take measurable time: a zero would mean the stage was not timed.
    assert!(stats["ecc"]["geodesic_seconds"].as_f64().unwrap() > 0.0);
    assert_eq!(json["params"]["ecc"]["local_size"], 0.4);

    // Without --per-vertex: parameters and statistics only.
    let out = salient(&["extract", path.to_str().unwrap(), "--json"]);
    let json: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(json.get("positions").is_none() && json.get("stats").is_some());

    // Text summary.
    let out = salient(&["extract", path.to_str().unwrap()]);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("642 vertices / 1280 triangles read"),
        "{text}"
    );
    assert!(text.contains("642 complete"), "{text}");
}

#[test]
fn simplification_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sphere.obj");
    shapes::write_obj(&path, &shapes::icosphere(4));
    let params = dir.path().join("params.json");
    std::fs::write(&params, r#"{"mesh": {"max_vertices": 1000}}"#).unwrap();
    let out = salient(&[
        "extract",
        path.to_str().unwrap(),
        "--json",
        "--params",
        params.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["stats"]["extraction"]["mesh"]["simplified"], true);
    assert!(
        json["stats"]["extraction"]["mesh"]["vertices"]
            .as_u64()
            .unwrap()
            <= 1000
    );
    assert_eq!(json["params"]["mesh"]["max_vertices"], 1000);
}

#[test]
fn bad_input_is_one_line_on_stderr_and_a_failure_code() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty.obj");
    std::fs::write(&empty, "").unwrap();
    let junk = dir.path().join("junk.bin");
    std::fs::write(&junk, [0xde, 0xad, 0xbe, 0xef, 0x00, 0x17]).unwrap();
    let bad_params = dir.path().join("p.json");
    std::fs::write(&bad_params, r#"{"ecc": {"no_such_field": 1}}"#).unwrap();
    let missing = dir.path().join("missing.obj");
    for args in [
        vec!["extract", empty.to_str().unwrap()],
        vec!["extract", junk.to_str().unwrap()],
        vec!["extract", missing.to_str().unwrap()],
        vec![
            "extract",
            empty.to_str().unwrap(),
            "--params",
            bad_params.to_str().unwrap(),
        ],
    ] {
        let out = salient(&args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let stderr = String::from_utf8(out.stderr).unwrap();
        assert!(stderr.starts_with("error: "), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
        assert!(out.stdout.is_empty());
    }
}

#[test]
fn out_of_range_parameters_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sphere.obj");
    shapes::write_obj(&path, &shapes::icosphere(1));
    for (params, name) in [
        (r#"{"ecc": {"waves": 0}}"#, "ecc.waves"),
        (r#"{"ecc": {"local_size": -1}}"#, "ecc.local_size"),
        (r#"{"mesh": {"max_vertices": 2}}"#, "mesh.max_vertices"),
    ] {
        let file = dir.path().join("p.json");
        std::fs::write(&file, params).unwrap();
        let out = salient(&[
            "extract",
            path.to_str().unwrap(),
            "--params",
            file.to_str().unwrap(),
        ]);
        assert_eq!(out.status.code(), Some(1));
        let stderr = String::from_utf8(out.stderr).unwrap();
        assert!(stderr.contains(name), "{stderr}");
    }
}

fn json_of(out: &Output) -> Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn extract_json_is_a_signature_and_compare_reads_it() {
    let dir = tempfile::tempdir().unwrap();
    let (star, cone) = (dir.path().join("star.obj"), dir.path().join("cone.obj"));
    shapes::write_obj(&star, &shapes::star(4, &shapes::five_tips()));
    shapes::write_obj(&cone, &shapes::cone(0.5, 40, 48));

    let signature = json_of(&salient(&["extract", star.to_str().unwrap(), "--json"]));
    let features = signature["features"].as_array().unwrap();
    assert_eq!(features.len(), 5);
    for f in features {
        for key in [
            "vertex",
            "position",
            "position_normalized",
            "ecc",
            "d2",
            "region_size",
            "region_area",
        ] {
            assert!(f.get(key).is_some(), "feature lacks {key}");
        }
        assert_eq!(f["ecc"].as_array().unwrap().len(), 10);
        assert_eq!(f["d2"].as_array().unwrap().len(), 64);
    }
    assert!(signature.get("params").is_some() && signature.get("stats").is_some());
    let saved = dir.path().join("star.json");
    std::fs::write(&saved, serde_json::to_string(&signature).unwrap()).unwrap();

    let meshes = json_of(&salient(&[
        "compare",
        star.to_str().unwrap(),
        cone.to_str().unwrap(),
        "--json",
    ]));
    let from_json = json_of(&salient(&[
        "compare",
        saved.to_str().unwrap(),
        cone.to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(meshes, from_json);
    assert_eq!(meshes["m"], 5);
    assert!(meshes["sim"].as_f64().unwrap() > 0.0);
    let m = meshes["m"].as_f64().unwrap();
    let n = meshes["n"].as_f64().unwrap();
    let emd = meshes["emd"].as_f64().unwrap();
    assert!((meshes["sim"].as_f64().unwrap() - emd * m.max(n) / m.min(n)).abs() < 1e-12);
    let itself = json_of(&salient(&[
        "compare",
        star.to_str().unwrap(),
        saved.to_str().unwrap(),
        "--json",
    ]));
    assert_eq!(itself["sim"], 0.0);

    let text = salient(&["compare", star.to_str().unwrap(), cone.to_str().unwrap()]);
    assert!(String::from_utf8(text.stdout).unwrap().starts_with("SIM "));
}

#[test]
fn search_ranks_a_folder_and_caches_signatures() {
    let dir = tempfile::tempdir().unwrap();
    let collection = dir.path().join("models");
    std::fs::create_dir_all(collection.join("stars")).unwrap();
    std::fs::create_dir_all(collection.join("other")).unwrap();
    let star = shapes::star(4, &shapes::five_tips());
    shapes::write_obj(&collection.join("stars/star.obj"), &star);
    shapes::write_obj(
        &collection.join("stars/moved.obj"),
        &shapes::transformed(&star, shapes::random_motion(4)),
    );
    shapes::write_obj(
        &collection.join("other/cone.obj"),
        &shapes::cone(0.5, 40, 48),
    );
    shapes::write_obj(
        &collection.join("other/tube.obj"),
        &shapes::tube(0.2, 60, 24),
    );
    std::fs::write(collection.join("other/notes.txt"), "not a mesh").unwrap();
    std::fs::write(collection.join("other/broken.obj"), "v 0 0 0\nf 1 2 3\n").unwrap();
    let query = collection.join("stars/star.obj");
    let args = |method: &str| {
        vec![
            "search".to_string(),
            query.to_str().unwrap().into(),
            collection.to_str().unwrap().into(),
            "-k".into(),
            "3".into(),
            "--method".into(),
            method.into(),
            "--json".into(),
        ]
    };
    let run = |method: &str| {
        json_of(&salient(
            &args(method).iter().map(String::as_str).collect::<Vec<_>>(),
        ))
    };

    let first = run("ecc");
    let ids: Vec<&str> = first["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["id"].as_str().unwrap())
        .collect();
    assert_eq!(&ids[..2], ["stars/star.obj", "stars/moved.obj"]);
    assert_eq!(first["results"][0]["distance"], 0.0);
    assert_eq!(first["results"][0]["rank"], 1);
    assert_eq!(first["collection"], 4);
    // The query itself was extracted (and cached) first.
    assert_eq!(
        (first["extracted"].as_u64(), first["cached"].as_u64()),
        (Some(3), Some(1))
    );
    assert_eq!(first["failed"][0]["path"], "other/broken.obj");
    assert!(collection.join(".salient-cache").is_dir());

    // Everything is cached now, and the ranking is the same.
    let second = run("ecc");
    assert_eq!(second["extracted"], 0);
    assert_eq!(second["cached"], 4);
    assert_eq!(second["results"], first["results"]);

    let d2 = run("d2");
    assert_eq!(d2["method"], "d2");
    assert_eq!(d2["results"][0]["id"], "stars/star.obj");
    let lfd = run("lfd");
    assert_eq!(lfd["method"], "lfd");
    assert_eq!(lfd["cached"], 4);
    assert_eq!(lfd["results"][0]["id"], "stars/star.obj");
    assert_eq!(lfd["results"][0]["distance"], 0.0);

    let bad = salient(&[
        "search",
        query.to_str().unwrap(),
        dir.path().join("nowhere").to_str().unwrap(),
    ]);
    assert_eq!(bad.status.code(), Some(1));
    let bad = salient(&[
        "search",
        query.to_str().unwrap(),
        collection.to_str().unwrap(),
        "--method",
        "sh",
    ]);
    assert_ne!(bad.status.code(), Some(0));
}

#[test]
fn search_partial_finds_the_model_a_piece_was_cut_from() {
    let dir = tempfile::tempdir().unwrap();
    let collection = dir.path().join("models");
    std::fs::create_dir_all(&collection).unwrap();
    let star = shapes::star(4, &shapes::five_tips());
    shapes::write_obj(&collection.join("star.obj"), &star);
    shapes::write_obj(&collection.join("tube.obj"), &shapes::tube(0.3, 30, 24));
    shapes::write_obj(&collection.join("sphere.obj"), &shapes::icosphere(4));
    let part = dir.path().join("spike.obj");
    let spike = salient_core::mesh::cut::cut(&star, DVec3::new(0.9, 0.0, 0.0), 0.6).unwrap();
    shapes::write_obj(&part, &spike);
    let (part, collection) = (part.to_str().unwrap(), collection.to_str().unwrap());

    let search = || {
        json_of(&salient(&[
            "search",
            part,
            collection,
            "--partial",
            "-k",
            "2",
            "--json",
        ]))
    };
    let found = search();
    assert_eq!(found["partial"], true);
    assert_eq!(found["results"][0]["id"], "star.obj", "{found}");
    assert!(found["results"][0]["part_scale"].is_f64());
    // Verified: the part lies on the star's surface, not on the next one's.
    let residual = |i: usize| found["results"][i]["residual"].as_f64().unwrap();
    assert!(
        residual(0) < 0.05 && 4.0 * residual(0) < residual(1),
        "{found}"
    );
    let known = json_of(&salient(&[
        "search",
        part,
        collection,
        "--partial",
        "--part-scale",
        "0.5",
        "--json",
    ]));
    assert_eq!(known["results"][0]["part_scale"], 0.5);

    // The models' patches are cached beside their signatures; a damaged entry is made again.
    let patches: Vec<std::path::PathBuf> =
        std::fs::read_dir(std::path::Path::new(collection).join(".salient-cache"))
            .unwrap()
            .map(|entry| entry.unwrap().path())
            .filter(|path| path.extension().is_some_and(|e| e == "patches"))
            .collect();
    assert_eq!(patches.len(), 3, "{patches:?}");
    for path in &patches {
        std::fs::write(path, b"damaged").unwrap();
    }
    let again = search();
    assert_eq!(again["results"], found["results"]);
    for path in &patches {
        assert_ne!(std::fs::read(path).unwrap(), b"damaged");
    }

    for bad in [
        vec!["search", part, collection, "--partial", "--method", "ecc"],
        vec![
            "search",
            part,
            collection,
            "--partial",
            "--part-scale",
            "0.1",
        ],
        vec!["search", part, collection, "--part-scale", "0.5"],
    ] {
        let out = salient(&bad);
        assert_ne!(out.status.code(), Some(0), "{bad:?}");
        assert!(!out.stderr.is_empty(), "{bad:?}");
    }
}

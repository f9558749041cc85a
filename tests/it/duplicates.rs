//! Near-duplicates (`docs/results/duplicates/`), with known answers: a generated model and its disguised copies
//! are one asset, another pose of it and other shapes are not; over HTTP, the check, the
//! rejecting upload and the library's groups.

use axum::http::StatusCode;
use glam::{DMat4, DQuat, DVec3};
use salient_core::duplicate::{judge, verify, Evidence, Shape};
use salient_core::mesh::load::NoResources;
use salient_core::mesh::weld::weld;
use salient_core::mesh::write::Export;
use salient_core::mesh::{load_bytes, RawMesh};
use salient_core::params::DuplicateParams;
use salient_core::Limits;
use salient_eval::disguise::{self, Indexed};
use serde_json::Value;

use crate::app::TestApp;
use crate::server::{fixture, obj};
use crate::shapes;
use crate::stores::{stores, Stores};
use rstest_reuse::apply;

/// A body with five limbs.
pub fn model() -> RawMesh {
    shapes::star(4, &shapes::five_tips())
}

/// The same body with its +x limb turned 45° at its root: another pose of the same
/// character, which is another asset.
fn posed() -> RawMesh {
    let joint = DVec3::new(0.45, 0.0, 0.0);
    let turn = DQuat::from_rotation_z(45f64.to_radians());
    let mut mesh = model();
    for p in &mut mesh.positions {
        if p.x > joint.x {
            *p = joint + turn * (*p - joint);
        }
    }
    mesh
}

/// Another model made from the same mesh (the same faces, the vertices moved): `mesh` 12 %
/// longer along x. Libraries hold such morphs (CAPOD's airplanes m42, m44 and m46).
fn stretched(mesh: &RawMesh) -> RawMesh {
    let mut mesh = mesh.clone();
    for p in &mut mesh.positions {
        p.x *= 1.12;
    }
    mesh
}

/// `mesh` remeshed to about half its vertices (meshoptimizer's edge collapse), then rotated,
/// scaled by 0.1 and moved.
pub fn remeshed(mesh: &RawMesh) -> RawMesh {
    disguised(mesh, disguise::edge_collapse)
}

/// `mesh` in inches rather than millimetres, moved: the same geometry.
pub fn rescaled(mesh: &RawMesh) -> RawMesh {
    let motion = DMat4::from_scale_rotation_translation(
        DVec3::splat(25.4),
        DQuat::IDENTITY,
        DVec3::new(-30.0, 12.0, 5.0),
    );
    shapes::transformed(mesh, motion)
}

/// The file of `mesh` as `export` writes it, read back as an upload would be.
pub fn file(mesh: &RawMesh, export: Export) -> (Vec<u8>, RawMesh) {
    let bytes = export.write(mesh);
    let read = load_bytes(&bytes, export.format(), &NoResources, &Limits::default()).unwrap();
    (bytes, read)
}

fn shape(mesh: &RawMesh) -> Shape {
    Shape::new(mesh, 1e-6).unwrap()
}

#[test]
fn a_model_and_its_disguised_copies_are_one_asset_and_another_pose_is_not() {
    let params = DuplicateParams::default();
    let original = shape(&model());
    let evidence = |copy: &RawMesh| verify(&original, &shape(copy), &params).map(|v| v.evidence);

    for export in [Export::BinaryStl, Export::AsciiStl, Export::Glb] {
        let (_, copy) = file(&rescaled(&model()), export);
        assert_eq!(
            evidence(&copy),
            Some(Evidence::IdenticalGeometry),
            "{}",
            export.name()
        );
    }
    let (_, copy) = file(&remeshed(&model()), Export::AsciiStl);
    assert_eq!(evidence(&copy), Some(Evidence::SameShape));

    assert_eq!(evidence(&posed()), None, "another pose");
    assert_eq!(evidence(&shapes::tube(0.3, 30, 24)), None, "another shape");
    let four_limbs = shapes::star(4, &shapes::five_tips()[..4]);
    assert_eq!(evidence(&four_limbs), None, "a limb fewer");
}

/// A re-tessellation of a welded mesh to about a vertex count.
type Family = fn(&[DVec3], &[[u32; 3]], usize) -> Indexed;

/// `mesh` welded, re-tessellated by `family` (the benchmark's disguises) to about half its
/// vertices, then rotated, scaled by 0.1 and moved.
fn disguised(mesh: &RawMesh, family: Family) -> RawMesh {
    let welded = weld(mesh, 1e-6).unwrap();
    let (positions, triangles) = family(
        &welded.positions,
        &welded.triangles,
        welded.positions.len() / 2,
    );
    let motion = DMat4::from_scale_rotation_translation(
        DVec3::splat(0.1),
        DQuat::from_axis_angle(DVec3::new(1.0, -2.0, 0.5).normalize(), 2.2),
        DVec3::new(4.0, -7.0, 1.5),
    );
    shapes::transformed(
        &RawMesh {
            positions,
            triangles,
        },
        motion,
    )
}

#[test]
fn every_common_simplifier_and_linear_subdivision_keep_the_shape_and_smoothing_a_morph_or_a_pose_do_not(
) {
    let params = DuplicateParams::default();
    let evidence = |original: &RawMesh, copy: &RawMesh| {
        verify(&shape(original), &shape(copy), &params).map(|v| v.evidence)
    };
    let families: [(&str, Family); 5] = [
        ("edge collapse", disguise::edge_collapse),
        ("quadric, optimal placement", disguise::quadric),
        ("vertex clustering", disguise::clustered),
        ("re-triangulated", |p, t, _| disguise::retriangulated(p, t)),
        ("midpoint subdivision", |p, t, _| disguise::midpoint(p, t)),
    ];
    // The body with five limbs, and the same coarser: a coarse mesh is moved farther by any
    // re-tessellation.
    for mesh in [model(), shapes::star(3, &shapes::five_tips())] {
        for (name, family) in families {
            let found = evidence(&mesh, &disguised(&mesh, family));
            assert!(
                matches!(
                    found,
                    Some(Evidence::SameShape | Evidence::IdenticalGeometry)
                ),
                "{name}: {found:?}"
            );
        }
        // Loop's smoothing subdivision is another asset, though it moves the surface too
        // little for the distances to say so (nine in ten of the vertices within the limit):
        // its mesh, a split, does.
        let smooth = disguised(&mesh, |p, t, _| disguise::loop_subdivided(p, t));
        assert_eq!(evidence(&mesh, &smooth), None, "Loop subdivision");
        let (a, b) = (shape(&mesh), shape(&smooth));
        assert!(a.split_of(&b) && b.split_of(&a));
        let distances_alone = judge(
            (a.geometry_deviation(&b, params.geometry), false),
            |reach, pass| a.align(&b, reach, pass),
            a.coarser(&b),
            &params,
        );
        assert_eq!(
            distances_alone.map(|v| v.evidence),
            Some(Evidence::SameShape)
        );
        // A morph of the quadric copy and another pose are still other assets.
        let morph = disguised(&stretched(&mesh), disguise::quadric);
        assert_eq!(evidence(&mesh, &morph), None, "a morph");
    }
    let posed = disguised(&posed(), disguise::clustered);
    assert_eq!(evidence(&model(), &posed), None, "another pose");
}

#[test]
fn a_remeshed_morph_is_not_the_model_it_was_made_from() {
    // Coarser than `model()`, so a remeshing moves the surface as far as the morph does.
    let coarse = shapes::star(3, &shapes::five_tips());
    let original = shape(&coarse);
    let params = DuplicateParams::default();
    let evidence = |copy: &RawMesh, params: &DuplicateParams| {
        verify(&original, &shape(copy), params).map(|v| v.evidence)
    };
    assert_eq!(
        evidence(&remeshed(&coarse), &params),
        Some(Evidence::SameShape)
    );
    let morph = remeshed(&stretched(&coarse));
    assert_eq!(evidence(&morph, &params), None);
    // What tells them apart is where the vertices lie, not the surfaces' distances.
    let surfaces_only = DuplicateParams {
        vertices_per_edge: 10.0,
        ..params
    };
    assert_eq!(evidence(&morph, &surfaces_only), Some(Evidence::SameShape));
}

#[test]
fn a_tree_that_lost_a_few_leaves_is_the_tree_and_one_that_lost_its_crown_is_not() {
    let params = DuplicateParams::default();
    let original = shape(&shapes::tree(1, 120, |_| true));
    let evidence = |copy: &RawMesh, params: &DuplicateParams| {
        verify(&original, &shape(copy), params).map(|v| v.evidence)
    };
    // Every tenth leaf deleted (as an edge collapse deletes isolated triangles), turned about
    // the trunk, where the tree's two moments are near-equal and its principal axes arbitrary,
    // then moved.
    let thinned = shapes::tree(1, 120, |leaf| leaf % 10 != 0);
    let turn = DMat4::from_rotation_z(37f64.to_radians());
    let copy = shapes::transformed(&thinned, shapes::random_motion(5) * turn);
    assert_eq!(evidence(&copy, &params), Some(Evidence::SameShape));
    // That is the forgiveness for deleted small pieces: without it, a leaf is too far.
    let unforgiving = DuplicateParams {
        deleted: 0.0,
        ..params.clone()
    };
    assert_eq!(evidence(&copy, &unforgiving), None);
    // The bare trunk (a fifth of the surface gone) and a trunk with other leaves (CAPOD's
    // trees m49 and m59 share one) are other assets.
    assert_eq!(evidence(&shapes::tree(1, 120, |_| false), &params), None);
    assert_eq!(evidence(&shapes::tree(2, 120, |_| true), &params), None);
}

#[test]
fn a_real_tree_simplified_to_half_is_the_tree() {
    // CAPOD's tree m50: a trunk and branches under ~2 000 leaves, each a separate triangle,
    // with two second moments within 0.4 %. Halving its vertices deletes leaves, and its
    // principal axes across the trunk are arbitrary: it was missed before both were handled.
    let raw = load_bytes(
        &fixture("capod_tree_m50.obj"),
        salient_core::mesh::Format::Obj,
        &NoResources,
        &Limits::default(),
    )
    .unwrap();
    let params = DuplicateParams::default();
    let original = shape(&raw);
    let copy = shape(&remeshed(&raw));
    assert_eq!(
        verify(&original, &copy, &params).map(|v| v.evidence),
        Some(Evidence::SameShape)
    );
    let unforgiving = DuplicateParams {
        deleted: 0.0,
        ..params
    };
    assert_eq!(verify(&original, &copy, &unforgiving), None);
}

#[test]
fn scores_fall_from_one_for_identical_meshes() {
    let params = DuplicateParams::default();
    let original = shape(&model());
    let same = verify(&original, &shape(&model()), &params).unwrap();
    assert_eq!(same.evidence, Evidence::IdenticalGeometry);
    assert!(same.score > 0.999, "{same:?}");
    let remeshed = verify(&original, &shape(&remeshed(&model())), &params).unwrap();
    assert!((0.0..1.0).contains(&remeshed.score), "{remeshed:?}");
}

async fn json(response: crate::app::TestResponse) -> Value {
    response.json()
}

#[apply(stores)]
#[tokio::test]
async fn duplicates_are_checked_rejected_and_grouped_over_http(#[case] store: Stores) {
    let app = TestApp::on(store);
    for (id, bytes) in [
        ("body", obj(&model())),
        ("posed", obj(&posed())),
        ("tube", obj(&shapes::tube(0.3, 30, 24))),
        ("horse", fixture("capod_horse_m155.obj")),
    ] {
        let response = app.add(&format!("id={id}"), "model/obj", bytes).await;
        assert_eq!(response.status(), StatusCode::CREATED, "{id}");
    }
    let (copy, _) = file(&remeshed(&model()), Export::BinaryStl);

    // The check: the copy is the body, not its other pose.
    let response = app
        .post("/v1/duplicates/check")
        .header("content-type", "model/stl")
        .body(copy.clone())
        .send()
        .await;
    assert_eq!(response.status(), StatusCode::OK);
    let matches = json(response).await["matches"].clone();
    assert_eq!(matches.as_array().unwrap().len(), 1, "{matches}");
    assert_eq!(matches[0]["id"], "body");
    assert_eq!(matches[0]["evidence"], "same_shape");

    // The same file is found as such, first.
    let checked = json(
        app.post("/v1/duplicates/check")
            .header("content-type", "model/obj")
            .body(obj(&model()))
            .send()
            .await,
    )
    .await;
    assert_eq!(checked["matches"][0]["id"], "body");
    assert_eq!(checked["matches"][0]["evidence"], "identical_file");
    assert_eq!(checked["matches"][0]["score"], 1.0);

    // Rejected on request, nothing stored; allowed by default.
    let response = app
        .add("id=copy&on_duplicate=reject", "model/stl", copy.clone())
        .await;
    assert_eq!(response.status(), StatusCode::CONFLICT);
    let body = json(response).await;
    assert_eq!(body["error"]["code"], "duplicate");
    assert_eq!(body["error"]["duplicate"]["id"], "body");
    assert_eq!(body["error"]["duplicate"]["evidence"], "same_shape");
    assert!(!app.listed_ids().await.contains("copy"));
    let (inches, _) = file(&rescaled(&model()), Export::Glb);
    let response = app.add("id=inches", "model/gltf-binary", inches).await;
    assert_eq!(response.status(), StatusCode::CREATED);
    // Uploading again what a model holds is not a duplicate of itself (the ingest client
    // retries).
    let response = app
        .add("id=body&on_duplicate=reject", "model/obj", obj(&model()))
        .await;
    assert_eq!(response.status(), StatusCode::OK);

    // The library's groups: the body and its copy in inches; the other pose stays apart.
    let page = app.get_json("/v1/duplicates").await;
    let groups = page["groups"].as_array().unwrap();
    assert_eq!(groups.len(), 1, "{page}");
    assert_eq!(groups[0]["ids"], serde_json::json!(["body", "inches"]));
    assert_eq!(groups[0]["evidence"], "identical_geometry");
    assert_eq!(groups[0]["scores"].as_array().unwrap().len(), 2);
    assert!(page["next"].is_null());
    let files_only = app
        .get_json("/v1/duplicates?min_evidence=identical_file")
        .await;
    assert_eq!(files_only["groups"], serde_json::json!([]));
    let after = app.get_json("/v1/duplicates?after=body").await;
    assert_eq!(after["groups"], serde_json::json!([]));

    for bad in ["limit=0", "limit=1001", "min_evidence=similar"] {
        let response = app.get(format!("/v1/duplicates?{bad}")).send().await;
        assert_eq!(response.status(), StatusCode::BAD_REQUEST, "{bad}");
        assert_eq!(json(response).await["error"]["code"], "invalid_query");
    }
}

/// An operator's "not a duplicate": the pair leaves the groups and the check, survives a
/// restart (it is in the store), and comes back when taken back.
#[tokio::test]
async fn a_dismissed_pair_leaves_the_groups_and_the_check_until_taken_back() {
    let dir = tempfile::tempdir().unwrap();
    let store: std::sync::Arc<dyn salient_server::store::Store> =
        std::sync::Arc::new(salient_server::store::SledStore::open(dir.path()).unwrap());
    let start = || TestApp::build(salient_server::api::Config::default(), store.clone(), None);
    let app = start();
    let inches = obj(&rescaled(&model()));
    for (id, bytes) in [
        ("a1", obj(&model())),
        ("a2", inches.clone()),
        ("a3", obj(&model())),
        ("tube", obj(&shapes::tube(0.3, 30, 24))),
    ] {
        let response = app.add(&format!("id={id}"), "model/obj", bytes).await;
        assert_eq!(response.status(), StatusCode::CREATED, "{id}");
    }
    let grouped = |page: Value| page["groups"][0]["ids"].clone();
    let all = serde_json::json!(["a1", "a2", "a3"]);
    assert_eq!(grouped(app.get_json("/v1/duplicates").await), all);

    // Refused: one model twice, a model that is not there, two models of one file.
    for (path, status, code) in [
        ("a1/a1", StatusCode::BAD_REQUEST, "invalid_path"),
        ("a1/nobody", StatusCode::NOT_FOUND, "not_found"),
        ("a1/a3", StatusCode::BAD_REQUEST, "identical_file"),
    ] {
        let response = app
            .request_with_method("PUT", format!("/v1/duplicates/dismissed/{path}"))
            .send()
            .await;
        crate::app::expect_error(&response, status, code);
    }
    // Named in any order, kept in id order; the same file (a3) is dismissed with it.
    let response = app
        .request_with_method("PUT", "/v1/duplicates/dismissed/a2/a1")
        .send()
        .await;
    assert_eq!(response.status(), StatusCode::OK, "{}", response.text());
    assert_eq!(
        (response.json()["a"].clone(), response.json()["b"].clone()),
        ("a1".into(), "a2".into())
    );
    let page = app.get_json("/v1/duplicates").await;
    assert_eq!(grouped(page), serde_json::json!(["a1", "a3"]));
    let checked = app
        .post("/v1/duplicates/check")
        .header("content-type", "model/obj")
        .body(inches.clone())
        .send()
        .await
        .json();
    let ids: Vec<&str> = checked["matches"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, ["a2"], "{checked}");

    // Kept in the store: a restarted service honours it.
    drop(app);
    let app = start();
    let listed = app.get_json("/v1/duplicates/dismissed").await;
    assert_eq!(listed["dismissed"].as_array().unwrap().len(), 1, "{listed}");
    assert_eq!(
        grouped(app.get_json("/v1/duplicates").await),
        serde_json::json!(["a1", "a3"])
    );

    // Taken back: one group again; a second time there is nothing to take back.
    let path = "/v1/duplicates/dismissed/a1/a2";
    let response = app.request_with_method("DELETE", path).send().await;
    assert_eq!(
        response.status(),
        StatusCode::NO_CONTENT,
        "{}",
        response.text()
    );
    assert_eq!(grouped(app.get_json("/v1/duplicates").await), all);
    let response = app.request_with_method("DELETE", path).send().await;
    crate::app::expect_error(&response, StatusCode::NOT_FOUND, "not_found");
}

#[apply(stores)]
#[tokio::test]
async fn pages_of_groups_follow_their_first_ids(#[case] store: Stores) {
    let app = TestApp::on(store);
    for (id, mesh) in [
        ("a1", model()),
        ("a2", rescaled(&model())),
        ("b1", shapes::tube(0.3, 30, 24)),
        ("b2", rescaled(&shapes::tube(0.3, 30, 24))),
    ] {
        let response = app.add(&format!("id={id}"), "model/obj", obj(&mesh)).await;
        assert_eq!(response.status(), StatusCode::CREATED, "{id}");
    }
    let first = app.get_json("/v1/duplicates?limit=1").await;
    assert_eq!(first["groups"][0]["ids"], serde_json::json!(["a1", "a2"]));
    assert_eq!(first["next"], "a1");
    let second = app.get_json("/v1/duplicates?limit=1&after=a1").await;
    assert_eq!(second["groups"][0]["ids"], serde_json::json!(["b1", "b2"]));
    assert!(second["next"].is_null());
}

/// Compressed copies of a stored model, as web tools write them (gltfpack, gltf-transform:
/// `tests/fixtures/web/make.sh`), upload over HTTP and are found as that model.
#[apply(stores)]
#[tokio::test]
async fn compressed_gltf_copies_are_found_as_their_original(#[case] store: Stores) {
    let app = TestApp::on(store);
    let response = app
        .add("id=horse", "model/obj", fixture("capod_horse_m155.obj"))
        .await;
    assert_eq!(response.status(), StatusCode::CREATED);
    for name in crate::common::COMPRESSED_HORSES {
        let response = app
            .post("/v1/duplicates/check")
            .header("content-type", "model/gltf-binary")
            .body(fixture(&format!("web/{name}")))
            .send()
            .await;
        assert_eq!(
            response.status(),
            StatusCode::OK,
            "{name}: {}",
            response.text()
        );
        let matches = json(response).await["matches"].clone();
        assert_eq!(matches[0]["id"], "horse", "{name}: {matches}");
        let evidence = matches[0]["evidence"].as_str().unwrap();
        assert!(
            ["identical_geometry", "same_shape"].contains(&evidence),
            "{name}: {evidence}"
        );
    }
}

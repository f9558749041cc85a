//! Near-duplicates (`docs/results/duplicates/`), with known answers: a generated model and its disguised copies
//! are one asset, another pose of it and other shapes are not; over HTTP, the check, the
//! rejecting upload and the library's groups.

use axum::http::StatusCode;
use glam::{DMat4, DQuat, DVec3};
use salient_core::duplicate::{judge, verify, Evidence, Reach, Shape};
use salient_core::mesh::load::NoResources;
use salient_core::mesh::weld::weld;
use salient_core::mesh::write::Export;
use salient_core::mesh::{load_bytes, RawMesh};
use salient_core::params::DuplicateParams;
use salient_core::Limits;
use salient_eval::disguise::{self, Indexed};
use serde_json::Value;

use crate::app::TestApp;
use crate::common::{TETRA_CORNERS, TETRA_TRIANGLES};
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
    let families: [(&str, Family); 6] = [
        ("edge collapse", disguise::edge_collapse),
        ("quadric, optimal placement", disguise::quadric),
        ("fast quadric (pyfqmr's)", |p, t, _| {
            disguise::fast_quadric(p, t, t.len() / 2)
        }),
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
        // A smoothing subdivision (Loop's, Catmull–Clark's) is another asset, though it moves
        // the surface too little for the distances to say so (nine in ten of the vertices
        // within the limit): its mesh, a split, does.
        let smoothing: [(&str, Family); 2] = [
            ("Loop", |p, t, _| disguise::loop_subdivided(p, t)),
            ("Catmull–Clark", |p, t, _| disguise::catmull_clark(p, t)),
        ];
        for (name, family) in smoothing {
            let smooth = disguised(&mesh, family);
            assert_eq!(evidence(&mesh, &smooth), None, "{name}");
            let (a, b) = (shape(&mesh), shape(&smooth));
            assert!(a.split_of(&b) && b.split_of(&a), "{name}");
            let distances_alone = judge(
                (a.geometry_deviation(&b, params.geometry), false),
                |reach, pass| a.align(&b, reach, pass),
                a.coarser(&b),
                &params,
            );
            assert_eq!(
                distances_alone.map(|v| v.evidence),
                Some(Evidence::SameShape),
                "{name}"
            );
        }
        // A morph of the quadric copy and another pose are still other assets.
        let morph = disguised(&stretched(&mesh), disguise::quadric);
        assert_eq!(evidence(&mesh, &morph), None, "a morph");
    }
    let posed = disguised(&posed(), disguise::clustered);
    assert_eq!(evidence(&model(), &posed), None, "another pose");
}

/// A CAPOD fixture as an upload reads it.
fn capod(name: &str) -> RawMesh {
    load_bytes(
        &fixture(name),
        salient_core::mesh::Format::Obj,
        &NoResources,
        &Limits::default(),
    )
    .unwrap()
}

#[test]
fn a_low_poly_piano_halved_by_fast_quadric_is_as_far_from_it_as_its_morph_halved() {
    // CAPOD's pianos m124 and m125: one mesh of 362 vertices, some moved (a morph). Fast
    // quadric simplification (pyfqmr's) keeps half the triangles and places its vertices on
    // the surface, within 0.01 of an edge, but cuts parts of so coarse a mesh away: the copy
    // of m125 lies as far from m125 as the same halving of the morph does (within a tenth,
    // 0.04 RMS radii on average, 0.35 at most), so no rule on these distances can take the
    // one and not the other. Both are refused (a rule that dropped `mean_at_most` for
    // vertices on the surface took both).
    let params = DuplicateParams::default();
    let fast_quadric: Family = |p, t, _| disguise::fast_quadric(p, t, t.len() / 2);
    let (piano, morph) = (capod("capod_piano_m125.obj"), capod("capod_piano_m124.obj"));
    let original = shape(&piano);
    let deviation = |copy: &Shape| {
        original
            .align(copy, Reach::new(&params, original.coarser(copy)), |_| true)
            .rotated
    };
    let (copy, halved_morph) = (
        shape(&disguised(&piano, fast_quadric)),
        shape(&disguised(&morph, fast_quadric)),
    );
    let (ours, theirs) = (deviation(&copy), deviation(&halved_morph));
    for d in [ours, theirs] {
        assert!(d.vertices.p90 < 0.01, "{d:?}");
    }
    let alike = |x: f64, y: f64| (x - y).abs() <= 0.1 * y;
    assert!(
        alike(ours.surfaces.absolute.mean, theirs.surfaces.absolute.mean)
            && alike(ours.surfaces.absolute.max, theirs.surfaces.absolute.max),
        "{ours:?} against {theirs:?}"
    );
    assert_eq!(verify(&original, &copy, &params), None);
    assert_eq!(verify(&original, &halved_morph, &params), None);
    assert_eq!(verify(&original, &shape(&morph), &params), None);
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
    // Every tenth leaf deleted and the trunk re-triangulated (as a simplifier deletes
    // isolated triangles and re-tessellates what it keeps), turned about the trunk, where the
    // tree's two moments are near-equal and its principal axes arbitrary, then moved.
    let thinned = shapes::tree(1, 120, |leaf| leaf % 10 != 0);
    let welded = weld(&thinned, 1e-6).unwrap();
    let (positions, triangles) = disguise::retriangulated(&welded.positions, &welded.triangles);
    let simplified = RawMesh {
        positions,
        triangles,
    };
    let turn = DMat4::from_rotation_z(37f64.to_radians());
    let copy = shapes::transformed(&simplified, shapes::random_motion(5) * turn);
    assert_eq!(evidence(&copy, &params), Some(Evidence::SameShape));
    // That is the forgiveness for deleted small pieces: without it, a leaf is too far.
    let unforgiving = DuplicateParams {
        deleted: 0.0,
        ..params.clone()
    };
    assert_eq!(evidence(&copy, &unforgiving), None);
    // The same leaves deleted from the tree as it is, every other triangle kept: a variant
    // with fewer leaves (CAPOD's tree m54 is m49 and 17 % more surface in leaves), not a
    // simplification, which re-tessellates what it keeps.
    let fewer = shapes::transformed(&thinned, shapes::random_motion(5) * turn);
    assert_eq!(evidence(&fewer, &params), None);
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
    // (Whether a deleted leaf lies beyond reach turns on a thousandth of its samples here;
    // the generated tree above shows the forgiveness at work.)
    let raw = capod("capod_tree_m50.obj");
    let params = DuplicateParams::default();
    let original = shape(&raw);
    let copy = shape(&remeshed(&raw));
    assert_eq!(
        verify(&original, &copy, &params).map(|v| v.evidence),
        Some(Evidence::SameShape)
    );
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

/// `mesh` with a layer over `share` of its area: its first triangles, copied a hundredth of its
/// size outward along its vertex normals as a piece of their own. A design that adds parts
/// (CAPOD's airplane m48 is m47's every face and 4 % more surface).
fn with_layer(mesh: &RawMesh, share: f64) -> RawMesh {
    let p = &mesh.positions;
    let normal = |t: &[u32; 3]| {
        let [a, b, c] = t.map(|v| p[v as usize]);
        (b - a).cross(c - a)
    };
    let mut normals = vec![DVec3::ZERO; p.len()];
    for t in &mesh.triangles {
        for v in t {
            normals[*v as usize] += normal(t);
        }
    }
    let total: f64 = mesh.triangles.iter().map(|t| normal(t).length()).sum();
    let (lo, hi) = p.iter().fold((DVec3::MAX, DVec3::MIN), |(lo, hi), &q| {
        (lo.min(q), hi.max(q))
    });
    let lift = 0.01 * lo.distance(hi);
    let mut layered = mesh.clone();
    let (mut covered, mut copies) = (0.0, std::collections::HashMap::new());
    for t in &mesh.triangles {
        if covered >= share * total {
            break;
        }
        covered += normal(t).length();
        let copy = t.map(|v| {
            *copies.entry(v).or_insert_with(|| {
                layered
                    .positions
                    .push(p[v as usize] + normals[v as usize].normalize() * lift);
                layered.positions.len() as u32 - 1
            })
        });
        layered.triangles.push(copy);
    }
    layered
}

#[test]
fn a_model_with_a_part_added_is_another_design_and_one_with_a_sliver_is_not() {
    // The tree: its leaves pin the alignment, so that its vertices pair with the copy's
    // (a smooth blob's may slide along the surface by an edge or more: no pairs, no rule).
    let params = DuplicateParams::default();
    let mesh = shapes::tree(1, 120, |_| true);
    let original = shape(&mesh);
    let evidence = |copy: &RawMesh, params: &DuplicateParams| {
        verify(&original, &shape(copy), params).map(|v| v.evidence)
    };
    let added = with_layer(&mesh, 0.04);
    assert_eq!(evidence(&added, &params), None, "4 % of the surface added");
    // The distances alone take it for the same shape: the layer lies within their limits
    // and every vertex of the model is one of its vertices.
    let distances_alone = DuplicateParams {
        added: 1.0,
        ..params.clone()
    };
    assert_eq!(
        evidence(&added, &distances_alone),
        Some(Evidence::SameShape)
    );
    // A sliver (0.4 % of the surface) is what a cleanup removes, or an exporter adds.
    let sliver = with_layer(&mesh, 0.004);
    assert_eq!(
        evidence(&sliver, &params),
        Some(Evidence::SameShape),
        "a sliver"
    );
}

#[test]
fn an_airplane_with_ten_parts_added_is_another_design() {
    // CAPOD's m48 is m47's every face and ten parts of 34 triangles more (4 % of the
    // surface), which its symmetry also fits mirrored; a library's copy of m48 moved and
    // rescaled is still not m47, while m48's own simplification is m48.
    let params = DuplicateParams::default();
    let (m47, m48) = (
        capod("capod_airplane_m47.obj"),
        capod("capod_airplane_m48.obj"),
    );
    let moved = shapes::transformed(&m48, shapes::random_motion(3));
    assert_eq!(verify(&shape(&m47), &shape(&moved), &params), None);
    assert_eq!(verify(&shape(&moved), &shape(&m47), &params), None);
    let simplified = verify(&shape(&m48), &shape(&remeshed(&m48)), &params);
    assert_eq!(simplified.map(|v| v.evidence), Some(Evidence::SameShape));
}

#[test]
fn one_mesh_with_leaves_moved_is_another_design_and_quantised_is_not() {
    // The tree: its leaves pin the alignment, so that its vertices pair with the copy's.
    let params = DuplicateParams::default();
    let mesh = shapes::tree(1, 120, |_| true);
    let original = shape(&mesh);
    // A twentieth of the leaves moved by a tenth of the crown's size, turned and moved.
    let mut edited = mesh.clone();
    for leaf in (0..120).step_by(20) {
        let first = edited.positions.len() - 3 * (120 - leaf);
        for p in &mut edited.positions[first..first + 3] {
            p.z += 0.06;
        }
    }
    let edited = shapes::transformed(&edited, shapes::random_motion(7));
    assert_eq!(
        verify(&original, &shape(&edited), &params),
        None,
        "leaves moved"
    );
    // The distances alone take it for the same shape: the leaves stay near where they were.
    let distances_alone = DuplicateParams {
        moved: f64::INFINITY,
        ..params.clone()
    };
    assert_eq!(
        verify(&original, &shape(&edited), &distances_alone).map(|v| v.evidence),
        Some(Evidence::SameShape)
    );
    // Positions quantised to 2⁻¹⁶ of the box (KHR_mesh_quantization) and turned: the same.
    let (lo, hi) = mesh
        .positions
        .iter()
        .fold((DVec3::MAX, DVec3::MIN), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        });
    let step = (hi - lo) / 65535.0;
    let quantised = RawMesh {
        positions: mesh
            .positions
            .iter()
            .map(|&p| lo + ((p - lo) / step).round() * step)
            .collect(),
        triangles: mesh.triangles.clone(),
    };
    let quantised = shapes::transformed(&quantised, shapes::random_motion(8));
    assert!(
        verify(&original, &shape(&quantised), &params).is_some(),
        "quantised"
    );
    // As many vertices and triangles, none moved: re-triangulated, it is the same shape.
    let welded = weld(&mesh, 1e-6).unwrap();
    let (positions, triangles) = disguise::retriangulated(&welded.positions, &welded.triangles);
    let flipped = shapes::transformed(
        &RawMesh {
            positions,
            triangles,
        },
        shapes::random_motion(9),
    );
    assert_eq!(
        verify(&original, &shape(&flipped), &params).map(|v| v.evidence),
        Some(Evidence::SameShape),
        "re-triangulated"
    );
}

#[test]
fn a_computer_with_a_part_moved_across_is_another_design_and_its_mirror_image_is_not() {
    // CAPOD's desktop computers m76 and m77 are one mesh (the same 760 faces) with a part of
    // 46 of the 396 vertices moved across: their surfaces mirror each other, and in the mirror
    // the vertices pair but for that part's. A copy of m76 reflected, turned and moved is
    // its mirror image.
    let params = DuplicateParams::default();
    let m76 = capod("capod_desktop_computer_m76.obj");
    let (a, b) = (shape(&m76), shape(&capod("capod_desktop_computer_m77.obj")));
    let mirror = a
        .align(&b, Reach::new(&params, a.coarser(&b)), |_| true)
        .mirrored;
    assert!(mirror.surfaces.absolute.mean < 0.01, "{mirror:?}");
    assert!(mirror.moved > 1.0, "{mirror:?}");
    assert_eq!(verify(&a, &b, &params), None);
    assert_eq!(verify(&b, &a, &params), None);
    let reflected = shapes::transformed(
        &m76,
        shapes::random_motion(5) * DMat4::from_scale(DVec3::new(-1.0, 1.0, 1.0)),
    );
    assert_eq!(
        verify(&a, &shape(&reflected), &params).map(|v| v.evidence),
        Some(Evidence::Mirrored)
    );
}

#[test]
fn a_pair_aligns_alike_whichever_comes_first() {
    // The service remembers a verdict by the unordered pair: asked either way, the alignment
    // must be the same. A re-triangulated copy has as many vertices as its model, which once
    // made the first of the two the one moved by ICP.
    let params = DuplicateParams::default();
    let families: [Family; 2] = [|p, t, _| disguise::retriangulated(p, t), disguise::quadric];
    for name in [
        "capod/horse_m145.obj",
        "capod/chair_m35.obj",
        "capod/hand_m95.obj",
    ] {
        let mesh = capod(name);
        for family in families {
            let (a, b) = (shape(&mesh), shape(&disguised(&mesh, family)));
            let reach = Reach::new(&params, a.coarser(&b));
            let (forth, back) = (
                a.align(&b, reach, |_| true).rotated,
                b.align(&a, reach, |_| true).rotated,
            );
            let near = |x: f64, y: f64| (x - y).abs() <= 1e-3 * x.abs().max(y.abs()) + 1e-4;
            for (x, y) in [
                (forth.surfaces.absolute.mean, back.surfaces.absolute.mean),
                (forth.surfaces.absolute.max, back.surfaces.absolute.max),
                (forth.vertices.p90, back.vertices.p90),
            ] {
                assert!(near(x, y), "{name}: {forth:?} against {back:?}");
            }
            assert_eq!(
                verify(&a, &b, &params).map(|v| v.evidence),
                verify(&b, &a, &params).map(|v| v.evidence),
                "{name}"
            );
        }
    }
}

/// A lathe (a tube of 160 segments) with three studs, small tetrahedra together 0.06 % of its
/// area, at `(angle, height)`: it fits its surface as well turned by any step of its
/// segments, and only the studs' vertices tell the turn (CAPOD's vase m64).
fn studded(studs: [(f64, f64); 3]) -> RawMesh {
    let mut mesh = shapes::tube(0.5, 12, 160);
    for (angle, z) in studs {
        let centre = DVec3::new(0.55 * angle.cos(), 0.55 * angle.sin(), z);
        let base = mesh.positions.len() as u32;
        mesh.positions.extend(
            TETRA_CORNERS.map(|corner| centre + DVec3::from(corner.map(f64::from)) * 0.025),
        );
        mesh.triangles.extend(
            TETRA_TRIANGLES
                .chunks(3)
                .map(|t| [t[0], t[1], t[2]].map(|i| base + i)),
        );
    }
    mesh
}

#[test]
fn a_lathe_re_triangulated_is_itself_at_any_turn_and_with_a_stud_moved_is_not() {
    // Re-triangulated, the lathe keeps its vertices, so it is one mesh with its model only if
    // they pair: the surfaces' fit, blind to the studs, settles on a step of the symmetry
    // that misplaces them, which took the copy for a morph until the vertices chose the turn.
    const STUDS: [(f64, f64); 3] = [(0.4, 0.5), (2.5, -0.3), (4.4, 0.1)];
    let params = DuplicateParams::default();
    let lathe = studded(STUDS);
    let original = shape(&lathe);
    let welded = weld(&lathe, 1e-6).unwrap();
    let (positions, triangles) = disguise::retriangulated(&welded.positions, &welded.triangles);
    let copy = RawMesh {
        positions,
        triangles,
    };
    for seed in 0..12 {
        let moved = shape(&shapes::transformed(&copy, shapes::random_motion(seed)));
        assert_eq!(
            verify(&original, &moved, &params).map(|v| v.evidence),
            Some(Evidence::SameShape),
            "turned by motion {seed}"
        );
    }
    // One stud moved a quarter of the way round: a part moved, another design, though the
    // body pairs at that turn too.
    let mut studs = STUDS;
    studs[0].0 += std::f64::consts::FRAC_PI_2;
    let edited = shape(&shapes::transformed(
        &studded(studs),
        shapes::random_motion(12),
    ));
    assert_eq!(verify(&original, &edited, &params), None);
}

/// The principal axes of a model spun about its axis (a double moment) must not depend on
/// its size: at 0.1 × its size a retriangulated cone once aligned 0.18 RMS radii off.
#[test]
fn a_small_model_aligns_as_well_as_a_large_one() {
    let params = DuplicateParams::default();
    let cone = shapes::cone(0.4, 24, 32);
    let welded = weld(&cone, 1e-6).unwrap();
    let (positions, triangles) = disguise::retriangulated(&welded.positions, &welded.triangles);
    let copy = RawMesh {
        positions,
        triangles,
    };
    let (_, rotation, translation) = shapes::random_motion(6).to_scale_rotation_translation();
    let original = shape(&cone);
    for scale in [0.1, 1.0, 25.4] {
        let motion =
            DMat4::from_scale_rotation_translation(DVec3::splat(scale), rotation, translation);
        let moved = shape(&shapes::transformed(&copy, motion));
        let reach = Reach::new(&params, original.coarser(&moved));
        let alignment = original.align(&moved, reach, |_| true).rotated;
        assert!(
            alignment.surfaces.absolute.mean < 0.002,
            "×{scale}: {alignment:?}"
        );
    }
}

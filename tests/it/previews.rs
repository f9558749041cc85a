//! What a person sees (SPEC §8): thumbnails, preview meshes, explained results, the
//! comparison picture and the page, on generated meshes whose salient features are known (a
//! sphere with five tips, the tips among its features) and a real CAPOD model.

use std::sync::Arc;

use axum::http::{header, StatusCode};
use glam::{DMat4, DVec3};
use salient_core::display::{region_colour, SURFACE};
use salient_core::preview::NO_REGION;
use salient_core::rank::Method;
use salient_server::api::config::Secret;
use salient_server::api::Config;
use salient_server::store::{Derived, InMemoryStore, Store};
use serde_json::Value;

use crate::app::{expect_error, Form, TestApp};
use crate::server::{fixture, obj};
use crate::shapes;
use crate::stores::{stores, Stores};
use rstest_reuse::apply;

/// The five-tipped star, moved away from the origin and scaled, so that "own coordinates"
/// differ from normalised ones.
fn star() -> Vec<u8> {
    let moved =
        DMat4::from_translation(DVec3::new(10.0, -4.0, 2.0)) * DMat4::from_scale(DVec3::splat(3.0));
    obj(&shapes::transformed(
        &shapes::star(3, &shapes::five_tips()),
        moved,
    ))
}

fn sphere() -> Vec<u8> {
    obj(&shapes::icosphere(3))
}

async fn with_models(app: &TestApp) {
    for (id, mesh) in [
        ("star", star()),
        ("star-copy", star()),
        ("sphere", sphere()),
    ] {
        let added = app.add(&format!("id={id}"), "model/obj", mesh).await;
        assert_eq!(added.status(), StatusCode::CREATED, "{}", added.text());
    }
    let horse = fixture("capod_horse_m155.obj");
    let added = app.add("id=horse", "model/obj", horse).await;
    assert_eq!(added.status(), StatusCode::CREATED);
}

fn decode_png(bytes: &[u8]) -> image::RgbImage {
    image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
        .expect("a PNG")
        .to_rgb8()
}

/// Whether the picture shows colour `c` (shaded: some multiple of it, within rounding).
fn shows(picture: &image::RgbImage, c: [f64; 3]) -> bool {
    picture.pixels().any(|p| {
        let k = p.0[0] as f64 / 255.0 / c[0];
        k > 0.3 && (0..3).all(|i| (p.0[i] as f64 / 255.0 - k * c[i]).abs() < 0.03)
    })
}

fn is_grey_or_red(p: &image::Rgb<u8>) -> bool {
    let [r, g, b] = p.0.map(i32::from);
    let grey = (r - g).abs() <= 6 && (g - b).abs() <= 8;
    grey || (r > 150 && g < 90 && b < 90)
}

#[tokio::test]
async fn a_thumbnail_is_cached_in_the_store_and_goes_with_its_model() {
    let store = Arc::new(InMemoryStore::new());
    let app = TestApp::build(Config::default(), store.clone(), None);
    with_models(&app).await;
    assert!(
        store.derived(Derived::Preview, "star").unwrap().is_none(),
        "made on first use"
    );

    let plain = app
        .get("/v1/models/star/thumbnail.png?size=64")
        .send()
        .await;
    assert_eq!(plain.status(), StatusCode::OK, "{}", plain.text());
    assert_eq!(plain.headers()[header::CONTENT_TYPE], "image/png");
    let picture = decode_png(&plain.body);
    assert_eq!(picture.dimensions(), (64, 64));
    assert!(
        picture.pixels().all(is_grey_or_red),
        "without features the model is grey"
    );
    assert!(shows(&picture, SURFACE));
    let cached = store
        .derived(Derived::Preview, "star")
        .unwrap()
        .expect("the preview is cached");

    // Regions in their colours (the star has more features than the palette has colours).
    let coloured = app
        .get("/v1/models/star/thumbnail.png?size=128&features=true")
        .send()
        .await;
    let picture = decode_png(&coloured.body);
    let visible = (0..6)
        .filter(|&i| shows(&picture, region_colour(i)))
        .count();
    assert!(visible >= 3, "{visible} of the 6 region colours visible");
    assert_eq!(
        store.derived(Derived::Preview, "star").unwrap().unwrap(),
        cached,
        "made once"
    );

    // Revalidation by ETag, per variant.
    let etag = coloured.headers()[header::ETAG]
        .to_str()
        .unwrap()
        .to_string();
    assert_ne!(etag, plain.headers()[header::ETAG].to_str().unwrap());
    let again = app
        .get("/v1/models/star/thumbnail.png?size=128&features=true")
        .header("if-none-match", &etag)
        .send()
        .await;
    assert_eq!(again.status(), StatusCode::NOT_MODIFIED);
    assert!(again.body.is_empty());

    // Bounded sizes; unknown models.
    for size in [8, 2000] {
        let bad = app
            .get(format!("/v1/models/star/thumbnail.png?size={size}"))
            .send()
            .await;
        expect_error(&bad, StatusCode::BAD_REQUEST, "invalid_query");
    }
    let missing = app.get("/v1/models/nothing/thumbnail.png").send().await;
    expect_error(&missing, StatusCode::NOT_FOUND, "not_found");

    // Replaced: the old picture is not served under the old tag; deleted: the cache goes.
    let replaced = app.add("id=star", "model/obj", sphere()).await;
    assert_eq!(replaced.status(), StatusCode::OK);
    assert!(store.derived(Derived::Preview, "star").unwrap().is_none());
    let fresh = app
        .get("/v1/models/star/thumbnail.png?size=128&features=true")
        .header("if-none-match", &etag)
        .send()
        .await;
    assert_eq!(fresh.status(), StatusCode::OK);
    assert_ne!(fresh.headers()[header::ETAG].to_str().unwrap(), etag);
    assert_eq!(
        app.delete("/v1/models/star").send().await.status(),
        StatusCode::NO_CONTENT
    );
    assert!(store.derived(Derived::Preview, "star").unwrap().is_none());
}

/// The GLB's attributes, read back with the `gltf` crate.
struct Glb {
    positions: Vec<[f32; 3]>,
    regions: Vec<u16>,
    triangles: usize,
    points: Vec<[f64; 3]>,
    up: String,
}

fn read_glb(bytes: &[u8]) -> Glb {
    let gltf = gltf::Gltf::from_slice(bytes).expect("a valid GLB");
    let bin = gltf.blob.clone().expect("a BIN chunk");
    let primitive = gltf.meshes().next().unwrap().primitives().next().unwrap();
    let reader = primitive.reader(|_| Some(&bin));
    let positions: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
    let triangles = reader.read_indices().unwrap().into_u32().count() / 3;
    let region = primitive
        .attributes()
        .find(|(s, _)| s.to_string() == "_REGION")
        .expect("a _REGION attribute")
        .1;
    let view = region.view().unwrap();
    let regions = bin[view.offset()..view.offset() + view.length()]
        .chunks_exact(2)
        .map(|c| u16::from_le_bytes([c[0], c[1]]))
        .collect();
    let document: Value =
        serde_json::from_slice(&gltf::binary::Glb::from_slice(bytes).unwrap().json).unwrap();
    let extras = &document["asset"]["extras"];
    let points = serde_json::from_value(extras["salient"]["points"].clone()).unwrap();
    Glb {
        positions,
        regions,
        triangles,
        points,
        up: extras["salient"]["up"].as_str().unwrap().to_string(),
    }
}

#[apply(stores)]
#[tokio::test]
async fn preview_meshes_carry_regions_and_points_in_the_models_own_coordinates(
    #[case] store: Stores,
) {
    let app = TestApp::on_with_config(store, |c| c.up_axis = salient_core::display::UpAxis::Z);
    with_models(&app).await;
    let record = app.get_json("/v1/models/star").await;
    let features = record["features"].as_u64().unwrap() as usize;
    assert!(features >= 5, "at least one feature per tip: {features}");

    let response = app.get("/v1/models/star/preview.glb").send().await;
    assert_eq!(response.status(), StatusCode::OK);
    assert_eq!(
        response.headers()[header::CONTENT_TYPE],
        "model/gltf-binary"
    );
    let glb = read_glb(&response.body);
    assert_eq!(glb.up, "z");
    assert_eq!(glb.positions.len(), glb.regions.len());
    assert!(glb.triangles > 0 && glb.triangles <= salient_core::preview::MAX_TRIANGLES);
    assert_eq!(glb.points.len(), features);
    let mut labels: Vec<u16> = glb
        .regions
        .iter()
        .copied()
        .filter(|&r| r != NO_REGION)
        .collect();
    labels.sort_unstable();
    labels.dedup();
    assert_eq!(
        labels,
        (0..features as u16).collect::<Vec<_>>(),
        "each feature's region is labelled"
    );
    assert!(glb.regions.contains(&NO_REGION), "the body is in no region");
    // Own coordinates: the star was scaled by 3 about (10, −4, 2); its tips are up to 1.3 · 3
    // out (normalised, everything would be within 1 of the origin).
    let centre = DVec3::new(10.0, -4.0, 2.0);
    let far = glb
        .positions
        .iter()
        .map(|p| DVec3::from(p.map(f64::from)).distance(centre))
        .fold(0.0, f64::max);
    assert!((3.5..3.95).contains(&far), "farthest {far}");
    for p in &glb.points {
        assert!(
            DVec3::from(*p).distance(centre) > 3.0,
            "points at the tips: {p:?}"
        );
    }

    // The same for an uploaded query, with and without features.
    let form = || Form::new().file("file", "star.obj", star());
    let query = app.post("/v1/preview").multipart(form()).send().await;
    assert_eq!(query.status(), StatusCode::OK, "{}", query.text());
    let query = read_glb(&query.body);
    assert_eq!(query.points, glb.points);
    assert_eq!(query.regions, glb.regions);
    let plain = app
        .post("/v1/preview?features=false")
        .multipart(form())
        .send()
        .await;
    let plain = read_glb(&plain.body);
    assert!(plain.points.is_empty());
    assert!(plain.regions.iter().all(|&r| r == NO_REGION));

    let bad = app
        .post("/v1/preview")
        .multipart(Form::new().file("file", "bad.obj", b"v 1 2\nf 1 2 9\n".to_vec()))
        .send()
        .await;
    assert!(bad.status().is_client_error(), "{}", bad.status());
}

#[apply(stores)]
#[tokio::test]
async fn explained_results_give_every_distance_and_the_emd_plan(#[case] store: Stores) {
    let app = TestApp::on(store);
    with_models(&app).await;
    let star_signature = app.get_json("/v1/models/star/signature").await;

    let response = app
        .post("/v1/search?k=4&explain=true")
        .multipart(Form::new().file("file", "star.obj", star()))
        .send()
        .await;
    assert_eq!(response.status(), StatusCode::OK, "{}", response.text());
    let body = response.json();
    let query = body["query"]["features"].as_array().unwrap();
    let features = star_signature["features"].as_array().unwrap().len();
    assert_eq!(query.len(), features);
    for (q, f) in query
        .iter()
        .zip(star_signature["features"].as_array().unwrap())
    {
        assert_eq!(q["position"], f["position"]);
    }
    let results = body["results"].as_array().unwrap();
    for hit in results {
        let explanation = &hit["explanation"];
        let distances = explanation["distances"].as_object().unwrap();
        let methods: Vec<String> = Method::ALL.iter().map(|m| m.to_string()).collect();
        assert_eq!(distances.keys().cloned().collect::<Vec<_>>(), {
            let mut sorted = methods.clone();
            sorted.sort();
            sorted
        });
        assert_eq!(body["method"], "hybrid", "the default");
        assert_eq!(
            distances["hybrid"], hit["distance"],
            "the ranking's own distance"
        );
        // The hybrid's terms add up to it.
        let terms = explanation["contributions"].as_object().unwrap();
        let mut weighed: Vec<String> = salient_core::rank::PARTS
            .iter()
            .zip(salient_core::params::HybridParams::default().terms())
            .filter(|(_, t)| t.weight > 0.0)
            .map(|(m, _)| m.to_string())
            .collect();
        weighed.sort();
        assert_eq!(terms.keys().cloned().collect::<Vec<_>>(), weighed);
        let sum: f64 = terms.values().map(|t| t.as_f64().unwrap()).sum();
        let hybrid = distances["hybrid"].as_f64().unwrap();
        assert!(
            (sum - hybrid).abs() <= 1e-9 * hybrid.max(1.0),
            "{sum} vs {hybrid}"
        );
        let matches = explanation["matches"].as_array().unwrap();
        let mass: f64 = matches.iter().map(|m| m["mass"].as_f64().unwrap()).sum();
        assert!((mass - 1.0).abs() < 1e-9, "masses sum to 1, not {mass}");
        for m in matches {
            let i = m["query"].as_u64().unwrap() as usize;
            assert_eq!(m["query_position"], query[i]["position"]);
        }
    }
    // Identical models: every feature goes whole onto its twin at no cost.
    let twins: Vec<&Value> = results.iter().filter(|h| h["distance"] == 0.0).collect();
    assert_eq!(twins.len(), 2, "star and star-copy");
    for hit in twins {
        let matches = hit["explanation"]["matches"].as_array().unwrap();
        assert_eq!(matches.len(), features);
        for m in matches {
            assert_eq!(m["query"], m["result"]);
            assert_eq!(m["ground_distance"], 0.0);
            assert_eq!(m["query_position"], m["result_position"]);
        }
    }
    // Without explain, none of it.
    let plain = app.get_json("/v1/models/star/similar?k=2").await;
    assert!(plain.get("query").is_none());
    assert!(plain["results"][0].get("explanation").is_none());
    let similar = app
        .get_json("/v1/models/star/similar?k=2&explain=true")
        .await;
    assert_eq!(similar["results"][0]["id"], "star-copy");
    assert_eq!(
        similar["query"]["features"].as_array().unwrap().len(),
        features
    );
}

#[apply(stores)]
#[tokio::test]
async fn a_comparison_of_twins_shows_the_same_picture_twice(#[case] store: Stores) {
    let app = TestApp::on(store);
    with_models(&app).await;
    let twins = app
        .get("/v1/compare?a=star&b=star-copy&size=96")
        .send()
        .await;
    assert_eq!(twins.status(), StatusCode::OK, "{}", twins.text());
    let picture = decode_png(&twins.body);
    assert_eq!(picture.dimensions(), (192, 96));
    let differing = (0..96)
        .flat_map(|y| (0..96).map(move |x| (x, y)))
        .filter(|&(x, y)| picture.get_pixel(x, y) != picture.get_pixel(x + 96, y))
        .count();
    assert_eq!(differing, 0, "matched regions take the same colours");
    assert!(
        (0..6)
            .filter(|&i| shows(&picture, region_colour(i)))
            .count()
            >= 3
    );

    let other = app.get("/v1/compare?a=star&b=horse").send().await;
    assert_eq!(other.status(), StatusCode::OK);
    assert_eq!(decode_png(&other.body).dimensions(), (512, 256));
    let missing = app.get("/v1/compare?a=star&b=nothing").send().await;
    expect_error(&missing, StatusCode::NOT_FOUND, "not_found");
    let invalid = app.get("/v1/compare?a=star&b=..").send().await;
    expect_error(&invalid, StatusCode::BAD_REQUEST, "invalid_id");
}

#[apply(stores)]
#[tokio::test]
async fn the_page_is_served_to_everyone_and_its_data_only_with_a_key(#[case] store: Stores) {
    let app = TestApp::on_with_config(store, |c| {
        c.inline_keys = Some(Secret("read:page-test-key-0123456789".into()))
    });
    let page = app.get("/").send().await;
    assert_eq!(page.status(), StatusCode::OK);
    assert!(page.headers()[header::CONTENT_TYPE]
        .to_str()
        .unwrap()
        .starts_with("text/html"));
    let policy = page.headers()[header::CONTENT_SECURITY_POLICY]
        .to_str()
        .unwrap();
    assert!(policy.contains("script-src 'self'") && policy.contains("frame-ancestors 'none'"));
    assert!(page.text().contains("/page/app.js"));
    for (file, kind) in [
        ("app.js", "text/javascript"),
        ("view.js", "text/javascript"),
        ("style.css", "text/css"),
    ] {
        let response = app.get(format!("/page/{file}")).send().await;
        assert_eq!(response.status(), StatusCode::OK, "{file}");
        assert!(response.headers()[header::CONTENT_TYPE]
            .to_str()
            .unwrap()
            .starts_with(kind));
    }
    let missing = app.get("/page/secret.txt").send().await;
    expect_error(&missing, StatusCode::NOT_FOUND, "not_found");

    let thumbnail = app.get("/v1/models/x/thumbnail.png").send().await;
    expect_error(&thumbnail, StatusCode::UNAUTHORIZED, "unauthorized");
    let listed = app
        .get("/v1/models")
        .bearer("page-test-key-0123456789")
        .send()
        .await;
    assert_eq!(listed.status(), StatusCode::OK);
}

/// Each model stands on its own up axis: its format's (glTF +y; STL, 3MF +z), else the
/// server's, unless it names its own on upload or by `PATCH`. Only pictures turn: the
/// signature is untouched and nothing is re-extracted.
#[apply(stores)]
#[tokio::test]
async fn each_model_stands_on_its_own_up_axis(#[case] store: Stores) {
    let app = TestApp::on(store);
    let horse = fixture("capod_horse_m155.obj");
    let stl = salient_core::mesh::write::Export::BinaryStl.write(
        &salient_core::mesh::load_bytes(
            &horse,
            salient_core::mesh::Format::Obj,
            &salient_core::mesh::load::NoResources,
            &salient_core::Limits::default(),
        )
        .unwrap(),
    );
    for (query, content_type, body) in [
        ("id=obj", "model/obj", horse.clone()),
        ("id=obj-z&up=z", "model/obj", horse.clone()),
        ("id=stl", "model/stl", stl.clone()),
        (
            "id=glb",
            "model/gltf-binary",
            fixture("web/horse_plain.glb"),
        ),
        ("id=print", "model/3mf", fixture("3mf/horse_production.3mf")),
    ] {
        let response = app.add(query, content_type, body).await;
        assert_eq!(
            response.status(),
            StatusCode::CREATED,
            "{query}: {}",
            response.text()
        );
    }
    let up = |id: &'static str| {
        let app = &app;
        async move {
            let response = app.get(format!("/v1/models/{id}/preview.glb")).send().await;
            assert_eq!(response.status(), StatusCode::OK);
            read_glb(&response.body).up
        }
    };
    let etag = |id: &'static str| {
        let app = &app;
        async move {
            let response = app
                .get(format!("/v1/models/{id}/thumbnail.png"))
                .send()
                .await;
            response.headers()[header::ETAG]
                .to_str()
                .unwrap()
                .to_string()
        }
    };
    for (id, expected) in [
        ("obj", "y"),
        ("obj-z", "z"),
        ("stl", "z"),
        ("glb", "y"),
        ("print", "z"),
    ] {
        assert_eq!(up(id).await, expected, "{id}");
    }
    assert_eq!(app.get_json("/v1/models/obj-z").await["up"], "z");
    assert_eq!(
        app.get_json("/v1/models/obj").await["up"],
        serde_json::Value::Null
    );
    // The same mesh on another axis is another picture.
    assert_ne!(etag("obj").await, etag("obj-z").await);
    let extractions = || async {
        let metrics = app.get("/metrics").send().await.text();
        metrics
            .lines()
            .find(|l| l.starts_with("salient_extraction_seconds_count"))
            .unwrap()
            .to_string()
    };
    let before = extractions().await;
    let signature = app.get("/v1/models/obj/signature").send().await.body;

    // PATCH turns it, and `null` returns it to its format's (here the server's).
    let patch = |body: serde_json::Value| {
        app.request_with_method("PATCH", "/v1/models/obj")
            .header("content-type", "application/json")
            .body(body.to_string())
            .send()
    };
    let patched = patch(serde_json::json!({"up": "z"})).await;
    assert_eq!(patched.status(), StatusCode::OK, "{}", patched.text());
    assert_eq!(patched.json()["up"], "z");
    assert_eq!(up("obj").await, "z");
    assert_eq!(
        etag("obj").await,
        etag("obj-z").await,
        "same mesh, same axis"
    );
    assert_eq!(
        app.get("/v1/models/obj/signature").send().await.body,
        signature
    );
    assert_eq!(extractions().await, before, "nothing re-extracted");
    patch(serde_json::json!({"up": null})).await;
    assert_eq!(up("obj").await, "y");
    let bad = patch(serde_json::json!({"up": "x"})).await;
    assert_eq!(bad.status(), StatusCode::BAD_REQUEST);
    let bad = app.add("id=bad&up=x", "model/obj", horse.clone()).await;
    expect_error(&bad, StatusCode::BAD_REQUEST, "invalid_parameter");

    // The same upload with the same axis is unchanged; another axis is a change.
    let stored = app.get_json("/v1/models/obj-z").await;
    let again = app.add("id=obj-z&up=z", "model/obj", horse.clone()).await;
    assert_eq!(again.status(), StatusCode::OK);
    assert_eq!(again.json(), stored);
    let turned = app.add("id=obj-z&up=y", "model/obj", horse.clone()).await;
    assert_eq!(turned.json()["up"], "y");

    // An uploaded query's preview: its format's axis, or the one it names.
    for (query, expected) in [("", "z"), ("?up=y", "y")] {
        let response = app
            .post(format!("/v1/preview{query}"))
            .header("content-type", "model/stl")
            .body(stl.clone())
            .send()
            .await;
        assert_eq!(response.status(), StatusCode::OK, "{}", response.text());
        assert_eq!(read_glb(&response.body).up, expected, "{query}");
    }
    // A comparison stands each model on its own axis: both are in its ETag.
    let compared = app.get("/v1/compare?a=glb&b=print").send().await;
    assert_eq!(compared.status(), StatusCode::OK);
    assert!(compared.headers()[header::ETAG]
        .to_str()
        .unwrap()
        .ends_with("yz\""));
}

/// A mixed library: each CAPOD model (posed with +z up) as a Z-up STL, as 3D-print files are,
/// and as a GLB turned to +y up, as glTF exporters write it. Each stands on its format's axis,
/// so the two thumbnails of a model are the same upright picture. `SALIENT_WRITE_SCREENSHOTS=1` writes them as the contact sheet
/// `docs/screenshots/up-axis.png` (GLB above, STL below).
#[tokio::test]
async fn a_mixed_library_stands_upright() {
    use salient_core::mesh::write::Export;
    let app = TestApp::new();
    let dir = crate::common::fixture("capod");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".obj"))
        .collect();
    names.sort();
    let size = 160u32;
    let mut sheet = image::RgbImage::new(size * names.len() as u32, 2 * size);
    for (column, name) in names.iter().enumerate() {
        let mesh = salient_core::mesh::load_path(&dir.join(name), &salient_core::Limits::default())
            .unwrap();
        let mut y_up = mesh.clone();
        for p in &mut y_up.positions {
            *p = DVec3::new(p.x, p.z, -p.y);
        }
        let stem = name.trim_end_matches(".obj");
        let mut pictures = Vec::new();
        for (row, (suffix, export, file)) in [
            ("glb", Export::Glb, &y_up),
            ("stl", Export::BinaryStl, &mesh),
        ]
        .into_iter()
        .enumerate()
        {
            let id = format!("{stem}-{suffix}");
            let added = app
                .add(
                    &format!("id={id}"),
                    export.format().media_type(),
                    export.write(file),
                )
                .await;
            assert_eq!(added.status(), StatusCode::CREATED, "{id}");
            let png = app
                .get(format!("/v1/models/{id}/thumbnail.png?size={size}"))
                .send()
                .await;
            let picture = decode_png(&png.body);
            image::imageops::replace(
                &mut sheet,
                &picture,
                (column as u32 * size).into(),
                (row as u32 * size).into(),
            );
            pictures.push(picture);
        }
        let difference = pictures[0]
            .pixels()
            .zip(pictures[1].pixels())
            .map(|(a, b)| (0..3).map(|i| a.0[i].abs_diff(b.0[i]) as f64).sum::<f64>() / 3.0)
            .sum::<f64>()
            / (size * size) as f64;
        assert!(
            difference < 2.0,
            "{stem}: the STL and the turned GLB differ by {difference}"
        );
    }
    if std::env::var_os("SALIENT_WRITE_SCREENSHOTS").is_some() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/screenshots/up-axis.png");
        sheet.save(path).unwrap();
    }
}

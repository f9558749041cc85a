//! The HTTP service in process (`tests/it/app.rs`): every endpoint and every error status
//! (SPEC §8, `openapi.yaml`), real meshes.

use std::sync::Arc;

use axum::body::Bytes;
use axum::http::StatusCode;
use salient_server::api::Config;
use salient_server::model::{ModelId, ModelRecord, Upload};
use salient_server::spool::SPOOL_BYTES;
use salient_server::store::{Derived, InMemoryStore, Loaded, Store, StoreError, StoreResult};
use serde_json::Value;

use crate::app::{Form, TestApp, TestResponse};
use crate::server::{fixture, obj};
use crate::shapes;
use crate::stores::{stores, Stores};
use rstest_reuse::apply;

async fn json(response: TestResponse) -> Value {
    response.json()
}

async fn expect_error(response: TestResponse, status: StatusCode, code: &str) {
    crate::app::expect_error(&response, status, code);
}

#[apply(stores)]
#[tokio::test]
async fn models_can_be_added_listed_read_replaced_and_deleted(#[case] store: Stores) {
    let app = TestApp::on(store);

    let horse = fixture("capod_horse_m155.obj");
    let created = app
        .add(
            "id=horse&name=Horse&tags=animal,capod&class=horse",
            "model/obj",
            horse.clone(),
        )
        .await;
    assert_eq!(created.status(), StatusCode::CREATED);
    let record = json(created).await;
    assert_eq!(record["id"], "horse");
    assert_eq!(record["tags"], serde_json::json!(["animal", "capod"]));
    assert_eq!(record["vertices"], 346);
    assert!(record["features"].as_u64().unwrap() >= 1);

    // The same upload again changes nothing; other content under the id replaces it.
    let again = app
        .add(
            "id=horse&name=Horse&tags=animal,capod&class=horse",
            "model/obj",
            horse.clone(),
        )
        .await;
    assert_eq!(again.status(), StatusCode::OK);
    assert_eq!(json(again).await, record);
    let star = obj(&shapes::star(3, &shapes::five_tips()));
    let replaced = app
        .add("id=horse&name=Star", "model/obj", star.clone())
        .await;
    assert_eq!(replaced.status(), StatusCode::OK);
    let replaced = json(replaced).await;
    assert_eq!(replaced["name"], "Star");
    assert_eq!(replaced["created_unix"], record["created_unix"]);
    assert_ne!(replaced["content_hash"], record["content_hash"]);

    // Without an id: the id comes from the content hash, and identical content is found.
    let glb = fixture("capod_horse_m155_split.glb");
    let anonymous = json(
        app.add("tags=split", "model/gltf-binary", glb.clone())
            .await,
    )
    .await;
    let id = anonymous["id"].as_str().unwrap().to_string();
    assert_eq!(id.len(), 16);
    let found = app.add("", "application/octet-stream", glb).await;
    assert_eq!(found.status(), StatusCode::OK);
    assert_eq!(json(found).await["id"], id.as_str());

    let third = json(
        app.add(
            "id=cone&class=cone&tags=capod",
            "model/obj",
            obj(&shapes::cone(0.5, 30, 32)),
        )
        .await,
    )
    .await;
    assert_eq!(third["class"], "cone");

    // Listing: id order, pages, filters.
    let page = json(app.get("/v1/models?limit=2").send().await).await;
    let ids: Vec<&str> = page["models"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids.len(), 2);
    let next = page["next"].as_str().unwrap();
    let rest = json(
        app.get(format!("/v1/models?limit=2&after={next}"))
            .send()
            .await,
    )
    .await;
    assert_eq!(rest["models"].as_array().unwrap().len(), 1);
    assert!(rest["next"].is_null());
    let tagged = json(app.get("/v1/models?tag=capod").send().await).await;
    assert_eq!(tagged["models"].as_array().unwrap().len(), 1);
    let by_class = json(app.get("/v1/models?class=cone").send().await).await;
    assert_eq!(by_class["models"][0]["id"], "cone");
    let hash = anonymous["content_hash"].as_str().unwrap();
    let by_hash = json(
        app.get(format!("/v1/models?content_hash={hash}"))
            .send()
            .await,
    )
    .await;
    assert_eq!(by_hash["models"][0]["id"], id.as_str());

    // One model, its signature.
    let one = json(app.get("/v1/models/cone").send().await).await;
    assert_eq!(one, third);
    let signature = json(app.get("/v1/models/cone/signature").send().await).await;
    assert_eq!(
        signature["features"].as_array().unwrap().len() as u64,
        third["features"].as_u64().unwrap()
    );
    assert_eq!(signature["params"]["ecc"]["waves"], 10);

    // Delete.
    let deleted = app.delete("/v1/models/cone").send().await;
    assert_eq!(deleted.status(), StatusCode::NO_CONTENT);
    expect_error(
        app.get("/v1/models/cone").send().await,
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
    expect_error(
        app.delete("/v1/models/cone").send().await,
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
    expect_error(
        app.get("/v1/models/cone/signature").send().await,
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
    let health = json(app.get("/healthz").send().await).await;
    assert_eq!(health["models"], 2);
}

#[apply(stores)]
#[tokio::test]
async fn multipart_uploads_carry_gltf_resources_and_fields(#[case] store: Stores) {
    let app = TestApp::on(store);
    let form = || {
        Form::new()
            .file("file", "tetra.gltf", fixture("gltf_external/tetra.gltf"))
            .file("file", "tetra.bin", fixture("gltf_external/tetra.bin"))
            .text("id", "tetra")
            .text("tags", "solid, small")
    };
    let created = app.post("/v1/models").multipart(form()).send().await;
    assert_eq!(created.status(), StatusCode::CREATED);
    let record = json(created).await;
    assert_eq!(record["format"], "gltf");
    assert_eq!(record["tags"], serde_json::json!(["solid", "small"]));
    assert!(record["resources"]["tetra.bin"].is_string());

    // Without its buffer the glTF cannot be read.
    let alone = Form::new().file("file", "tetra.gltf", fixture("gltf_external/tetra.gltf"));
    expect_error(
        app.post("/v1/models").multipart(alone).send().await,
        StatusCode::BAD_REQUEST,
        "bad_mesh",
    )
    .await;
    let empty = Form::new().text("id", "nothing");
    expect_error(
        app.post("/v1/models").multipart(empty).send().await,
        StatusCode::BAD_REQUEST,
        "empty_body",
    )
    .await;
}

/// What browsers and web pipelines send: a Blob named `blob` with its format in `format`, a
/// `.gltf` whose buffer is `buffers/NAME` sent as `NAME`; files of other applications are
/// refused as unsupported, with a conversion.
#[apply(stores)]
#[tokio::test]
async fn uploads_as_browsers_send_them_and_unsupported_kinds_say_how_to_convert(
    #[case] store: Stores,
) {
    let app = TestApp::on(store);
    let blob = Form::new()
        .file("file", "blob", fixture("capod_horse_m155_split.glb"))
        .text("format", "glb")
        .text("id", "blob");
    let created = app.post("/v1/models").multipart(blob).send().await;
    assert_eq!(created.status(), StatusCode::CREATED);
    assert_eq!(json(created).await["format"], "glb");
    // No name and no `format`: the content tells.
    let sniffed = Form::new()
        .file("file", "blob", fixture("capod_horse_m155_split.glb"))
        .text("id", "sniffed");
    assert_eq!(
        app.post("/v1/models")
            .multipart(sniffed)
            .send()
            .await
            .status(),
        StatusCode::CREATED
    );

    let gltf = String::from_utf8(fixture("gltf_external/tetra.gltf"))
        .unwrap()
        .replace("\"tetra.bin\"", "\"buffers/tetra.bin\"");
    let nested = || {
        Form::new()
            .file("file", "tetra.gltf", gltf.clone().into_bytes())
            .file("file", "tetra.bin", fixture("gltf_external/tetra.bin"))
    };
    let created = app
        .post("/v1/models?id=nested")
        .multipart(nested())
        .send()
        .await;
    assert_eq!(created.status(), StatusCode::CREATED);
    // Two files of that base name: which one is meant cannot be told.
    let ambiguous = nested().file(
        "file",
        "other/tetra.bin",
        fixture("gltf_external/tetra.bin"),
    );
    expect_error(
        app.post("/v1/models?id=ambiguous")
            .multipart(ambiguous)
            .send()
            .await,
        StatusCode::BAD_REQUEST,
        "bad_mesh",
    )
    .await;

    // A zip of a glTF with its buffer, raw or in a form.
    let zipped = crate::common::zip(&[
        ("tetra/tetra.gltf", &fixture("gltf_external/tetra.gltf")),
        ("tetra/tetra.bin", &fixture("gltf_external/tetra.bin")),
    ]);
    let raw = app
        .add("id=zipped", "application/zip", zipped.clone())
        .await;
    assert_eq!(raw.status(), StatusCode::CREATED, "{}", raw.text());
    assert_eq!(json(raw).await["format"], "gltf");
    // `format` names the kind over the content type.
    let named = app
        .add("id=zipped-named&format=zip", "model/obj", zipped.clone())
        .await;
    assert_eq!(named.status(), StatusCode::CREATED, "{}", named.text());
    let form = Form::new().file("file", "tetra.zip", zipped);
    let created = app
        .post("/v1/models?id=zipped-form")
        .multipart(form)
        .send()
        .await;
    assert_eq!(created.status(), StatusCode::CREATED, "{}", created.text());
    let bomb = crate::common::zip(&[("bomb.obj", &vec![0u8; 4 << 20])]);
    let limited = TestApp::with_config(|c| c.limits.max_unpacked_bytes = 1 << 20);
    let refused = limited.add("id=bomb", "application/zip", bomb).await;
    assert!(
        refused.text().contains("max_unpacked_bytes"),
        "{}",
        refused.text()
    );
    expect_error(refused, StatusCode::PAYLOAD_TOO_LARGE, "payload_too_large").await;

    // 3MF by its media type, its name, or its content (not taken for a zip of a mesh).
    let print = fixture("3mf/horse_production.3mf");
    for (query, content_type) in [
        ("id=print", "model/3mf"),
        ("id=print-sniffed", "application/octet-stream"),
        ("id=print-named&format=3mf", "application/octet-stream"),
    ] {
        let created = app.add(query, content_type, print.clone()).await;
        assert_eq!(
            created.status(),
            StatusCode::CREATED,
            "{query}: {}",
            created.text()
        );
        assert_eq!(json(created).await["format"], "3mf");
    }
    let form = Form::new().file("file", "print.3mf", print.clone());
    let created = app
        .post("/v1/models?id=print-form")
        .multipart(form)
        .send()
        .await;
    assert_eq!(created.status(), StatusCode::CREATED, "{}", created.text());

    let fbx = b"Kaydara FBX Binary  \x00\x1a\x00\x00\x00\x00".to_vec();
    for response in [
        app.add("id=chair", "application/octet-stream", fbx.clone())
            .await,
        app.add(
            "id=chair&format=fbx",
            "application/octet-stream",
            fbx.clone(),
        )
        .await,
        app.post("/v1/models")
            .multipart(Form::new().file("file", "chair.fbx", fbx.clone()))
            .send()
            .await,
    ] {
        assert_eq!(response.status(), StatusCode::UNPROCESSABLE_ENTITY);
        let error = &json(response).await["error"];
        assert_eq!(error["code"], "unsupported_mesh_feature");
        assert!(
            error["message"].as_str().unwrap().contains("FBX"),
            "{error}"
        );
        assert!(
            error["message"].as_str().unwrap().contains("glTF 2.0"),
            "{error}"
        );
    }
}

#[apply(stores)]
#[tokio::test]
async fn bad_input_gets_the_right_status_and_the_server_keeps_serving(#[case] store: Stores) {
    let app = TestApp::on_with_config(store, |config| {
        config.max_body_bytes = 100_000;
        config.max_upload_bytes = 200_000;
        config.limits.max_input_vertices = 5000;
    });
    let horse = fixture("capod_horse_m155.obj");

    // Every 413 names the limit and how to raise it: adding a model has its own, larger one.
    let big = app.add("id=big", "model/obj", vec![b'#'; 300_000]).await;
    assert!(big.text().contains("--max-upload-bytes"), "{}", big.text());
    expect_error(big, StatusCode::PAYLOAD_TOO_LARGE, "payload_too_large").await;
    let form = Form::new().file("file", "big.obj", vec![b'#'; 300_000]);
    let big_form = app.post("/v1/models?id=big").multipart(form).send().await;
    assert!(
        big_form.text().contains("--max-upload-bytes"),
        "{}",
        big_form.text()
    );
    expect_error(big_form, StatusCode::PAYLOAD_TOO_LARGE, "payload_too_large").await;
    let between = vec![b'#'; 150_000];
    let search = app
        .post("/v1/search")
        .header("content-type", "model/obj")
        .body(between.clone())
        .send()
        .await;
    assert!(
        search.text().contains("--max-body-bytes"),
        "{}",
        search.text()
    );
    expect_error(search, StatusCode::PAYLOAD_TOO_LARGE, "payload_too_large").await;
    // The same body is within the limit of adding (and refused for what it holds).
    let added = app.add("id=between", "model/obj", between).await;
    assert_ne!(
        added.status(),
        StatusCode::PAYLOAD_TOO_LARGE,
        "{}",
        added.text()
    );
    let many = obj(&shapes::icosphere(4)); // over the body limit
    expect_error(
        app.add("id=many", "model/obj", many).await,
        StatusCode::PAYLOAD_TOO_LARGE,
        "payload_too_large",
    )
    .await;
    // A mesh over a count limit: 162 vertices, 320 triangles.
    let small = obj(&shapes::icosphere(2));
    for (configure, flag) in [
        (
            (|c: &mut Config| c.limits.max_input_vertices = 100) as fn(&mut Config),
            "--max-vertices",
        ),
        (
            |c: &mut Config| c.limits.max_input_triangles = 300,
            "--max-triangles",
        ),
    ] {
        let limited = TestApp::with_config(configure);
        let refused = limited.add("id=many", "model/obj", small.clone()).await;
        assert!(refused.text().contains(flag), "{}", refused.text());
        expect_error(refused, StatusCode::PAYLOAD_TOO_LARGE, "payload_too_large").await;
    }
    expect_error(
        app.add("id=json", "application/json", b"{}".to_vec()).await,
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
        "unsupported_format",
    )
    .await;
    expect_error(
        app.add(
            "id=junk",
            "application/octet-stream",
            vec![0xde, 0xad, 0xbe, 0xef],
        )
        .await,
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
        "unsupported_format",
    )
    .await;
    expect_error(
        app.add("id=x&format=xyz", "application/octet-stream", horse.clone())
            .await,
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
        "unsupported_format",
    )
    .await;
    // A format salient knows of but does not read says how to convert it.
    expect_error(
        app.add("id=x&format=fbx", "application/octet-stream", horse.clone())
            .await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "unsupported_mesh_feature",
    )
    .await;
    expect_error(
        app.add("id=corrupt", "model/obj", b"v 0 0 0\nf 1 2 7\n".to_vec())
            .await,
        StatusCode::BAD_REQUEST,
        "bad_mesh",
    )
    .await;
    expect_error(
        app.add(
            "id=nan",
            "model/obj",
            b"v nan 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\n".to_vec(),
        )
        .await,
        StatusCode::BAD_REQUEST,
        "bad_mesh",
    )
    .await;
    expect_error(
        app.add(
            "id=flat",
            "model/obj",
            b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n".to_vec(),
        )
        .await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "unusable_mesh",
    )
    .await;
    expect_error(
        app.add(
            "id=lines",
            "model/obj",
            b"v 0 0 0\nv 1 0 0\nl 1 2\n".to_vec(),
        )
        .await,
        StatusCode::UNPROCESSABLE_ENTITY,
        "unusable_mesh",
    )
    .await;
    expect_error(
        app.add("id=empty", "model/obj", Vec::new()).await,
        StatusCode::BAD_REQUEST,
        "empty_body",
    )
    .await;
    for id in ["..", ".hidden", "a%2Fb", "a%20b", &"x".repeat(129)] {
        expect_error(
            app.add(&format!("id={id}"), "model/obj", horse.clone())
                .await,
            StatusCode::BAD_REQUEST,
            "invalid_id",
        )
        .await;
    }
    for path in [
        "/v1/models/..%2F..%2Fetc%2Fpasswd",
        "/v1/models/..%5C..",
        "/v1/models/a%5Cb/signature",
    ] {
        expect_error(
            app.get(path).send().await,
            StatusCode::BAD_REQUEST,
            "invalid_id",
        )
        .await;
    }
    expect_error(
        app.get("/v1/models?limit=abc").send().await,
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    expect_error(
        app.get("/v1/models?limit=0").send().await,
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    let search = |query: &'static str| {
        app.post(format!("/v1/search?{query}"))
            .header("content-type", "model/obj")
            .body(horse.clone())
            .send()
    };
    expect_error(
        search("k=0").await,
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    expect_error(
        search("k=-3").await,
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    expect_error(
        search("method=sh").await,
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    expect_error(
        search("w=2").await,
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    expect_error(
        app.get("/v1/nothing").send().await,
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;

    // Still serving, and nothing bad was stored.
    assert_eq!(
        app.add("id=horse", "model/obj", horse).await.status(),
        StatusCode::CREATED
    );
    let all = json(app.get("/v1/models").send().await).await;
    assert_eq!(all["models"].as_array().unwrap().len(), 1);
}

#[tokio::test]
async fn search_similar_and_extract() {
    let dir = tempfile::tempdir().unwrap();
    let collection = dir.path().join("collection");
    std::fs::create_dir_all(&collection).unwrap();
    let app = TestApp::new();
    let star = shapes::star(4, &shapes::five_tips());
    let meshes = [
        ("star", obj(&star), "tips"),
        (
            "moved",
            obj(&shapes::transformed(&star, shapes::random_motion(3))),
            "tips",
        ),
        (
            "three",
            obj(&shapes::star(4, &shapes::five_tips()[..3])),
            "tips",
        ),
        ("cone", obj(&shapes::cone(0.5, 40, 48)), "plain"),
        ("tube", obj(&shapes::tube(0.2, 60, 24)), "plain"),
        ("horse", fixture("capod_horse_m155.obj"), "plain"),
    ];
    for (id, bytes, tag) in &meshes {
        std::fs::write(collection.join(format!("{id}.obj")), bytes).unwrap();
        let status = app
            .add(&format!("id={id}&tags={tag}"), "model/obj", bytes.clone())
            .await
            .status();
        assert_eq!(status, StatusCode::CREATED);
    }
    let query = obj(&shapes::star(
        4,
        &[
            glam::DVec3::X,
            glam::DVec3::Y,
            glam::DVec3::Z,
            -glam::DVec3::Z,
        ],
    ));
    std::fs::write(dir.path().join("query.obj"), &query).unwrap();

    for method in ["ecc", "d2", "lfd"] {
        let response = app
            .post(format!("/v1/search?k=6&method={method}"))
            .header("content-type", "model/obj")
            .body(query.clone())
            .send()
            .await;
        assert_eq!(response.status(), StatusCode::OK);
        let ranked = json(response).await;
        let ids: Vec<String> = ranked["results"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["id"].as_str().unwrap().to_string())
            .collect();
        assert_eq!(ids.len(), 6);
        assert_eq!(ranked["results"][0]["rank"], 1);
        assert!(ranked["timings"]["extract_ms"].as_f64().unwrap() > 0.0);
        let timing = |part: &str| ranked["timings"][part].as_f64().unwrap();
        assert!(timing("search_ms") > 0.0);
        // Extraction and ranking are disjoint parts of the request's time.
        assert!(timing("total_ms") >= timing("extract_ms") + timing("search_ms"));

        // The same ranking as the offline `salient search` on the same files.
        let offline = std::process::Command::new(env!("CARGO_BIN_EXE_salient"))
            .args([
                "search",
                dir.path().join("query.obj").to_str().unwrap(),
                collection.to_str().unwrap(),
                "-k",
                "6",
                "--json",
                "--method",
                method,
            ])
            .output()
            .unwrap();
        let offline: Value = serde_json::from_slice(&offline.stdout).unwrap();
        let offline_ids: Vec<String> = offline["results"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| {
                r["id"]
                    .as_str()
                    .unwrap()
                    .trim_end_matches(".obj")
                    .to_string()
            })
            .collect();
        assert_eq!(ids, offline_ids, "{method}");
        for (online, offline) in ranked["results"]
            .as_array()
            .unwrap()
            .iter()
            .zip(offline["results"].as_array().unwrap())
        {
            assert_eq!(online["distance"], offline["distance"]);
        }
    }

    // A method that compares no salient features runs no ECC of the upload (new content, so
    // nothing remembered serves it), and ranks exactly as with the full signature: asked
    // again after an `ecc` search of the same content, which extracts everything.
    let search = |method: &'static str, body: Vec<u8>| {
        let app = &app;
        async move {
            json(
                app.post(format!("/v1/search?k=6&method={method}"))
                    .header("content-type", "model/obj")
                    .body(body)
                    .send()
                    .await,
            )
            .await
        }
    };
    for (i, method) in ["d2", "lfd", "geodesic"].into_iter().enumerate() {
        // Trailing blank lines: the same mesh, another upload.
        let fresh = [query.clone(), vec![b'\n'; i + 1]].concat();
        let global = search(method, fresh.clone()).await;
        assert_eq!(global["query_features"], 0, "{method}: no ECC ran");
        let full = search("ecc", fresh.clone()).await;
        assert!(full["query_features"].as_u64().unwrap() > 0);
        let again = search(method, fresh).await;
        assert_eq!(global["results"], again["results"], "{method}");
    }

    // Filtered by tag; and similar-to-stored leaves the model itself out.
    let tips = json(
        app.post("/v1/search?tag=tips")
            .header("content-type", "model/obj")
            .body(query.clone())
            .send()
            .await,
    )
    .await;
    assert!(tips["results"]
        .as_array()
        .unwrap()
        .iter()
        .all(|r| r["tags"][0] == "tips"));
    assert_eq!(tips["results"].as_array().unwrap().len(), 3);
    let similar = json(app.get("/v1/models/star/similar?k=2").send().await).await;
    assert_eq!(similar["results"][0]["id"], "moved");
    assert_eq!(similar["results"].as_array().unwrap().len(), 2);
    let weighted = json(app.get("/v1/models/star/similar?k=2&w=0.9").send().await).await;
    assert_eq!(weighted["results"][0]["id"], "moved");
    // `w` weighs the ECC distance against the region D2 distance: another weight, another
    // distance (the same one would mean `w` was ignored).
    assert_ne!(
        weighted["results"][0]["distance"],
        similar["results"][0]["distance"]
    );
    let by_views = json(
        app.get("/v1/models/star/similar?k=2&method=lfd")
            .send()
            .await,
    )
    .await;
    assert_eq!(by_views["method"], "lfd");
    assert_eq!(by_views["results"][0]["id"], "moved");
    expect_error(
        app.get("/v1/models/nobody/similar").send().await,
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;

    // Extraction without storing.
    let before = json(app.get("/healthz").send().await).await["models"].clone();
    let signature = json(
        app.post("/v1/extract")
            .header("content-type", "model/obj")
            .body(query)
            .send()
            .await,
    )
    .await;
    assert_eq!(signature["features"].as_array().unwrap().len(), 4);
    assert_eq!(
        json(app.get("/healthz").send().await).await["models"],
        before
    );
}

#[apply(stores)]
#[tokio::test]
async fn operations_endpoints(#[case] store: Stores) {
    let app = TestApp::on(store);
    for path in ["/healthz", "/readyz"] {
        let status = json(app.get(path).send().await).await;
        assert_eq!(status["status"], "ok");
    }
    app.add("id=horse", "model/obj", fixture("capod_horse_m155.obj"))
        .await;
    let metrics = app.get("/metrics").send().await.text();
    assert!(metrics.contains("salient_models 1"), "{metrics}");
    assert!(
        metrics.contains(
            "salient_http_requests_total{method=\"POST\",route=\"/v1/models\",status=\"201\"} 1"
        ),
        "{metrics}"
    );
    assert!(metrics.contains("salient_extraction_seconds_count 1"));
    let spec = app.get("/openapi.yaml").send().await.text();
    let committed = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("openapi.yaml"),
    )
    .unwrap();
    assert_eq!(spec, committed);
    let traced = app
        .get("/healthz")
        .header("x-request-id", "abc-123")
        .send()
        .await;
    assert_eq!(traced.headers()["x-request-id"], "abc-123");
    let fresh = app.get("/healthz").send().await;
    assert!(fresh.headers().contains_key("x-request-id"));
}

/// A store whose content index is damaged: every lookup fails with a detail (a path) that is
/// for the server's log only.
struct DamagedStore(InMemoryStore);

const SECRET_DETAIL: &str = "/var/lib/salient/db: checksum mismatch";

impl Store for DamagedStore {
    fn put(&self, r: &ModelRecord, s: &[u8], u: &Upload) -> StoreResult<Option<ModelRecord>> {
        self.0.put(r, s, u)
    }
    fn update_model(&self, r: &ModelRecord, s: &[u8]) -> StoreResult<bool> {
        self.0.update_model(r, s)
    }
    fn get(&self, id: &str) -> StoreResult<Option<ModelRecord>> {
        self.0.get(id)
    }
    fn signature(&self, id: &str) -> StoreResult<Option<Vec<u8>>> {
        self.0.signature(id)
    }
    fn upload(&self, id: &str) -> StoreResult<Option<Upload>> {
        self.0.upload(id)
    }
    fn blob(&self, hash: &str) -> StoreResult<Option<Bytes>> {
        self.0.blob(hash)
    }
    fn delete(&self, id: &str) -> StoreResult<Option<ModelRecord>> {
        self.0.delete(id)
    }
    fn list(&self, after: Option<&str>, limit: usize) -> StoreResult<Vec<ModelRecord>> {
        self.0.list(after, limit)
    }
    fn find_content(&self, _: &str) -> StoreResult<Option<ModelId>> {
        Err(StoreError::Corrupt {
            key: "content".into(),
            message: SECRET_DETAIL.into(),
        })
    }
    fn load_all(&self) -> Box<dyn Iterator<Item = StoreResult<Loaded>> + '_> {
        self.0.load_all()
    }
    fn len(&self) -> usize {
        self.0.len()
    }
    fn derived(&self, cache: Derived, id: &str) -> StoreResult<Option<Vec<u8>>> {
        self.0.derived(cache, id)
    }
    fn put_derived(
        &self,
        cache: Derived,
        id: &str,
        content_hash: &str,
        entry: &[u8],
    ) -> StoreResult<bool> {
        self.0.put_derived(cache, id, content_hash, entry)
    }
    fn all_derived(
        &self,
        cache: Derived,
    ) -> Box<dyn Iterator<Item = StoreResult<(ModelId, Vec<u8>)>> + '_> {
        self.0.all_derived(cache)
    }
    fn state(&self, key: &str) -> StoreResult<Option<Vec<u8>>> {
        self.0.state(key)
    }
    fn set_state(&self, key: &str, value: &[u8]) -> StoreResult<()> {
        self.0.set_state(key, value)
    }
    fn states(&self) -> StoreResult<Vec<(String, Vec<u8>)>> {
        self.0.states()
    }
}

/// An internal error is a 500 in the JSON shape that says what happened in general terms and
/// where to look (the request id); its detail never reaches the client.
#[tokio::test]
async fn internal_errors_say_nothing_of_their_detail() {
    let app = TestApp::build(
        Config::default(),
        Arc::new(DamagedStore(InMemoryStore::new())),
        None,
    );
    let failed = app
        .add("id=horse", "model/obj", fixture("capod_horse_m155.obj"))
        .await;
    expect_error(
        failed.clone(),
        StatusCode::INTERNAL_SERVER_ERROR,
        "internal",
    )
    .await;
    let text = failed.text();
    assert!(
        !text.contains("/var/lib") && !text.contains("checksum"),
        "{text}"
    );
    assert!(failed.json()["error"]["message"]
        .as_str()
        .unwrap()
        .contains("x-request-id"));
    assert!(failed.headers().contains_key("x-request-id"));
}

/// The original files come back byte for byte, with their type, `ETag` and name; a client
/// holding the current copy gets a 304.
/// A body past the spool threshold, raw or in a form, is read through its spool
/// (`salient_server::spool`): stored byte for byte, and extracted as the same mesh sent small.
#[apply(stores)]
#[tokio::test]
async fn a_body_past_the_spool_threshold_is_stored_and_extracted(#[case] store: Stores) {
    let app = TestApp::on(store);
    let horse = fixture("capod_horse_m155.obj");
    let mut padded = vec![b'#'; SPOOL_BYTES];
    padded.push(b'\n');
    padded.extend_from_slice(&horse);
    let added = app.add("id=raw", "model/obj", padded.clone()).await;
    assert_eq!(added.status, StatusCode::CREATED, "{}", added.text());
    let form = Form::new().file("file", "padded.obj", padded.clone());
    let added = app.post("/v1/models?id=form").multipart(form).send().await;
    assert_eq!(added.status, StatusCode::CREATED, "{}", added.text());
    let added = app.add("id=small", "model/obj", horse).await;
    assert_eq!(added.status, StatusCode::CREATED, "{}", added.text());

    let geometry = |mut signature: Value| {
        signature.as_object_mut().unwrap().remove("stats");
        signature
    };
    let small = geometry(app.get_json("/v1/models/small/signature").await);
    for id in ["raw", "form"] {
        let file = app.get(format!("/v1/models/{id}/file")).send().await;
        assert!(file.body == padded, "{id}: the stored file differs");
        let record = app.get_json(&format!("/v1/models/{id}")).await;
        assert_eq!(
            record["content_hash"],
            salient_server::model::sha256_hex(&padded)
        );
        let signature = app.get_json(&format!("/v1/models/{id}/signature")).await;
        assert_eq!(geometry(signature), small, "{id}");
    }
}

/// A spool that cannot be written (its folder gone) is the server's fault, said without the
/// folder's path.
#[tokio::test]
async fn a_spool_that_cannot_be_written_is_a_500_that_names_no_path() {
    let gone = tempfile::tempdir()
        .unwrap()
        .path()
        .join("spool-folder-gone");
    let app = TestApp::with_config(|config| config.shelf_dir = Some(gone));
    let failed = app
        .add("id=big", "model/obj", vec![b'#'; SPOOL_BYTES + 1])
        .await;
    crate::app::expect_error(&failed, StatusCode::INTERNAL_SERVER_ERROR, "internal");
    assert!(
        !failed.text().contains("spool-folder-gone"),
        "{}",
        failed.text()
    );
    // The server keeps serving.
    assert_eq!(app.get("/healthz").send().await.status, StatusCode::OK);
}

#[apply(stores)]
#[tokio::test]
async fn original_files_come_back_byte_for_byte(#[case] store: Stores) {
    let app = TestApp::on(store);
    let horse = fixture("capod_horse_m155.obj");
    assert_eq!(
        app.add("id=horse", "model/obj", horse.clone()).await.status,
        StatusCode::CREATED
    );
    let file = app.get("/v1/models/horse/file").send().await;
    assert_eq!(file.status, StatusCode::OK);
    assert_eq!(file.body, horse);
    assert_eq!(file.headers["content-type"], "model/obj");
    let record = app.get_json("/v1/models/horse").await;
    let etag = format!("\"{}\"", record["mesh_blob"].as_str().unwrap());
    assert_eq!(file.headers["etag"].to_str().unwrap(), etag);
    assert_eq!(
        file.headers["content-disposition"],
        "attachment; filename=\"horse.obj\""
    );
    let again = app
        .get("/v1/models/horse/file")
        .header("if-none-match", &etag)
        .send()
        .await;
    assert_eq!(again.status, StatusCode::NOT_MODIFIED);
    assert!(again.body.is_empty());

    // A multi-file glTF: the document and its buffer, each as uploaded.
    let form = Form::new()
        .file("file", "tetra.gltf", fixture("gltf_external/tetra.gltf"))
        .file("file", "tetra.bin", fixture("gltf_external/tetra.bin"))
        .text("id", "tetra");
    let created = app.post("/v1/models").multipart(form).send().await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    let document = app.get("/v1/models/tetra/file").send().await;
    assert_eq!(document.body, fixture("gltf_external/tetra.gltf"));
    assert_eq!(document.headers["content-type"], "model/gltf+json");
    let buffer = app.get("/v1/models/tetra/files/tetra.bin").send().await;
    assert_eq!(buffer.status, StatusCode::OK);
    assert_eq!(buffer.body, fixture("gltf_external/tetra.bin"));
    expect_error(
        app.get("/v1/models/tetra/files/other.bin").send().await,
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
    expect_error(
        app.get("/v1/models/nobody/file").send().await,
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
}

/// Name, tags and class change without re-extraction; a bad patch is a 400.
/// How many extractions the service has run, from `/metrics`.
async fn extractions(app: &TestApp) -> u64 {
    let metrics = app.get("/metrics").send().await.text();
    metrics
        .lines()
        .find_map(|l| l.strip_prefix("salient_extraction_seconds_count "))
        .expect("the extraction histogram is exported")
        .parse()
        .unwrap()
}

/// A search's query is checked before its upload is extracted: a bad `k` or `w` costs no
/// extraction.
#[apply(stores)]
#[tokio::test]
async fn a_bad_search_query_is_refused_before_any_extraction(#[case] store: Stores) {
    let app = TestApp::on(store);
    let horse = fixture("capod_horse_m155.obj");
    let search = |query: &str| {
        app.post(format!("/v1/search?{query}"))
            .header("content-type", "model/obj")
            .body(horse.clone())
            .send()
    };
    for query in ["k=0", "k=1000000", "w=2", "w=-0.5", "method=ecc&k=0"] {
        expect_error(
            search(query).await,
            StatusCode::BAD_REQUEST,
            "invalid_query",
        )
        .await;
        assert_eq!(extractions(&app).await, 0, "{query}");
    }
    assert_eq!(search("k=3").await.status, StatusCode::OK);
    assert_eq!(extractions(&app).await, 1);
}

#[apply(stores)]
#[tokio::test]
async fn a_patch_edits_fields_without_re_extracting(#[case] store: Stores) {
    let app = TestApp::on(store);
    let added = app
        .add(
            "id=horse&name=Horse&tags=animal",
            "model/obj",
            fixture("capod_horse_m155.obj"),
        )
        .await
        .json();
    let signature = app.get_json("/v1/models/horse/signature").await;
    let before = extractions(&app).await;
    let patched = app
        .request_with_method("PATCH", "/v1/models/horse")
        .header("content-type", "application/json")
        .body(r#"{"tags": ["animal", " capod ", ""], "class": "horse", "name": null}"#)
        .send()
        .await;
    assert_eq!(patched.status, StatusCode::OK, "{}", patched.text());
    let patched = patched.json();
    assert_eq!(patched["tags"], serde_json::json!(["animal", "capod"]));
    assert_eq!(patched["class"], "horse");
    assert!(patched["name"].is_null());
    assert_eq!(patched["content_hash"], added["content_hash"]);
    assert_eq!(app.get_json("/v1/models/horse").await, patched);
    assert_eq!(app.get_json("/v1/models/horse/signature").await, signature);
    assert_eq!(extractions(&app).await, before, "nothing was re-extracted");
    let tagged = app.get_json("/v1/models?tag=capod").await;
    assert_eq!(tagged["models"][0]["id"], "horse");

    let patch = |body: &'static str| {
        app.request_with_method("PATCH", "/v1/models/horse")
            .header("content-type", "application/json")
            .body(body)
            .send()
    };
    expect_error(
        patch(r#"{"colour": "red"}"#).await,
        StatusCode::BAD_REQUEST,
        "invalid_json",
    )
    .await;
    expect_error(
        patch(r#"{"tags": "a,b"}"#).await,
        StatusCode::BAD_REQUEST,
        "invalid_json",
    )
    .await;
    expect_error(
        app.request_with_method("PATCH", "/v1/models/nobody")
            .header("content-type", "application/json")
            .body("{}")
            .send()
            .await,
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
}

/// The index's entry is made before the store is written: when its shelf cannot be written,
/// the upload fails with an internal error that names no path, and nothing is stored.
#[tokio::test]
async fn an_unwritable_index_shelf_fails_the_upload_and_stores_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing");
    let store = Arc::new(InMemoryStore::new());
    let config = Config {
        shelf_dir: Some(missing.clone()),
        ..Config::default()
    };
    let app = TestApp::build(config, store.clone(), None);
    let response = app
        .add("id=horse", "model/obj", fixture("capod_horse_m155.obj"))
        .await;
    assert!(!response.text().contains(missing.to_str().unwrap()));
    expect_error(response, StatusCode::INTERNAL_SERVER_ERROR, "internal").await;
    assert!(store.is_empty());
    assert!(app.listed_ids().await.is_empty());
}

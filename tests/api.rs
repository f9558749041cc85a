//! The HTTP service end to end: the real binary on a loopback port, real meshes, every
//! endpoint and every error status (SPEC §8, `openapi.yaml`).

mod server;
mod shapes;

use reqwest::{Client, Response, StatusCode};
use serde_json::Value;
use server::{fixture, obj, Server};

async fn json(response: Response) -> Value {
    response.json().await.expect("a JSON body")
}

/// Asserts an error response: status, the JSON error shape, and its code.
async fn expect_error(response: Response, status: StatusCode, code: &str) {
    assert_eq!(response.status(), status, "{:?}", response.url().path());
    let body = json(response).await;
    assert_eq!(body["error"]["code"], code, "{body}");
    assert!(body["error"]["message"]
        .as_str()
        .is_some_and(|m| !m.is_empty()));
}

async fn add(
    client: &Client,
    server: &Server,
    query: &str,
    content_type: &str,
    body: Vec<u8>,
) -> Response {
    client
        .post(server.at(&format!("/v1/models?{query}")))
        .header("content-type", content_type)
        .body(body)
        .send()
        .await
        .unwrap()
}

#[tokio::test]
async fn models_can_be_added_listed_read_replaced_and_deleted() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("store"), &[]);
    let client = Client::new();

    let horse = fixture("capod_horse_m155.obj");
    let created = add(
        &client,
        &server,
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
    let again = add(
        &client,
        &server,
        "id=horse&name=Horse&tags=animal,capod&class=horse",
        "model/obj",
        horse.clone(),
    )
    .await;
    assert_eq!(again.status(), StatusCode::OK);
    assert_eq!(json(again).await, record);
    let star = obj(&shapes::star(3, &shapes::five_tips()));
    let replaced = add(
        &client,
        &server,
        "id=horse&name=Star",
        "model/obj",
        star.clone(),
    )
    .await;
    assert_eq!(replaced.status(), StatusCode::OK);
    let replaced = json(replaced).await;
    assert_eq!(replaced["name"], "Star");
    assert_eq!(replaced["created_unix"], record["created_unix"]);
    assert_ne!(replaced["content_hash"], record["content_hash"]);

    // Without an id: the id comes from the content hash, and identical content is found.
    let glb = fixture("capod_horse_m155_split.glb");
    let anonymous = json(
        add(
            &client,
            &server,
            "tags=split",
            "model/gltf-binary",
            glb.clone(),
        )
        .await,
    )
    .await;
    let id = anonymous["id"].as_str().unwrap().to_string();
    assert_eq!(id.len(), 16);
    let found = add(&client, &server, "", "application/octet-stream", glb).await;
    assert_eq!(found.status(), StatusCode::OK);
    assert_eq!(json(found).await["id"], id.as_str());

    let third = json(
        add(
            &client,
            &server,
            "id=cone&class=cone&tags=capod",
            "model/obj",
            obj(&shapes::cone(0.5, 30, 32)),
        )
        .await,
    )
    .await;
    assert_eq!(third["class"], "cone");

    // Listing: id order, pages, filters.
    let page = json(
        client
            .get(server.at("/v1/models?limit=2"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    let ids: Vec<&str> = page["models"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids.len(), 2);
    let next = page["next"].as_str().unwrap();
    let rest = json(
        client
            .get(server.at(&format!("/v1/models?limit=2&after={next}")))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(rest["models"].as_array().unwrap().len(), 1);
    assert!(rest["next"].is_null());
    let tagged = json(
        client
            .get(server.at("/v1/models?tag=capod"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(tagged["models"].as_array().unwrap().len(), 1);
    let by_class = json(
        client
            .get(server.at("/v1/models?class=cone"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(by_class["models"][0]["id"], "cone");
    let hash = anonymous["content_hash"].as_str().unwrap();
    let by_hash = json(
        client
            .get(server.at(&format!("/v1/models?content_hash={hash}")))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(by_hash["models"][0]["id"], id.as_str());

    // One model, its signature.
    let one = json(
        client
            .get(server.at("/v1/models/cone"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(one, third);
    let signature = json(
        client
            .get(server.at("/v1/models/cone/signature"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(
        signature["features"].as_array().unwrap().len() as u64,
        third["features"].as_u64().unwrap()
    );
    assert_eq!(signature["params"]["ecc"]["waves"], 10);

    // Delete.
    let deleted = client
        .delete(server.at("/v1/models/cone"))
        .send()
        .await
        .unwrap();
    assert_eq!(deleted.status(), StatusCode::NO_CONTENT);
    expect_error(
        client
            .get(server.at("/v1/models/cone"))
            .send()
            .await
            .unwrap(),
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
    expect_error(
        client
            .delete(server.at("/v1/models/cone"))
            .send()
            .await
            .unwrap(),
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
    expect_error(
        client
            .get(server.at("/v1/models/cone/signature"))
            .send()
            .await
            .unwrap(),
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;
    let health = json(client.get(server.at("/healthz")).send().await.unwrap()).await;
    assert_eq!(health["models"], 2);
}

#[tokio::test]
async fn multipart_uploads_carry_gltf_resources_and_fields() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("store"), &[]);
    let client = Client::new();
    let form = || {
        reqwest::multipart::Form::new()
            .part(
                "file",
                reqwest::multipart::Part::bytes(fixture("gltf_external/tetra.gltf"))
                    .file_name("tetra.gltf"),
            )
            .part(
                "file",
                reqwest::multipart::Part::bytes(fixture("gltf_external/tetra.bin"))
                    .file_name("tetra.bin"),
            )
            .text("id", "tetra")
            .text("tags", "solid, small")
    };
    let created = client
        .post(server.at("/v1/models"))
        .multipart(form())
        .send()
        .await
        .unwrap();
    assert_eq!(created.status(), StatusCode::CREATED);
    let record = json(created).await;
    assert_eq!(record["format"], "gltf");
    assert_eq!(record["tags"], serde_json::json!(["solid", "small"]));
    assert!(record["resources"]["tetra.bin"].is_string());

    // Without its buffer the glTF cannot be read.
    let alone = reqwest::multipart::Form::new().part(
        "file",
        reqwest::multipart::Part::bytes(fixture("gltf_external/tetra.gltf"))
            .file_name("tetra.gltf"),
    );
    expect_error(
        client
            .post(server.at("/v1/models"))
            .multipart(alone)
            .send()
            .await
            .unwrap(),
        StatusCode::BAD_REQUEST,
        "bad_mesh",
    )
    .await;
    let empty = reqwest::multipart::Form::new().text("id", "nothing");
    expect_error(
        client
            .post(server.at("/v1/models"))
            .multipart(empty)
            .send()
            .await
            .unwrap(),
        StatusCode::BAD_REQUEST,
        "empty_body",
    )
    .await;
}

#[tokio::test]
async fn bad_input_gets_the_right_status_and_the_server_keeps_serving() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(
        &dir.path().join("store"),
        &["--max-body-bytes", "200000", "--max-vertices", "5000"],
    );
    let client = Client::new();
    let horse = fixture("capod_horse_m155.obj");

    let big = vec![b'#'; 300_000];
    expect_error(
        add(&client, &server, "id=big", "model/obj", big).await,
        StatusCode::PAYLOAD_TOO_LARGE,
        "payload_too_large",
    )
    .await;
    let many = obj(&shapes::icosphere(4)); // 2 562 vertices, over --max-vertices
    expect_error(
        add(&client, &server, "id=many", "model/obj", many).await,
        StatusCode::PAYLOAD_TOO_LARGE,
        "payload_too_large",
    )
    .await;
    expect_error(
        add(
            &client,
            &server,
            "id=json",
            "application/json",
            b"{}".to_vec(),
        )
        .await,
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
        "unsupported_format",
    )
    .await;
    expect_error(
        add(
            &client,
            &server,
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
        add(
            &client,
            &server,
            "id=x&format=fbx",
            "application/octet-stream",
            horse.clone(),
        )
        .await,
        StatusCode::UNSUPPORTED_MEDIA_TYPE,
        "unsupported_format",
    )
    .await;
    expect_error(
        add(
            &client,
            &server,
            "id=corrupt",
            "model/obj",
            b"v 0 0 0\nf 1 2 7\n".to_vec(),
        )
        .await,
        StatusCode::BAD_REQUEST,
        "bad_mesh",
    )
    .await;
    expect_error(
        add(
            &client,
            &server,
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
        add(
            &client,
            &server,
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
        add(
            &client,
            &server,
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
        add(&client, &server, "id=empty", "model/obj", Vec::new()).await,
        StatusCode::BAD_REQUEST,
        "empty_body",
    )
    .await;
    for id in ["..", ".hidden", "a%2Fb", "a%20b", &"x".repeat(129)] {
        expect_error(
            add(
                &client,
                &server,
                &format!("id={id}"),
                "model/obj",
                horse.clone(),
            )
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
            client.get(server.at(path)).send().await.unwrap(),
            StatusCode::BAD_REQUEST,
            "invalid_id",
        )
        .await;
    }
    expect_error(
        client
            .get(server.at("/v1/models?limit=abc"))
            .send()
            .await
            .unwrap(),
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    expect_error(
        client
            .get(server.at("/v1/models?limit=0"))
            .send()
            .await
            .unwrap(),
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    let search = |query: &'static str| {
        client
            .post(server.at(&format!("/v1/search?{query}")))
            .header("content-type", "model/obj")
            .body(horse.clone())
            .send()
    };
    expect_error(
        search("k=0").await.unwrap(),
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    expect_error(
        search("k=-3").await.unwrap(),
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    expect_error(
        search("method=sh").await.unwrap(),
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    expect_error(
        search("w=2").await.unwrap(),
        StatusCode::BAD_REQUEST,
        "invalid_query",
    )
    .await;
    expect_error(
        client.get(server.at("/v1/nothing")).send().await.unwrap(),
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;

    // Still serving, and nothing bad was stored.
    assert_eq!(
        add(&client, &server, "id=horse", "model/obj", horse)
            .await
            .status(),
        StatusCode::CREATED
    );
    let all = json(client.get(server.at("/v1/models")).send().await.unwrap()).await;
    assert_eq!(all["models"].as_array().unwrap().len(), 1);
}

#[tokio::test]
async fn search_similar_and_extract() {
    let dir = tempfile::tempdir().unwrap();
    let collection = dir.path().join("collection");
    std::fs::create_dir_all(&collection).unwrap();
    let server = Server::start(&dir.path().join("store"), &[]);
    let client = Client::new();
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
        let status = add(
            &client,
            &server,
            &format!("id={id}&tags={tag}"),
            "model/obj",
            bytes.clone(),
        )
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
        let response = client
            .post(server.at(&format!("/v1/search?k=6&method={method}")))
            .header("content-type", "model/obj")
            .body(query.clone())
            .send()
            .await
            .unwrap();
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
        assert!(
            ranked["timings"]["total_ms"].as_f64().unwrap()
                >= ranked["timings"]["search_ms"].as_f64().unwrap()
        );

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

    // Filtered by tag; and similar-to-stored leaves the model itself out.
    let tips = json(
        client
            .post(server.at("/v1/search?tag=tips"))
            .header("content-type", "model/obj")
            .body(query.clone())
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert!(tips["results"]
        .as_array()
        .unwrap()
        .iter()
        .all(|r| r["tags"][0] == "tips"));
    assert_eq!(tips["results"].as_array().unwrap().len(), 3);
    let similar = json(
        client
            .get(server.at("/v1/models/star/similar?k=2"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(similar["results"][0]["id"], "moved");
    assert_eq!(similar["results"].as_array().unwrap().len(), 2);
    let weighted = json(
        client
            .get(server.at("/v1/models/star/similar?k=2&w=0.9"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(weighted["results"][0]["id"], "moved");
    let by_views = json(
        client
            .get(server.at("/v1/models/star/similar?k=2&method=lfd"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(by_views["method"], "lfd");
    assert_eq!(by_views["results"][0]["id"], "moved");
    expect_error(
        client
            .get(server.at("/v1/models/nobody/similar"))
            .send()
            .await
            .unwrap(),
        StatusCode::NOT_FOUND,
        "not_found",
    )
    .await;

    // Extraction without storing.
    let before =
        json(client.get(server.at("/healthz")).send().await.unwrap()).await["models"].clone();
    let signature = json(
        client
            .post(server.at("/v1/extract"))
            .header("content-type", "model/obj")
            .body(query)
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(signature["features"].as_array().unwrap().len(), 4);
    assert_eq!(
        json(client.get(server.at("/healthz")).send().await.unwrap()).await["models"],
        before
    );
}

/// A model stored before signatures carried the light field descriptor (format 1) is left
/// out of `lfd` rankings, and asking for its `lfd` neighbours is a 409 that names the fix,
/// `salient reindex`, which works.
#[tokio::test]
async fn models_stored_without_a_light_field_descriptor() {
    use salient::store::{SledStore, Store};
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("store");
    let client = Client::new();
    let mut server = Server::start(&data, &[]);
    for (id, mesh) in [
        ("old", shapes::star(3, &shapes::five_tips())),
        ("new", shapes::cone(0.5, 20, 24)),
    ] {
        let response = add(
            &client,
            &server,
            &format!("id={id}"),
            "model/obj",
            obj(&mesh),
        )
        .await;
        assert_eq!(response.status(), StatusCode::CREATED);
    }
    server.kill();
    {
        let store = SledStore::open(&data).unwrap();
        let record = store.get("old").unwrap().unwrap();
        let upload = store.upload("old").unwrap().unwrap();
        let mut signature =
            salient::Signature::from_bytes(&store.signature("old").unwrap().unwrap()).unwrap();
        signature.lfd = None;
        // Format 1 is format 2 without the trailing descriptor (here `None`, one byte).
        let mut bytes = signature.to_bytes();
        bytes[4..6].copy_from_slice(&1u16.to_le_bytes());
        bytes.pop();
        store.put(&record, &bytes, &upload).unwrap();
    }
    let server = Server::start(&data, &[]);
    assert!(
        server.log().contains("light field descriptor"),
        "{}",
        server.log()
    );
    let ranked = json(
        client
            .get(server.at("/v1/models/new/similar?method=lfd"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(ranked["results"].as_array().unwrap().len(), 0, "{ranked}");
    let ranked = json(
        client
            .get(server.at("/v1/models/new/similar?method=ecc"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(ranked["results"][0]["id"], "old");
    expect_error(
        client
            .get(server.at("/v1/models/old/similar?method=lfd"))
            .send()
            .await
            .unwrap(),
        StatusCode::CONFLICT,
        "missing_descriptor",
    )
    .await;

    // The fix the message names: `salient reindex` gives every model its descriptor.
    let mut server = server;
    server.kill();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_salient"))
        .args(["reindex", "--data", data.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let server = Server::start(&data, &[]);
    let ranked = json(
        client
            .get(server.at("/v1/models/old/similar?method=lfd"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(ranked["results"][0]["id"], "new", "{ranked}");
}

#[tokio::test]
async fn operations_endpoints() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("store"), &[]);
    let client = Client::new();
    for path in ["/healthz", "/readyz"] {
        let status = json(client.get(server.at(path)).send().await.unwrap()).await;
        assert_eq!(status["status"], "ok");
    }
    add(
        &client,
        &server,
        "id=horse",
        "model/obj",
        fixture("capod_horse_m155.obj"),
    )
    .await;
    let metrics = client
        .get(server.at("/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(metrics.contains("salient_models 1"), "{metrics}");
    assert!(
        metrics.contains(
            "salient_http_requests_total{method=\"POST\",route=\"/v1/models\",status=\"201\"} 1"
        ),
        "{metrics}"
    );
    assert!(metrics.contains("salient_extraction_seconds_count 1"));
    let spec = client
        .get(server.at("/openapi.yaml"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    let committed = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("openapi.yaml"),
    )
    .unwrap();
    assert_eq!(spec, committed);
    let traced = client
        .get(server.at("/healthz"))
        .header("x-request-id", "abc-123")
        .send()
        .await
        .unwrap();
    assert_eq!(traced.headers()["x-request-id"], "abc-123");
    let fresh = client.get(server.at("/healthz")).send().await.unwrap();
    assert!(fresh.headers().contains_key("x-request-id"));
}

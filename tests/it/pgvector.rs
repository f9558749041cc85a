//! The first stage in PostgreSQL (`--index pgvector`, #40): on a catalogue the oversampling
//! covers, the same rankings as the exact in-memory index, said to be approximate; filters,
//! the model itself left out, deletes and edits honoured; nothing per model in the replica's
//! memory, and every search served there or refused clearly.

use std::sync::Arc;

use axum::http::StatusCode;
use salient_core::Signature;
use salient_server::api::config::FirstStageKind;
use salient_server::api::{first_stage, App, Config};
use salient_server::store::{PostgresStore, Store};
use serde_json::{json, Value};

use crate::app::TestApp;
use crate::server::obj;
use crate::shapes;
use crate::stores::fresh_database_url;

/// A service on `url` whose first stage runs where `index` says, as `salient serve` opens it.
fn service(url: &str, index: FirstStageKind) -> TestApp {
    let config = Config {
        index,
        ..Config::default()
    };
    let store = first_stage::open_store(url, &config).expect("the test database opens");
    TestApp::serving(App::new(config, Arc::new(store)).expect("the service starts"))
}

/// Tubes, cones and stars, tagged by kind.
fn catalogue() -> Vec<(String, &'static str, Vec<u8>)> {
    let mut models = Vec::new();
    for (i, r) in [0.15, 0.2, 0.3, 0.4].into_iter().enumerate() {
        models.push((format!("tube{i}"), "tube", obj(&shapes::tube(r, 20, 16))));
    }
    for (i, beta) in [0.5, 0.8, 1.1].into_iter().enumerate() {
        models.push((format!("cone{i}"), "cone", obj(&shapes::cone(beta, 12, 24))));
    }
    models.push((
        "star".into(),
        "star",
        obj(&shapes::star(2, &shapes::five_tips())),
    ));
    models
}

async fn ranked(app: &TestApp, path: &str) -> Value {
    let response = app.get(path).send().await;
    assert_eq!(response.status(), StatusCode::OK, "{path}");
    response.json()
}

fn ids(body: &Value) -> Vec<(String, f64)> {
    body["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            (
                r["id"].as_str().unwrap().to_string(),
                r["distance"].as_f64().unwrap(),
            )
        })
        .collect()
}

postgres_only! {
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn the_first_stage_in_postgres_ranks_as_the_exact_index_where_it_covers_the_catalogue() {
        let url = fresh_database_url();
        let approximate = service(&url, FirstStageKind::Pgvector);
        for (id, tag, bytes) in catalogue() {
            let response = approximate.add(&format!("id={id}&tags={tag}"), "model/obj", bytes).await;
            assert_eq!(response.status(), StatusCode::CREATED, "{id}");
        }
        // A replica started later on the same database, exact.
        let exact = service(&url, FirstStageKind::Memory);
        for path in [
            "/v1/models/tube1/similar?k=5",
            "/v1/models/cone0/similar?k=7",
            "/v1/models/tube0/similar?k=3&tag=cone",
        ] {
            let (a, e) = (ranked(&approximate, path).await, ranked(&exact, path).await);
            assert_eq!(a["approximate"], true, "{path}");
            assert_eq!(e["approximate"], false, "{path}");
            assert_eq!(ids(&a), ids(&e), "{path}");
        }
        // A model written by the exact replica is in the first stage too.
        let response = exact.add("id=late&tags=cone", "model/obj", obj(&shapes::cone(0.9, 12, 24))).await;
        assert_eq!(response.status(), StatusCode::CREATED);
        let late = ids(&ranked(&approximate, "/v1/models/cone0/similar?k=10").await);
        assert!(late.iter().any(|(id, _)| id == "late"), "{late:?}");
        let deleted = exact.delete("/v1/models/late").send().await;
        assert_eq!(deleted.status(), StatusCode::NO_CONTENT);

        let cones = ids(&ranked(&approximate, "/v1/models/tube0/similar?k=10&tag=cone").await);
        assert_eq!(cones.len(), 3);
        assert!(cones.iter().all(|(id, _)| id.starts_with("cone")), "{cones:?}");
        let all = ids(&ranked(&approximate, "/v1/models/star/similar?k=10").await);
        assert_eq!(all.len(), 7, "every other model, itself left out: {all:?}");
        // Other methods and weights rank the first stage's candidates too.
        for path in ["/v1/models/star/similar?method=d2", "/v1/models/tube1/similar?w=0.3"] {
            let (a, e) = (ranked(&approximate, path).await, ranked(&exact, path).await);
            assert_eq!((&a["approximate"], &e["approximate"]), (&json!(true), &json!(false)));
            assert_eq!(ids(&a), ids(&e), "{path}");
        }

        // A deleted model leaves the first stage; an edited tag moves a model's filter.
        let deleted = approximate.delete("/v1/models/cone1").send().await;
        assert_eq!(deleted.status(), StatusCode::NO_CONTENT);
        let edited = approximate
            .request_with_method("PATCH", "/v1/models/tube3")
            .header("content-type", "application/json")
            .body(r#"{"tags": ["cone"]}"#)
            .send()
            .await;
        assert_eq!(edited.status(), StatusCode::OK);
        let mut cones: Vec<String> = ids(&ranked(&approximate, "/v1/models/tube0/similar?k=10&tag=cone").await)
            .into_iter()
            .map(|(id, _)| id)
            .collect();
        cones.sort();
        assert_eq!(cones, ["cone0", "cone2", "tube3"]);

        // A tag's rows can be read through the tags' index, without a scan of the table (what
        // the planner takes for a rare tag of a large catalogue).
        let (client, connection) = tokio_postgres::connect(&url, tokio_postgres::NoTls)
            .await
            .unwrap();
        tokio::spawn(connection);
        client.batch_execute("SET enable_seqscan = off").await.unwrap();
        let plan: Vec<String> = client
            .query("EXPLAIN SELECT id FROM model_vectors WHERE tags @> ARRAY['cone']", &[])
            .await
            .unwrap()
            .iter()
            .map(|row| row.get(0))
            .collect();
        assert!(plan.iter().any(|line| line.contains("model_vectors_tags")), "{plan:?}");
    }
}

postgres_only! {
    /// Vectors made for other weights are made again when a replica opens the first stage; a
    /// stale model has none, is left out of rankings (and counted so) and cannot be asked
    /// about until re-extracted; a replica without the first stage cannot serve
    /// `index = "pgvector"`.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn the_first_stage_is_made_again_for_other_weights_and_required_by_its_mode() {
        let url = fresh_database_url();
        {
            let app = service(&url, FirstStageKind::Pgvector);
            let response = app.add("id=m", "model/obj", obj(&shapes::tube(0.3, 20, 16))).await;
            assert_eq!(response.status(), StatusCode::CREATED);
        }
        let client = || async {
            let (client, connection) = tokio_postgres::connect(&url, tokio_postgres::NoTls)
                .await
                .unwrap();
            tokio::spawn(connection);
            client
        };
        // The one model's row: the weights it was made for, and whether it has a vector, a
        // compact form and a light field.
        let kept = || async {
            let row = client()
                .await
                .query_one(
                    "SELECT made_for, v IS NOT NULL AND compact IS NOT NULL AND light_field IS NOT NULL \
                     FROM model_vectors",
                    &[],
                )
                .await
                .unwrap();
            (row.get::<_, String>(0), row.get::<_, bool>(1))
        };
        let mut params = salient_core::Params::default();
        assert_eq!(kept().await, (first_stage::spec(&params).key, true));
        // The table as the first release made it: no compact forms nor light fields, its key
        // without the form's version. Made again when a replica opens it.
        let first_release = serde_json::to_string(&(
            params.similarity.ecc_weight,
            &params.similarity.hybrid,
        ))
        .unwrap();
        client()
            .await
            .batch_execute(&format!(
                "ALTER TABLE model_vectors DROP COLUMN compact, DROP COLUMN light_field; \
                 UPDATE model_vectors SET made_for = '{first_release}'"
            ))
            .await
            .unwrap();
        drop(service(&url, FirstStageKind::Pgvector));
        assert_eq!(kept().await, (first_stage::spec(&params).key, true));
        params.similarity.hybrid.lfd.weight *= 2.0;
        let spec = first_stage::spec(&params);
        let mut other_w = params.clone();
        other_w.similarity.ecc_weight /= 2.0;
        assert_ne!(first_stage::spec(&other_w).key, spec.key, "the vectors depend on W too");
        let store = PostgresStore::open(&url).unwrap().with_first_stage(spec.clone()).unwrap();
        assert_eq!(kept().await, (spec.key.clone(), true));

        // A model stored before a descriptor existed has no vector: left out of the first
        // stage, which says so, and not a query until it is re-extracted.
        let record = store.get("m").unwrap().unwrap();
        let mut signature = Signature::from_bytes(&store.signature("m").unwrap().unwrap()).unwrap();
        signature.geodesic = None;
        assert!(store.update_model(&record, &signature.to_bytes()).unwrap());
        assert_eq!(kept().await, (spec.key.clone(), false));
        drop(store);
        let app = service(&url, FirstStageKind::Pgvector);
        let response = app.get("/v1/models/m/similar").send().await;
        assert_eq!(response.status(), StatusCode::CONFLICT);
        let body: Value = response.json();
        assert!(body["error"]["message"].as_str().unwrap().contains("reindex"), "{body}");
        let response = app.post("/v1/search").header("content-type", "model/obj").body(obj(&shapes::tube(0.3, 20, 16))).send().await;
        assert_eq!(response.status(), StatusCode::OK);
        let body: Value = response.json();
        assert_eq!((body["results"].as_array().unwrap().len(), &body["left_out"]), (0, &json!(1)), "{body}");

        let config = Config {
            index: FirstStageKind::Pgvector,
            ..Config::default()
        };
        let plain = PostgresStore::open(&url).unwrap();
        let refused = App::new(config, Arc::new(plain)).err().expect("refused");
        assert!(refused.to_string().contains("--index pgvector"), "{refused}");
    }
}

postgres_only! {
    /// A replica with its first stage in the database keeps no row per model, and serves
    /// from there a partial search (among the models the patches name) and a duplicate check
    /// as the exact replica does on a small catalogue; duplicate groups, which compare every
    /// model with every other, it refuses and says where to ask.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_replica_with_its_first_stage_in_the_database_keeps_no_rows_and_serves_parts_and_duplicates() {
        let url = fresh_database_url();
        let lean = service(&url, FirstStageKind::Pgvector);
        for (id, mesh) in crate::partial::collection() {
            let response = lean.add(&format!("id={id}"), "model/obj", obj(&mesh)).await;
            assert_eq!(response.status(), StatusCode::CREATED, "{id}");
        }
        let mut pending = lean.app.patches_pending();
        lean.app.start_background();
        pending.wait_for(|p| *p == Some(0)).await.unwrap();
        let exact = service(&url, FirstStageKind::Memory);
        assert_eq!((lean.app.rows_in_memory(), exact.app.rows_in_memory()), (0, 4));

        /// The response of an upload posted to `path` on `app`, which must answer 200.
        async fn posted(app: &TestApp, path: &str, body: Vec<u8>) -> Value {
            let response = app.post(path).header("content-type", "model/obj").body(body).send().await;
            assert_eq!(response.status(), StatusCode::OK, "{path}");
            response.json()
        }
        let part = obj(&crate::partial::spike());
        let path = "/v1/search?mode=partial&k=3";
        let (a, e) = (posted(&lean, path, part.clone()).await, posted(&exact, path, part).await);
        assert_eq!((&a["approximate"], &e["approximate"]), (&json!(true), &json!(false)));
        assert_eq!(a["results"][0]["id"], "star", "{a}");
        assert_eq!(ids(&a), ids(&e));

        let copy = obj(&crate::duplicates::rescaled(&shapes::tube(0.3, 30, 24)));
        let path = "/v1/duplicates/check";
        let (a, e) = (posted(&lean, path, copy.clone()).await, posted(&exact, path, copy).await);
        assert_eq!(a["matches"][0]["id"], "tube", "{a}");
        assert_eq!(a["matches"], e["matches"]);

        let groups = lean.get("/v1/duplicates").send().await;
        assert_eq!(groups.status(), StatusCode::CONFLICT);
        let body: Value = groups.json();
        assert_eq!(body["error"]["code"], "not_configured");
        assert!(body["error"]["message"].as_str().unwrap().contains("--index memory"), "{body}");
        assert_eq!(exact.get("/v1/duplicates").send().await.status(), StatusCode::OK);
    }
}

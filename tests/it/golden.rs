//! Stored data written by release 0.1.0 (`tests/fixtures/golden/release-0.1.0`, never
//! rewritten) opens in this release: the store migrates at open, every model is listed, its
//! record and signature are served as that release served them, and `similar` answers with
//! the same ranking; its signature files decode.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use axum::http::StatusCode;
use salient_core::signature::{Signature, Staleness, SIGNATURE_FORMAT};
use salient_server::api::Config;
use salient_server::store::{Derived, SledStore, Store};
use serde_json::Value;

use crate::app::TestApp;

pub fn golden() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/golden/release-0.1.0")
}

fn expected(name: &str) -> Value {
    let path = golden().join("expected").join(name);
    serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap()
}

/// A writable copy of the golden store (sled writes at open).
pub fn golden_store(into: &Path) -> SledStore {
    copy_dir(&golden().join("store"), into);
    SledStore::open(into).expect("the release-0.1.0 store opens")
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

/// Every field `old` has, `new` has with the same value; `new` may have more (fields added
/// since take their defaults), arrays keep their length.
pub fn assert_contains(old: &Value, new: &Value, at: &str) {
    match (old, new) {
        (Value::Object(old), Value::Object(new)) => {
            for (key, value) in old {
                let field = new.get(key).unwrap_or_else(|| panic!("{at}.{key} is gone"));
                assert_contains(value, field, &format!("{at}.{key}"));
            }
        }
        (Value::Array(old), Value::Array(new)) => {
            assert_eq!(old.len(), new.len(), "{at}: length");
            for (i, (a, b)) in old.iter().zip(new).enumerate() {
                assert_contains(a, b, &format!("{at}[{i}]"));
            }
        }
        _ => assert_eq!(old, new, "{at}"),
    }
}

#[test]
fn release_0_1_0_signature_files_read_as_they_were_written() {
    for id in ["horse", "tetra"] {
        let bytes = std::fs::read(golden().join(format!("{id}.sig"))).unwrap();
        assert_eq!(Signature::format_of(&bytes), Some(2));
        let signature = Signature::from_bytes(&bytes).unwrap();
        // Through text, as the service serves it (single-precision bins print as such).
        let json = serde_json::from_str(&serde_json::to_string(&signature).unwrap()).unwrap();
        assert_contains(&expected(&format!("{id}.signature.json")), &json, id);
        // Made by the 0.1.0 extraction: stale now, never silently current.
        assert_eq!(
            signature.staleness(&salient_core::Params::default()),
            Some(Staleness::Parameters)
        );
        // Written again in today's format, it reads back the same.
        let today = signature.to_bytes();
        assert_eq!(Signature::format_of(&today), Some(SIGNATURE_FORMAT));
        assert_eq!(Signature::from_bytes(&today).unwrap(), signature);
    }
}

#[tokio::test]
async fn release_0_1_0_store_opens_lists_serves_and_ranks() {
    let dir = tempfile::tempdir().unwrap();
    let store = golden_store(&dir.path().join("store"));
    assert_eq!(SledStore::stored_version(store.db()).unwrap(), 5);
    for loaded in store.load_all() {
        let loaded = loaded.unwrap();
        assert_eq!(
            Signature::format_of(&loaded.signature),
            Some(SIGNATURE_FORMAT),
            "{} migrated",
            loaded.record.id
        );
    }
    let config = Config {
        reindex_on_start: false,
        ..Config::default()
    };
    let store = Arc::new(store);
    let app = TestApp::build(config, store.clone(), None);
    assert_eq!(app.app.stale_count(), 3);

    let list = app.get_json("/v1/models?limit=1000").await;
    assert_contains(&expected("list.json"), &list, "list");
    for id in ["horse", "horse-split", "tetra"] {
        let record = app.get_json(&format!("/v1/models/{id}")).await;
        assert_contains(&expected(&format!("{id}.record.json")), &record, id);
        let signature = app.get_json(&format!("/v1/models/{id}/signature")).await;
        assert_contains(&expected(&format!("{id}.signature.json")), &signature, id);
        // Pictures of models stored before previews existed, from their stale signatures.
        for picture in ["thumbnail.png?features=true", "preview.glb"] {
            let response = app.get(format!("/v1/models/{id}/{picture}")).send().await;
            assert_eq!(response.status(), StatusCode::OK, "{id} {picture}");
            assert!(!response.body.is_empty());
        }
    }
    for method in ["ecc", "d2", "lfd"] {
        let ranked = app
            .get_json(&format!("/v1/models/horse/similar?method={method}"))
            .await;
        let old = expected(&format!("horse.similar-{method}.json"));
        let hits = |v: &Value| {
            v["results"]
                .as_array()
                .unwrap()
                .iter()
                .map(|r| (r["id"].clone(), r["distance"].as_f64().unwrap()))
                .collect::<Vec<_>>()
        };
        let (ranked, old) = (hits(&ranked), hits(&old));
        // The same models in the same order at the same distances, to within the rounding
        // of the release that wrote the expectations: it compared region D2 bins after a
        // conversion to f32, the index now compares the stored u16 bins exactly.
        assert_eq!(ranked.len(), old.len(), "{method}");
        for ((id, d), (old_id, old_d)) in ranked.iter().zip(&old) {
            assert_eq!(id, old_id, "{method}");
            assert!(
                (d - old_d).abs() <= 1e-7 * old_d,
                "{method} {id}: {d} vs {old_d}"
            );
        }
        assert!(!ranked.is_empty());
    }

    // Its models get the patches partial search picks its candidates by, in the background.
    let mut pending = app.app.patches_pending();
    app.app.start_background();
    pending.wait_for(|p| *p == Some(0)).await.unwrap();
    let patched: Vec<String> = store
        .all_derived(Derived::Patches)
        .map(|entry| entry.unwrap().0.to_string())
        .collect();
    assert_eq!(patched, ["horse", "horse-split", "tetra"]);
}

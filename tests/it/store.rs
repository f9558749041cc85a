//! The sled store: migrations at open, refusal of newer stores, deduplicated files, and the
//! `reindex` command.

use crate::server;
use crate::shapes;

use rstest_reuse::apply;
use salient_core::mesh::Format;
use salient_server::model::{sha256_hex, Fields, ModelId, ModelRecord, Upload};
use salient_server::store::{SledStore, Store, StoreError};

use crate::stores::{stores, Stores};

/// A record of `upload` under `id` (the store does not read the signature's content).
fn record(id: &str, upload: &Upload) -> ModelRecord {
    static SIGNATURE: std::sync::OnceLock<salient_core::Signature> = std::sync::OnceLock::new();
    let signature = SIGNATURE.get_or_init(|| {
        salient_core::pipeline::compute(&shapes::icosphere(1), &salient_core::Params::default())
            .unwrap()
    });
    ModelRecord::new(
        ModelId::parse(id).unwrap(),
        Fields::default(),
        upload,
        signature,
    )
}

/// The id of the model holding `content_hash`.
fn owner(store: &dyn Store, content_hash: &str) -> Option<String> {
    let id = store.find_content(content_hash).unwrap();
    id.map(|id| id.as_str().to_string())
}

/// A file past 1 MiB (a print file's size class): sled keeps it as a file, PostgreSQL in
/// chunks.
fn large_file() -> Vec<u8> {
    let mut big = b"# a large comment\n".repeat(80_000);
    big.extend_from_slice(b"v 0 0 0\n");
    assert!(big.len() > 1 << 20);
    big
}

fn upload(bytes: &[u8]) -> Upload {
    Upload::single(Format::Obj, bytes.to_vec())
}

/// Version 0 is a store with no schema key (as sled leaves a new folder, or as a store
/// predating versioning would be): opening it applies every migration.
#[test]
fn a_version_0_store_is_migrated_at_open() {
    let dir = tempfile::tempdir().unwrap();
    {
        let db = sled::open(dir.path()).unwrap();
        db.insert(b"unrelated", b"kept").unwrap();
        db.flush().unwrap();
        assert_eq!(SledStore::stored_version(&db).unwrap(), 0);
    }
    let store = SledStore::open(dir.path()).unwrap();
    assert_eq!(SledStore::stored_version(store.db()).unwrap(), 5);
    let names: Vec<_> = store
        .db()
        .tree_names()
        .into_iter()
        .map(|n| String::from_utf8(n.to_vec()).unwrap())
        .collect();
    for tree in [
        "models",
        "signatures",
        "blobs",
        "blob_files",
        "blob_refs",
        "content",
        "state",
        "previews",
        "patches",
    ] {
        assert!(names.contains(&tree.to_string()), "{names:?}");
    }
    assert_eq!(
        store.db().get(b"unrelated").unwrap().as_deref(),
        Some(&b"kept"[..])
    );
    assert!(store.is_empty());
}

#[test]
fn a_store_from_a_newer_salient_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    {
        let db = sled::open(dir.path()).unwrap();
        db.insert(b"schema_version", &99u32.to_be_bytes()).unwrap();
        db.flush().unwrap();
    }
    match reopen(dir.path()) {
        Err(StoreError::Incompatible {
            found: 99,
            supported: 5,
        }) => {}
        other => panic!("expected a refusal, got {:?}", other.map(|_| ())),
    }
}

#[test]
fn files_are_deduplicated_and_released_with_their_last_model() {
    let dir = tempfile::tempdir().unwrap();
    let store = SledStore::open(dir.path()).unwrap();
    let (a, b) = (upload(b"v 0 0 0\n"), upload(b"v 1 1 1\n"));
    store.put(&record("one", &a), b"sig1", &a).unwrap();
    store.put(&record("two", &a), b"sig2", &a).unwrap();
    let blobs = store.db().open_tree("blobs").unwrap();
    assert_eq!(blobs.len(), 1);
    assert_eq!(owner(&store, a.content_hash()).as_deref(), Some("two"));

    // Replacing "two" with other content keeps "one"'s file.
    let replaced = store.put(&record("two", &b), b"sig3", &b).unwrap();
    assert_eq!(replaced.unwrap().content_hash, a.content_hash());
    assert_eq!(blobs.len(), 2);
    assert_eq!(store.upload("one").unwrap().unwrap().mesh, a.mesh);
    assert_eq!(
        store.signature("two").unwrap().as_deref(),
        Some(&b"sig3"[..])
    );

    assert!(store.delete("one").unwrap().is_some());
    assert_eq!(blobs.len(), 1);
    assert!(blobs.get(sha256_hex(&a.mesh)).unwrap().is_none());
    assert!(store.delete("one").unwrap().is_none());
    assert_eq!(store.list(None, 10).unwrap().len(), 1);

    // Reopening finds everything as it was.
    drop(blobs);
    drop(store);
    let store = reopen(dir.path()).unwrap();
    assert_eq!(store.upload("two").unwrap().unwrap().mesh, b.mesh);
    assert_eq!(store.load_all().count(), 1);
}

/// A large file (a print file) is kept as a file beside sled, not in it: shared by the models
/// that have it, read back whole, and removed with the last of them; small ones stay in sled.
#[test]
fn large_files_are_kept_as_files_and_released_with_their_last_model() {
    let dir = tempfile::tempdir().unwrap();
    let store = SledStore::open(dir.path()).unwrap();
    let big = large_file();
    let (large, small) = (upload(&big), upload(b"v 1 1 1\n"));
    store.put(&record("a", &large), b"sig", &large).unwrap();
    store.put(&record("b", &large), b"sig", &large).unwrap();
    store.put(&record("c", &small), b"sig", &small).unwrap();
    let file = dir.path().join("files").join(sha256_hex(&big));
    assert_eq!(std::fs::read(&file).unwrap(), big);
    let blobs = store.db().open_tree("blobs").unwrap();
    assert_eq!(blobs.len(), 1, "only the small file is in sled");
    drop(blobs);
    drop(store);
    let store = reopen(dir.path()).unwrap();
    assert_eq!(store.upload("b").unwrap().unwrap().mesh, big);
    assert!(store.delete("a").unwrap().is_some());
    assert!(file.exists(), "b still has it");
    // Replaced by other content: the last reference goes, and the file with it.
    store.put(&record("b", &small), b"sig", &small).unwrap();
    assert!(!file.exists());
    assert_eq!(store.upload("b").unwrap().unwrap().mesh, small.mesh);
    assert_eq!(
        std::fs::read_dir(dir.path().join("files")).unwrap().count(),
        0,
        "no file left behind"
    );
}

/// `salient reindex` re-extracts every stored model with new parameters.
#[tokio::test]
async fn reindex_re_extracts_with_new_parameters() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("store");
    {
        let server = server::Server::start(&data, &[]);
        let client = reqwest::Client::new();
        for (id, mesh) in [
            ("star", shapes::star(3, &shapes::five_tips())),
            ("cone", shapes::cone(0.5, 30, 32)),
        ] {
            let response = client
                .post(server.at(&format!("/v1/models?id={id}")))
                .header("content-type", "model/obj")
                .body(server::obj(&mesh))
                .send()
                .await
                .unwrap();
            assert_eq!(response.status(), reqwest::StatusCode::CREATED);
        }
    }
    let params = dir.path().join("params.json");
    std::fs::write(&params, r#"{"d2": {"samples": 500}}"#).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_salient"))
        .args([
            "reindex",
            "--data",
            data.to_str().unwrap(),
            "--params",
            params.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("re-extracted 2 of 2"));
    // Now nothing is stale under those parameters: a second run renews nothing.
    let again = std::process::Command::new(env!("CARGO_BIN_EXE_salient"))
        .args(["reindex", "--data", data.to_str().unwrap()])
        .args(["--params", params.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        String::from_utf8_lossy(&again.stdout)
            .contains("re-extracted 0 of 2 models (2 were current)"),
        "{}",
        String::from_utf8_lossy(&again.stdout)
    );
    let store = SledStore::open(&data).unwrap();
    for loaded in store.load_all() {
        let loaded = loaded.unwrap();
        let signature = salient_core::Signature::from_bytes(&loaded.signature).unwrap();
        assert_eq!(signature.params.d2.samples, 500, "{}", loaded.record.id);
        assert_eq!(
            loaded.record.params_version,
            salient_core::params::PARAMS_VERSION
        );
    }
}

/// Opens a store this process had open: sled's flusher thread can hold the file lock for a
/// moment after the last handle is dropped, so a lock failure is retried for up to 5 s.
fn reopen(dir: &std::path::Path) -> salient_server::store::StoreResult<SledStore> {
    let mut result = SledStore::open(dir);
    for _ in 0..50 {
        if !matches!(result, Err(StoreError::Backend(_))) {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
        result = SledStore::open(dir);
    }
    result
}

/// A start reads the store in batches while it decodes the batch before: every model of a
/// store several batches long is served, and an unreadable signature stops the start with an
/// error naming its model (not a panic, not a hang of the reading thread).
#[test]
fn a_start_loads_every_model_across_batches_and_names_an_unreadable_one() {
    use salient_server::api::{App, Config};
    use salient_server::store::InMemoryStore;
    use std::sync::Arc;

    let signature =
        salient_core::pipeline::compute(&shapes::icosphere(1), &salient_core::Params::default())
            .unwrap();
    let bytes = signature.to_bytes();
    let store = Arc::new(InMemoryStore::new());
    let count = 2_500;
    for i in 0..count {
        let upload = upload(format!("# model {i}\n").as_bytes());
        let record = ModelRecord::new(
            ModelId::parse(&format!("m{i:05}")).unwrap(),
            Fields::default(),
            &upload,
            &signature,
        );
        store.put(&record, &bytes, &upload).unwrap();
    }
    let app = App::new(Config::default(), store.clone()).expect("the service starts");
    assert_eq!(app.catalog_len(), count);

    let upload = upload(b"# the unreadable one\n");
    let unreadable = ModelRecord::new(
        ModelId::parse("m01234x").unwrap(),
        Fields::default(),
        &upload,
        &signature,
    );
    store.put(&unreadable, b"not a signature", &upload).unwrap();
    let error = App::new(Config::default(), store)
        .err()
        .expect("an unreadable signature stops the start");
    assert!(error.to_string().contains("m01234x"), "{error}");
}

/// What the service relies on of any store, over each: a model's record, signature and files
/// written together, replaced and deleted whole; files shared and released with their last
/// model; derived data bound to the content; listing in id order; a start loads every model.
#[apply(stores)]
fn every_store_keeps_models_files_and_derived_data_as_the_service_expects(#[case] store: Stores) {
    use salient_server::store::Derived;

    let store = store.open();
    let (a, b) = (upload(b"v 0 0 0\n"), upload(b"v 1 1 1\n"));
    let big = large_file();
    let large = upload(&big);
    assert!(store
        .put(&record("one", &a), b"sig1", &a)
        .unwrap()
        .is_none());
    store.put(&record("two", &a), b"sig2", &a).unwrap();
    store.put(&record("big", &large), b"sig4", &large).unwrap();
    assert_eq!(store.len(), 3);
    assert_eq!(owner(&*store, a.content_hash()).as_deref(), Some("two"));
    assert_eq!(store.upload("big").unwrap().unwrap().mesh, big);
    assert_eq!(store.blob(&sha256_hex(&big)).unwrap().unwrap(), big);

    assert!(store
        .put_derived(Derived::Preview, "two", a.content_hash(), b"p")
        .unwrap());
    assert!(!store
        .put_derived(Derived::Preview, "two", b.content_hash(), b"p")
        .unwrap());
    assert!(!store
        .put_derived(Derived::Preview, "gone", a.content_hash(), b"p")
        .unwrap());
    assert_eq!(
        store.derived(Derived::Preview, "two").unwrap().as_deref(),
        Some(&b"p"[..])
    );
    // The ids of the entries of one layout (their first bytes), without the entries.
    store
        .put_derived(Derived::Preview, "one", a.content_hash(), b"q")
        .unwrap();
    let of_layout = |prefix: &[u8]| -> Vec<String> {
        store
            .derived_ids(Derived::Preview, prefix)
            .map(|id| id.unwrap().to_string())
            .collect()
    };
    assert_eq!(of_layout(b"p"), ["two"]);
    assert_eq!(of_layout(b""), ["one", "two"]);
    assert!(of_layout(b"pp").is_empty());

    // Replacing "two" with other content keeps "one"'s file and drops "two"'s derived data.
    let replaced = store.put(&record("two", &b), b"sig3", &b).unwrap();
    assert_eq!(replaced.unwrap().content_hash, a.content_hash());
    assert_eq!(store.derived(Derived::Preview, "two").unwrap(), None);
    assert_eq!(store.upload("one").unwrap().unwrap().mesh, a.mesh);
    assert_eq!(
        store.signature("two").unwrap().as_deref(),
        Some(&b"sig3"[..])
    );

    // An update holds only while the model has the content it was made from.
    let mut edited = record("two", &b);
    edited.name = Some("edited".into());
    assert!(store.update_model(&edited, b"sig5").unwrap());
    assert!(!store.update_model(&record("two", &a), b"sig6").unwrap());
    assert_eq!(
        store.get("two").unwrap().unwrap().name.as_deref(),
        Some("edited")
    );

    assert!(store.delete("one").unwrap().is_some());
    assert!(store.delete("one").unwrap().is_none());
    assert!(store.blob(&sha256_hex(&a.mesh)).unwrap().is_none());
    assert!(store.delete("big").unwrap().is_some());
    assert!(store.blob(&sha256_hex(&big)).unwrap().is_none());
    assert_eq!(store.find_content(a.content_hash()).unwrap(), None);

    for i in 0..600 {
        let u = upload(format!("# {i}\n").as_bytes());
        store
            .put(&record(&format!("m{i:04}"), &u), b"s", &u)
            .unwrap();
    }
    let listed: Vec<String> = store
        .list(Some("m0299"), 2)
        .unwrap()
        .into_iter()
        .map(|r| r.id.as_str().to_string())
        .collect();
    assert_eq!(listed, ["m0300", "m0301"]);
    let loaded: Vec<String> = store
        .load_all()
        .map(|l| l.unwrap().record.id.as_str().to_string())
        .collect();
    assert_eq!(loaded.len(), 601);
    assert!(loaded.windows(2).all(|w| w[0] < w[1]), "id order");
    store.set_state("progress", b"7").unwrap();
    store.set_state("progress", b"8").unwrap();
    assert_eq!(store.state("progress").unwrap().as_deref(), Some(&b"8"[..]));
}

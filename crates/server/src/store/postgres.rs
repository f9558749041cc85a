//! The PostgreSQL backend: one catalogue shared by any number of `salient serve` processes
//! (issue #37).
//!
//! [`Store`](super::Store) is synchronous and the service calls it from blocking threads.
//! This backend keeps it so with an async client (tokio-postgres, pooled by deadpool) on a
//! runtime of its own: each call spawns its work there and waits on a std channel. Nothing
//! blocks on a runtime of the service's (no `block_on` on one of its workers), and a call
//! made from any thread works. Every write is one transaction, acknowledged after it commits.
//!
//! The schema is `migrations/postgres/` (refinery), applied at open under an advisory lock so
//! that replicas starting together migrate once; a database migrated by a newer salient is
//! refused, as sled's store is.
//!
//! Replicas stay in step through a change log ([`Shared`]): every writing transaction takes
//! the next position from one locked row as its last statement, so positions follow commit
//! order, and notifies the others (`LISTEN salient_changes`), which read on from the last
//! position they applied.

use std::collections::BTreeMap;
use std::future::Future;
use std::pin::Pin;
use std::str::FromStr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use bytes::{Bytes, BytesMut};
use deadpool_postgres::{Manager, ManagerConfig, Pool, RecyclingMethod, Runtime, Timeouts};
use rayon::prelude::*;
use tokio_postgres::config::{Host, SslMode};
use tokio_postgres::error::SqlState;
use tokio_postgres::tls::{MakeTlsConnect, TlsConnect};
use tokio_postgres::{AsyncMessage, NoTls, Socket, Transaction};

use super::{
    blob_hashes, upload_files, Candidate, Change, Changes, Derived, FirstStage, Kept, Loaded,
    Shared, StoreError, StoreResult, VectorSpec,
};
use crate::model::{ModelId, ModelRecord, Upload};

mod embedded {
    refinery::embed_migrations!("../../migrations/postgres");
}

/// Connections the pool holds at most: the service's blocking threads share them.
const CONNECTIONS: usize = 16;
/// How long a call waits for a connection (or to make one) before the store is reported
/// unavailable: a database that is down answers 503 in seconds, not after a TCP timeout.
const WAIT: Duration = Duration::from_secs(5);
/// A file's bytes are stored in chunks of this size (`blob_chunks`).
const CHUNK_BYTES: usize = 1 << 20;
/// Models read per query while the index loads (`load_all`): ~2 MB of signatures.
const PAGE: i64 = 256;
/// Key of the advisory lock held while migrating.
const MIGRATION_LOCK: i64 = 0x5a11_e470;
/// A transaction that deadlocked or lost a serialisation race is run again up to this often.
const ATTEMPTS: usize = 4;
/// The channel a committed change is announced on, with its position.
const CHANNEL: &str = "salient_changes";
/// How long the listener waits before connecting again after it lost its connection.
const RECONNECT: Duration = Duration::from_secs(1);

/// A PostgreSQL database holding a salient catalogue.
pub struct PostgresStore {
    pool: Pool,
    /// What the listening connection heard, and whether it holds.
    listener: Arc<Listener>,
    /// The last position this process committed.
    written: Arc<AtomicU64>,
    /// The runtime the client runs on; shut down without waiting when the store is dropped
    /// (dropping a runtime from inside another one would panic).
    runtime: Option<tokio::runtime::Runtime>,
    /// The first stage's vectors, when kept ([`PostgresStore::with_first_stage`]).
    vectors: Option<VectorSpec>,
}

impl std::fmt::Debug for PostgresStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PostgresStore").finish_non_exhaustive()
    }
}

impl Drop for PostgresStore {
    fn drop(&mut self) {
        if let Some(runtime) = self.runtime.take() {
            runtime.shutdown_background();
        }
    }
}

/// The schema version this code writes (the newest migration).
fn schema_version() -> u32 {
    embedded::migrations::runner()
        .get_migrations()
        .iter()
        .map(|m| m.version())
        .max()
        .unwrap_or(0)
}

/// A backend error, or [`StoreError::Unavailable`] when the database cannot be reached.
fn backend(e: tokio_postgres::Error) -> StoreError {
    if e.is_closed() || e.as_db_error().is_none() && e.code().is_none() {
        StoreError::Unavailable(Box::new(e))
    } else {
        StoreError::Backend(Box::new(e))
    }
}

fn pool_error(e: deadpool_postgres::PoolError) -> StoreError {
    match e {
        deadpool_postgres::PoolError::Backend(e) => backend(e),
        other => StoreError::Unavailable(Box::new(other)),
    }
}

fn decode_record(id: &str, json: &str) -> StoreResult<ModelRecord> {
    serde_json::from_str(json).map_err(|e| StoreError::Corrupt {
        key: id.to_string(),
        message: e.to_string(),
    })
}

fn parse_id(id: &str) -> StoreResult<ModelId> {
    ModelId::parse(id).map_err(|_| StoreError::Corrupt {
        key: id.to_string(),
        message: "not a model id".to_string(),
    })
}

fn cache_name(cache: Derived) -> &'static str {
    match cache {
        Derived::Preview => "preview",
        Derived::Patches => "patches",
    }
}

/// A transaction's error that is worth running it again for.
fn is_retryable(e: &StoreError) -> bool {
    let StoreError::Backend(e) = e else {
        return false;
    };
    e.downcast_ref::<tokio_postgres::Error>()
        .and_then(tokio_postgres::Error::code)
        .is_some_and(|code| {
            *code == SqlState::T_R_DEADLOCK_DETECTED || *code == SqlState::T_R_SERIALIZATION_FAILURE
        })
}

impl PostgresStore {
    /// Connects to the database `url` names (a `postgres://` URL or `key=value` pairs;
    /// `sslmode` honoured) and brings its schema up to date.
    pub fn open(url: &str) -> StoreResult<Self> {
        let config = tokio_postgres::Config::from_str(url).map_err(|_| {
            // The parser's message may quote the string, password included.
            StoreError::Config("the PostgreSQL connection string does not parse".to_string())
        })?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("salient-postgres")
            .enable_all()
            .build()?;
        let manager_config = ManagerConfig {
            recycling_method: RecyclingMethod::Fast,
        };
        // A server reached over a Unix socket talks no TLS (as with libpq); any other gets
        // rustls with the web's roots, which also verifies the certificate under `require`.
        let local = config
            .get_hosts()
            .iter()
            .all(|host| !matches!(host, Host::Tcp(_)));
        let listener = Arc::new(Listener::default());
        let manager = if local || config.get_ssl_mode() == SslMode::Disable {
            runtime.spawn(listen(config.clone(), NoTls, listener.clone()));
            Manager::from_config(config, NoTls, manager_config)
        } else {
            let roots =
                rustls::RootCertStore::from_iter(webpki_roots::TLS_SERVER_ROOTS.iter().cloned());
            let tls = rustls::ClientConfig::builder_with_provider(Arc::new(
                rustls::crypto::ring::default_provider(),
            ))
            .with_safe_default_protocol_versions()
            .map_err(|e| StoreError::Config(e.to_string()))?
            .with_root_certificates(roots)
            .with_no_client_auth();
            let tls = tokio_postgres_rustls::MakeRustlsConnect::new(tls);
            runtime.spawn(listen(config.clone(), tls.clone(), listener.clone()));
            Manager::from_config(config, tls, manager_config)
        };
        let pool = {
            let _entered = runtime.enter();
            Pool::builder(manager)
                .max_size(CONNECTIONS)
                .timeouts(Timeouts {
                    wait: Some(WAIT),
                    create: Some(WAIT),
                    recycle: Some(WAIT),
                })
                .runtime(Runtime::Tokio1)
                .build()
                .map_err(|e| StoreError::Config(e.to_string()))?
        };
        let store = Self {
            pool,
            listener,
            written: Arc::new(AtomicU64::new(0)),
            runtime: Some(runtime),
            vectors: None,
        };
        store.run(|pool| async move { migrate(&pool).await })?;
        Ok(store)
    }

    /// Runs `work` on the store's runtime and waits for it on this thread.
    fn run<T, F>(&self, work: impl FnOnce(Pool) -> F) -> StoreResult<T>
    where
        T: Send + 'static,
        F: Future<Output = StoreResult<T>> + Send + 'static,
    {
        let (sender, receiver) = std::sync::mpsc::sync_channel(1);
        let work = work(self.pool.clone());
        self.runtime
            .as_ref()
            .expect("present until dropped")
            .spawn(async move {
                let _ = sender.send(work.await);
            });
        receiver.recv().map_err(|_| {
            StoreError::Unavailable("the store's runtime stopped before answering".into())
        })?
    }

    /// Runs `work` in one transaction, committed before this returns; again (from the start)
    /// when it deadlocked with another writer. The change `work` reports, if any, is logged
    /// in the same transaction ([`log_change`]).
    fn transaction<T, W>(&self, work: W) -> StoreResult<T>
    where
        T: Send + 'static,
        W: for<'a> Fn(&'a Transaction<'a>) -> TxFuture<'a, (T, Option<Change>)>
            + Send
            + Sync
            + 'static,
    {
        let written = self.written.clone();
        self.run(|pool| async move {
            let mut attempt = 0;
            loop {
                attempt += 1;
                let result = async {
                    let mut client = pool.get().await.map_err(pool_error)?;
                    let tx = client.transaction().await.map_err(backend)?;
                    let (value, change) = work(&tx).await?;
                    let position = match change {
                        Some(change) => Some(log_change(&tx, &change).await?),
                        None => None,
                    };
                    tx.commit().await.map_err(backend)?;
                    if let Some(position) = position {
                        written.fetch_max(position, Ordering::AcqRel);
                    }
                    Ok(value)
                }
                .await;
                match result {
                    Err(e) if attempt < ATTEMPTS && is_retryable(&e) => continue,
                    result => return result,
                }
            }
        })
    }

    /// One statement's rows, outside a transaction.
    fn query(
        &self,
        sql: &'static str,
        params: Vec<Param>,
    ) -> StoreResult<Vec<tokio_postgres::Row>> {
        self.run(|pool| async move {
            let client = pool.get().await.map_err(pool_error)?;
            let refs: Vec<&(dyn tokio_postgres::types::ToSql + Sync)> =
                params.iter().map(Param::as_sql).collect();
            client.query(sql, &refs).await.map_err(backend)
        })
    }
}

/// A statement's parameter, owned so that it can travel to the store's runtime.
enum Param {
    Text(String),
    Texts(Vec<String>),
    Bytes(Vec<u8>),
    Int(i64),
}

impl Param {
    fn as_sql(&self) -> &(dyn tokio_postgres::types::ToSql + Sync) {
        match self {
            Param::Text(s) => s,
            Param::Texts(s) => s,
            Param::Bytes(b) => b,
            Param::Int(i) => i,
        }
    }
}

/// The work of one transaction ([`PostgresStore::transaction`]), borrowing it.
type TxFuture<'a, T> = Pin<Box<dyn Future<Output = StoreResult<T>> + Send + 'a>>;

/// What the connection listening on [`CHANNEL`] heard ([`listen`]).
#[derive(Default)]
struct Listener {
    /// The last position announced (changed, too, after each connection).
    notified: tokio::sync::watch::Sender<u64>,
    /// Whether the connection is up: the database answers.
    connected: tokio::sync::watch::Sender<bool>,
    /// Connections made after the first.
    reconnections: AtomicU64,
}

/// Keeps a connection that listens on [`CHANNEL`] and tells `listener` of each position
/// announced, connecting again whenever it is lost; after each (re)connection it tells it
/// too, since changes committed meanwhile were announced to nobody.
async fn listen<T>(mut config: tokio_postgres::Config, tls: T, listener: Arc<Listener>)
where
    T: MakeTlsConnect<Socket> + Clone + Send + 'static,
    T::Stream: Send + 'static,
    T::TlsConnect: Send,
    <T::TlsConnect as TlsConnect<Socket>>::Future: Send,
{
    config.connect_timeout(WAIT);
    let mut first = true;
    loop {
        if let Ok((client, mut connection)) = config.connect(tls.clone()).await {
            let announced = listener.clone();
            let messages = tokio::spawn(async move {
                while let Some(Ok(message)) =
                    std::future::poll_fn(|cx| connection.poll_message(cx)).await
                {
                    if let AsyncMessage::Notification(n) = message {
                        if let Ok(position) = n.payload().parse::<u64>() {
                            announced
                                .notified
                                .send_modify(|last| *last = (*last).max(position));
                        }
                    }
                }
            });
            if client
                .batch_execute(&format!("LISTEN {CHANNEL}"))
                .await
                .is_ok()
            {
                if !std::mem::take(&mut first) {
                    listener.reconnections.fetch_add(1, Ordering::Relaxed);
                }
                listener.connected.send_replace(true);
                listener.notified.send_modify(|_| {});
                // Until the connection ends; the client is kept open meanwhile.
                let _ = messages.await;
                listener.connected.send_replace(false);
            } else {
                messages.abort();
            }
        }
        tokio::time::sleep(RECONNECT).await;
    }
}

/// Logs `change` at the next position, announces it on [`CHANNEL`] (delivered at commit)
/// and returns the position. Taking the position locks `change_head` until the transaction
/// ends, so positions are handed out in commit order; it comes last, to hold that lock for
/// as short a time as it can.
async fn log_change(tx: &Transaction<'_>, change: &Change) -> StoreResult<u64> {
    let position: i64 = tx
        .query_one(
            "UPDATE change_head SET position = position + 1 RETURNING position",
            &[],
        )
        .await
        .map_err(backend)?
        .get(0);
    let (model, state) = match change {
        Change::Model(id) => (Some(id.as_str()), None),
        Change::State(key) => (None, Some(key.as_str())),
    };
    tx.execute(
        "INSERT INTO changes (position, model_id, state_key) VALUES ($1, $2, $3)",
        &[&position, &model, &state],
    )
    .await
    .map_err(backend)?;
    tx.execute(
        "SELECT pg_notify($1, $2)",
        &[&CHANNEL, &position.to_string()],
    )
    .await
    .map_err(backend)?;
    u64::try_from(position).map_err(|_| StoreError::Corrupt {
        key: "change_head".to_string(),
        message: format!("position {position}"),
    })
}

/// Applies the migrations this binary has and the database lacks, under an advisory lock;
/// refuses a database a newer salient migrated.
async fn migrate(pool: &Pool) -> StoreResult<()> {
    let mut client = pool.get().await.map_err(pool_error)?;
    client
        .execute("SELECT pg_advisory_lock($1)", &[&MIGRATION_LOCK])
        .await
        .map_err(backend)?;
    let result = async {
        let runner = embedded::migrations::runner();
        // refinery's own table; a new database has none.
        let history: Option<String> = client
            .query_one("SELECT to_regclass('refinery_schema_history')::text", &[])
            .await
            .map_err(backend)?
            .get(0);
        let found: Option<i32> = match history {
            None => None,
            Some(_) => client
                .query_one("SELECT max(version) FROM refinery_schema_history", &[])
                .await
                .map_err(backend)?
                .get(0),
        };
        let supported = schema_version();
        if let Some(found) = found.and_then(|v| u32::try_from(v).ok()) {
            if found > supported {
                return Err(StoreError::Incompatible { found, supported });
            }
        }
        let report = runner
            .run_async(&mut **client)
            .await
            .map_err(|e| StoreError::Backend(Box::new(e)))?;
        for migration in report.applied_migrations() {
            tracing::info!(
                version = migration.version(),
                name = migration.name(),
                "migrated the PostgreSQL store"
            );
        }
        Ok(())
    }
    .await;
    client
        .execute("SELECT pg_advisory_unlock($1)", &[&MIGRATION_LOCK])
        .await
        .map_err(backend)?;
    result
}

/// Changes the references of blobs by `deltas` (hash → change), in hash order so that two
/// writers lock them in the same order: a blob gaining its first reference is stored from
/// `bytes`, one losing its last is removed with its chunks.
async fn change_refs(
    tx: &Transaction<'_>,
    deltas: &BTreeMap<String, i64>,
    bytes: &BTreeMap<String, Bytes>,
) -> StoreResult<()> {
    for (hash, &delta) in deltas {
        if delta > 0 {
            let file = bytes.get(hash).ok_or_else(|| StoreError::Corrupt {
                key: hash.clone(),
                message: "a blob gained a reference without its bytes".to_string(),
            })?;
            let row = tx
                .query_one(
                    "INSERT INTO blobs (hash, size, refs) VALUES ($1, $2, $3) \
                     ON CONFLICT (hash) DO UPDATE SET refs = blobs.refs + EXCLUDED.refs \
                     RETURNING refs",
                    &[hash, &(file.len() as i64), &delta],
                )
                .await
                .map_err(backend)?;
            if row.get::<_, i64>(0) == delta {
                for (seq, chunk) in file.chunks(CHUNK_BYTES).enumerate() {
                    tx.execute(
                        "INSERT INTO blob_chunks (hash, seq, bytes) VALUES ($1, $2, $3)",
                        &[hash, &(seq as i32), &chunk],
                    )
                    .await
                    .map_err(backend)?;
                }
            }
        } else if delta < 0 {
            // The last references go with the blob (and its chunks); fewer only lower it.
            let removed = tx
                .execute(
                    "DELETE FROM blobs WHERE hash = $1 AND refs + $2 <= 0",
                    &[hash, &delta],
                )
                .await
                .map_err(backend)?;
            if removed == 0 {
                tx.execute(
                    "UPDATE blobs SET refs = refs + $2 WHERE hash = $1",
                    &[hash, &delta],
                )
                .await
                .map_err(backend)?;
            }
        }
    }
    Ok(())
}

/// The record stored under `id`, locked until the transaction ends.
async fn locked_record(tx: &Transaction<'_>, id: &str) -> StoreResult<Option<ModelRecord>> {
    tx.query_opt(
        "SELECT record::text FROM models WHERE id = $1 FOR UPDATE",
        &[&id],
    )
    .await
    .map_err(backend)?
    .map(|row| decode_record(id, row.get(0)))
    .transpose()
}

/// Removes `old`'s rows but its `models` row (which the caller replaces or deletes).
async fn unlink(
    tx: &Transaction<'_>,
    old: &ModelRecord,
    deltas: &mut BTreeMap<String, i64>,
) -> StoreResult<()> {
    tx.execute("DELETE FROM derived WHERE id = $1", &[&old.id.as_str()])
        .await
        .map_err(backend)?;
    tx.execute(
        "DELETE FROM content WHERE content_hash = $1 AND id = $2",
        &[&old.content_hash, &old.id.as_str()],
    )
    .await
    .map_err(backend)?;
    for hash in blob_hashes(old) {
        *deltas.entry(hash.to_string()).or_default() -= 1;
    }
    Ok(())
}

async fn read_blob(client: &Transaction<'_>, hash: &str) -> StoreResult<Option<Bytes>> {
    let Some(size) = client
        .query_opt("SELECT size FROM blobs WHERE hash = $1", &[&hash])
        .await
        .map_err(backend)?
        .map(|row| row.get::<_, i64>(0))
    else {
        return Ok(None);
    };
    let mut bytes = BytesMut::with_capacity(usize::try_from(size).unwrap_or(0));
    // One chunk a query: the file is never one row, nor one result set, in memory twice.
    let mut seq = 0i32;
    while let Some(row) = client
        .query_opt(
            "SELECT bytes FROM blob_chunks WHERE hash = $1 AND seq = $2",
            &[&hash, &seq],
        )
        .await
        .map_err(backend)?
    {
        bytes.extend_from_slice(row.get::<_, &[u8]>(0));
        seq += 1;
    }
    if bytes.len() as i64 != size {
        return Err(StoreError::Corrupt {
            key: hash.to_string(),
            message: format!("{} of {size} bytes stored", bytes.len()),
        });
    }
    Ok(Some(bytes.freeze()))
}

impl super::Store for PostgresStore {
    fn put(
        &self,
        record: &ModelRecord,
        signature: &[u8],
        upload: &Upload,
    ) -> StoreResult<Option<ModelRecord>> {
        let encoded = serde_json::to_string(record).expect("records serialise");
        let record = Arc::new(record.clone());
        let signature: Arc<[u8]> = signature.into();
        let bytes: Arc<BTreeMap<String, Bytes>> = Arc::new(
            upload_files(&record, upload)
                .map(|(hash, bytes)| (hash, bytes.clone()))
                .collect(),
        );
        let encoded: Arc<str> = encoded.into();
        let vector = self.vector_of(&signature);
        self.transaction(move |tx| {
            let (record, signature, bytes, encoded, vector) = (
                record.clone(),
                signature.clone(),
                bytes.clone(),
                encoded.clone(),
                vector.clone(),
            );
            Box::pin(async move {
                let id = record.id.as_str();
                let previous = locked_record(tx, id).await?;
                let mut deltas = BTreeMap::new();
                if let Some(old) = &previous {
                    unlink(tx, old, &mut deltas).await?;
                }
                for hash in blob_hashes(&record) {
                    *deltas.entry(hash.to_string()).or_default() += 1;
                }
                change_refs(tx, &deltas, &bytes).await?;
                tx.execute(
                    "INSERT INTO models (id, content_hash, record, signature) \
                     VALUES ($1, $2, $3::text::jsonb, $4) \
                     ON CONFLICT (id) DO UPDATE SET content_hash = EXCLUDED.content_hash, \
                     record = EXCLUDED.record, signature = EXCLUDED.signature",
                    &[&id, &record.content_hash, &&*encoded, &&*signature],
                )
                .await
                .map_err(backend)?;
                tx.execute(
                    "INSERT INTO content (content_hash, id) VALUES ($1, $2) \
                     ON CONFLICT (content_hash) DO UPDATE SET id = EXCLUDED.id",
                    &[&record.content_hash, &id],
                )
                .await
                .map_err(backend)?;
                if let Some(vector) = &vector {
                    put_vector(tx, &record, vector).await?;
                }
                Ok((previous, Some(Change::Model(record.id.clone()))))
            })
        })
    }

    fn update_model(&self, record: &ModelRecord, signature: &[u8]) -> StoreResult<bool> {
        let encoded: Arc<str> = serde_json::to_string(record)
            .expect("records serialise")
            .into();
        let vector = self.vector_of(signature);
        let (record, signature): (Arc<ModelRecord>, Arc<[u8]>) =
            (Arc::new(record.clone()), signature.into());
        self.transaction(move |tx| {
            let (record, signature, encoded, vector) = (
                record.clone(),
                signature.clone(),
                encoded.clone(),
                vector.clone(),
            );
            Box::pin(async move {
                let id = &record.id;
                let rows = tx
                    .execute(
                        "UPDATE models SET record = $3::text::jsonb, signature = $4 \
                         WHERE id = $1 AND content_hash = $2",
                        &[&id.as_str(), &record.content_hash, &&*encoded, &&*signature],
                    )
                    .await
                    .map_err(backend)?;
                let updated = rows == 1;
                if let (true, Some(vector)) = (updated, &vector) {
                    put_vector(tx, &record, vector).await?;
                }
                Ok((updated, updated.then(|| Change::Model(id.clone()))))
            })
        })
    }

    fn get(&self, id: &str) -> StoreResult<Option<ModelRecord>> {
        let rows = self.query(
            "SELECT record::text FROM models WHERE id = $1",
            vec![Param::Text(id.to_string())],
        )?;
        rows.first()
            .map(|row| decode_record(id, row.get(0)))
            .transpose()
    }

    fn signature(&self, id: &str) -> StoreResult<Option<Vec<u8>>> {
        let rows = self.query(
            "SELECT signature FROM models WHERE id = $1",
            vec![Param::Text(id.to_string())],
        )?;
        Ok(rows.first().map(|row| row.get(0)))
    }

    fn model(&self, id: &str) -> StoreResult<Option<Loaded>> {
        let rows = self.query(
            "SELECT record::text, signature FROM models WHERE id = $1",
            vec![Param::Text(id.to_string())],
        )?;
        rows.first()
            .map(|row| {
                Ok(Loaded {
                    record: decode_record(id, row.get(0))?,
                    signature: row.get(1),
                })
            })
            .transpose()
    }

    fn upload(&self, id: &str) -> StoreResult<Option<Upload>> {
        let Some(record) = self.get(id)? else {
            return Ok(None);
        };
        super::assemble_upload(&record, |hash| self.blob(hash)).map(Some)
    }

    fn blob(&self, hash: &str) -> StoreResult<Option<Bytes>> {
        let hash = hash.to_string();
        self.run(|pool| async move {
            let mut client = pool.get().await.map_err(pool_error)?;
            // One snapshot for the size and every chunk: a file released meanwhile is read
            // whole or not at all.
            let tx = client
                .build_transaction()
                .isolation_level(tokio_postgres::IsolationLevel::RepeatableRead)
                .read_only(true)
                .start()
                .await
                .map_err(backend)?;
            let blob = read_blob(&tx, &hash).await?;
            tx.commit().await.map_err(backend)?;
            Ok(blob)
        })
    }

    fn delete(&self, id: &str) -> StoreResult<Option<ModelRecord>> {
        let id: Arc<str> = id.into();
        self.transaction(move |tx| {
            let id = id.clone();
            Box::pin(async move {
                let Some(old) = locked_record(tx, &id).await? else {
                    return Ok((None, None));
                };
                let mut deltas = BTreeMap::new();
                unlink(tx, &old, &mut deltas).await?;
                tx.execute("DELETE FROM models WHERE id = $1", &[&&*id])
                    .await
                    .map_err(backend)?;
                change_refs(tx, &deltas, &BTreeMap::new()).await?;
                let change = Change::Model(old.id.clone());
                Ok((Some(old), Some(change)))
            })
        })
    }

    fn list(&self, after: Option<&str>, limit: usize) -> StoreResult<Vec<ModelRecord>> {
        let rows = self.query(
            "SELECT id, record::text FROM models WHERE id > $1 ORDER BY id LIMIT $2",
            vec![
                Param::Text(after.unwrap_or("").to_string()),
                Param::Int(i64::try_from(limit).unwrap_or(i64::MAX)),
            ],
        )?;
        rows.iter()
            .map(|row| decode_record(row.get(0), row.get(1)))
            .collect()
    }

    fn find_content(&self, content_hash: &str) -> StoreResult<Option<ModelId>> {
        let rows = self.query(
            "SELECT id FROM content WHERE content_hash = $1",
            vec![Param::Text(content_hash.to_string())],
        )?;
        rows.first().map(|row| parse_id(row.get(0))).transpose()
    }

    fn load_all(&self) -> Box<dyn Iterator<Item = StoreResult<Loaded>> + '_> {
        let pages = Pages {
            after: Some(String::new()),
            fetch: move |after: &str| -> StoreResult<Page<Loaded>> {
                let rows = self.query(
                    "SELECT id, record::text, signature FROM models \
                     WHERE id > $1 ORDER BY id LIMIT $2",
                    vec![Param::Text(after.to_string()), Param::Int(PAGE)],
                )?;
                rows.iter()
                    .map(|row| {
                        let id: &str = row.get(0);
                        let loaded = Loaded {
                            record: decode_record(id, row.get(1))?,
                            signature: row.get(2),
                        };
                        Ok((id.to_string(), loaded))
                    })
                    .collect()
            },
        };
        Box::new(pages.flatten())
    }

    fn len(&self) -> usize {
        self.query("SELECT count(*) FROM models", Vec::new())
            .ok()
            .and_then(|rows| rows.first().map(|row| row.get::<_, i64>(0)))
            .map_or(0, |n| usize::try_from(n).unwrap_or(0))
    }

    fn derived(&self, cache: Derived, id: &str) -> StoreResult<Option<Vec<u8>>> {
        let rows = self.query(
            "SELECT entry FROM derived WHERE cache = $1 AND id = $2",
            vec![
                Param::Text(cache_name(cache).to_string()),
                Param::Text(id.to_string()),
            ],
        )?;
        Ok(rows.first().map(|row| row.get(0)))
    }

    fn put_derived(
        &self,
        cache: Derived,
        id: &str,
        content_hash: &str,
        entry: &[u8],
    ) -> StoreResult<bool> {
        // `FOR SHARE` waits for a replacement of the model under way and then sees its new
        // content: an entry made from the old upload is not kept for the new one.
        let rows = self.query(
            "WITH model AS (SELECT id FROM models WHERE id = $2 AND content_hash = $3 FOR SHARE) \
             INSERT INTO derived (cache, id, entry) SELECT $1, id, $4 FROM model \
             ON CONFLICT (cache, id) DO UPDATE SET entry = EXCLUDED.entry RETURNING 1",
            vec![
                Param::Text(cache_name(cache).to_string()),
                Param::Text(id.to_string()),
                Param::Text(content_hash.to_string()),
                Param::Bytes(entry.to_vec()),
            ],
        )?;
        Ok(!rows.is_empty())
    }

    fn all_derived(
        &self,
        cache: Derived,
    ) -> Box<dyn Iterator<Item = StoreResult<(ModelId, Vec<u8>)>> + '_> {
        let pages = Pages {
            after: Some(String::new()),
            fetch: move |after: &str| -> StoreResult<Page<(ModelId, Vec<u8>)>> {
                let rows = self.query(
                    "SELECT id, entry FROM derived WHERE cache = $1 AND id > $2 \
                     ORDER BY id LIMIT $3",
                    vec![
                        Param::Text(cache_name(cache).to_string()),
                        Param::Text(after.to_string()),
                        Param::Int(PAGE),
                    ],
                )?;
                rows.iter()
                    .map(|row| {
                        let id: &str = row.get(0);
                        Ok((id.to_string(), (parse_id(id)?, row.get(1))))
                    })
                    .collect()
            },
        };
        Box::new(pages.flatten())
    }

    fn derived_ids(
        &self,
        cache: Derived,
        prefix: &[u8],
    ) -> Box<dyn Iterator<Item = StoreResult<ModelId>> + '_> {
        let prefix = prefix.to_vec();
        let pages = Pages {
            after: Some(String::new()),
            fetch: move |after: &str| -> StoreResult<Page<ModelId>> {
                let rows = self.query(
                    "SELECT id FROM derived WHERE cache = $1 AND id > $2 \
                     AND substring(entry FROM 1 FOR length($3::bytea)) = $3::bytea ORDER BY id LIMIT $4",
                    vec![
                        Param::Text(cache_name(cache).to_string()),
                        Param::Text(after.to_string()),
                        Param::Bytes(prefix.clone()),
                        Param::Int(PAGE),
                    ],
                )?;
                rows.iter()
                    .map(|row| {
                        let id: &str = row.get(0);
                        Ok((id.to_string(), parse_id(id)?))
                    })
                    .collect()
            },
        };
        Box::new(pages.flatten())
    }

    fn state(&self, key: &str) -> StoreResult<Option<Vec<u8>>> {
        let rows = self.query(
            "SELECT value FROM state WHERE key = $1",
            vec![Param::Text(key.to_string())],
        )?;
        Ok(rows.first().map(|row| row.get(0)))
    }

    fn set_state(&self, key: &str, value: &[u8]) -> StoreResult<()> {
        let (key, value): (Arc<str>, Arc<[u8]>) = (key.into(), value.into());
        self.transaction(move |tx| {
            let (key, value) = (key.clone(), value.clone());
            Box::pin(async move {
                tx.execute(
                    "INSERT INTO state (key, value) VALUES ($1, $2) \
                     ON CONFLICT (key) DO UPDATE SET value = EXCLUDED.value",
                    &[&&*key, &&*value],
                )
                .await
                .map_err(backend)?;
                Ok(((), Some(Change::State(key.to_string()))))
            })
        })
    }

    fn states(&self) -> StoreResult<Vec<(String, Vec<u8>)>> {
        let rows = self.query("SELECT key, value FROM state ORDER BY key", Vec::new())?;
        Ok(rows.iter().map(|row| (row.get(0), row.get(1))).collect())
    }

    fn first_stage(&self) -> Option<&dyn FirstStage> {
        self.vectors.as_ref().map(|_| self as _)
    }

    fn shared(&self) -> Option<&dyn Shared> {
        Some(self)
    }
}

impl Shared for PostgresStore {
    fn head(&self) -> StoreResult<u64> {
        let rows = self.query("SELECT position FROM change_head", Vec::new())?;
        let position: i64 = rows.first().map_or(0, |row| row.get(0));
        Ok(u64::try_from(position).unwrap_or(0))
    }

    fn changes_after(&self, position: u64, limit: usize) -> StoreResult<Changes> {
        let rows = self.query(
            "SELECT position, model_id, state_key FROM changes \
             WHERE position > $1 ORDER BY position LIMIT $2",
            vec![
                Param::Int(i64::try_from(position).unwrap_or(i64::MAX)),
                Param::Int(i64::try_from(limit).unwrap_or(i64::MAX)),
            ],
        )?;
        let mut changes = Vec::with_capacity(rows.len());
        for row in &rows {
            let at = u64::try_from(row.get::<_, i64>(0)).unwrap_or(0);
            // Positions have no gaps (each is taken in the transaction that logs it): one
            // missing was trimmed.
            if at != position + changes.len() as u64 + 1 {
                return Ok(Changes::Trimmed);
            }
            let change = match (row.get::<_, Option<&str>>(1), row.get::<_, Option<&str>>(2)) {
                (Some(id), _) => Change::Model(parse_id(id)?),
                (None, Some(key)) => Change::State(key.to_string()),
                (None, None) => {
                    return Err(StoreError::Corrupt {
                        key: format!("change {at}"),
                        message: "names neither a model nor a state key".to_string(),
                    })
                }
            };
            changes.push((at, change));
        }
        Ok(Changes::Next(changes))
    }

    fn subscribe(&self) -> tokio::sync::watch::Receiver<u64> {
        self.listener.notified.subscribe()
    }

    fn connected(&self) -> tokio::sync::watch::Receiver<bool> {
        self.listener.connected.subscribe()
    }

    fn reconnections(&self) -> u64 {
        self.listener.reconnections.load(Ordering::Relaxed)
    }

    fn written(&self) -> u64 {
        self.written.load(Ordering::Acquire)
    }

    fn trim(&self, age: Duration) -> StoreResult<u64> {
        let rows = self.query(
            "WITH gone AS (DELETE FROM changes \
             WHERE at < now() - make_interval(secs => $1::bigint) \
             AND position < (SELECT position FROM change_head) RETURNING 1) \
             SELECT count(*) FROM gone",
            vec![Param::Int(i64::try_from(age.as_secs()).unwrap_or(i64::MAX))],
        )?;
        Ok(rows
            .first()
            .map_or(0, |row| u64::try_from(row.get::<_, i64>(0)).unwrap_or(0)))
    }

    fn lock(&self, name: &str) -> StoreResult<Box<dyn Send>> {
        let lock = self.advisory_lock(name, "SELECT pg_advisory_lock($1), true")?;
        Ok(Box::new(
            lock.expect("pg_advisory_lock waits until it holds the lock"),
        ))
    }

    fn try_lock(&self, name: &str) -> StoreResult<Option<Box<dyn Send>>> {
        let lock = self.advisory_lock(name, "SELECT 1, pg_try_advisory_lock($1)")?;
        Ok(lock.map(|lock| Box::new(lock) as Box<dyn Send>))
    }
}

/// A model's first-stage row as a write keeps it: the key of the parameters it was made for,
/// and its vector, compact form and packed light field (`None` for a signature without them).
type KeptVector = Arc<(String, Option<(pgvector::Vector, Kept)>)>;

/// The name of the lock held while a replica makes the vectors the first stage lacks.
const FILLING: &str = "first stage vectors";

impl PostgresStore {
    /// Keeps a first stage of ranking in the database (`--index pgvector`, #40): a table of
    /// one `spec` vector per model under pgvector's HNSW index for the L1 distance, written in
    /// the transaction that writes the model. Vectors missing or made for other parameters
    /// (another `spec.key`) are made now, by one replica at a time. Needs the `vector`
    /// extension on the server; the table is made here rather than by a migration, as only
    /// this mode needs the extension, and its width follows the extraction parameters.
    pub fn with_first_stage(mut self, spec: VectorSpec) -> StoreResult<Self> {
        let dimensions = spec.dimensions;
        self.run(move |pool| async move { prepare_vectors(&pool, dimensions).await })?;
        self.vectors = Some(spec);
        let _filling = self.lock(FILLING)?;
        self.fill_vectors()?;
        self.run(|pool| async move { index_vectors(&pool).await })?;
        Ok(self)
    }

    /// Whether the database keeps a first stage ([`PostgresStore::with_first_stage`]), which
    /// every replica that writes must then keep whole, whatever its own `index`.
    pub fn has_first_stage(&self) -> StoreResult<bool> {
        let rows = self.query("SELECT to_regclass('model_vectors') IS NOT NULL", vec![])?;
        Ok(rows[0].get(0))
    }

    /// The vector `signature` is kept with, when the store keeps a first stage.
    fn vector_of(&self, signature: &[u8]) -> Option<KeptVector> {
        let spec = self.vectors.as_ref()?;
        let kept = (spec.vector)(signature)
            .map(|mut k| (pgvector::Vector::from(std::mem::take(&mut k.vector)), k));
        Some(Arc::new((spec.key.clone(), kept)))
    }

    /// Makes the vectors of the models without one of today's key, a page at a time.
    fn fill_vectors(&self) -> StoreResult<()> {
        let key = self.vectors.as_ref().expect("kept").key.clone();
        let counts = self.query(
            "SELECT count(*) FILTER (WHERE v.id IS NULL OR v.made_for <> $1), count(*) \
             FROM models m LEFT JOIN model_vectors v USING (id)",
            vec![Param::Text(key.clone())],
        )?;
        let (missing, models): (i64, i64) = (counts[0].get(0), counts[0].get(1));
        if missing * 10 > models {
            // Built again at once after: faster than kept up row by row.
            self.query("DROP INDEX IF EXISTS model_vectors_l1", vec![])?;
        }
        let (mut made, mut after) = (0usize, String::new());
        loop {
            // `v.id > $2` in the join too: without it the merge join read the vectors'
            // index from its start on every page, quadratic in the catalogue (a 1 000 000-model
            // start made 168 000 vectors in 7 min, slowing down).
            let rows = self.query(
                "SELECT m.id, m.signature, m.record::text FROM models m \
                 LEFT JOIN model_vectors v ON v.id = m.id AND v.id > $2 \
                 WHERE (v.id IS NULL OR v.made_for <> $1) AND m.id > $2 ORDER BY m.id LIMIT $3",
                vec![
                    Param::Text(key.clone()),
                    Param::Text(after.clone()),
                    Param::Int(PAGE),
                ],
            )?;
            let Some(last) = rows.last() else {
                break;
            };
            after = last.get::<_, &str>(0).to_string();
            // Decoding a signature and making its row is most of a start that makes them.
            let page: Vec<(ModelRecord, KeptVector)> = rows
                .par_iter()
                .map(|row| {
                    let id: &str = row.get(0);
                    let record = decode_record(id, row.get(2))?;
                    Ok((record, self.vector_of(row.get(1)).expect("kept")))
                })
                .collect::<StoreResult<_>>()?;
            made += page.len();
            let page = Arc::new(page);
            self.transaction(move |tx| {
                let page = page.clone();
                Box::pin(async move {
                    for (record, vector) in page.iter() {
                        put_vector(tx, record, vector).await?;
                    }
                    Ok(((), None))
                })
            })?;
        }
        if made > 0 {
            tracing::info!(models = made, "made the first stage's vectors");
            // Statistics now rather than when autovacuum gets to them, for the planner.
            self.query("ANALYZE model_vectors", vec![])?;
        }
        Ok(())
    }
}

/// Makes the extension, the table of vectors and its index if missing; a table of another
/// width (other extraction parameters) is made again.
async fn prepare_vectors(pool: &Pool, dimensions: usize) -> StoreResult<()> {
    let client = pool.get().await.map_err(pool_error)?;
    client
        .execute("SELECT pg_advisory_lock($1)", &[&MIGRATION_LOCK])
        .await
        .map_err(backend)?;
    let result = async {
        client
            .batch_execute("CREATE EXTENSION IF NOT EXISTS vector")
            .await
            .map_err(|_| {
                StoreError::Config(
                    "--index pgvector needs the pgvector extension on the PostgreSQL server \
                     (https://github.com/pgvector/pgvector; CREATE EXTENSION vector)"
                        .to_string(),
                )
            })?;
        let width: Option<i32> = client
            .query_opt(
                "SELECT atttypmod FROM pg_attribute \
                 WHERE attrelid = to_regclass('model_vectors') AND attname = 'v'",
                &[],
            )
            .await
            .map_err(backend)?
            .map(|row| row.get(0));
        if width.is_some_and(|w| w != dimensions as i32) {
            client
                .batch_execute("DROP TABLE model_vectors")
                .await
                .map_err(backend)?;
        }
        // One row per model (`v`, `compact` and `light_field` NULL for a model without
        // them); its tags beside it, for a filtered scan of the index to test without a join.
        // `compact` and `light_field` came after the first release of the table; the rows
        // made before them are made again (their key is not today's: `spec`). The compact
        // form is kept in the row, not out of line (`MAIN`: ~1.9 KB, near TOAST's 2 KB), so
        // that a ranking's thousand candidates are a thousand reads, not two thousand; the
        // light field (4.5 KB, incompressible) out of line (`EXTERNAL`), read only for the
        // candidates the bounds leave, and not by the candidates' scan.
        client
            .batch_execute(&format!(
                "CREATE TABLE IF NOT EXISTS model_vectors ( \
                   id text COLLATE \"C\" PRIMARY KEY REFERENCES models ON DELETE CASCADE, \
                   made_for text NOT NULL, \
                   tags text[] NOT NULL, \
                   v vector({dimensions})); \
                 ALTER TABLE model_vectors ADD COLUMN IF NOT EXISTS compact bytea; \
                 ALTER TABLE model_vectors ALTER COLUMN compact SET STORAGE MAIN; \
                 ALTER TABLE model_vectors ADD COLUMN IF NOT EXISTS light_field bytea; \
                 ALTER TABLE model_vectors ALTER COLUMN light_field SET STORAGE EXTERNAL"
            ))
            .await
            .map_err(backend)
    }
    .await;
    client
        .execute("SELECT pg_advisory_unlock($1)", &[&MIGRATION_LOCK])
        .await
        .map_err(backend)?;
    result
}

/// Builds the HNSW index of the vectors for the L1 distance if it is missing: a graph built
/// in memory when it fits in `maintenance_work_mem`, ten times faster than one that does not,
/// so the build asks for [`GRAPH_BYTES_PER_MODEL`] a model (at least 1 GB, at most
/// [`GRAPH_MEMORY_CAP`]) for itself alone. Denser than pgvector's defaults (m 16, ef_construction 64), whose
/// graph keeps at most 0.95 of the exact top 10 within reach at 100 000 models whose near
/// copies crowd together, however far the scan goes; m 32 and ef_construction 256 reach
/// 0.98 at 500 candidates (`benches/first_stage.rs`'s dump, 43 s to build on two cores).
///
/// And a GIN index of the tags, so that a ranking filtered by a rare tag reads that tag's rows
/// (a bitmap scan, exact) where the graph's filtered walk stops short of them and a
/// sequential scan reads the whole table: on a synthetic table of 100 000 rows of this shape,
/// a tag on 0.1 % of them 95 → 2.5 ms, on 1 % 100–118 → 21–43 ms (the graph, forced: ~210 of
/// the 1 000 asked for). Its statistics are gathered after, so that the planner knows how
/// common each tag is (a tag on half the rows stays on the graph).
async fn index_vectors(pool: &Pool) -> StoreResult<()> {
    let client = pool.get().await.map_err(pool_error)?;
    let clock = std::time::Instant::now();
    let rows: i64 = client
        .query_one("SELECT count(*) FROM model_vectors", &[])
        .await
        .map_err(backend)?
        .get(0);
    let memory = (rows.max(0) as u64 * GRAPH_BYTES_PER_MODEL).clamp(1 << 30, GRAPH_MEMORY_CAP);
    client
        .batch_execute(&format!(
            "SET maintenance_work_mem = '{}kB'; \
             CREATE INDEX IF NOT EXISTS model_vectors_l1 ON model_vectors \
               USING hnsw (v vector_l1_ops) WITH (m = 32, ef_construction = 256); \
             CREATE INDEX IF NOT EXISTS model_vectors_tags ON model_vectors USING gin (tags); \
             RESET maintenance_work_mem; \
             ANALYZE model_vectors",
            memory >> 10
        ))
        .await
        .map_err(backend)?;
    tracing::debug!(
        seconds = clock.elapsed().as_secs_f64(),
        "the first stage's index is ready"
    );
    Ok(())
}

/// What the graph of one model's vector takes while built: its 247 floats and m 32's
/// neighbour lists, with room (pgvector's own estimate is ~1.3 KB).
const GRAPH_BYTES_PER_MODEL: u64 = 2048;

/// The most memory a graph's build asks of the database server: a build that does not fit
/// goes on, on disk, only slower.
const GRAPH_MEMORY_CAP: u64 = 8 << 30;

/// Keeps `record`'s vector (and tags) in the first stage's table.
async fn put_vector(
    tx: &Transaction<'_>,
    record: &ModelRecord,
    kept: &KeptVector,
) -> StoreResult<()> {
    let (key, kept) = &**kept;
    let (vector, kept) = kept.as_ref().map(|(v, k)| (v, k)).unzip();
    let (compact, light_field) = kept.map(|k| (&k.compact, &k.light_field)).unzip();
    tx.execute(
        "INSERT INTO model_vectors (id, made_for, tags, v, compact, light_field) \
         VALUES ($1, $2, $3, $4, $5, $6) \
         ON CONFLICT (id) DO UPDATE SET made_for = EXCLUDED.made_for, tags = EXCLUDED.tags, \
         v = EXCLUDED.v, compact = EXCLUDED.compact, light_field = EXCLUDED.light_field",
        &[
            &record.id.as_str(),
            key,
            &record.tags,
            &vector,
            &compact,
            &light_field,
        ],
    )
    .await
    .map_err(backend)?;
    Ok(())
}

/// `ids` as one text array parameter.
fn texts(ids: &[&str]) -> Param {
    Param::Texts(ids.iter().map(|id| id.to_string()).collect())
}

/// The candidates in `rows` of (id, compact form), those without a compact form left out.
fn candidates(rows: &[tokio_postgres::Row]) -> StoreResult<Vec<Candidate>> {
    rows.iter()
        .filter_map(|row| Some((row.get(0), row.get::<_, Option<Vec<u8>>>(1)?)))
        .map(|(id, compact)| {
            Ok(Candidate {
                id: parse_id(id)?,
                compact,
            })
        })
        .collect()
}

impl FirstStage for PostgresStore {
    fn nearest(
        &self,
        vector: &[f32],
        count: usize,
        tag: Option<&str>,
        without: Option<&str>,
    ) -> StoreResult<Vec<Candidate>> {
        let vector = Arc::new(pgvector::Vector::from(vector.to_vec()));
        let (tag, without) = (tag.map(str::to_string), without.map(str::to_string));
        // pgvector's range; an iterative scan goes on past it when a filter or the limit needs.
        let search = count.clamp(40, 1000);
        let count = count as i64;
        self.transaction(move |tx| {
            let (vector, tag, without) = (vector.clone(), tag.clone(), without.clone());
            Box::pin(async move {
                tx.batch_execute(&format!(
                    "SET LOCAL hnsw.ef_search = {search}; \
                     SET LOCAL hnsw.iterative_scan = relaxed_order"
                ))
                .await
                .map_err(backend)?;
                let rows = tx
                    .query(
                        "SELECT id, compact FROM model_vectors \
                         WHERE ($2::text IS NULL OR tags @> ARRAY[$2::text]) \
                           AND ($3::text IS NULL OR id <> $3::text) \
                         ORDER BY v <+> $1 LIMIT $4",
                        &[&*vector, &tag, &without, &count],
                    )
                    .await
                    .map_err(backend)?;
                // A model without a vector has no compact form either; a scan past the
                // index's rows may return it last.
                Ok((candidates(&rows)?, None))
            })
        })
    }

    fn compacts(&self, ids: &[&str]) -> StoreResult<Vec<Candidate>> {
        let rows = self.query(
            "SELECT id, compact FROM model_vectors WHERE id = ANY($1)",
            vec![texts(ids)],
        )?;
        candidates(&rows)
    }

    fn light_fields(&self, ids: &[&str]) -> StoreResult<Vec<(ModelId, Vec<u8>)>> {
        let rows = self.query(
            "SELECT id, light_field FROM model_vectors \
             WHERE id = ANY($1) AND light_field IS NOT NULL",
            vec![texts(ids)],
        )?;
        rows.iter()
            .map(|row| Ok((parse_id(row.get(0))?, row.get(1))))
            .collect()
    }
}

impl PostgresStore {
    /// Takes the session advisory lock `name` with `sql` (whose second column says whether
    /// it is held) on a connection of its own, which then holds it until the guard drops.
    fn advisory_lock(&self, name: &str, sql: &'static str) -> StoreResult<Option<AdvisoryLock>> {
        let key = advisory_key(name);
        let taken = self.run(move |pool| async move {
            let client = pool.get().await.map_err(pool_error)?;
            let held: bool = client
                .query_one(sql, &[&key])
                .await
                .map_err(backend)?
                .get(1);
            Ok(held.then_some(client))
        })?;
        Ok(taken.map(|client| AdvisoryLock {
            client: Some(client),
            key,
            runtime: self
                .runtime
                .as_ref()
                .expect("present until dropped")
                .handle()
                .clone(),
        }))
    }
}

/// The advisory lock key of a lock's name: the first 8 bytes of its SHA-256.
fn advisory_key(name: &str) -> i64 {
    let hash = crate::model::sha256_hex(name.as_bytes());
    u64::from_str_radix(&hash[..16], 16).map_or(0, |k| k as i64)
}

/// A session advisory lock, held on its connection until dropped.
struct AdvisoryLock {
    client: Option<deadpool_postgres::Object>,
    key: i64,
    runtime: tokio::runtime::Handle,
}

impl Drop for AdvisoryLock {
    fn drop(&mut self) {
        let (Some(client), key) = (self.client.take(), self.key) else {
            return;
        };
        self.runtime.spawn(async move {
            let unlocked = client
                .query_one("SELECT pg_advisory_unlock($1)", &[&key])
                .await
                .is_ok_and(|row| row.get::<_, bool>(0));
            if !unlocked {
                // Closing the session releases whatever it holds; the pool makes another.
                drop(deadpool_postgres::Object::take(client));
            }
        });
    }
}

/// Rows read a page at a time in id order (keyset pagination: each page starts after the
/// last id of the one before), so a catalogue of any size loads in bounded memory. Yields
/// pages of items; an error ends it.
struct Pages<F> {
    /// Where the next page starts; `None` once done.
    after: Option<String>,
    fetch: F,
}

/// One page: each item with its id.
type Page<T> = Vec<(String, T)>;

impl<T, F> Iterator for Pages<F>
where
    F: FnMut(&str) -> StoreResult<Page<T>>,
{
    type Item = Vec<StoreResult<T>>;

    fn next(&mut self) -> Option<Self::Item> {
        let after = self.after.take()?;
        match (self.fetch)(&after) {
            Err(e) => Some(vec![Err(e)]),
            Ok(rows) if rows.is_empty() => None,
            Ok(rows) => {
                if rows.len() as i64 == PAGE {
                    self.after = rows.last().map(|(id, _)| id.clone());
                }
                Some(rows.into_iter().map(|(_, item)| Ok(item)).collect())
            }
        }
    }
}

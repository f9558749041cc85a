//! Whether the integration tests run their PostgreSQL cases: only with a server to run them
//! on (`SALIENT_TEST_POSTGRES`, a connection string; `.ci/run` starts one). Without it they
//! are compiled as ignored, with the reason in the runner's summary (`tests/it/stores.rs`).

fn main() {
    println!("cargo::rustc-check-cfg=cfg(postgres_tests)");
    println!("cargo::rerun-if-env-changed=SALIENT_TEST_POSTGRES");
    println!("cargo::rerun-if-changed=build.rs");
    if std::env::var_os("SALIENT_TEST_POSTGRES").is_some_and(|url| !url.is_empty()) {
        println!("cargo::rustc-cfg=postgres_tests");
    }
}

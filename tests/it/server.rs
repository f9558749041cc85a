//! Runs the real `salient serve` binary on a loopback port for integration tests.
#![allow(dead_code)] // the benches include this file and use a part of it

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

/// A server process; killed when dropped.
pub struct Server {
    child: Child,
    pub url: String,
    pub data: PathBuf,
    log: PathBuf,
}

impl Server {
    /// Starts `salient serve` on `data` with extra flags and waits until it listens.
    pub fn start(data: &Path, extra: &[&str]) -> Server {
        let log = data.with_extension("log");
        let mut child = Command::new(env!("CARGO_BIN_EXE_salient"))
            .args([
                "serve",
                "--addr",
                "127.0.0.1:0",
                "--data",
                data.to_str().unwrap(),
            ])
            .args(extra)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .expect("the binary starts");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let url = match line.trim().strip_prefix("listening on ") {
            Some(url) => url.to_string(),
            None => panic!(
                "server did not start: {}",
                std::fs::read_to_string(&log).unwrap_or_default()
            ),
        };
        Server {
            child,
            url,
            data: data.to_path_buf(),
            log,
        }
    }

    pub fn at(&self, path: &str) -> String {
        format!("{}{path}", self.url)
    }

    /// Sends the process a signal by name (`HUP`, `TERM`).
    pub fn signal(&self, name: &str) {
        let sent = Command::new("kill")
            .args([&format!("-{name}"), &self.child.id().to_string()])
            .status()
            .unwrap();
        assert!(sent.success(), "kill -{name}");
    }

    /// Kills the process at once (SIGKILL), as a crash would.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// The ids of every stored model (one page of up to 1 000).
    pub async fn listed_ids(&self) -> std::collections::BTreeSet<String> {
        let page: serde_json::Value = reqwest::get(self.at("/v1/models?limit=1000"))
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        page["models"]
            .as_array()
            .unwrap()
            .iter()
            .map(|m| m["id"].as_str().unwrap().to_string())
            .collect()
    }

    /// The server's resident memory in MiB, from `/proc` (Linux), for the load figures.
    pub fn resident_mib(&self) -> Option<f64> {
        self.status_mib("VmRSS:")
    }

    /// The server's peak resident memory so far in MiB (Linux).
    pub fn peak_resident_mib(&self) -> Option<f64> {
        self.status_mib("VmHWM:")
    }

    fn status_mib(&self, field: &str) -> Option<f64> {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).ok()?;
        let line = status.lines().find(|l| l.starts_with(field))?;
        let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kib / 1024.0)
    }

    /// What the server wrote to stderr.
    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.kill();
    }
}

/// An OBJ file's text for a mesh.
pub fn obj(mesh: &salient_core::mesh::RawMesh) -> Vec<u8> {
    salient_core::mesh::write::Export::Obj.write(mesh)
}

pub fn fixture(name: &str) -> Vec<u8> {
    std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures")
            .join(name),
    )
    .unwrap()
}

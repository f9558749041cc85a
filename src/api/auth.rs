//! API keys: who may do what. A request names its key as `Authorization: Bearer KEY`; the key
//! has a [`Scope`], and each route needs one ([`required_scope`], the policy in one place).
//!
//! Keys come from the environment (`SALIENT_API_KEYS="write:KEY1,read:KEY2"`, for containers
//! and secrets) and from a file of hashed keys (`--keys FILE`, lines `SCOPE SHA256 LABEL`,
//! written by `salient keys new`), which the server reads again on SIGHUP. Only SHA-256
//! hashes are held; a presented key is hashed and compared with every stored hash in
//! constant time. No key, part of one or hash appears in a response or a log line: a key is
//! known in logs by its label.

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use axum::http::Method;
use base64::Engine;
use rand::RngCore;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use subtle::ConstantTimeEq;

/// What a key allows; each scope includes the ones before it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scope {
    /// List, get, signatures, files, search, similar, extract.
    Read,
    /// Read, and add, replace, edit, delete.
    Write,
    /// Write, and re-extraction and the other operations.
    Admin,
}

impl fmt::Display for Scope {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Scope::Read => "read",
            Scope::Write => "write",
            Scope::Admin => "admin",
        })
    }
}

impl FromStr for Scope {
    type Err = KeyError;
    fn from_str(s: &str) -> Result<Self, KeyError> {
        match s {
            "read" => Ok(Scope::Read),
            "write" => Ok(Scope::Write),
            "admin" => Ok(Scope::Admin),
            other => Err(KeyError(format!(
                "unknown scope {other:?} (expected read, write or admin)"
            ))),
        }
    }
}

/// The scope a route needs, or `None` for the open ones (liveness, readiness, the API
/// description). `route` is the matched pattern (`/v1/models/{id}`). Searching and
/// extracting are `POST`s that change nothing, so they need only `read`.
pub fn required_scope(method: &Method, route: &str, metrics_open: bool) -> Option<Scope> {
    match route {
        // The page holds no data: it asks for a key when the API does.
        "/healthz" | "/readyz" | "/openapi.yaml" | "/" | "/page/{file}" => None,
        "/metrics" => (!metrics_open).then_some(Scope::Admin),
        admin if admin.starts_with("/v1/admin/") => Some(Scope::Admin),
        "/v1/search" | "/v1/extract" | "/v1/preview" | "/v1/duplicates/check" => Some(Scope::Read),
        _ if method == Method::GET || method == Method::HEAD => Some(Scope::Read),
        _ => Some(Scope::Write),
    }
}

/// Keys that cannot be used. The message never holds a key or a hash.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct KeyError(String);

struct Key {
    scope: Scope,
    hash: [u8; 32],
    label: String,
}

/// The keys a server accepts.
#[derive(Default)]
pub struct KeySet {
    keys: Vec<Key>,
}

/// Labels and scopes only: hashes are not for printing either.
impl fmt::Debug for KeySet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list()
            .entries(self.keys.iter().map(|k| (k.scope, &k.label)))
            .finish()
    }
}

fn sha256(key: &str) -> [u8; 32] {
    Sha256::digest(key.as_bytes()).into()
}

/// Reads the keys of both sources: `inline` (`SCOPE:KEY,…`, from the environment) and a
/// key file.
pub fn load_keys(inline: Option<&str>, file: Option<&Path>) -> Result<KeySet, KeyError> {
    let mut keys = KeySet::from_inline(inline.unwrap_or(""))?;
    if let Some(path) = file {
        keys.keys.extend(KeySet::from_file(path)?.keys);
    }
    Ok(keys)
}

impl KeySet {
    /// `SCOPE:KEY` pairs separated by commas; each key is labelled `env-N` in logs.
    pub fn from_inline(spec: &str) -> Result<Self, KeyError> {
        let mut keys = Vec::new();
        for (n, pair) in spec
            .split(',')
            .map(str::trim)
            .filter(|p| !p.is_empty())
            .enumerate()
        {
            let (scope, key) = pair
                .split_once(':')
                .ok_or_else(|| KeyError(format!("API key {} is not SCOPE:KEY", n + 1)))?;
            let key = key.trim();
            if key.len() < 16 {
                return Err(KeyError(format!(
                    "API key {} is shorter than 16 characters",
                    n + 1
                )));
            }
            keys.push(Key {
                scope: scope.trim().parse()?,
                hash: sha256(key),
                label: format!("env-{}", n + 1),
            });
        }
        Ok(Self { keys })
    }

    /// A key file: one `SCOPE SHA256 LABEL` line per key (the label may hold spaces), `#`
    /// comments and blank lines ignored.
    pub fn from_file(path: &Path) -> Result<Self, KeyError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| KeyError(format!("cannot read the key file {}: {e}", path.display())))?;
        let mut keys = Vec::new();
        for (n, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let bad = |what: &str| {
                KeyError(format!(
                    "key file {} line {}: {what}",
                    path.display(),
                    n + 1
                ))
            };
            let mut fields = line.splitn(3, char::is_whitespace);
            let scope = fields
                .next()
                .unwrap_or("")
                .parse()
                .map_err(|e: KeyError| bad(&e.0))?;
            let mut hash = [0u8; 32];
            hex::decode_to_slice(fields.next().unwrap_or(""), &mut hash)
                .map_err(|_| bad("the second field is not a SHA-256 in hex"))?;
            let label = fields.next().unwrap_or("").trim();
            if label.is_empty() {
                return Err(bad("no label"));
            }
            keys.push(Key {
                scope,
                hash,
                label: label.to_string(),
            });
        }
        Ok(Self { keys })
    }

    pub fn len(&self) -> usize {
        self.keys.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// The scope and label of a presented key. Every stored hash is compared, each in
    /// constant time, so the answer's timing says nothing about which key came close.
    pub fn check(&self, presented: &str) -> Option<(Scope, &str)> {
        let hash = sha256(presented);
        let mut found = None;
        for key in &self.keys {
            if bool::from(key.hash.ct_eq(&hash)) && found.is_none() {
                found = Some((key.scope, key.label.as_str()));
            }
        }
        found
    }
}

/// A new random key (256 bits, URL-safe base64 after a `slk_` prefix) and the line of a key
/// file that accepts it.
pub fn new_key(scope: Scope, label: &str) -> (String, String) {
    let mut bytes = [0u8; 32];
    rand::rngs::OsRng.fill_bytes(&mut bytes);
    let key = format!(
        "slk_{}",
        base64::engine::general_purpose::URL_SAFE_NO_PAD.encode(bytes)
    );
    let line = format!("{scope} {} {label}", hex::encode(sha256(&key)));
    (key, line)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn routes_need_the_scope_of_what_they_do() {
        let get = |route| required_scope(&Method::GET, route, false);
        let post = |route| required_scope(&Method::POST, route, false);
        assert_eq!(get("/healthz"), None);
        assert_eq!(get("/openapi.yaml"), None);
        assert_eq!(get("/metrics"), Some(Scope::Admin));
        assert_eq!(required_scope(&Method::GET, "/metrics", true), None);
        assert_eq!(get("/v1/models/{id}"), Some(Scope::Read));
        assert_eq!(post("/v1/search"), Some(Scope::Read));
        assert_eq!(post("/v1/extract"), Some(Scope::Read));
        assert_eq!(post("/v1/models"), Some(Scope::Write));
        assert_eq!(
            required_scope(&Method::DELETE, "/v1/models/{id}", false),
            Some(Scope::Write)
        );
        assert_eq!(post("/v1/admin/reindex"), Some(Scope::Admin));
        assert_eq!(get("/v1/admin/reindex"), Some(Scope::Admin));
        assert!(Scope::Read < Scope::Write && Scope::Write < Scope::Admin);
    }

    #[test]
    fn inline_keys_parse_and_bad_ones_say_which_without_the_key() {
        let keys = KeySet::from_inline("write:0123456789abcdef, read:fedcba9876543210").unwrap();
        assert_eq!(keys.len(), 2);
        assert_eq!(
            keys.check("0123456789abcdef"),
            Some((Scope::Write, "env-1"))
        );
        assert_eq!(keys.check("fedcba9876543210"), Some((Scope::Read, "env-2")));
        assert_eq!(keys.check("0123456789abcde"), None);
        assert_eq!(keys.check(""), None);
        for bad in ["write:tiny7", "owner:0123456789abcdef", "0123456789abcdef"] {
            let error = KeySet::from_inline(bad).unwrap_err().to_string();
            assert!(
                !error.contains("0123456789abcdef") && !error.contains("tiny7"),
                "{error}"
            );
        }
    }

    #[test]
    fn key_files_hold_hashes_and_labels() {
        let dir = tempfile::tempdir().unwrap();
        let (key, line) = new_key(Scope::Admin, "ops team");
        assert!(key.starts_with("slk_") && key.len() > 40);
        assert!(!line.contains(&key));
        let path = dir.path().join("keys");
        std::fs::write(&path, format!("# keys\n\n{line}\n")).unwrap();
        let keys = KeySet::from_file(&path).unwrap();
        assert_eq!(keys.check(&key), Some((Scope::Admin, "ops team")));
        assert_eq!(keys.check(&key[..key.len() - 1]), None);
        std::fs::write(&path, "read nothex label\n").unwrap();
        let error = KeySet::from_file(&path).unwrap_err().to_string();
        assert!(error.contains("line 1"), "{error}");
        let (_, other) = new_key(Scope::Read, "x");
        let hash = other.split(' ').nth(1).unwrap();
        std::fs::write(&path, format!("read {hash}\n")).unwrap();
        assert!(KeySet::from_file(&path)
            .unwrap_err()
            .to_string()
            .contains("no label"));
    }
}

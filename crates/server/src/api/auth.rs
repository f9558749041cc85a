//! API keys: who may do what. A request names its key as `Authorization: Bearer KEY`; the key
//! has a [`Scope`], and each route needs one ([`Access`], declared beside the route).
//!
//! Keys come from the environment (`SALIENT_API_KEYS="write:KEY1,read:KEY2"`, for containers
//! and secrets) and from a file of hashed keys (`--keys FILE`, lines `SCOPE SHA256 LABEL`,
//! written by `salient keys new`), which the server reads again on SIGHUP. Only SHA-256
//! hashes are held; a presented key is hashed and compared with every stored hash in
//! constant time. No key, part of one or hash appears in a response or a log line: a key is
//! known in logs by its label.

use std::collections::HashMap;
use std::fmt;
use std::path::Path;
use std::str::FromStr;

use axum::http::Method;
use base64::Engine;
use rand::RngCore;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use subtle::ConstantTimeEq;
use utoipa::openapi::path::{Operation, PathItem, Paths};
use utoipa::openapi::security::SecurityRequirement;
use utoipa::openapi::{ContentBuilder, Ref, ResponseBuilder};

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

/// What an operation needs of the caller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Nothing: liveness, readiness, the API description, the page (which holds no data and
    /// asks for a key when the API does).
    Open,
    /// A key of at least this scope.
    Key(Scope),
}

/// The access each operation needs, declared beside its route (`api::routes`): the one
/// place both the key check ([`AccessTable::needed`]) and `openapi.yaml`'s security come from.
#[derive(Debug, Clone, Default)]
pub struct AccessTable {
    needs: HashMap<(Method, String), Access>,
}

/// Every operation of a documented path, with its method.
fn operations_mut(item: &mut PathItem) -> impl Iterator<Item = (Method, &mut Operation)> {
    [
        (Method::GET, &mut item.get),
        (Method::PUT, &mut item.put),
        (Method::POST, &mut item.post),
        (Method::DELETE, &mut item.delete),
        (Method::OPTIONS, &mut item.options),
        (Method::HEAD, &mut item.head),
        (Method::PATCH, &mut item.patch),
        (Method::TRACE, &mut item.trace),
    ]
    .into_iter()
    .filter_map(|(method, operation)| Some((method, operation.as_mut()?)))
}

/// Names `scope` in `operation`'s security, with the answers a key check may give.
fn describe_key(operation: &mut Operation, scope: Scope) {
    let error = |description: &str| {
        ResponseBuilder::new()
            .description(description)
            .content(
                "application/json",
                ContentBuilder::new()
                    .schema(Some(Ref::from_schema_name("ErrorBody")))
                    .build(),
            )
            .build()
    };
    operation.security = Some(vec![SecurityRequirement::new(
        "api_key",
        [scope.to_string()],
    )]);
    let responses = &mut operation.responses.responses;
    responses.insert("401".into(), error("No API key, or not a valid one").into());
    responses.insert(
        "403".into(),
        error(&format!("The key's scope is below {scope}")).into(),
    );
    responses.insert(
        "429".into(),
        error("The key made more requests than `requests_per_minute` allows; retry after `Retry-After` seconds").into(),
    );
}

impl AccessTable {
    /// Records `access` for every operation of `paths`, and names a key's scope in their
    /// description (the `api_key` security requirement).
    pub fn declare(&mut self, access: Access, paths: &mut Paths) {
        for (path, item) in paths.paths.iter_mut() {
            for (method, operation) in operations_mut(item) {
                self.needs.insert((method, path.clone()), access);
                if let Access::Key(scope) = access {
                    describe_key(operation, scope);
                }
            }
        }
    }

    /// Records `access` for a route outside the API's description (the page).
    pub fn declare_route(&mut self, method: Method, route: &str, access: Access) {
        self.needs.insert((method, route.to_string()), access);
    }

    /// The scope a request needs, `None` for an open operation. `route` is the matched pattern
    /// (`/v1/models/{id}`); `HEAD` needs what `GET` does. An operation nobody declared needs
    /// `admin`: a route added without its access is closed, never open.
    pub fn needed(&self, method: &Method, route: &str) -> Option<Scope> {
        let method = if method == Method::HEAD {
            Method::GET
        } else {
            method.clone()
        };
        match self.needs.get(&(method, route.to_string())) {
            Some(Access::Open) => None,
            Some(Access::Key(scope)) => Some(*scope),
            None => Some(Scope::Admin),
        }
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
    fn operations_need_what_they_declare_and_undeclared_ones_need_admin() {
        let mut access = AccessTable::default();
        access.declare_route(Method::GET, "/v1/models/{id}", Access::Key(Scope::Read));
        access.declare_route(Method::GET, "/healthz", Access::Open);
        assert_eq!(
            access.needed(&Method::GET, "/v1/models/{id}"),
            Some(Scope::Read)
        );
        assert_eq!(
            access.needed(&Method::HEAD, "/v1/models/{id}"),
            Some(Scope::Read)
        );
        assert_eq!(access.needed(&Method::GET, "/healthz"), None);
        assert_eq!(
            access.needed(&Method::PATCH, "/v1/models/{id}"),
            Some(Scope::Admin)
        );
        assert_eq!(access.needed(&Method::GET, "/v1/new"), Some(Scope::Admin));
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

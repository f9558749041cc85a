//! Bulk ingest of a mesh folder or a manifest into the service (`salient ingest`): which file
//! becomes which model, what each upload carries, and when to retry. The HTTP client itself lives in the
//! CLI; everything here is plain data, so it is tested without a server.

use std::collections::{BTreeMap, HashSet};
use std::path::{Component, Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

use salient_core::collection::{find_meshes, is_mesh_file};
use salient_core::display::UpAxis;
use salient_core::mesh::load::archive;
use salient_core::mesh::load::DirResources;
use salient_core::mesh::{Format, Resources};
use salient_core::{Error, Result};
use salient_server::model::{sha256_hex, ModelId, Upload, MAX_ID_LEN};

/// One file of the folder and the model it becomes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Item {
    pub path: PathBuf,
    /// The path below the ingested folder, as reports show it.
    pub relative: PathBuf,
    pub id: String,
    /// The file stem.
    pub name: String,
    /// The first folder below the ingested one, with `class_from_folder`.
    pub class: Option<String>,
    /// The file's format; `None` for a zip archive, unpacked when read ([`read_upload`]).
    pub format: Option<Format>,
    /// The model's up axis (a manifest's), when its format's is not the right one.
    pub up: Option<UpAxis>,
    /// Tags of this model alone (a manifest's), instead of the run's.
    pub tags: Option<Vec<String>>,
    /// The id and fields are the library's own (a manifest's): the model is compared with
    /// what is stored under its id, not looked up by content.
    pub from_manifest: bool,
}

/// One line of a manifest (`salient ingest --manifest`): an asset library's own id and
/// fields for a file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    /// Relative to the manifest's folder, or absolute.
    path: PathBuf,
    id: Option<String>,
    name: Option<String>,
    tags: Option<Vec<String>>,
    class: Option<String>,
    /// `y` or `z`.
    up: Option<UpAxis>,
}

/// The models a JSON Lines manifest names, one `{"path", "id", "name", "tags", "class", "up"}` per
/// line (all but `path` optional; blank lines skipped). Ids default to [`model_id`] of the
/// path, names to the file stem. Any bad line fails the whole plan, naming its line, so that
/// nothing is uploaded from a manifest that says something else than meant.
pub fn plan_manifest(manifest: &Path) -> Result<Vec<Item>> {
    let text = std::fs::read_to_string(manifest).map_err(|source| Error::Io {
        path: manifest.to_path_buf(),
        source,
    })?;
    let folder = manifest.parent().unwrap_or(Path::new("."));
    let bad = |line: usize, message: String| Error::Manifest {
        path: manifest.to_path_buf(),
        line,
        message,
    };
    let mut taken = HashSet::new();
    let mut items = Vec::new();
    for (n, line) in text.lines().enumerate().map(|(n, l)| (n + 1, l.trim())) {
        if line.is_empty() {
            continue;
        }
        let entry: Entry = serde_json::from_str(line).map_err(|e| bad(n, e.to_string()))?;
        if !is_mesh_file(&entry.path) {
            return Err(bad(
                n,
                format!("{} is not a known mesh format", entry.path.display()),
            ));
        }
        let format = Format::from_path(&entry.path);
        let id = match entry.id {
            Some(id) => ModelId::parse(&id)
                .map_err(|e| bad(n, e.to_string()))?
                .to_string(),
            None => model_id(&entry.path),
        };
        if !taken.insert(id.clone()) {
            return Err(bad(n, format!("the id {id:?} is given twice")));
        }
        items.push(Item {
            path: folder.join(&entry.path),
            name: entry.name.unwrap_or_else(|| lossy(entry.path.file_stem())),
            relative: entry.path,
            id,
            class: entry.class,
            up: entry.up,
            format,
            tags: entry.tags,
            from_manifest: true,
        });
    }
    Ok(items)
}

/// The models the mesh files below `dir` become, in path order. Ids come from the relative
/// paths ([`model_id`]), so that ingesting the same folder again addresses the same models;
/// two paths that sanitise to the same id get a suffix from their path's hash.
pub fn plan(dir: &Path, class_from_folder: bool) -> Result<Vec<Item>> {
    let mut taken = HashSet::new();
    let mut items = Vec::new();
    for path in find_meshes(dir)? {
        let relative = path.strip_prefix(dir).unwrap_or(&path).to_path_buf();
        let mut id = model_id(&relative);
        if taken.contains(&id) {
            id = with_suffix(&id, &path_hash(&relative));
        }
        let mut n = 2;
        while taken.contains(&id) {
            id = with_suffix(&id, &n.to_string());
            n += 1;
        }
        taken.insert(id.clone());
        let folders: Vec<_> = relative
            .parent()
            .into_iter()
            .flat_map(Path::components)
            .collect();
        let class = match folders.first() {
            Some(Component::Normal(name)) if class_from_folder => {
                Some(name.to_string_lossy().into_owned())
            }
            _ => None,
        };
        items.push(Item {
            name: lossy(relative.file_stem()),
            format: Format::from_path(&path),
            path,
            relative,
            id,
            class,
            up: None,
            tags: None,
            from_manifest: false,
        });
    }
    Ok(items)
}

fn lossy(s: Option<&std::ffi::OsStr>) -> String {
    s.map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn path_hash(relative: &Path) -> String {
    sha256_hex(relative.to_string_lossy().as_bytes())[..8].to_string()
}

/// `id` with `-suffix`, shortened to stay within [`MAX_ID_LEN`].
fn with_suffix(id: &str, suffix: &str) -> String {
    let keep = MAX_ID_LEN - suffix.len() - 1;
    format!("{}-{suffix}", &id[..id.len().min(keep)])
}

/// A model id for a file at `relative` below the ingested folder: its folders and stem joined
/// by `-` (`hand/181.off` → `hand-181`), every character the service refuses in ids replaced by
/// `_`, leading dots dropped. Ids longer than [`MAX_ID_LEN`] are cut and end with a hash of
/// the whole path, so they stay distinct.
pub fn model_id(relative: &Path) -> String {
    let stem = relative.with_extension("");
    let parts: Vec<String> = stem
        .components()
        .filter_map(|c| match c {
            Component::Normal(part) => Some(part.to_string_lossy().into_owned()),
            _ => None,
        })
        .collect();
    let joined: String = parts
        .join("-")
        .chars()
        .map(|c| if ModelId::allowed(c) { c } else { '_' })
        .collect();
    let id = joined.trim_start_matches('.');
    if id.is_empty() {
        return format!("model-{}", path_hash(relative));
    }
    if id.len() > MAX_ID_LEN {
        return with_suffix(id, &path_hash(relative));
    }
    id.to_string()
}

/// The upload of `item`: the file and, for a `.gltf`, the sibling files it references
/// ([`gltf_references`]), keyed by their URI as the loader looks them up. Its
/// [`Upload::content_hash`] is the one the service computes, so stored files can be skipped
/// before sending them.
pub fn read_upload(item: &Item) -> Result<Upload> {
    let mesh = std::fs::read(&item.path).map_err(|source| Error::Io {
        path: item.path.clone(),
        source,
    })?;
    let Some(format) = item.format else {
        let unpacked = archive::unpack(&mesh, &salient_core::Limits::default())?;
        let resources = unpacked
            .resources
            .into_iter()
            .map(|(name, bytes)| (name, bytes.into()))
            .collect();
        return Ok(Upload::new(
            unpacked.format,
            unpacked.mesh.into(),
            resources,
        ));
    };
    let mut resources = BTreeMap::new();
    if format == Format::Gltf {
        let folder = DirResources(item.path.parent().unwrap_or(Path::new(".")).to_path_buf());
        for (uri, required) in gltf_references(&mesh)? {
            match folder.get(&uri) {
                Some(bytes) => {
                    resources.insert(uri, bytes.into());
                }
                None if required => return Err(Error::MissingResource { uri }),
                None => {}
            }
        }
    }
    Ok(Upload::new(format, mesh.into(), resources))
}

/// The external files a glTF document references, percent-decoded, with whether the geometry
/// needs them: buffers are required, images are sent when present (they are part of the asset
/// but not of its shape). `data:` URIs are embedded and skipped.
pub fn gltf_references(json: &[u8]) -> Result<Vec<(String, bool)>> {
    let document: serde_json::Value = serde_json::from_slice(json).map_err(|e| Error::Parse {
        format: Format::Gltf,
        message: e.to_string(),
    })?;
    let mut references = Vec::new();
    for (key, required) in [("buffers", true), ("images", false)] {
        let entries = document.get(key).and_then(|v| v.as_array());
        for uri in entries
            .into_iter()
            .flatten()
            .filter_map(|entry| entry.get("uri")?.as_str())
            .filter(|uri| {
                !uri.get(..5)
                    .is_some_and(|s| s.eq_ignore_ascii_case("data:"))
            })
        {
            let decoded = percent_encoding::percent_decode_str(uri)
                .decode_utf8_lossy()
                .into_owned();
            if !references.iter().any(|(u, _)| u == &decoded) {
                references.push((decoded, required));
            }
        }
    }
    Ok(references)
}

/// When to retry a request the server could not take (503, 429, connection errors, timeouts):
/// delays double from `first` up to `max`, never shorter than the server's `Retry-After`, and
/// at most `attempts` tries in all.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Backoff {
    pub first: Duration,
    pub max: Duration,
    pub attempts: u32,
}

impl Default for Backoff {
    fn default() -> Self {
        Self {
            first: Duration::from_millis(250),
            max: Duration::from_secs(30),
            attempts: 8,
        }
    }
}

impl Backoff {
    /// The wait before retry `retry` (0 for the first). `jitter` in [0, 1) lengthens it by up
    /// to that fraction, so clients turned away together do not come back together. A
    /// `Retry-After` over `max` is cut to `max`: a bulk client keeps going.
    pub fn delay(&self, retry: u32, retry_after: Option<Duration>, jitter: f64) -> Duration {
        let doubled = self.first.saturating_mul(1u32 << retry.min(20));
        let base = doubled.max(retry_after.unwrap_or_default()).min(self.max);
        base.mul_f64(1.0 + jitter.clamp(0.0, 1.0))
    }

    /// Whether a try that failed as try number `attempt` (1-based) may be followed by another.
    pub fn may_retry(&self, attempt: u32) -> bool {
        attempt < self.attempts
    }
}

/// A `Retry-After` header in its delay-seconds form; the HTTP-date form (which this service
/// never sends) gives `None`, so the client falls back to its own backoff.
pub fn parse_retry_after(value: &str) -> Option<Duration> {
    value.trim().parse::<u64>().ok().map(Duration::from_secs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_follow_the_relative_path_and_the_service_rules() {
        assert_eq!(model_id(Path::new("hand/181.off")), "hand-181");
        assert_eq!(model_id(Path::new("m155.obj")), "m155");
        assert_eq!(model_id(Path::new("a b/c+d.v2.obj")), "a_b-c_d.v2");
        assert_eq!(model_id(Path::new("..x/.y.obj")), "x-.y");
        assert_eq!(model_id(Path::new("chaise/été.ply")), "chaise-_t_");
        let long = format!("{}/{}.stl", "d".repeat(100), "f".repeat(100));
        let id = model_id(Path::new(&long));
        assert_eq!(id.len(), MAX_ID_LEN);
        assert_ne!(id, model_id(Path::new(&long.replace(".stl", "g.stl"))));
        for id in [id, model_id(Path::new(".obj"))] {
            assert!(ModelId::parse(&id).is_ok(), "{id}");
        }
    }

    #[test]
    fn plan_names_classes_and_disambiguates() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        for file in [
            "hand/181.off",
            "hand/181.obj",
            "top.stl",
            "a b/x.ply",
            "a_b/x.ply",
        ] {
            let path = root.join(file);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(&path, "").unwrap();
        }
        std::fs::write(root.join("notes.txt"), "").unwrap();
        let items = plan(root, true).unwrap();
        let summary: Vec<_> = items
            .iter()
            .map(|i| {
                (
                    i.relative.to_str().unwrap(),
                    i.name.as_str(),
                    i.class.as_deref(),
                )
            })
            .collect();
        assert_eq!(
            summary,
            [
                ("a b/x.ply", "x", Some("a b")),
                ("a_b/x.ply", "x", Some("a_b")),
                ("hand/181.obj", "181", Some("hand")),
                ("hand/181.off", "181", Some("hand")),
                ("top.stl", "top", None),
            ]
        );
        let ids: Vec<_> = items.iter().map(|i| i.id.as_str()).collect();
        assert_eq!(ids[0], "a_b-x");
        assert_eq!(ids[2], "hand-181");
        assert!(ids[1].starts_with("a_b-x-") && ids[3].starts_with("hand-181-"));
        assert_eq!(ids.iter().collect::<HashSet<_>>().len(), ids.len());
        assert_eq!(items[3].format, Some(Format::Off));
        assert!(plan(root, false).unwrap().iter().all(|i| i.class.is_none()));
        // The same folder plans the same ids.
        assert_eq!(plan(root, true).unwrap(), items);
    }

    #[test]
    fn gltf_uploads_carry_their_buffers_and_hash_as_the_service_does() {
        let dir = tempfile::tempdir().unwrap();
        let gltf = br#"{"asset": {"version": "2.0"},
            "buffers": [{"uri": "my%20mesh.bin", "byteLength": 4},
                        {"uri": "data:application/octet-stream;base64,AAAA", "byteLength": 3}],
            "images": [{"uri": "skin.png"}, {"uri": "gone.png"}]}"#;
        std::fs::write(dir.path().join("m.gltf"), gltf).unwrap();
        std::fs::write(dir.path().join("my mesh.bin"), [1, 2, 3, 4]).unwrap();
        std::fs::write(dir.path().join("skin.png"), [9]).unwrap();
        assert_eq!(
            gltf_references(gltf).unwrap(),
            [
                ("my mesh.bin".to_string(), true),
                ("skin.png".to_string(), false),
                ("gone.png".to_string(), false)
            ]
        );
        let item = &plan(dir.path(), false).unwrap()[0];
        let upload = read_upload(item).unwrap();
        assert_eq!(upload.format, Format::Gltf);
        assert_eq!(
            upload.resources.keys().collect::<Vec<_>>(),
            ["my mesh.bin", "skin.png"]
        );
        assert_ne!(upload.content_hash(), sha256_hex(gltf));

        std::fs::remove_file(dir.path().join("my mesh.bin")).unwrap();
        assert!(matches!(
            read_upload(item),
            Err(Error::MissingResource { uri }) if uri == "my mesh.bin"
        ));
        std::fs::write(dir.path().join("m.gltf"), "{ not json").unwrap();
        assert!(matches!(read_upload(item), Err(Error::Parse { .. })));
    }

    #[test]
    fn single_files_hash_to_their_sha256() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("m.obj"), "v 0 0 0\n").unwrap();
        let upload = read_upload(&plan(dir.path(), false).unwrap()[0]).unwrap();
        assert_eq!(upload.content_hash(), sha256_hex(b"v 0 0 0\n"));
        assert!(upload.resources.is_empty());
    }

    #[test]
    fn media_types_name_their_format() {
        for format in Format::ALL {
            assert_eq!(Format::from_content_type(format.media_type()), Some(format));
        }
    }

    #[test]
    fn backoff_doubles_honours_retry_after_and_is_bounded() {
        let b = Backoff {
            first: Duration::from_millis(100),
            max: Duration::from_secs(2),
            attempts: 4,
        };
        let ms = |d: Duration| d.as_millis();
        assert_eq!(ms(b.delay(0, None, 0.0)), 100);
        assert_eq!(ms(b.delay(1, None, 0.0)), 200);
        assert_eq!(ms(b.delay(3, None, 0.0)), 800);
        assert_eq!(ms(b.delay(10, None, 0.0)), 2000);
        assert_eq!(ms(b.delay(63, None, 0.0)), 2000);
        assert_eq!(ms(b.delay(0, Some(Duration::from_secs(1)), 0.0)), 1000);
        assert_eq!(ms(b.delay(0, Some(Duration::from_secs(60)), 0.0)), 2000);
        assert_eq!(ms(b.delay(1, None, 0.5)), 300);
        assert!(b.may_retry(3) && !b.may_retry(4));
        assert_eq!(parse_retry_after(" 3 "), Some(Duration::from_secs(3)));
        assert_eq!(parse_retry_after("Wed, 21 Oct 2015 07:28:00 GMT"), None);
    }
}

//! Reading meshes from files and uploads (SPEC §1.1).
//!
//! Every format loader turns bytes into a [`RawMesh`] in the file's own coordinates (glTF node
//! transforms applied); [`load_bytes`] then runs the checks common to all formats in one place:
//! counts within [`Limits`], at least one triangle, indices in range, finite coordinates.
//! Input is untrusted (uploads): loaders check declared counts against the limits and against
//! the byte length before allocating, and malformed input is a typed [`Error`], never a panic.

pub mod archive;
mod gltf;
mod obj;
mod off;
mod ply;
mod stl;
mod three_mf;

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};

use crate::error::{Error, Result};
use crate::mesh::RawMesh;
use crate::params::Limits;

pub use crate::format::Format;

impl Format {
    /// Recognises a format from the first bytes (magic numbers and first keywords), for uploads
    /// without a usable name or content type.
    pub fn sniff(bytes: &[u8]) -> Option<Format> {
        if bytes.starts_with(b"glTF") {
            return Some(Format::Glb);
        }
        if three_mf::is_3mf(bytes) {
            return Some(Format::ThreeMf);
        }
        if stl::is_binary(bytes) {
            return Some(Format::Stl);
        }
        let text = skip_bom_and_space(bytes);
        if text.starts_with(b"{") {
            return Some(Format::Gltf);
        }
        let first_word = text
            .split(|b| b.is_ascii_whitespace())
            .next()
            .unwrap_or_default();
        if first_word == b"ply" {
            return Some(Format::Ply);
        }
        if off::is_header_keyword(first_word) {
            return Some(Format::Off);
        }
        if first_word == b"solid" && contains(&text[..text.len().min(4096)], b"facet") {
            return Some(Format::Stl);
        }
        if obj::looks_like_obj(text) {
            return Some(Format::Obj);
        }
        None
    }
}

/// A kind of file salient does not read, and how to make one it reads.
struct Foreign {
    kind: &'static str,
    extensions: &'static [&'static str],
    /// Whether the first bytes are this kind's.
    signature: fn(&[u8]) -> bool,
    conversion: &'static str,
}

/// Whether `bytes` is a zip archive holding an entry whose name contains `entry`.
fn zip_holding(bytes: &[u8], entry: &[u8]) -> bool {
    bytes.starts_with(b"PK\x03\x04") && contains(&bytes[..bytes.len().min(1 << 16)], entry)
}

/// What users most often send instead of a mesh file of ours: 3D applications' own formats.
const FOREIGN: [Foreign; 3] = [
    Foreign {
        kind: "FBX",
        extensions: &["fbx"],
        signature: |b| b.starts_with(b"Kaydara FBX Binary") || b.starts_with(b"; FBX"),
        conversion: "export it as glTF 2.0 (.glb) or OBJ, e.g. in Blender: File > Import > FBX, then File > Export > glTF 2.0",
    },
    Foreign {
        kind: "USD / USDZ",
        extensions: &["usdz", "usd", "usda", "usdc"],
        signature: |b| {
            b.starts_with(b"PXR-USDC") || b.starts_with(b"#usda") || zip_holding(b, b".usdc") || zip_holding(b, b".usda")
        },
        conversion: "export it as glTF 2.0 (.glb), e.g. in Blender: File > Import > Universal Scene Description, then File > Export > glTF 2.0",
    },
    Foreign {
        kind: "a Blender file (.blend)",
        extensions: &["blend"],
        signature: |b| b.starts_with(b"BLENDER"),
        conversion: "export it from Blender as glTF 2.0 (File > Export > glTF 2.0) or STL",
    },
];

/// The [`Error::Unsupported`] for a file of a kind salient does not read, recognised by its
/// first bytes or by its extension (`name`, a file name or a bare extension); `None` for
/// anything else.
pub fn unsupported(bytes: &[u8], name: Option<&str>) -> Option<Error> {
    let extension = name.map(|n| n.rsplit('.').next().unwrap_or(n).to_ascii_lowercase());
    FOREIGN
        .iter()
        .find(|f| {
            (f.signature)(bytes)
                || extension
                    .as_deref()
                    .is_some_and(|e| f.extensions.contains(&e))
        })
        .map(|f| Error::Unsupported {
            feature: f.kind.to_string(),
            conversion: f.conversion,
        })
}

/// External files a glTF may reference (sibling `.bin` buffers). Uploads supply them in memory,
/// files on disk from their directory.
pub trait Resources {
    /// The bytes of `uri` (already percent-decoded), or `None` if it is not available.
    fn get(&self, uri: &str) -> Option<Vec<u8>>;
}

/// No external resources: only self-contained files (GLB, `data:` URIs) load.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoResources;

impl Resources for NoResources {
    fn get(&self, _uri: &str) -> Option<Vec<u8>> {
        None
    }
}

/// Resources read from one directory. URIs that could leave it (absolute paths, `..`
/// components, schemes or drive letters) are refused, which the loader reports as missing:
/// a file must not make the service read arbitrary paths.
#[derive(Debug, Clone)]
pub struct DirResources(pub PathBuf);

impl Resources for DirResources {
    fn get(&self, uri: &str) -> Option<Vec<u8>> {
        let relative = Path::new(uri);
        let stays_inside = !uri.is_empty()
            && !uri.contains(['\\', ':'])
            && relative
                .components()
                .all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
        if !stays_inside {
            return None;
        }
        std::fs::read(self.0.join(relative)).ok()
    }
}

/// Which of `names` supplies `uri`: the one equal to it, else the only one with its base name
/// (a browser sends `x.bin` for a `.gltf`'s `buffers/x.bin`, never the path); `None` when
/// there is none or several.
fn supplying<'a>(
    mut names: impl Iterator<Item = &'a String> + Clone,
    uri: &str,
) -> Option<&'a String> {
    if let Some(exact) = names.clone().find(|name| *name == uri) {
        return Some(exact);
    }
    let base = |name: &str| name.rsplit(['/', '\\']).next().unwrap_or(name).to_string();
    let wanted = base(uri);
    let mut same_base = names.by_ref().filter(|name| base(name) == wanted);
    match (same_base.next(), same_base.next()) {
        (Some(only), None) => Some(only),
        _ => None,
    }
}

/// In-memory resources keyed by file name or URI, e.g. the other parts of a multipart
/// upload ([`supplying`]).
impl<B: AsRef<[u8]>> Resources for HashMap<String, B> {
    fn get(&self, uri: &str) -> Option<Vec<u8>> {
        let name = supplying(self.keys(), uri)?;
        HashMap::get(self, name).map(|b| b.as_ref().to_vec())
    }
}

impl<B: AsRef<[u8]>> Resources for std::collections::BTreeMap<String, B> {
    fn get(&self, uri: &str) -> Option<Vec<u8>> {
        let name = supplying(self.keys(), uri)?;
        std::collections::BTreeMap::get(self, name).map(|b| b.as_ref().to_vec())
    }
}

/// Parses `bytes` as `format` and checks the result (SPEC §1.1). `resources` supplies the
/// external buffers of a `.gltf`; other formats ignore it.
pub fn load_bytes(
    bytes: &[u8],
    format: Format,
    resources: &dyn Resources,
    limits: &Limits,
) -> Result<RawMesh> {
    let mesh = match format {
        Format::Obj => obj::load(bytes, limits)?,
        Format::Gltf | Format::Glb => gltf::load(bytes, format, resources, limits)?,
        Format::Off => off::load(bytes, limits)?,
        Format::Ply => ply::load(bytes, limits)?,
        Format::Stl => stl::load(bytes, limits)?,
        Format::ThreeMf => three_mf::load(bytes, limits)?,
    };
    check(mesh, limits)
}

/// Reads a mesh file. The format comes from the extension, else from the content; a `.gltf`'s
/// external buffers are read from its directory.
pub fn load_path(path: &Path, limits: &Limits) -> Result<RawMesh> {
    let bytes = std::fs::read(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let name = path.file_name().and_then(|n| n.to_str());
    let format = match Format::from_path(path) {
        Some(format) => format,
        None => match (unsupported(&bytes, name), Format::sniff(&bytes)) {
            (Some(error), _) => return Err(error),
            // A zip is an archive of a mesh, unless it is a 3MF package.
            (None, sniffed) if archive::is_zip(&bytes) && sniffed != Some(Format::ThreeMf) => {
                let unpacked = archive::unpack(&bytes, limits)?;
                return load_bytes(&unpacked.mesh, unpacked.format, &unpacked.resources, limits);
            }
            (None, Some(format)) => format,
            (None, None) => return Err(Error::UnknownFormat(path.display().to_string())),
        },
    };
    let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    load_bytes(&bytes, format, &DirResources(dir), limits)
}

/// The checks common to all formats, in one place.
fn check(mesh: RawMesh, limits: &Limits) -> Result<RawMesh> {
    check_limit("vertices", mesh.positions.len(), limits.max_input_vertices)?;
    check_limit(
        "triangles",
        mesh.triangles.len(),
        limits.max_input_triangles,
    )?;
    if mesh.triangles.is_empty() {
        return Err(Error::NoTriangles);
    }
    let vertex_count = mesh.positions.len();
    for (face, triangle) in mesh.triangles.iter().enumerate() {
        if let Some(&index) = triangle.iter().find(|&&i| i as usize >= vertex_count) {
            return Err(Error::IndexOutOfRange {
                face,
                index: index.into(),
                vertex_count,
            });
        }
    }
    if let Some(vertex) = mesh.positions.iter().position(|p| !p.is_finite()) {
        return Err(Error::NonFinite { vertex });
    }
    Ok(mesh)
}

/// `Err(TooLarge)` if `count` exceeds `limit`.
fn check_limit(what: &'static str, count: usize, limit: usize) -> Result<()> {
    if count > limit {
        return Err(Error::TooLarge { what, count, limit });
    }
    Ok(())
}

/// `n` as a vertex index, for offsets of merged parts.
fn vertex_id(n: usize) -> Result<u32> {
    u32::try_from(n).map_err(|_| Error::TooLarge {
        what: "vertices",
        count: n,
        limit: u32::MAX as usize,
    })
}

/// A [`Error::Parse`] for `format`.
fn parse_error(format: Format, message: impl Into<String>) -> Error {
    Error::Parse {
        format,
        message: message.into(),
    }
}

/// Appends the fan triangulation `(c0, c_k, c_k+1)` of polygon number `face` (OFF and PLY),
/// checking every corner against `vertex_count` and the running triangle count against the
/// limit. Points and lines (fewer than 3 corners) add nothing.
fn push_fan(
    triangles: &mut Vec<[u32; 3]>,
    face: usize,
    corners: &[u64],
    vertex_count: usize,
    limits: &Limits,
) -> Result<()> {
    let id = |index: u64| {
        u32::try_from(index)
            .ok()
            .filter(|&i| (i as usize) < vertex_count)
            .ok_or(Error::IndexOutOfRange {
                face,
                index,
                vertex_count,
            })
    };
    let [first, second, rest @ ..] = corners else {
        return Ok(());
    };
    if rest.is_empty() {
        return Ok(());
    }
    check_limit(
        "triangles",
        triangles.len().saturating_add(rest.len()),
        limits.max_input_triangles,
    )?;
    let first = id(*first)?;
    let mut previous = id(*second)?;
    for &corner in rest {
        let current = id(corner)?;
        triangles.push([first, previous, current]);
        previous = current;
    }
    Ok(())
}

/// The bytes after a UTF-8 byte-order mark and leading whitespace.
fn skip_bom_and_space(bytes: &[u8]) -> &[u8] {
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    &bytes[start..]
}

/// Whether `needle` occurs in `haystack`.
fn contains(haystack: &[u8], needle: &[u8]) -> bool {
    haystack.windows(needle.len()).any(|w| w == needle)
}

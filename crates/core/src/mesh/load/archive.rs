//! Zip archives of one mesh, the way glTF is most often distributed: the `.gltf` with its
//! buffers and textures (or a single mesh file of any format) in a `.zip`. The archive is
//! unpacked into the mesh file and its resources, which then load as if uploaded together.
//!
//! The archive is untrusted: its entry count and the sizes its entries declare are checked
//! against the [`Limits`] before anything is inflated, and an entry that inflates past what it
//! declared is refused, so a zip bomb costs at most the limit, never the memory it claims.

use std::collections::BTreeMap;
use std::io::{Cursor, Read};

use super::{check_limit, unsupported, Format};
use crate::error::{Error, Result};
use crate::params::Limits;

/// A zip archive's mesh file and its resources.
#[derive(Debug, Clone, PartialEq)]
pub struct Unpacked {
    /// The mesh file's name within the archive.
    pub name: String,
    pub format: Format,
    pub mesh: Vec<u8>,
    /// A glTF's other entries (buffers, images), named relative to the `.gltf`'s folder; none
    /// for other formats, which reference nothing.
    pub resources: BTreeMap<String, Vec<u8>>,
}

/// Whether `bytes` start like a zip archive.
pub fn is_zip(bytes: &[u8]) -> bool {
    bytes.starts_with(b"PK\x03\x04")
}

/// What an archive tool adds beside the files: folders and macOS metadata.
fn is_clutter(name: &str) -> bool {
    let base = name.rsplit('/').next().unwrap_or(name);
    name.ends_with('/')
        || name.starts_with("__MACOSX/")
        || base.starts_with("._")
        || base == ".DS_Store"
}

/// Unpacks the one mesh file of a zip archive, with its resources when it is a glTF.
pub fn unpack(bytes: &[u8], limits: &Limits) -> Result<Unpacked> {
    let bad = |message: String| Error::Archive(message);
    let mut archive = zip::ZipArchive::new(Cursor::new(bytes)).map_err(|e| bad(format!("{e}")))?;
    check_limit("archive entries", archive.len(), limits.max_archive_entries)?;
    // Every entry's name and declared size, before anything is inflated.
    let mut entries = Vec::new();
    for index in 0..archive.len() {
        let entry = archive.by_index(index).map_err(|e| bad(format!("{e}")))?;
        let name = entry.name().map_err(|e| bad(format!("{e}")))?.into_owned();
        if !is_clutter(&name) && !entry.is_dir() {
            entries.push((index, name, entry.size()));
        }
    }
    let meshes: Vec<&(usize, String, u64)> = entries
        .iter()
        .filter(|(_, name, _)| Format::from_path(std::path::Path::new(name)).is_some())
        .collect();
    let (mesh_index, name, _) = match meshes.as_slice() {
        [one] => (*one).clone(),
        [] => {
            // A 3D application's own file zipped is still that file.
            let foreign = entries
                .iter()
                .find_map(|(_, name, _)| unsupported(&[], Some(name)));
            return Err(foreign.unwrap_or_else(|| {
                bad("it holds no mesh file (OBJ, glTF/GLB, OFF, PLY, STL)".into())
            }));
        }
        several => {
            let names: Vec<&str> = several.iter().map(|(_, n, _)| n.as_str()).collect();
            return Err(bad(format!(
                "it holds {} mesh files ({}); upload one mesh per archive",
                names.len(),
                names.join(", ")
            )));
        }
    };
    let format = Format::from_path(std::path::Path::new(&name)).expect("a mesh name");
    let folder = name.rsplit_once('/').map_or("", |(folder, _)| folder);
    let wanted: Vec<&(usize, String, u64)> = entries
        .iter()
        .filter(|(index, _, _)| *index == mesh_index || format == Format::Gltf)
        .collect();
    let declared = wanted
        .iter()
        .fold(0u64, |sum, (_, _, size)| sum.saturating_add(*size));
    check_limit(
        "bytes unpacked",
        usize::try_from(declared).unwrap_or(usize::MAX),
        limits.max_unpacked_bytes,
    )?;
    let mut unpacked = Unpacked {
        name: name.clone(),
        format,
        mesh: Vec::new(),
        resources: BTreeMap::new(),
    };
    for &&(index, ref entry_name, size) in &wanted {
        let entry = archive.by_index(index).map_err(|e| bad(format!("{e}")))?;
        let mut data = Vec::with_capacity(usize::try_from(size).unwrap_or(0));
        entry
            .take(size.saturating_add(1))
            .read_to_end(&mut data)
            .map_err(|e| bad(format!("{entry_name}: {e}")))?;
        if data.len() as u64 > size {
            return Err(bad(format!(
                "{entry_name} inflates past the {size} bytes it declares"
            )));
        }
        if index == mesh_index {
            unpacked.mesh = data;
        } else {
            let relative = entry_name
                .strip_prefix(folder)
                .and_then(|rest| rest.strip_prefix('/'))
                .filter(|_| !folder.is_empty())
                .unwrap_or(entry_name);
            unpacked.resources.insert(relative.to_string(), data);
        }
    }
    Ok(unpacked)
}

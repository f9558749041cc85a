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

/// A zip archive opened under the limits: its entries listed with the sizes they declare,
/// nothing inflated yet. Each read is checked, with all reads before it, against
/// `limits.max_unpacked_bytes` before it inflates anything.
pub(super) struct Archive<'a> {
    zip: zip::ZipArchive<Cursor<&'a [u8]>>,
    /// Every file entry but the archiver's clutter: its index, name and declared size.
    pub entries: Vec<(usize, String, u64)>,
    inflated: u64,
    max_unpacked: u64,
}

impl<'a> Archive<'a> {
    pub(super) fn open(bytes: &'a [u8], limits: &Limits) -> Result<Self> {
        let mut zip = zip::ZipArchive::new(Cursor::new(bytes)).map_err(bad)?;
        check_limit("archive entries", zip.len(), limits.max_archive_entries)?;
        let mut entries = Vec::new();
        for index in 0..zip.len() {
            let entry = zip.by_index(index).map_err(bad)?;
            let name = entry.name().map_err(bad)?.into_owned();
            if !is_clutter(&name) && !entry.is_dir() {
                entries.push((index, name, entry.size()));
            }
        }
        Ok(Self {
            zip,
            entries,
            inflated: 0,
            max_unpacked: limits.max_unpacked_bytes as u64,
        })
    }

    /// The entry named `name`: exactly, else the only one equal ignoring ASCII case.
    pub(super) fn find(&self, name: &str) -> Option<&(usize, String, u64)> {
        self.entries.iter().find(|(_, n, _)| n == name).or_else(|| {
            let mut same = self
                .entries
                .iter()
                .filter(|(_, n, _)| n.eq_ignore_ascii_case(name));
            match (same.next(), same.next()) {
                (Some(only), None) => Some(only),
                _ => None,
            }
        })
    }

    /// Inflates entry `index`, refusing it when its declared size would take the archive past
    /// the limit, or when it inflates past what it declares.
    pub(super) fn read(&mut self, index: usize) -> Result<Vec<u8>> {
        let (_, name, size) = self
            .entries
            .iter()
            .find(|(i, _, _)| *i == index)
            .cloned()
            .ok_or_else(|| Error::Archive(format!("no entry {index}")))?;
        let total = self.inflated.saturating_add(size);
        if total > self.max_unpacked {
            return Err(Error::TooLarge {
                what: "bytes unpacked",
                count: usize::try_from(total).unwrap_or(usize::MAX),
                limit: usize::try_from(self.max_unpacked).unwrap_or(usize::MAX),
            });
        }
        self.inflated = total;
        let entry = self.zip.by_index(index).map_err(bad)?;
        let mut data = Vec::with_capacity(usize::try_from(size).unwrap_or(0));
        entry
            .take(size.saturating_add(1))
            .read_to_end(&mut data)
            .map_err(|e| Error::Archive(format!("{name}: {e}")))?;
        if data.len() as u64 > size {
            return Err(Error::Archive(format!(
                "{name} inflates past the {size} bytes it declares"
            )));
        }
        Ok(data)
    }
}

fn bad(e: impl std::fmt::Display) -> Error {
    Error::Archive(e.to_string())
}

/// Unpacks the one mesh file of a zip archive, with its resources when it is a glTF.
pub fn unpack(bytes: &[u8], limits: &Limits) -> Result<Unpacked> {
    let mut archive = Archive::open(bytes, limits)?;
    let meshes: Vec<&(usize, String, u64)> = archive
        .entries
        .iter()
        .filter(|(_, name, _)| Format::from_path(std::path::Path::new(name)).is_some())
        .collect();
    let (mesh_index, name, _) = match meshes.as_slice() {
        [one] => (*one).clone(),
        [] => {
            // A 3D application's own file zipped is still that file.
            let foreign = archive
                .entries
                .iter()
                .find_map(|(_, name, _)| unsupported(&[], Some(name)));
            return Err(foreign.unwrap_or_else(|| {
                Error::Archive("it holds no mesh file (OBJ, glTF/GLB, OFF, PLY, STL, 3MF)".into())
            }));
        }
        several => {
            let names: Vec<&str> = several.iter().map(|(_, n, _)| n.as_str()).collect();
            return Err(Error::Archive(format!(
                "it holds {} mesh files ({}); upload one mesh per archive",
                names.len(),
                names.join(", ")
            )));
        }
    };
    let format = Format::from_path(std::path::Path::new(&name)).expect("a mesh name");
    let folder = name.rsplit_once('/').map_or("", |(folder, _)| folder);
    let wanted: Vec<(usize, String, u64)> = archive
        .entries
        .iter()
        .filter(|(index, _, _)| *index == mesh_index || format == Format::Gltf)
        .cloned()
        .collect();
    // All of what will be inflated, checked before any of it is.
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
    for (index, entry_name, _) in wanted {
        let data = archive.read(index)?;
        if index == mesh_index {
            unpacked.mesh = data;
        } else {
            let relative = entry_name
                .strip_prefix(folder)
                .and_then(|rest| rest.strip_prefix('/'))
                .filter(|_| !folder.is_empty())
                .unwrap_or(&entry_name);
            unpacked.resources.insert(relative.to_string(), data);
        }
    }
    Ok(unpacked)
}

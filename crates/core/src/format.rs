//! The mesh file formats, by name, extension and media type: what an error, an upload and a
//! loader all name ([`crate::mesh::load`] reads them and recognises them by content).

use std::fmt;
use std::path::Path;

/// A supported mesh file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// Wavefront OBJ (text).
    Obj,
    /// glTF 2.0 JSON (`.gltf`), buffers embedded as `data:` URIs or in sibling files.
    Gltf,
    /// Binary glTF 2.0 (`.glb`).
    Glb,
    /// Object File Format (text; binary OFF is refused).
    Off,
    /// Stanford PLY (text or binary).
    Ply,
    /// STereoLithography (text or binary).
    Stl,
    /// 3D Manufacturing Format: a zip of XML models (core specification and the Production
    /// extension's parts); the whole build is one model.
    #[serde(rename = "3mf")]
    ThreeMf,
}

impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Format::Obj => "OBJ",
            Format::Gltf => "glTF",
            Format::Glb => "GLB",
            Format::Off => "OFF",
            Format::Ply => "PLY",
            Format::Stl => "STL",
            Format::ThreeMf => "3MF",
        })
    }
}

impl Format {
    /// Every supported format.
    pub const ALL: [Format; 7] = [
        Format::Obj,
        Format::Gltf,
        Format::Glb,
        Format::Off,
        Format::Ply,
        Format::Stl,
        Format::ThreeMf,
    ];

    /// The format of a file extension (without the dot, any case).
    pub fn from_extension(ext: &str) -> Option<Format> {
        match ext.to_ascii_lowercase().as_str() {
            "obj" => Some(Format::Obj),
            "gltf" => Some(Format::Gltf),
            "glb" => Some(Format::Glb),
            "off" => Some(Format::Off),
            "ply" => Some(Format::Ply),
            "stl" => Some(Format::Stl),
            "3mf" => Some(Format::ThreeMf),
            _ => None,
        }
    }

    /// The format named by a path's extension.
    pub fn from_path(path: &Path) -> Option<Format> {
        Format::from_extension(path.extension()?.to_str()?)
    }

    /// The format of an HTTP `Content-Type` (parameters such as `; charset=utf-8` ignored).
    /// Generic types (`application/octet-stream`, `text/plain`) give `None`: sniff instead.
    pub fn from_content_type(content_type: &str) -> Option<Format> {
        let essence = content_type.split(';').next()?.trim().to_ascii_lowercase();
        match essence.as_str() {
            "model/obj" | "application/x-obj" | "text/x-obj" => Some(Format::Obj),
            "model/gltf+json" => Some(Format::Gltf),
            "model/gltf-binary" => Some(Format::Glb),
            "model/off" | "model/x-off" | "application/off" | "application/x-off" => {
                Some(Format::Off)
            }
            "model/ply" | "model/x-ply" | "application/ply" | "application/x-ply" => {
                Some(Format::Ply)
            }
            "model/stl"
            | "model/x.stl-ascii"
            | "model/x.stl-binary"
            | "application/sla"
            | "application/vnd.ms-pki.stl"
            | "application/x-stl" => Some(Format::Stl),
            "model/3mf" | "application/vnd.ms-package.3dmanufacturing-3dmodel+xml" => {
                Some(Format::ThreeMf)
            }
            _ => None,
        }
    }

    /// The usual file extension, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            Format::Obj => "obj",
            Format::Gltf => "gltf",
            Format::Glb => "glb",
            Format::Off => "off",
            Format::Ply => "ply",
            Format::Stl => "stl",
            Format::ThreeMf => "3mf",
        }
    }

    /// The content type a client sends a file of this format with (the inverse of
    /// [`Format::from_content_type`]).
    pub fn media_type(self) -> &'static str {
        match self {
            Format::Obj => "model/obj",
            Format::Gltf => "model/gltf+json",
            Format::Glb => "model/gltf-binary",
            Format::Off => "model/x-off",
            Format::Ply => "model/ply",
            Format::Stl => "model/stl",
            Format::ThreeMf => "model/3mf",
        }
    }
}

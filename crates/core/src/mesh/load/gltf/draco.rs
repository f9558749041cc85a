//! `KHR_draco_mesh_compression`: a primitive whose positions and triangles are a Draco stream
//! (Blender's "compression" export, `gltf-transform draco`).
//!
//! Decoded by `draco-core`, a pure-Rust implementation of Draco's decoder: Google's library
//! needs cmake to build, and the build must need nothing but the Rust toolchain and a C
//! compiler. The stream is decoded whether the extension is required or only used: a file
//! that lists it as optional carries placeholder accessors (no data, or a coarse fallback),
//! and the Draco stream is the real geometry.

use std::collections::BTreeMap;

use draco_core::{DecodeLimits, DecoderBuffer, ErrorKind, Mesh, MeshDecoder};
use serde::Deserialize;

use ::gltf::json::mesh::Mode;
use glam::DVec3;

use super::super::parse_error;
use super::Geometry;
use crate::error::Error;
use crate::format::Format;

pub(super) const NAME: &str = "KHR_draco_mesh_compression";

/// The extension's object on a primitive: the view holding the stream, and the stream's id
/// of each glTF attribute.
#[derive(Debug, Deserialize)]
#[serde(rename_all = "camelCase")]
pub(super) struct DracoPrimitive {
    pub buffer_view: u32,
    attributes: BTreeMap<String, u32>,
}

impl DracoPrimitive {
    /// The Draco stream a primitive's extensions declare, if any.
    pub(super) fn of(
        extensions: Option<&::gltf::json::extensions::mesh::Primitive>,
    ) -> Option<Result<Self, String>> {
        let value = extensions?.others.get(NAME)?;
        Some(
            serde_json::from_value(value.clone())
                .map_err(|e| format!("invalid {NAME} on a primitive: {e}")),
        )
    }

    /// Decodes `stream` into its positions and triangles.
    /// `max_faces` and `max_bytes` bound the decode before the decoder allocates for them.
    pub(super) fn decode(
        &self,
        format: Format,
        stream: &[u8],
        max_faces: usize,
        max_bytes: usize,
    ) -> Result<Geometry, Error> {
        let invalid = |message: String| parse_error(format, message);
        let position_id = *self
            .attributes
            .get("POSITION")
            .ok_or_else(|| invalid(format!("the {NAME} stream names no POSITION attribute")))?;
        let limits = DecodeLimits::default()
            .with_max_faces(max_faces as u64)
            .with_max_decoded_bytes(max_bytes as u64);
        let mut buffer = DecoderBuffer::new(stream).with_limits(limits);
        let mut mesh = Mesh::new();
        MeshDecoder::new()
            .decode(&mut buffer, &mut mesh)
            .map_err(|e| match e.kind() {
                ErrorKind::LimitExceeded => Error::DecodesTooLarge(format!("Draco: {e}")),
                _ => invalid(format!("the {NAME} stream does not decode: {e}")),
            })?;
        let attribute = mesh.attribute_by_unique_id(position_id).ok_or_else(|| {
            invalid(format!(
                "the {NAME} stream has no attribute {position_id} for POSITION"
            ))
        })?;
        if attribute.num_components() != 3 {
            return Err(invalid(format!(
                "the {NAME} POSITION attribute has {} components",
                attribute.num_components()
            )));
        }
        let positions = attribute
            .read_f32s(mesh.num_points(), 3)
            .as_chunks::<3>()
            .0
            .iter()
            .map(|p| DVec3::from_array(p.map(f64::from)))
            .collect();
        let corners = mesh.faces().iter().flatten().map(|point| point.0).collect();
        Ok(Geometry {
            positions,
            corners,
            mode: Mode::Triangles,
        })
    }
}

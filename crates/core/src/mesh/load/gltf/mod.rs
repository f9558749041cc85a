//! glTF 2.0, JSON (`.gltf`) and binary (`.glb`), via the `gltf` crate (SPEC §1.1).
//!
//! The default scene (else the first scene, else every node that is no node's child) is walked
//! with node transforms composed in `f64`; every `TRIANGLES`, `TRIANGLE_STRIP` and
//! `TRIANGLE_FAN` primitive is read in world coordinates, strips and fans converted to
//! triangles, and the winding flipped under a mirroring transform so that faces keep their
//! orientation. Other primitive modes are ignored. Buffers come from the GLB binary chunk,
//! from `data:` URIs, or from [`Resources`] (sibling files, upload parts).
//!
//! Files as web pipelines write them load too: meshopt-compressed buffer views
//! ([`meshopt`]), Draco-compressed primitives ([`draco`]), quantized positions
//! (`KHR_mesh_quantization`) and GPU instancing (`EXT_mesh_gpu_instancing`: each instance a
//! placed copy of its node's mesh).
//!
//! `gltf` splits GLB files and deserialises the JSON; the JSON tree is then read with
//! bounds-checked lookups. The crate's validation and accessor readers are not safe on hostile
//! input, so neither is used: validation indexes `accessors` with an unchecked `POSITION`
//! index (a panic on an out-of-range index), and the accessor iterators compute `count - 1` and
//! `offset + stride × (count - 1)` unchecked and `debug_assert` the element type. Accessors
//! are read here instead, every range checked first.

mod draco;
mod meshopt;

use std::borrow::Cow;

use ::gltf::json::accessor::{ComponentType, GenericComponentType, IndexComponentType, Type};
use ::gltf::json::mesh::{Mode, Primitive, Semantic};
use ::gltf::json::validation::Checked;
use ::gltf::json::{self, Index, Root};
use base64::engine::general_purpose::{GeneralPurpose, GeneralPurposeConfig};
use base64::engine::DecodePaddingMode;
use base64::Engine;
use glam::{DMat4, DQuat, DVec3, DVec4};

use super::{check_limit, parse_error, vertex_id, Format, Resources};
use crate::error::{Error, Result};
use crate::mesh::RawMesh;
use crate::params::Limits;

/// Required extensions whose geometry this loader reads, or that do not change geometry
/// (materials, textures, lights). Any other required extension is refused as unsupported, as
/// the glTF specification demands.
const READABLE_EXTENSIONS: [&str; 12] = [
    "KHR_mesh_quantization",
    "EXT_meshopt_compression",
    "KHR_meshopt_compression",
    draco::NAME,
    INSTANCING,
    "KHR_materials_",
    "KHR_texture_",
    "EXT_texture_",
    "KHR_lights_",
    "KHR_techniques_webgl",
    "KHR_xmp",
    "EXT_lights_",
];

/// Loads a `.gltf` or `.glb` file (either is accepted whatever `format` says; `format` names
/// the file in errors).
pub(super) fn load(
    bytes: &[u8],
    format: Format,
    resources: &dyn Resources,
    limits: &Limits,
) -> Result<RawMesh> {
    let bytes = if bytes.starts_with(b"glTF") {
        check_glb_header(bytes, format)?;
        bytes
    } else {
        bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes)
    };
    let ::gltf::Gltf { document, blob } = ::gltf::Gltf::from_slice_without_validation(bytes)
        .map_err(|e| {
            if is_gltf_1(bytes) {
                return Error::Unsupported {
                    feature: "glTF 1.0".into(),
                    conversion: "convert it to glTF 2.0, e.g. `npx gltf-pipeline -i model.gltf -o model-2.gltf` (gltf-pipeline upgrades 1.0 files), or import and export it in Blender",
                };
            }
            parse_error(format, e.to_string())
        })?;
    let root = document.into_json();
    if let Some(name) = root.extensions_required.iter().find(|name| {
        !READABLE_EXTENSIONS
            .iter()
            .any(|prefix| name.starts_with(prefix))
    }) {
        return Err(Error::Unsupported {
            feature: format!("the required glTF extension {name}"),
            conversion: "save the file again without it, e.g. with Blender's glTF 2.0 export, or `npx @gltf-transform/cli` commands that remove the extension",
        });
    }

    let mut reader = Reader {
        root: &root,
        format,
        resources,
        limits,
        blob,
        buffers: vec![None; root.buffers.len()],
        decoded: vec![None; root.buffer_views.len()],
    };
    let mut mesh = RawMesh::default();
    for placed in placements(&root, format)? {
        let primitives = &root.meshes[placed.mesh].primitives;
        for world in reader.instances(&root.nodes[placed.node], placed.world)? {
            for primitive in primitives {
                reader.append_primitive(&mut mesh, primitive, world)?;
            }
        }
    }
    Ok(mesh)
}

/// The extension that places many copies of a node's mesh.
const INSTANCING: &str = "EXT_mesh_gpu_instancing";

/// The most bytes one decoded stream (a meshopt view, a Draco primitive) may take: 64 per
/// vertex the limits allow (positions and the attributes stored beside them), or 12 per
/// triangle (32-bit indices), whichever is more.
fn max_decoded_bytes(limits: &Limits) -> usize {
    limits
        .max_input_vertices
        .saturating_mul(64)
        .max(limits.max_input_triangles.saturating_mul(12))
}

/// Whether a file `gltf` cannot read is glTF 1.0: a GLB of version 1, or JSON whose
/// `asset.version` starts with 1 (1.0 files name it; a few name none, and are not told apart).
fn is_gltf_1(bytes: &[u8]) -> bool {
    if bytes.starts_with(b"glTF") {
        return bytes.get(4..8) == Some(&1u32.to_le_bytes()[..]);
    }
    serde_json::from_slice::<serde_json::Value>(bytes).is_ok_and(|json| {
        json["asset"]["version"]
            .as_str()
            .is_some_and(|v| v.starts_with("1."))
    })
}

/// Rejects a GLB header whose total length is shorter than the header itself: `gltf`
/// subtracts the header size from it unchecked (an overflow panic in debug builds).
fn check_glb_header(bytes: &[u8], format: Format) -> Result<()> {
    let length = bytes
        .get(8..12)
        .and_then(|b| <[u8; 4]>::try_from(b).ok())
        .map(u32::from_le_bytes);
    match length {
        Some(length) if length >= 12 => Ok(()),
        Some(length) => Err(parse_error(
            format,
            format!("the GLB header declares a total length of {length} bytes"),
        )),
        None => Err(parse_error(format, "the GLB header is truncated")),
    }
}

/// A node of the scene that holds a mesh, and its world matrix.
struct Placement {
    node: usize,
    mesh: usize,
    world: DMat4,
}

/// Every mesh placed in the scene: the default scene, else the first, else all nodes that are
/// no node's child. Each node may be reached once: glTF node trees are disjoint, and a cycle or
/// shared children would otherwise loop or multiply the work.
fn placements(root: &Root, format: Format) -> Result<Vec<Placement>> {
    let error = |message: String| parse_error(format, message);
    let scene = match root.scene {
        Some(index) => Some(root.get(index).ok_or_else(|| {
            error(format!(
                "the default scene {} does not exist",
                index.value()
            ))
        })?),
        None => root.scenes.first(),
    };
    let roots: Vec<usize> = match scene {
        Some(scene) => scene.nodes.iter().map(Index::value).collect(),
        None => {
            let mut is_child = vec![false; root.nodes.len()];
            for child in root.nodes.iter().flat_map(|n| n.children.iter().flatten()) {
                if let Some(flag) = is_child.get_mut(child.value()) {
                    *flag = true;
                }
            }
            (0..root.nodes.len()).filter(|&i| !is_child[i]).collect()
        }
    };

    let mut reached = vec![false; root.nodes.len()];
    let mut stack: Vec<(usize, DMat4)> =
        roots.iter().rev().map(|&i| (i, DMat4::IDENTITY)).collect();
    let mut found = Vec::new();
    while let Some((index, parent)) = stack.pop() {
        let node = root
            .nodes
            .get(index)
            .ok_or_else(|| error(format!("node {index} does not exist")))?;
        if std::mem::replace(&mut reached[index], true) {
            return Err(error(format!(
                "node {index} is reached twice in the scene graph (a cycle or a shared child)"
            )));
        }
        let world = parent * local_matrix(node);
        if let Some(mesh) = node.mesh {
            if mesh.value() >= root.meshes.len() {
                return Err(error(format!(
                    "node {index} refers to mesh {}, which does not exist",
                    mesh.value()
                )));
            }
            found.push(Placement {
                node: index,
                mesh: mesh.value(),
                world,
            });
        }
        for child in node.children.iter().flatten().rev() {
            stack.push((child.value(), world));
        }
    }
    Ok(found)
}

/// A node's local transform: its `matrix` (column-major), else translation × rotation × scale.
fn local_matrix(node: &json::Node) -> DMat4 {
    if let Some(m) = node.matrix {
        return DMat4::from_cols_array(&m.map(f64::from));
    }
    let translation = DVec3::from_array(node.translation.unwrap_or([0.0; 3]).map(f64::from));
    let rotation = DVec4::from_array(node.rotation.unwrap_or_default().0.map(f64::from))
        .try_normalize()
        .map_or(DQuat::IDENTITY, DQuat::from_vec4);
    let scale = DVec3::from_array(node.scale.unwrap_or([1.0; 3]).map(f64::from));
    DMat4::from_scale_rotation_translation(scale, rotation, translation)
}

/// Reads accessors, resolving each buffer and decoding each compressed view once, on first
/// use.
struct Reader<'a> {
    root: &'a Root,
    format: Format,
    resources: &'a dyn Resources,
    limits: &'a Limits,
    /// The GLB binary chunk, until buffer 0 takes it.
    blob: Option<Vec<u8>>,
    buffers: Vec<Option<Vec<u8>>>,
    /// Each meshopt-compressed buffer view's decoded bytes.
    decoded: Vec<Option<Vec<u8>>>,
}

/// A primitive's geometry in its mesh's coordinates: positions, and corners (indices into
/// them) read in `mode`.
struct Geometry {
    positions: Vec<DVec3>,
    corners: Vec<u32>,
    mode: Mode,
}

impl Geometry {
    fn triangle_count(&self) -> usize {
        match self.mode {
            Mode::Triangles => self.corners.len() / 3,
            _ => self.corners.len().saturating_sub(2),
        }
    }

    /// The corners of triangle `face`, in the winding of its primitive mode.
    fn triangle(&self, face: usize) -> [u32; 3] {
        let c = &self.corners;
        match self.mode {
            Mode::Triangles => [c[3 * face], c[3 * face + 1], c[3 * face + 2]],
            Mode::TriangleStrip if face.is_multiple_of(2) => [c[face], c[face + 1], c[face + 2]],
            Mode::TriangleStrip => [c[face], c[face + 2], c[face + 1]],
            _ => [c[face + 1], c[face + 2], c[0]],
        }
    }
}

impl<'a> Reader<'a> {
    fn error(&self, message: impl Into<String>) -> Error {
        parse_error(self.format, message)
    }

    /// The world matrices of a node's copies: the node's own, or with
    /// `EXT_mesh_gpu_instancing` one per instance, its TRS composed after the node's.
    fn instances(&mut self, node: &json::Node, world: DMat4) -> Result<Vec<DMat4>> {
        let Some(value) = node
            .extensions
            .as_ref()
            .and_then(|e| e.others.get(INSTANCING))
        else {
            return Ok(vec![world]);
        };
        let attributes: std::collections::BTreeMap<String, Index<json::Accessor>> =
            serde_json::from_value(value["attributes"].clone())
                .map_err(|e| self.error(format!("invalid {INSTANCING} attributes: {e}")))?;
        let mut read = |name: &str, width: usize| -> Result<Option<Vec<DVec4>>> {
            attributes
                .get(name)
                .map(|&index| self.vectors(self.accessor(index)?, width, name))
                .transpose()
        };
        let translations = read("TRANSLATION", 3)?;
        let rotations = read("ROTATION", 4)?;
        let scales = read("SCALE", 3)?;
        let counts: Vec<usize> = [&translations, &rotations, &scales]
            .into_iter()
            .flatten()
            .map(Vec::len)
            .collect();
        let Some(&count) = counts.first() else {
            return Ok(vec![world]);
        };
        if counts.iter().any(|&c| c != count) {
            return Err(self.error(format!(
                "the {INSTANCING} attributes of a node have different counts {counts:?}"
            )));
        }
        Ok((0..count)
            .map(|i| {
                let at =
                    |v: &Option<Vec<DVec4>>, default: DVec4| v.as_ref().map_or(default, |v| v[i]);
                let rotation = at(&rotations, DVec4::W)
                    .try_normalize()
                    .map_or(DQuat::IDENTITY, DQuat::from_vec4);
                world
                    * DMat4::from_scale_rotation_translation(
                        at(&scales, DVec4::ONE).truncate(),
                        rotation,
                        at(&translations, DVec4::ZERO).truncate(),
                    )
            })
            .collect())
    }

    /// Appends one primitive, transformed by `world`, if it is made of triangles.
    fn append_primitive(
        &mut self,
        mesh: &mut RawMesh,
        primitive: &Primitive,
        world: DMat4,
    ) -> Result<()> {
        let mode = match primitive.mode {
            Checked::Valid(mode @ (Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan)) => {
                mode
            }
            _ => return Ok(()),
        };
        let geometry = match draco::DracoPrimitive::of(primitive.extensions.as_ref()) {
            Some(draco) => self.draco(&draco.map_err(|e| self.error(e))?, mesh)?,
            None => self.accessors(primitive, mode, mesh)?,
        };
        let triangle_count = geometry.triangle_count();
        check_limit(
            "triangles",
            mesh.triangles.len().saturating_add(triangle_count),
            self.limits.max_input_triangles,
        )?;
        let offset = vertex_id(mesh.positions.len())?;
        // Every index of this primitive, offset, must fit in a u32 too.
        vertex_id(mesh.positions.len() + geometry.positions.len())?;
        let first_face = mesh.triangles.len();
        let vertex_count = geometry.positions.len();
        let corner = |c: u32, face: usize| {
            if (c as usize) < vertex_count {
                Ok(c + offset)
            } else {
                Err(Error::IndexOutOfRange {
                    face: first_face + face,
                    index: c.into(),
                    vertex_count,
                })
            }
        };
        let flip = world.determinant() < 0.0;
        for face in 0..triangle_count {
            let [a, b, c] = geometry.triangle(face);
            let [a, b, c] = [corner(a, face)?, corner(b, face)?, corner(c, face)?];
            mesh.triangles
                .push(if flip { [a, c, b] } else { [a, b, c] });
        }
        mesh.positions.extend(
            geometry
                .positions
                .iter()
                .map(|&p| world.transform_point3(p)),
        );
        Ok(())
    }

    /// A primitive's geometry from its accessors.
    fn accessors(&mut self, primitive: &Primitive, mode: Mode, mesh: &RawMesh) -> Result<Geometry> {
        let position_accessor = primitive
            .attributes
            .iter()
            .find(|(semantic, _)| matches!(semantic, Checked::Valid(Semantic::Positions)))
            .map(|(_, &index)| self.accessor(index))
            .ok_or_else(|| self.error("a triangle primitive has no POSITION attribute"))??;
        if matches!(
            position_accessor.component_type,
            Checked::Valid(GenericComponentType(ComponentType::U32))
        ) {
            return Err(self.error("POSITION must be a VEC3 of floats or small integers"));
        }
        let vertex_count = count(position_accessor);
        check_limit(
            "vertices",
            mesh.positions.len().saturating_add(vertex_count),
            self.limits.max_input_vertices,
        )?;
        let index_accessor = primitive.indices.map(|i| self.accessor(i)).transpose()?;
        let corner_count = index_accessor.map_or(vertex_count, count);
        if mode == Mode::Triangles && corner_count % 3 != 0 {
            return Err(self.error(format!(
                "a TRIANGLES primitive has {corner_count} corners, not a multiple of 3"
            )));
        }
        check_limit(
            "triangles",
            mesh.triangles.len().saturating_add(corner_count / 3),
            self.limits.max_input_triangles,
        )?;
        let positions = self
            .vectors(position_accessor, 3, "POSITION")?
            .into_iter()
            .map(DVec4::truncate)
            .collect();
        let corners = match index_accessor {
            Some(accessor) => {
                let index_type = match (accessor.type_, accessor.component_type) {
                    (Checked::Valid(Type::Scalar), Checked::Valid(GenericComponentType(t)))
                        if matches!(
                            t,
                            ComponentType::U8 | ComponentType::U16 | ComponentType::U32
                        ) =>
                    {
                        t
                    }
                    _ => return Err(self.error("indices must be unsigned integer scalars")),
                };
                self.read(accessor, component_size(index_type), 0, |b| {
                    unsigned(b, index_type)
                })?
            }
            None => (0..vertex_id(vertex_count)?).collect(),
        };
        Ok(Geometry {
            positions,
            corners,
            mode,
        })
    }

    /// A Draco-compressed primitive's geometry (the accessors are placeholders).
    fn draco(&mut self, draco: &draco::DracoPrimitive, mesh: &RawMesh) -> Result<Geometry> {
        let view: Index<json::buffer::View> = Index::new(draco.buffer_view);
        let length = self
            .root
            .get(view)
            .ok_or_else(|| self.error(format!("buffer view {} does not exist", view.value())))?
            .byte_length
            .0;
        let length = usize::try_from(length).unwrap_or(usize::MAX);
        let max_faces = self
            .limits
            .max_input_triangles
            .saturating_sub(mesh.triangles.len());
        let max_bytes = max_decoded_bytes(self.limits);
        let format = self.format;
        let (stream, _) = self.view(view, 0, length, 1, true)?;
        let geometry = draco.decode(format, stream, max_faces, max_bytes)?;
        check_limit(
            "vertices",
            mesh.positions
                .len()
                .saturating_add(geometry.positions.len()),
            self.limits.max_input_vertices,
        )?;
        Ok(geometry)
    }

    /// The elements of a `width`-component float (or normalised integer) accessor, padded
    /// to 4 components with zeros.
    fn vectors(
        &mut self,
        accessor: &json::Accessor,
        width: usize,
        name: &str,
    ) -> Result<Vec<DVec4>> {
        let component_type = match (accessor.type_, accessor.component_type) {
            (Checked::Valid(t), Checked::Valid(GenericComponentType(c)))
                if t.multiplicity() == width =>
            {
                c
            }
            _ => {
                return Err(self.error(format!(
                    "{name} must be a {width}-component vector accessor"
                )))
            }
        };
        let normalized = accessor.normalized;
        let size = component_size(component_type);
        self.read(accessor, width * size, DVec4::ZERO, |b| {
            let mut v = [0.0; 4];
            for (k, slot) in v.iter_mut().take(width).enumerate() {
                *slot = component(&b[k * size..], component_type, normalized);
            }
            DVec4::from_array(v)
        })
    }

    fn accessor(&self, index: Index<json::Accessor>) -> Result<&'a json::Accessor> {
        let root: &'a Root = self.root;
        root.get(index)
            .ok_or_else(|| self.error(format!("accessor {} does not exist", index.value())))
    }

    /// The `count` elements of `accessor`, each `element_size` bytes decoded by `decode`,
    /// sparse substitution applied (`zero` where the accessor has no buffer view).
    fn read<T: Clone>(
        &mut self,
        accessor: &json::Accessor,
        element_size: usize,
        zero: T,
        decode: impl Fn(&[u8]) -> T,
    ) -> Result<Vec<T>> {
        let count = count(accessor);
        if count == 0 {
            return Ok(Vec::new());
        }
        let mut values = match accessor.buffer_view {
            Some(view) => {
                let offset = accessor.byte_offset.map_or(0, |o| o.0);
                let (data, stride) = self.view(view, offset, count, element_size, false)?;
                (0..count)
                    .map(|i| decode(&data[i * stride..][..element_size]))
                    .collect()
            }
            None => vec![zero; count],
        };
        let format = self.format;
        if let Some(sparse) = &accessor.sparse {
            let changed = usize::try_from(sparse.count.0).unwrap_or(usize::MAX);
            if changed > count {
                return Err(self.error(format!(
                    "a sparse accessor changes {changed} of its {count} elements"
                )));
            }
            let index_type = match sparse.indices.component_type {
                Checked::Valid(IndexComponentType(t)) => t,
                Checked::Invalid => return Err(self.error("invalid sparse index type")),
            };
            let index_size = component_size(index_type);
            let (data, _) = self.view(
                sparse.indices.buffer_view,
                sparse.indices.byte_offset.0,
                changed,
                index_size,
                true,
            )?;
            let targets: Vec<u32> = data
                .chunks_exact(index_size)
                .map(|b| unsigned(b, index_type))
                .collect();
            let (data, _) = self.view(
                sparse.values.buffer_view,
                sparse.values.byte_offset.0,
                changed,
                element_size,
                true,
            )?;
            for (&target, bytes) in targets.iter().zip(data.chunks_exact(element_size)) {
                let slot = values.get_mut(target as usize).ok_or_else(|| {
                    parse_error(
                        format,
                        format!("sparse index {target} is beyond the accessor's {count} elements"),
                    )
                })?;
                *slot = decode(bytes);
            }
        }
        Ok(values)
    }

    /// The bytes of `count` elements of `element_size` bytes at `offset` in buffer view
    /// `index`, and the stride between them (`packed`: sparse data ignores `byteStride`).
    /// Every range is checked against the view, the view against its buffer's declared
    /// length, and that against the bytes actually supplied.
    fn view(
        &mut self,
        index: Index<json::buffer::View>,
        offset: u64,
        count: usize,
        element_size: usize,
        packed: bool,
    ) -> Result<(&[u8], usize)> {
        let root: &'a Root = self.root;
        let view = root
            .get(index)
            .ok_or_else(|| self.error(format!("buffer view {} does not exist", index.value())))?;
        let stride = match view.byte_stride {
            Some(s) if !packed && s.0 != 0 => s.0,
            _ => element_size,
        };
        if stride < element_size {
            return Err(self.error(format!(
                "buffer view {} has a stride of {stride} bytes for {element_size}-byte elements",
                index.value()
            )));
        }
        let span = (count as u64)
            .checked_sub(1)
            .and_then(|n| n.checked_mul(stride as u64))
            .and_then(|n| n.checked_add(element_size as u64))
            .unwrap_or(0);
        let end_in_view = offset.checked_add(span);
        let view_length = view.byte_length.0;
        if end_in_view.is_none_or(|end| end > view_length) {
            return Err(self.error(format!(
                "an accessor reads {count} elements at offset {offset}, beyond the {view_length} \
                 bytes of buffer view {}",
                index.value()
            )));
        }
        let data = self.view_bytes(index.value(), view)?;
        // In range: offset + span <= view_length == data.len().
        let from = offset as usize;
        Ok((&data[from..from + span as usize], stride))
    }

    /// The `byteLength` bytes of buffer view `index`: from its buffer, or decoded from their
    /// meshopt-compressed form (then the view's own buffer is a fallback, never read).
    fn view_bytes(&mut self, index: usize, view: &'a json::buffer::View) -> Result<&[u8]> {
        let length = view.byte_length.0;
        let Some(compressed) = meshopt::Compressed::of(view.extensions.as_ref()) else {
            let start = view.byte_offset.map_or(0, |o| o.0);
            return self.buffer_range(view.buffer.value(), start, length);
        };
        if self.decoded[index].is_none() {
            let compressed = compressed.map_err(|e| self.error(e))?;
            let decoded_len = compressed
                .decoded_len(max_decoded_bytes(self.limits))
                .map_err(|e| self.error(e))?;
            if (decoded_len as u64) < length {
                return Err(self.error(format!(
                    "buffer view {index} of {length} bytes decodes to {decoded_len} bytes"
                )));
            }
            let encoded = self.buffer_range(
                compressed.buffer,
                compressed.byte_offset,
                compressed.byte_length,
            )?;
            let bytes = compressed
                .decode(encoded, decoded_len)
                .map_err(|e| self.error(e))?;
            self.decoded[index] = Some(bytes);
        }
        let bytes = self.decoded[index].as_deref().unwrap_or_default();
        Ok(&bytes[..length as usize])
    }

    /// `length` bytes at `start` of buffer `index`, checked against the buffer's declared
    /// length, and that against the bytes actually supplied.
    fn buffer_range(&mut self, index: usize, start: u64, length: u64) -> Result<&[u8]> {
        let declared = self
            .root
            .buffers
            .get(index)
            .ok_or_else(|| self.error(format!("buffer {index} does not exist")))?
            .byte_length
            .0;
        if start.checked_add(length).is_none_or(|end| end > declared) {
            return Err(self.error(format!(
                "{length} bytes at offset {start} end beyond the {declared} bytes of buffer {index}"
            )));
        }
        let data = self.buffer(index)?;
        // In range: start + length <= declared <= data.len() (checked when resolved).
        Ok(&data[start as usize..(start + length) as usize])
    }

    /// The bytes of buffer `index` (which exists), resolved on first use.
    fn buffer(&mut self, index: usize) -> Result<&[u8]> {
        if self.buffers[index].is_none() {
            let bytes = self.resolve(index)?;
            self.buffers[index] = Some(bytes);
        }
        Ok(self.buffers[index].as_deref().unwrap_or_default())
    }

    /// Fetches buffer `index` from the GLB chunk, a `data:` URI or the resources, and checks
    /// that it holds at least its declared `byteLength`.
    fn resolve(&mut self, index: usize) -> Result<Vec<u8>> {
        let root = self.root;
        let buffer = &root.buffers[index];
        let bytes = match buffer.uri.as_deref() {
            None if index == 0 => self.blob.take().ok_or_else(|| {
                self.error("buffer 0 has no uri, and there is no GLB binary chunk")
            })?,
            None => return Err(self.error(format!("buffer {index} has no uri"))),
            Some(uri)
                if uri
                    .get(..5)
                    .is_some_and(|s| s.eq_ignore_ascii_case("data:")) =>
            {
                self.data_uri(index, &uri[5..])?
            }
            Some(uri) => {
                let decoded: Cow<str> = percent_encoding::percent_decode_str(uri)
                    .decode_utf8()
                    .unwrap_or(Cow::Borrowed(uri));
                self.resources
                    .get(&decoded)
                    .ok_or_else(|| Error::MissingResource {
                        uri: decoded.into_owned(),
                    })?
            }
        };
        let declared = buffer.byte_length.0;
        if (bytes.len() as u64) < declared {
            return Err(self.error(format!(
                "buffer {index} declares {declared} bytes but holds {}",
                bytes.len()
            )));
        }
        Ok(bytes)
    }

    /// Decodes the part of a `data:` URI after the scheme (RFC 2397): base64 (padding
    /// optional) or percent-encoded.
    fn data_uri(&self, index: usize, rest: &str) -> Result<Vec<u8>> {
        let (media_type, data) = rest
            .split_once(',')
            .ok_or_else(|| self.error(format!("buffer {index} has a data URI without a comma")))?;
        if media_type.to_ascii_lowercase().ends_with(";base64") {
            let engine = GeneralPurpose::new(
                &base64::alphabet::STANDARD,
                GeneralPurposeConfig::new()
                    .with_decode_padding_mode(DecodePaddingMode::Indifferent),
            );
            engine.decode(data).map_err(|e| {
                self.error(format!(
                    "buffer {index} has an invalid base64 data URI: {e}"
                ))
            })
        } else {
            Ok(percent_encoding::percent_decode_str(data).collect())
        }
    }
}

/// An accessor's element count.
fn count(accessor: &json::Accessor) -> usize {
    usize::try_from(accessor.count.0).unwrap_or(usize::MAX)
}

/// Size in bytes of one component.
fn component_size(t: ComponentType) -> usize {
    match t {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

/// One little-endian component as `f64`; normalised integers map to [-1, 1] or [0, 1].
fn component(b: &[u8], t: ComponentType, normalized: bool) -> f64 {
    let (value, scale) = match t {
        ComponentType::I8 => (f64::from(b[0] as i8), 127.0),
        ComponentType::U8 => (f64::from(b[0]), 255.0),
        ComponentType::I16 => (f64::from(i16::from_le_bytes([b[0], b[1]])), 32767.0),
        ComponentType::U16 => (f64::from(u16::from_le_bytes([b[0], b[1]])), 65535.0),
        ComponentType::U32 => (f64::from(unsigned(b, t)), f64::from(u32::MAX)),
        ComponentType::F32 => return f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
    };
    if normalized {
        (value / scale).max(-1.0)
    } else {
        value
    }
}

/// One little-endian unsigned integer component (signed types are read as their bits).
fn unsigned(b: &[u8], t: ComponentType) -> u32 {
    match t {
        ComponentType::I8 | ComponentType::U8 => b[0].into(),
        ComponentType::I16 | ComponentType::U16 => u16::from_le_bytes([b[0], b[1]]).into(),
        ComponentType::U32 | ComponentType::F32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
    }
}

//! 3MF, the 3D Manufacturing Format (core specification 1.3 and the Production extension):
//! what slicers (PrusaSlicer, Bambu Studio, Cura) and CAD tools write for printing.
//!
//! A 3MF file is a zip package of XML model parts. Objects are meshes or assemblies of
//! components (other objects, with transforms, and with the Production extension's `p:path`
//! in other model parts); the build places objects with transforms. One upload is one model:
//! the whole build, every item placed, in millimetres whatever the file's `unit`. Support
//! objects (`type="support"` / `"solidsupport"`) are not part of the design and are left out.
//! Extensions a file requires that can change geometry (slices, beams, booleans,
//! displacement, volumetric, encryption) are refused as unsupported.
//!
//! The package is untrusted: entries are inflated under [`Limits`] ([`Archive`]), vertices and
//! triangles are counted against the limits as they are parsed, and placements (components
//! can multiply a mesh) before they are appended; component nesting is bounded, so a cycle is
//! an error.

use std::collections::HashMap;

use glam::{DMat4, DVec3, DVec4};
use quick_xml::events::{BytesStart, Event};

use super::archive::{is_zip, Archive};
use super::{check_limit, parse_error, vertex_id, Format};
use crate::error::{Error, Result};
use crate::mesh::RawMesh;
use crate::params::Limits;

/// The relationship type of a package's root model part.
const MODEL_RELATIONSHIP: &str = "http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel";

/// Where the root model part is when the package does not say.
const DEFAULT_ROOT: &str = "3D/3dmodel.model";

/// Extensions that may be required without changing what is read here: the Production
/// extension (parts in other model files, read), materials and colours (ignored).
const READABLE_EXTENSIONS: [&str; 2] = [
    "http://schemas.microsoft.com/3dmanufacturing/production/2015/06",
    "http://schemas.microsoft.com/3dmanufacturing/material/2015/02",
];

/// How deep components may nest: far beyond real assemblies, and a cycle hits it at once.
const MAX_NESTING: usize = 16;

/// Whether `bytes` are a 3MF package: a zip whose directory holds a `.model` part under `3D/`.
pub(super) fn is_3mf(bytes: &[u8]) -> bool {
    is_zip(bytes)
        && zip::ZipArchive::new(std::io::Cursor::new(bytes)).is_ok_and(|zip| {
            zip.file_names().any(|name| {
                let name = name.unwrap_or_default().to_ascii_lowercase();
                name.starts_with("3d/") && name.ends_with(".model")
            })
        })
}

/// Loads the whole build of a 3MF package.
pub(super) fn load(bytes: &[u8], limits: &Limits) -> Result<RawMesh> {
    let mut package = Package {
        archive: Archive::open(bytes, limits).map_err(in_package)?,
        parts: HashMap::new(),
        limits,
        parsed_vertices: 0,
        parsed_triangles: 0,
    };
    let root = package.root_path()?;
    let (build, unit) = {
        let part = package.part(&root)?;
        (part.build.clone(), part.millimetres_per_unit)
    };
    let mut mesh = RawMesh::default();
    let to_millimetres = DMat4::from_scale(DVec3::splat(unit));
    for item in &build {
        let path = item.path.clone().unwrap_or_else(|| root.clone());
        package.place(
            &mut mesh,
            &path,
            item.object,
            to_millimetres * item.transform,
            0,
        )?;
    }
    Ok(mesh)
}

fn error(message: impl Into<String>) -> Error {
    parse_error(Format::ThreeMf, message)
}

/// A zip error of the package is a malformed 3MF file, not an unusable upload archive.
fn in_package(e: Error) -> Error {
    match e {
        Error::Archive(message) => error(format!("the zip package: {message}")),
        other => other,
    }
}

/// A reference to an object: a build item or a component.
#[derive(Debug, Clone)]
struct Reference {
    object: u32,
    /// The model part holding the object (Production extension's `p:path`), if not this one.
    path: Option<String>,
    transform: DMat4,
}

#[derive(Debug, Default)]
struct Object {
    /// A support structure, not part of the design.
    support: bool,
    positions: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
    components: Vec<Reference>,
}

/// One model part, parsed.
#[derive(Debug)]
struct Part {
    objects: HashMap<u32, Object>,
    build: Vec<Reference>,
    millimetres_per_unit: f64,
}

struct Package<'a> {
    archive: Archive<'a>,
    parts: HashMap<String, Part>,
    limits: &'a Limits,
    parsed_vertices: usize,
    parsed_triangles: usize,
}

impl Package<'_> {
    /// The root model part's entry name: the package relationship's target, else the default.
    fn root_path(&mut self) -> Result<String> {
        let Some(&(index, _, _)) = self.archive.find("_rels/.rels") else {
            return Ok(DEFAULT_ROOT.into());
        };
        let rels = self.archive.read(index).map_err(in_package)?;
        let mut reader = quick_xml::Reader::from_reader(rels.as_slice());
        loop {
            match reader.read_event() {
                Ok(Event::Start(e) | Event::Empty(e))
                    if e.local_name().as_ref() == "Relationship" =>
                {
                    let kind = attribute(&e, "Type")?;
                    if kind.as_deref() == Some(MODEL_RELATIONSHIP) {
                        if let Some(target) = attribute(&e, "Target")? {
                            return Ok(entry_name(&target));
                        }
                    }
                }
                Ok(Event::Eof) => return Ok(DEFAULT_ROOT.into()),
                Ok(_) => {}
                Err(e) => return Err(error(format!("_rels/.rels: {e}"))),
            }
        }
    }

    /// The model part at `path`, parsed on first use.
    fn part(&mut self, path: &str) -> Result<&Part> {
        if !self.parts.contains_key(path) {
            let &(index, _, _) = self
                .archive
                .find(path)
                .ok_or_else(|| error(format!("the package has no model part {path}")))?;
            let xml = self.archive.read(index).map_err(in_package)?;
            let part = self.parse(path, &xml)?;
            self.parts.insert(path.to_string(), part);
        }
        Ok(&self.parts[path])
    }

    /// Appends object `id` of part `path` and its components, placed by `world`.
    fn place(
        &mut self,
        mesh: &mut RawMesh,
        path: &str,
        id: u32,
        world: DMat4,
        depth: usize,
    ) -> Result<()> {
        if depth > MAX_NESTING {
            return Err(error(format!(
                "components nest more than {MAX_NESTING} deep (a cycle?)"
            )));
        }
        let limits = self.limits;
        let object = self.part(path)?.objects.get(&id).ok_or_else(|| {
            error(format!(
                "{path}: a build item or component refers to object {id}, which does not exist"
            ))
        })?;
        if object.support {
            return Ok(());
        }
        check_limit(
            "vertices",
            mesh.positions.len().saturating_add(object.positions.len()),
            limits.max_input_vertices,
        )?;
        check_limit(
            "triangles",
            mesh.triangles.len().saturating_add(object.triangles.len()),
            limits.max_input_triangles,
        )?;
        let offset = vertex_id(mesh.positions.len())?;
        vertex_id(mesh.positions.len() + object.positions.len())?;
        let flip = world.determinant() < 0.0;
        mesh.triangles.extend(object.triangles.iter().map(|t| {
            let [a, b, c] = t.map(|i| i + offset);
            if flip {
                [a, c, b]
            } else {
                [a, b, c]
            }
        }));
        mesh.positions
            .extend(object.positions.iter().map(|&p| world.transform_point3(p)));
        let components = object.components.clone();
        for component in components {
            let part = component.path.as_deref().unwrap_or(path).to_string();
            self.place(
                mesh,
                &part,
                component.object,
                world * component.transform,
                depth + 1,
            )?;
        }
        Ok(())
    }

    /// Parses one model part.
    fn parse(&mut self, path: &str, xml: &[u8]) -> Result<Part> {
        let at = |position: u64| {
            let end = (position as usize).min(xml.len());
            1 + xml[..end].iter().filter(|&&b| b == b'\n').count()
        };
        let mut reader = quick_xml::Reader::from_reader(xml);
        let mut part = Part {
            objects: HashMap::new(),
            build: Vec::new(),
            millimetres_per_unit: 1.0,
        };
        // The object being read, and its id.
        let mut current: Option<(u32, Object)> = None;
        // Elements open: a part cut short ends inside one.
        let mut open = 0usize;
        loop {
            let event = reader
                .read_event()
                .map_err(|e| error(format!("{path}, line {}: {e}", at(reader.error_position()))))?;
            let line = || at(reader.buffer_position());
            let in_part = |message: String| error(format!("{path}, line {}: {message}", line()));
            match &event {
                Event::Start(_) => open += 1,
                Event::End(_) => open = open.saturating_sub(1),
                _ => {}
            }
            match event {
                Event::Start(e) | Event::Empty(e) => match e.local_name().as_ref() {
                    "model" => {
                        part.millimetres_per_unit = unit(&e).map_err(in_part)?;
                        check_required(&e).map_err(|e| match e {
                            Refusal::Unsupported(error) => error,
                            Refusal::Invalid(message) => in_part(message),
                        })?;
                    }
                    "object" => {
                        let id = number::<u32>(&e, "id").map_err(in_part)?;
                        let kind = attribute(&e, "type")?.unwrap_or_default();
                        current = Some((
                            id,
                            Object {
                                support: kind == "support" || kind == "solidsupport",
                                ..Object::default()
                            },
                        ));
                    }
                    "vertex" => {
                        let (_, object) = current
                            .as_mut()
                            .ok_or_else(|| in_part("a vertex outside an object".into()))?;
                        self.parsed_vertices += 1;
                        check_limit(
                            "vertices",
                            self.parsed_vertices,
                            self.limits.max_input_vertices,
                        )?;
                        let [x, y, z] = ["x", "y", "z"].map(|name| number::<f64>(&e, name));
                        object.positions.push(DVec3::new(
                            x.map_err(in_part)?,
                            y.map_err(in_part)?,
                            z.map_err(in_part)?,
                        ));
                    }
                    "triangle" => {
                        let (_, object) = current
                            .as_mut()
                            .ok_or_else(|| in_part("a triangle outside an object".into()))?;
                        self.parsed_triangles += 1;
                        check_limit(
                            "triangles",
                            self.parsed_triangles,
                            self.limits.max_input_triangles,
                        )?;
                        let [a, b, c] = ["v1", "v2", "v3"].map(|name| number::<u32>(&e, name));
                        let triangle = [
                            a.map_err(in_part)?,
                            b.map_err(in_part)?,
                            c.map_err(in_part)?,
                        ];
                        if let Some(&index) = triangle
                            .iter()
                            .find(|&&i| i as usize >= object.positions.len())
                        {
                            return Err(in_part(format!(
                                "a triangle refers to vertex {index}, but the object has {} vertices",
                                object.positions.len()
                            )));
                        }
                        object.triangles.push(triangle);
                    }
                    "component" => {
                        let reference = reference(&e).map_err(in_part)?;
                        let (_, object) = current
                            .as_mut()
                            .ok_or_else(|| in_part("a component outside an object".into()))?;
                        object.components.push(reference);
                    }
                    "item" => part.build.push(reference(&e).map_err(in_part)?),
                    _ => {}
                },
                Event::End(e) if e.local_name().as_ref() == "object" => {
                    if let Some((id, object)) = current.take() {
                        part.objects.insert(id, object);
                    }
                }
                Event::Eof if open > 0 => {
                    return Err(error(format!(
                        "{path} is cut short: it ends inside an element"
                    )))
                }
                Event::Eof => return Ok(part),
                _ => {}
            }
        }
    }
}

/// The zip entry name of a package path (`/3D/x.model` → `3D/x.model`).
fn entry_name(target: &str) -> String {
    target.trim_start_matches('/').to_string()
}

/// Attribute `name` (its local name: `p:path` is `path`), unescaped.
fn attribute(e: &BytesStart, name: &str) -> Result<Option<String>> {
    for attr in e.attributes() {
        let attr = attr.map_err(|e| error(e.to_string()))?;
        if attr.key.local_name().as_ref() == name {
            let value = attr
                .normalized_value(quick_xml::XmlVersion::Implicit1_0)
                .map_err(|e| error(e.to_string()))?;
            return Ok(Some(value.into_owned()));
        }
    }
    Ok(None)
}

/// Attribute `name`, which must be present, as a number.
fn number<T: std::str::FromStr>(e: &BytesStart, name: &str) -> std::result::Result<T, String> {
    let label = name;
    let value = attribute(e, name)
        .map_err(|e| e.to_string())?
        .ok_or_else(|| format!("a {} has no {label}", e.local_name().as_ref()))?;
    value
        .trim()
        .parse()
        .map_err(|_| format!("{label}={value:?} is not a number"))
}

/// A build item or component: its object, part and transform.
fn reference(e: &BytesStart) -> std::result::Result<Reference, String> {
    let transform = match attribute(e, "transform").map_err(|e| e.to_string())? {
        Some(text) => matrix(&text)?,
        None => DMat4::IDENTITY,
    };
    Ok(Reference {
        object: number(e, "objectid")?,
        path: attribute(e, "path")
            .map_err(|e| e.to_string())?
            .map(|p| entry_name(&p)),
        transform,
    })
}

/// A 3MF transform: twelve numbers, the 4×3 matrix of row vectors `m00 m01 m02 … m30 m31
/// m32` (3MF core §3.3), so that `x' = m00·x + m10·y + m20·z + m30`.
fn matrix(text: &str) -> std::result::Result<DMat4, String> {
    let values: Vec<f64> = text
        .split_ascii_whitespace()
        .map(str::parse)
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| format!("transform {text:?} is not twelve numbers"))?;
    let [m00, m01, m02, m10, m11, m12, m20, m21, m22, m30, m31, m32] = values[..] else {
        return Err(format!("transform {text:?} is not twelve numbers"));
    };
    if values.iter().any(|v| !v.is_finite()) {
        return Err(format!("transform {text:?} is not finite"));
    }
    Ok(DMat4::from_cols(
        DVec4::new(m00, m01, m02, 0.0),
        DVec4::new(m10, m11, m12, 0.0),
        DVec4::new(m20, m21, m22, 0.0),
        DVec4::new(m30, m31, m32, 1.0),
    ))
}

/// Millimetres per unit of the model's `unit` (millimetre when absent).
fn unit(e: &BytesStart) -> std::result::Result<f64, String> {
    let unit = attribute(e, "unit").map_err(|e| e.to_string())?;
    Ok(match unit.as_deref().unwrap_or("millimeter") {
        "micron" => 0.001,
        "millimeter" => 1.0,
        "centimeter" => 10.0,
        "inch" => 25.4,
        "foot" => 304.8,
        "meter" => 1000.0,
        other => return Err(format!("unknown unit {other:?}")),
    })
}

enum Refusal {
    Unsupported(Error),
    Invalid(String),
}

/// Refuses a model that requires an extension this loader cannot honour: its
/// `requiredextensions` name namespace prefixes declared on the same element.
fn check_required(e: &BytesStart) -> std::result::Result<(), Refusal> {
    let invalid = |e: Error| Refusal::Invalid(e.to_string());
    let Some(required) = attribute(e, "requiredextensions").map_err(invalid)? else {
        return Ok(());
    };
    for prefix in required.split_ascii_whitespace() {
        let mut namespace = None;
        for attr in e.attributes() {
            let attr = attr.map_err(|e| Refusal::Invalid(e.to_string()))?;
            let key = attr.key.as_ref();
            if key.strip_prefix("xmlns:") == Some(prefix) {
                namespace = Some(attr.value.into_owned());
            }
        }
        let namespace = namespace.ok_or_else(|| {
            Refusal::Invalid(format!(
                "required extension prefix {prefix:?} is not declared"
            ))
        })?;
        if !READABLE_EXTENSIONS.contains(&namespace.as_str()) {
            return Err(Refusal::Unsupported(Error::Unsupported {
                feature: format!("the required 3MF extension {namespace}"),
                conversion: "export the model as STL, or as 3MF without that extension, from the slicer or CAD tool that made it",
            }));
        }
    }
    Ok(())
}

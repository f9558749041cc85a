//! Stanford PLY via `ply-rs-bw`, text and binary of either byte order (SPEC §1.1).
//!
//! Positions come from the `x`, `y`, `z` properties (any scalar type) of the `vertex` element,
//! polygons from the `vertex_indices` (or `vertex_index`) integer list of the `face` element,
//! fan-triangulated. Elements are read one at a time into a small record that keeps only
//! those properties, straight into the mesh, rather than into the crate's per-element maps.
//! Before any element is read, the declared counts are checked against the limits and against
//! the bytes left after the header: an element count is not bounded by the crate otherwise, and
//! elements without properties would take no bytes at all.

use std::borrow::Cow;
use std::io::{BufRead, Cursor};

use glam::DVec3;
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{
    ElementDef, Encoding, Property, PropertyAccess, PropertyAccessResult, PropertyType, ScalarType,
};

use super::{check_limit, parse_error, push_fan, Format};
use crate::error::{Error, Result};
use crate::mesh::RawMesh;
use crate::params::Limits;

/// Names of the face property holding the corner indices.
const INDEX_PROPERTIES: [&str; 2] = ["vertex_indices", "vertex_index"];

/// Loads a PLY file.
pub(super) fn load(bytes: &[u8], limits: &Limits) -> Result<RawMesh> {
    let parser = Parser::<Record>::new();
    let (header_text, body) = split_header(bytes);
    let header = parser
        .read_header(&mut Reader::new(Cursor::new(&header_text[..])))
        .map_err(error)?;
    let mut cursor = Cursor::new(body);

    let vertex = header.elements.get("vertex");
    let face = header.elements.get("face");
    let vertex_count = vertex.map_or(0, |v| v.count);
    check_limit("vertices", vertex_count, limits.max_input_vertices)?;
    check_limit(
        "faces",
        face.map_or(0, |f| f.count),
        limits.max_input_triangles,
    )?;
    if let Some(vertex) = vertex {
        for axis in ["x", "y", "z"] {
            if !matches!(
                vertex.properties.get(axis).map(|p| &p.data_type),
                Some(PropertyType::Scalar(_))
            ) {
                return Err(parse_error(
                    Format::Ply,
                    format!("the vertex element has no scalar property `{axis}`"),
                ));
            }
        }
    }
    let strips = header.elements.get("tristrips");
    for face in [face, strips].into_iter().flatten().filter(|f| f.count > 0) {
        let has_indices = INDEX_PROPERTIES.iter().any(|name| {
            matches!(
                face.properties.get(*name).map(|p| &p.data_type),
                Some(PropertyType::List(_, t)) if is_integer(t)
            )
        });
        if !has_indices {
            return Err(parse_error(
                Format::Ply,
                format!(
                    "the {} element has no integer list property `vertex_indices`",
                    face.name
                ),
            ));
        }
    }
    let available = body.len();
    let needed = header.elements.values().fold(0usize, |sum, element| {
        sum.saturating_add(
            element
                .count
                .saturating_mul(min_size(element, header.encoding)),
        )
    });
    if needed > available.saturating_add(1) {
        return Err(parse_error(
            Format::Ply,
            format!(
                "the header declares at least {needed} bytes of data, but only {available} follow it"
            ),
        ));
    }

    let mut mesh = RawMesh {
        positions: Vec::with_capacity(vertex_count),
        triangles: Vec::new(),
    };
    let mut corners = Vec::new();
    let mut line = String::new();
    // Text elements' line numbers, from 1 at the file's first line, for errors.
    let mut line_number = header_text.iter().filter(|&&b| b == b'\n').count();
    // Elements after `vertex` and the faces need not be read.
    let last = header
        .elements
        .keys()
        .rposition(|name| matches!(name.as_str(), "vertex" | "face" | "tristrips"))
        .map_or(0, |i| i + 1);
    for element in header.elements.values().take(last) {
        for item in 0..element.count {
            let record = match header.encoding {
                Encoding::Ascii => {
                    line.clear();
                    if cursor.read_line(&mut line).map_err(|e| error(e.into()))? == 0 {
                        return Err(parse_error(
                            Format::Ply,
                            format!(
                                "the file ends after {item} of {} `{}` elements",
                                element.count, element.name
                            ),
                        ));
                    }
                    line_number += 1;
                    parser
                        .read_ascii_element(&line, element)
                        .map_err(|e| parse_error(Format::Ply, format!("line {line_number}: {e}")))?
                }
                Encoding::BinaryLittleEndian => parser
                    .read_little_endian_element(&mut cursor, element)
                    .map_err(error)?,
                Encoding::BinaryBigEndian => parser
                    .read_big_endian_element(&mut cursor, element)
                    .map_err(error)?,
            };
            match element.name.as_str() {
                "vertex" => mesh.positions.push(DVec3::from_array(record.xyz)),
                "face" => {
                    corners.clear();
                    for &index in &record.indices {
                        corners.push(u64::try_from(index).map_err(|_| {
                            parse_error(
                                Format::Ply,
                                format!("face {item} has the negative vertex index {index}"),
                            )
                        })?);
                    }
                    push_fan(&mut mesh.triangles, item, &corners, vertex_count, limits)?;
                }
                "tristrips" => {
                    push_strips(&mut mesh.triangles, &record.indices, vertex_count, limits)?
                }
                _ => {}
            }
        }
    }
    Ok(mesh)
}

/// Appends the triangles of triangle strips (`element tristrips`, as classic range scans are
/// stored): runs of vertex indices separated by -1, every three consecutive indices of a run a
/// triangle, every second one turned to keep the winding.
fn push_strips(
    triangles: &mut Vec<[u32; 3]>,
    indices: &[i64],
    vertex_count: usize,
    limits: &Limits,
) -> Result<()> {
    let mut strip = Vec::new();
    for run in indices.split(|&i| i == -1) {
        strip.clear();
        for &index in run {
            let id = u32::try_from(index)
                .ok()
                .filter(|&i| (i as usize) < vertex_count)
                .ok_or(Error::IndexOutOfRange {
                    // The triangle it would have been part of.
                    face: triangles.len() + strip.len().saturating_sub(2),
                    index: index.unsigned_abs(),
                    vertex_count,
                })?;
            strip.push(id);
        }
        check_limit(
            "triangles",
            triangles
                .len()
                .saturating_add(strip.len().saturating_sub(2)),
            limits.max_input_triangles,
        )?;
        triangles.extend(strip.windows(3).enumerate().map(|(k, t)| match k % 2 {
            0 => [t[0], t[1], t[2]],
            _ => [t[1], t[0], t[2]],
        }));
    }
    Ok(())
}

/// The properties of one PLY element that the loader uses; everything else is ignored.
#[derive(Debug, Default)]
struct Record {
    xyz: [f64; 3],
    indices: Vec<i64>,
}

impl PropertyAccess for Record {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        let axis = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ if INDEX_PROPERTIES.contains(&name) => {
                self.indices = match property {
                    Property::ListChar(v) => v.into_iter().map(i64::from).collect(),
                    Property::ListUChar(v) => v.into_iter().map(i64::from).collect(),
                    Property::ListShort(v) => v.into_iter().map(i64::from).collect(),
                    Property::ListUShort(v) => v.into_iter().map(i64::from).collect(),
                    Property::ListInt(v) => v.into_iter().map(i64::from).collect(),
                    Property::ListUInt(v) => v.into_iter().map(i64::from).collect(),
                    _ => return PropertyAccessResult::UnsupportedType,
                };
                return PropertyAccessResult::Set;
            }
            _ => return PropertyAccessResult::Ignored,
        };
        self.xyz[axis] = match property {
            Property::Char(v) => v.into(),
            Property::UChar(v) => v.into(),
            Property::Short(v) => v.into(),
            Property::UShort(v) => v.into(),
            Property::Int(v) => v.into(),
            Property::UInt(v) => v.into(),
            Property::Float(v) => v.into(),
            Property::Double(v) => v,
            _ => return PropertyAccessResult::UnsupportedType,
        };
        PropertyAccessResult::Set
    }
}

/// Whether a PLY scalar type is an integer type.
fn is_integer(t: &ScalarType) -> bool {
    !matches!(t, ScalarType::Float | ScalarType::Double)
}

/// The header, its line ends made `\n`, and the data after it. Some writers (Rhino) end the
/// header's lines with a lone `\r`, which `ply-rs-bw` reads as one line running into the
/// binary data; `\n` and `\r\n` headers are passed as they are.
fn split_header(bytes: &[u8]) -> (Cow<'_, [u8]>, &[u8]) {
    const END: &[u8] = b"end_header";
    let Some(at) = bytes.windows(END.len()).position(|w| w == END) else {
        return (Cow::Borrowed(bytes), &[]);
    };
    let after = &bytes[at + END.len()..];
    let ending = match after {
        [b'\r', b'\n', ..] => 2,
        [b'\r', ..] | [b'\n', ..] => 1,
        _ => 0,
    };
    let (header, body) = bytes.split_at(at + END.len() + ending);
    if bytes.get(3) == Some(&b'\r') && bytes.get(4) != Some(&b'\n') {
        let text = header
            .iter()
            .map(|&b| if b == b'\r' { b'\n' } else { b })
            .collect();
        return (Cow::Owned(text), body);
    }
    (Cow::Borrowed(header), body)
}

/// The fewest bytes one item of `element` can take: in text, a character and a separator per
/// property; in binary, each scalar and each list length. At least one, so that a count of
/// property-less elements cannot make the reader loop without consuming input.
fn min_size(element: &ElementDef, encoding: Encoding) -> usize {
    let size = match encoding {
        Encoding::Ascii => 2 * element.properties.len(),
        Encoding::BinaryBigEndian | Encoding::BinaryLittleEndian => element
            .properties
            .values()
            .map(|p| match &p.data_type {
                PropertyType::Scalar(t) | PropertyType::List(t, _) => scalar_size(t),
            })
            .sum(),
    };
    size.max(1)
}

/// Size in bytes of a binary PLY scalar.
fn scalar_size(t: &ScalarType) -> usize {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// A [`crate::Error::Parse`] from the PLY crate's error.
fn error(e: ply_rs_bw::parser::ParseError) -> crate::Error {
    parse_error(Format::Ply, e.to_string())
}

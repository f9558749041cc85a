//! Wavefront OBJ via `tobj` (SPEC §1.1): polygons fan-triangulated, all objects and groups
//! merged into one mesh; normals, texture coordinates, polylines and materials ignored.
//!
//! Only `v` and `f` lines reach `tobj`. Besides skipping what is not needed, this keeps two
//! `tobj` behaviours away from untrusted input: its texture/normal index arithmetic overflows
//! on hostile relative indices (a panic with overflow checks), and it reads `l` polylines of
//! three or more points as faces. The same pass counts vertices and triangles against the
//! limits before `tobj` allocates anything and resolves face indices, so that a bad index is
//! reported with its face.

use glam::DVec3;

use super::{check_limit, parse_error, vertex_id, Format};
use crate::error::{Error, Result};
use crate::mesh::RawMesh;
use crate::params::Limits;

/// Loads an OBJ file.
pub(super) fn load(bytes: &[u8], limits: &Limits) -> Result<RawMesh> {
    let geometry = geometry_lines(bytes, limits)?;
    // `..Default::default()` covers the fields that tobj's optional features add.
    #[allow(clippy::needless_update)]
    let options = tobj::LoadOptions {
        single_index: false,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let (models, _materials) = tobj::load_obj_buf(&mut geometry.as_slice(), &options, |_| {
        Ok(Default::default())
    })
    .map_err(|e| parse_error(Format::Obj, e.to_string()))?;

    let mut mesh = RawMesh::default();
    for model in models {
        let offset = vertex_id(mesh.positions.len())?;
        mesh.positions.extend(
            model
                .mesh
                .positions
                .chunks_exact(3)
                .map(|p| DVec3::new(p[0].into(), p[1].into(), p[2].into())),
        );
        mesh.triangles.extend(
            model
                .mesh
                .indices
                .chunks_exact(3)
                .map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]),
        );
    }
    Ok(mesh)
}

/// The `v` and `f` lines of `bytes`, after checking the vertex and triangle counts against the
/// limits, the lines' syntax and every face index against the vertices. A line ending in `\`
/// goes on on the next (some exporters wrap long faces so); errors name the line (from 1).
fn geometry_lines(bytes: &[u8], limits: &Limits) -> Result<Vec<u8>> {
    let mut kept = Vec::new();
    let mut vertices = 0usize;
    let mut triangles = 0usize;
    let mut faces = 0usize;
    // The largest absolute index and its face: it can only be checked once all `v` are known.
    let mut largest: Option<(u64, usize)> = None;
    let mut joined: Vec<u8> = Vec::new();
    let mut first_line = 0;
    for (number, physical) in bytes.split(|&b| b == b'\n').enumerate() {
        let physical = physical.trim_ascii_end();
        if joined.is_empty() {
            first_line = number + 1;
        }
        if let Some(head) = physical.strip_suffix(b"\\") {
            joined.extend_from_slice(head);
            joined.push(b' ');
            continue;
        }
        let line = if joined.is_empty() {
            physical
        } else {
            joined.extend_from_slice(physical);
            &joined[..]
        };
        let error =
            |message: String| parse_error(Format::Obj, format!("line {first_line}: {message}"));
        let mut words = line
            .split(|b| b.is_ascii_whitespace())
            .filter(|w| !w.is_empty());
        match words.next() {
            Some(b"v") => {
                let numbers = words
                    .take(3)
                    .filter(|w| std::str::from_utf8(w).is_ok_and(|w| w.parse::<f64>().is_ok()))
                    .count();
                if numbers < 3 {
                    return Err(error("a vertex needs three coordinates".into()));
                }
                vertices += 1;
            }
            Some(b"f") => {
                let mut corners = 0usize;
                for word in words {
                    corners += 1;
                    let Some(index) = position_index(word) else {
                        return Err(error(format!(
                            "face corner `{}` is not a vertex index",
                            String::from_utf8_lossy(word)
                        )));
                    };
                    let index = match index {
                        1.. => index.unsigned_abs() - 1,
                        0 => {
                            return Err(error(format!(
                                "face {faces} uses index 0 (OBJ indices start at 1)"
                            )))
                        }
                        _ => match u64::try_from(vertices as i128 + i128::from(index)) {
                            Ok(resolved) => resolved,
                            Err(_) => {
                                return Err(error(format!(
                                    "face {faces} uses relative index {index}, but only \
                                     {vertices} vertices precede it"
                                )))
                            }
                        },
                    };
                    if largest.is_none_or(|(l, _)| index > l) {
                        largest = Some((index, faces));
                    }
                }
                triangles = triangles.saturating_add(corners.saturating_sub(2));
                faces += 1;
            }
            _ => {
                joined.clear();
                continue;
            }
        }
        kept.extend_from_slice(line);
        kept.push(b'\n');
        joined.clear();
    }
    check_limit("vertices", vertices, limits.max_input_vertices)?;
    check_limit("triangles", triangles, limits.max_input_triangles)?;
    if let Some((index, face)) = largest.filter(|&(l, _)| l >= vertices as u64) {
        return Err(Error::IndexOutOfRange {
            face,
            index,
            vertex_count: vertices,
        });
    }
    Ok(kept)
}

/// The position index of a face corner `v`, `v/vt`, `v//vn` or `v/vt/vn`, if it is a number.
fn position_index(corner: &[u8]) -> Option<i64> {
    let position = corner.split(|&b| b == b'/').next()?;
    std::str::from_utf8(position).ok()?.parse().ok()
}

/// Whether `text` starts like an OBJ file: its first line that is neither blank nor a comment
/// begins with an OBJ keyword.
pub(super) fn looks_like_obj(text: &[u8]) -> bool {
    const KEYWORDS: [&[u8]; 11] = [
        b"v", b"vn", b"vt", b"vp", b"f", b"l", b"o", b"g", b"s", b"mtllib", b"usemtl",
    ];
    text.split(|&b| b == b'\n')
        .take(64)
        .filter_map(|line| {
            line.split(|b| b.is_ascii_whitespace())
                .find(|w| !w.is_empty())
        })
        .find(|word| !word.starts_with(b"#"))
        .is_some_and(|word| KEYWORDS.contains(&word))
}

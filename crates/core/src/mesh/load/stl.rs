//! STereoLithography, text via `stl_io` and binary read here (SPEC §1.1); corners with the
//! same coordinates are merged into shared vertices.
//!
//! The loader, not `stl_io`, decides between text and binary: `stl_io` takes any file whose
//! first line starts with `solid ` for text, which many binary exporters write into their
//! free-form 80-byte header, and takes a text file starting `solid` without a name for binary.
//! A binary file is accepted only if its length is exactly `84 + 50 × count` for the count in
//! its header, so a lying header cannot make the reader loop or allocate. Text files may hold
//! several `solid … endsolid` blocks; all are read.

use std::collections::hash_map::Entry;
use std::io::Cursor;

use glam::DVec3;
use rustc_hash::FxHashMap;

use super::{check_limit, parse_error, skip_bom_and_space, vertex_id, Format};
use crate::error::Result;
use crate::mesh::RawMesh;
use crate::params::Limits;

/// Size of the binary header: 80 free bytes and the triangle count.
const HEADER: usize = 84;
/// Size of one binary facet: normal, three corners, attribute word.
const FACET: u64 = 50;

/// Whether `bytes` is a binary STL: its length matches the triangle count in its header.
pub(super) fn is_binary(bytes: &[u8]) -> bool {
    declared_triangles(bytes).is_some_and(|n| bytes.len() as u64 == HEADER as u64 + FACET * n)
}

/// The triangle count of a binary STL header.
fn declared_triangles(bytes: &[u8]) -> Option<u64> {
    let count: [u8; 4] = bytes.get(80..HEADER)?.try_into().ok()?;
    Some(u32::from_le_bytes(count).into())
}

/// Loads an STL file.
pub(super) fn load(bytes: &[u8], limits: &Limits) -> Result<RawMesh> {
    let text = skip_bom_and_space(bytes);
    if is_binary(bytes) || !text.starts_with(b"solid") {
        return load_binary(bytes, limits);
    }
    let mut mesh = RawMesh::default();
    for solid in solids(text) {
        // Give `stl_io` the `solid ` line it insists on, whatever the name or indentation.
        let body = solid
            .iter()
            .position(|&b| b == b'\n')
            .map_or(&[][..], |end| &solid[end..]);
        let mut normalised = Vec::with_capacity(body.len() + 6);
        normalised.extend_from_slice(b"solid ");
        normalised.extend_from_slice(body);
        append(&mut mesh, &normalised)?;
    }
    Ok(mesh)
}

/// Loads a binary STL after checking its declared triangle count against the limit and the
/// file length.
fn load_binary(bytes: &[u8], limits: &Limits) -> Result<RawMesh> {
    let count = declared_triangles(bytes).ok_or_else(|| {
        parse_error(
            Format::Stl,
            "neither text STL (starting with `solid`) nor binary STL (84-byte header)",
        )
    })?;
    check_limit(
        "triangles",
        usize::try_from(count).unwrap_or(usize::MAX),
        limits.max_input_triangles,
    )?;
    let expected = HEADER as u64 + FACET * count;
    if bytes.len() as u64 != expected {
        return Err(parse_error(
            Format::Stl,
            format!(
                "binary STL header declares {count} triangles, which take {expected} bytes, but \
                 the file has {} bytes",
                bytes.len()
            ),
        ));
    }
    // Read here rather than by `stl_io`: its indexed mesh keeps a normal and three `usize`s
    // per facet, and it needs a copy of any file whose header starts with `solid`, so a
    // 4 M-triangle print file would take twice its size again (`benches/big.rs`). Corners
    // with the same bits are one vertex, as `stl_io` makes them.
    let count = count as usize;
    let mut mesh = RawMesh {
        positions: Vec::with_capacity(count / 2 + 3),
        triangles: Vec::with_capacity(count),
    };
    let mut vertices: FxHashMap<[u32; 3], u32> = FxHashMap::default();
    vertices.reserve(count / 2 + 3);
    for facet in bytes[HEADER..].chunks_exact(FACET as usize) {
        let mut triangle = [0u32; 3];
        for (slot, corner) in triangle.iter_mut().zip(facet[12..48].chunks_exact(12)) {
            let bits = [0, 4, 8].map(|at| {
                u32::from_le_bytes([corner[at], corner[at + 1], corner[at + 2], corner[at + 3]])
            });
            let next = mesh.positions.len();
            *slot = match vertices.entry(bits) {
                Entry::Occupied(known) => *known.get(),
                Entry::Vacant(new) => {
                    let id = vertex_id(next)?;
                    mesh.positions
                        .push(DVec3::from_array(bits.map(|b| f32::from_bits(b).into())));
                    *new.insert(id)
                }
            };
        }
        mesh.triangles.push(triangle);
    }
    Ok(mesh)
}

/// The `solid … endsolid` blocks of a text STL: each starts at a line whose first word is
/// `solid`.
fn solids(text: &[u8]) -> impl Iterator<Item = &[u8]> {
    let mut starts: Vec<usize> = Vec::new();
    let mut offset = 0;
    for line in text.split_inclusive(|&b| b == b'\n') {
        if line
            .split(|b| b.is_ascii_whitespace())
            .find(|w| !w.is_empty())
            == Some(b"solid")
        {
            starts.push(offset);
        }
        offset += line.len();
    }
    let ends: Vec<usize> = starts.iter().skip(1).copied().chain([text.len()]).collect();
    starts
        .into_iter()
        .zip(ends)
        .map(move |(start, end)| &text[start..end])
}

/// Reads one STL (text or binary, as `stl_io` decides) and appends it to `mesh`.
fn append(mesh: &mut RawMesh, input: &[u8]) -> Result<()> {
    let indexed = stl_io::read_stl(&mut Cursor::new(input))
        .map_err(|e| parse_error(Format::Stl, e.to_string()))?;
    let offset = mesh.positions.len();
    mesh.positions.extend(
        indexed
            .vertices
            .iter()
            .map(|v| DVec3::new(v.0[0].into(), v.0[1].into(), v.0[2].into())),
    );
    for face in &indexed.faces {
        let [a, b, c] = face.vertices;
        mesh.triangles.push([
            vertex_id(offset + a)?,
            vertex_id(offset + b)?,
            vertex_id(offset + c)?,
        ]);
    }
    Ok(())
}

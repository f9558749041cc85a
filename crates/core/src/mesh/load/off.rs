//! Object File Format (OFF), text only (SPEC §1.1). There is no well-kept OFF crate, so this
//! is a small hand-written parser.
//!
//! Accepted: an optional header keyword (`OFF`, `COFF`, `NOFF`, `CNOFF`, `STOFF`, … — the
//! prefixes only add per-vertex columns, which are ignored), possibly followed on the same line
//! by the counts; `#` comments and blank lines anywhere; the counts `nv nf [ne]`; one vertex per
//! line (`x y z` and any extra columns); one face per line (`k i1 … ik` and an optional colour),
//! fan-triangulated. Faces with fewer than 3 corners are skipped. Binary OFF, 4-D (`4OFF`) and
//! n-D (`nOFF`) files are refused with a clear message.

use glam::DVec3;

use super::{check_limit, parse_error, push_fan, Format};
use crate::error::Result;
use crate::mesh::RawMesh;
use crate::params::Limits;

/// Whether `word` is an OFF header keyword: `OFF` preceded by any of the prefixes
/// `ST`, `C`, `N`, `4`, `n`.
pub(super) fn is_header_keyword(word: &[u8]) -> bool {
    word.strip_suffix(b"OFF")
        .is_some_and(|prefix| prefix.iter().all(|b| b"STCN4n".contains(b)))
}

/// Loads an OFF file.
pub(super) fn load(bytes: &[u8], limits: &Limits) -> Result<RawMesh> {
    let text = std::str::from_utf8(bytes).map_err(|_| {
        let binary = bytes.windows(6).take(64).any(|w| w == b"BINARY");
        error(if binary {
            "binary OFF is not supported; convert the file to text OFF, PLY or OBJ"
        } else {
            "the file is not UTF-8 text (binary OFF is not supported)"
        })
    })?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(number, line)| (number + 1, line.split('#').next().unwrap_or_default()))
        .filter(|(_, line)| !line.trim().is_empty());

    let (_, first) = lines.next().ok_or_else(|| error("the file is empty"))?;
    let mut words = first.split_whitespace();
    let mut counts: Vec<&str> = words.clone().collect();
    if let Some(keyword) = words.next().filter(|w| is_header_keyword(w.as_bytes())) {
        if keyword.contains('4') || keyword.contains('n') {
            return Err(error(format!(
                "`{keyword}` files (vertices not in 3-D) are not supported"
            )));
        }
        counts = words.collect();
        if counts.first() == Some(&"BINARY") {
            return Err(error(
                "binary OFF is not supported; convert the file to text OFF, PLY or OBJ",
            ));
        }
        if counts.is_empty() {
            let (_, line) = lines
                .next()
                .ok_or_else(|| error("the file ends after the header"))?;
            counts = line.split_whitespace().collect();
        }
    }
    let count = |i: usize, what: &str| -> Result<usize> {
        counts.get(i).and_then(|w| w.parse().ok()).ok_or_else(|| {
            error(format!(
                "expected the {what} count, found `{}`",
                counts.join(" ")
            ))
        })
    };
    let vertex_count = count(0, "vertex")?;
    let face_count = count(1, "face")?;
    check_limit("vertices", vertex_count, limits.max_input_vertices)?;
    check_limit("faces", face_count, limits.max_input_triangles)?;

    // A vertex line takes at least 6 bytes (`0 0 0\n`) and a face line 4, so the input bounds
    // the allocation even when the counts lie.
    let mut mesh = RawMesh {
        positions: Vec::with_capacity(vertex_count.min(bytes.len() / 6)),
        triangles: Vec::with_capacity(face_count.min(bytes.len() / 4)),
    };
    for found in 0..vertex_count {
        let (number, line) = lines.next().ok_or_else(|| {
            error(format!(
                "the file ends after {found} of {vertex_count} vertices"
            ))
        })?;
        let mut xyz = [0.0; 3];
        let mut words = line.split_whitespace();
        for c in &mut xyz {
            *c = words.next().and_then(|w| w.parse().ok()).ok_or_else(|| {
                error(format!(
                    "line {number}: expected a vertex `x y z`, found `{line}`"
                ))
            })?;
        }
        mesh.positions.push(DVec3::from_array(xyz));
    }
    let mut corners = Vec::new();
    for face in 0..face_count {
        let (number, line) = lines
            .next()
            .ok_or_else(|| error(format!("the file ends after {face} of {face_count} faces")))?;
        let bad_face = || {
            error(format!(
                "line {number}: expected a face `k i1 … ik`, found `{line}`"
            ))
        };
        let mut words = line.split_whitespace();
        let k: usize = words
            .next()
            .and_then(|w| w.parse().ok())
            .ok_or_else(bad_face)?;
        corners.clear();
        for word in words.by_ref().take(k) {
            corners.push(word.parse::<u64>().map_err(|_| bad_face())?);
        }
        if corners.len() < k {
            return Err(bad_face());
        }
        push_fan(&mut mesh.triangles, face, &corners, vertex_count, limits)?;
    }
    Ok(mesh)
}

/// A [`crate::Error::Parse`] for OFF.
fn error(message: impl Into<String>) -> crate::Error {
    parse_error(Format::Off, message)
}

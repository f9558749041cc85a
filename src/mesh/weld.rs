//! Welding and cleaning (SPEC §1.2).
//!
//! Exporters split vertices at UV and normal seams; geodesics need one vertex per position.
//! The welded mesh is also put in a canonical order (vertices sorted by quantised position,
//! triangles sorted), so the same surface gives the same mesh — and the same signature —
//! whatever the file format, vertex order or face order it came in.

use glam::DVec3;

use super::RawMesh;
use crate::{Error, Result};

/// A cleaned, welded triangle mesh in input coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct Welded {
    pub positions: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
    pub degenerate_removed: usize,
    pub duplicates_removed: usize,
}

/// Merges vertices whose positions agree after quantisation to `tolerance` × the bounding-box
/// diagonal, then drops degenerate triangles (repeated vertex or zero area), duplicate
/// triangles (the same three vertices in either winding) and unreferenced vertices.
pub fn weld(raw: &RawMesh, tolerance: f64) -> Result<Welded> {
    if raw.triangles.is_empty() {
        return Err(Error::NoTriangles);
    }
    let (min, max) = bounds(&raw.positions);
    let diagonal = (max - min).length();
    if diagonal == 0.0 {
        return Err(Error::TooFewVertices { count: 1 });
    }
    // Areas and volumes go up to the cube of the extent: keep them inside f64's range.
    if !(1e-100..=1e100).contains(&diagonal) {
        return Err(Error::ExtentOutOfRange { diagonal });
    }
    let quantum = tolerance * diagonal;
    let key = |p: DVec3| {
        let q = ((p - min) / quantum).round();
        (q.x as i64, q.y as i64, q.z as i64)
    };

    // Canonical vertex order: along a Morton (Z-order) curve, so that vertices near in space
    // are near in memory (extraction walks neighbourhoods), then by quantised key, then by
    // exact coordinates so the representative kept for a cell does not depend on input order.
    let mut order: Vec<u32> = (0..raw.positions.len() as u32).collect();
    let exact = |i: u32| {
        let p = raw.positions[i as usize];
        let k = key(p);
        (
            morton(p, min, max),
            k,
            p.x.to_bits(),
            p.y.to_bits(),
            p.z.to_bits(),
        )
    };
    order.sort_unstable_by_key(|&i| exact(i));
    let mut remap = vec![0u32; raw.positions.len()];
    let mut positions = Vec::new();
    let mut last_key = None;
    for &i in &order {
        let p = raw.positions[i as usize];
        let k = key(p);
        if last_key != Some(k) {
            positions.push(p);
            last_key = Some(k);
        }
        remap[i as usize] = positions.len() as u32 - 1;
    }

    let area_floor = 1e-14 * diagonal * diagonal;
    let mut degenerate_removed = 0;
    let mut triangles: Vec<[u32; 3]> = Vec::with_capacity(raw.triangles.len());
    for t in &raw.triangles {
        let t = t.map(|v| remap[v as usize]);
        let [a, b, c] = t.map(|v| positions[v as usize]);
        if t[0] == t[1]
            || t[1] == t[2]
            || t[0] == t[2]
            || (b - a).cross(c - a).length() <= area_floor
        {
            degenerate_removed += 1;
        } else {
            triangles.push(t);
        }
    }
    if triangles.is_empty() {
        return Err(Error::OnlyDegenerate {
            count: raw.triangles.len(),
        });
    }

    // Duplicates: same vertex set. Keep the first in input order (a stable sort keeps it first).
    let before = triangles.len();
    let mut indexed: Vec<(usize, [u32; 3])> = triangles.into_iter().enumerate().collect();
    indexed.sort_by_key(|&(i, t)| (sorted(t), i));
    indexed.dedup_by_key(|(_, t)| sorted(*t));
    let duplicates_removed = before - indexed.len();
    let triangles: Vec<[u32; 3]> = indexed.into_iter().map(|(_, t)| t).collect();

    let (positions, triangles) = compact(&positions, &triangles);
    if positions.len() < 4 {
        return Err(Error::TooFewVertices {
            count: positions.len(),
        });
    }
    Ok(Welded {
        positions,
        triangles,
        degenerate_removed,
        duplicates_removed,
    })
}

/// Drops vertices no triangle uses (keeping the order of the rest) and puts the triangles in
/// canonical order: each rotated to start at its smallest index (winding kept), then sorted.
pub fn compact(positions: &[DVec3], triangles: &[[u32; 3]]) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut used = vec![false; positions.len()];
    for t in triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let mut remap = vec![u32::MAX; positions.len()];
    let mut kept = Vec::new();
    for (i, p) in positions.iter().enumerate() {
        if used[i] {
            remap[i] = kept.len() as u32;
            kept.push(*p);
        }
    }
    let mut triangles: Vec<[u32; 3]> = triangles
        .iter()
        .map(|t| t.map(|v| remap[v as usize]))
        .collect();
    canonical_order(&mut triangles);
    (kept, triangles)
}

/// Rotates each triangle to start at its smallest index (winding kept) and sorts them, so
/// that equal meshes have equal triangle lists.
pub fn canonical_order(triangles: &mut [[u32; 3]]) {
    for t in triangles.iter_mut() {
        *t = rotate_to_min(*t);
    }
    triangles.sort_unstable();
}

/// Axis-aligned bounds of a point set.
pub fn bounds(points: &[DVec3]) -> (DVec3, DVec3) {
    points.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    )
}

/// Interleaves the bits of the position quantised to 21 bits per axis over the bounds.
fn morton(p: DVec3, min: DVec3, max: DVec3) -> u64 {
    let cell = ((p - min) / (max - min).max(DVec3::splat(f64::MIN_POSITIVE)) * 2_097_151.0)
        .clamp(DVec3::ZERO, DVec3::splat(2_097_151.0));
    let spread = |v: f64| {
        let mut x = v as u64;
        x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
        x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
        x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
        x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
        (x | (x << 2)) & 0x1249_2492_4924_9249
    };
    spread(cell.x) | (spread(cell.y) << 1) | (spread(cell.z) << 2)
}

fn sorted(mut t: [u32; 3]) -> [u32; 3] {
    t.sort_unstable();
    t
}

fn rotate_to_min([a, b, c]: [u32; 3]) -> [u32; 3] {
    if a <= b && a <= c {
        [a, b, c]
    } else if b <= c {
        [b, c, a]
    } else {
        [c, a, b]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra_split() -> RawMesh {
        // A tetrahedron with every corner duplicated per face, listed in scrambled order.
        let p = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(0.0, 0.0, 1.0),
        ];
        let faces = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]];
        let mut raw = RawMesh::default();
        for f in faces.iter().rev() {
            let base = raw.positions.len() as u32;
            raw.positions
                .extend(f.iter().map(|&i| p[i] + DVec3::splat(1e-9)));
            raw.triangles.push([base, base + 1, base + 2]);
        }
        raw
    }

    #[test]
    fn seam_split_vertices_merge_and_order_is_canonical() {
        let raw = tetra_split();
        let w = weld(&raw, 1e-6).unwrap();
        assert_eq!(w.positions.len(), 4);
        assert_eq!(w.triangles.len(), 4);
        let mut reversed = raw.clone();
        reversed.triangles.reverse();
        assert_eq!(weld(&reversed, 1e-6).unwrap(), w);
    }

    #[test]
    fn degenerate_and_duplicate_triangles_are_dropped() {
        let mut raw = tetra_split();
        raw.triangles.push([0, 0, 1]); // repeated index
        raw.triangles.push([0, 1, 2]); // exact duplicate of the first
        raw.triangles.push([1, 2, 0]); // the first rotated
        raw.triangles.push([0, 2, 1]); // the first in reverse winding
        let mid = (raw.positions[0] + raw.positions[1]) / 2.0; // collinear with 0 and 1
        raw.positions.push(mid);
        let c = raw.positions.len() as u32 - 1;
        raw.triangles.push([0, 1, c]);
        let w = weld(&raw, 1e-6).unwrap();
        assert_eq!(w.triangles.len(), 4);
        assert_eq!(w.degenerate_removed, 2);
        assert_eq!(w.duplicates_removed, 3);
    }

    #[test]
    fn too_little_left_is_a_typed_error() {
        let raw = RawMesh {
            positions: vec![DVec3::ZERO, DVec3::X, DVec3::Y],
            triangles: vec![[0, 1, 2]],
        };
        assert!(matches!(
            weld(&raw, 1e-6),
            Err(Error::TooFewVertices { count: 3 })
        ));
        let flat = RawMesh {
            positions: vec![DVec3::ZERO, DVec3::X, DVec3::X * 2.0],
            triangles: vec![[0, 1, 2]],
        };
        assert!(matches!(
            weld(&flat, 1e-6),
            Err(Error::OnlyDegenerate { count: 1 })
        ));
    }
}

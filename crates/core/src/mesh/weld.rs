//! Welding and cleaning (SPEC §1.2).
//!
//! Exporters split vertices at UV and normal seams, and STL files are triangle soups; float32
//! round-off moves the copies of a vertex apart by ~1e-7 of the model's size. Geodesics need
//! one vertex per position, so every vertex within the tolerance of another is merged with
//! it, wherever the two fall on the grid. The welded mesh is also put in a canonical order
//! (vertices along a Morton curve, triangles sorted), so the same surface gives the same mesh
//! — and the same signature — whatever the file format, vertex order or face order it came in.
//!
//! Hand-written rather than a k-d tree crate: a uniform grid whose cell is the tolerance finds
//! every pair within it in the 27 cells around a point, which is all a weld needs, and a
//! union–find with the smallest member as root makes the result independent of input order.

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

/// Merges vertices closer than `tolerance` × the bounding-box diagonal (transitively: a chain
/// of close copies becomes one vertex, at the position of its least member in coordinate
/// order), then drops degenerate triangles (repeated vertex or zero area), duplicate
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
    let root = merge_close(&raw.positions, (min, max), tolerance * diagonal);
    let key = |i: u32| coordinate_key(raw.positions[i as usize]);

    // Canonical vertex order: along a Morton (Z-order) curve, so that vertices near in space
    // are near in memory (extraction walks neighbourhoods), then by exact coordinates.
    let mut ordered: Vec<(u64, u32)> = (0..raw.positions.len() as u32)
        .filter(|&i| root[i as usize] == i)
        .map(|i| (morton(raw.positions[i as usize], min, max), i))
        .collect();
    ordered.sort_unstable_by_key(|&(m, i)| (m, key(i)));
    let kept: Vec<u32> = ordered.into_iter().map(|(_, i)| i).collect();
    let mut slot = vec![0u32; raw.positions.len()];
    for (new, &old) in kept.iter().enumerate() {
        slot[old as usize] = new as u32;
    }
    let remap: Vec<u32> = root.iter().map(|&r| slot[r as usize]).collect();
    let positions: Vec<DVec3> = kept.iter().map(|&i| raw.positions[i as usize]).collect();

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

    // Duplicates: same vertex set. Keep the first in input order (the index breaks ties).
    // Sorted as indices, four bytes a triangle: a print file has millions.
    let before = triangles.len();
    let mut order: Vec<u32> = (0..before as u32).collect();
    order.sort_unstable_by_key(|&i| (sorted(triangles[i as usize]), i));
    order.dedup_by_key(|i| sorted(triangles[*i as usize]));
    let duplicates_removed = before - order.len();
    let triangles: Vec<[u32; 3]> = order.into_iter().map(|i| triangles[i as usize]).collect();

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

/// For each vertex, the root of the group it is merged into: the group's least member in
/// [`coordinate_key`] order. Two vertices are merged when they lie within `quantum` of each
/// other, or in the same cell of the grid of side `quantum` anchored at `min` (so a weld is
/// linear in the vertex count whatever the input: no cell is compared with itself pairwise).
fn merge_close(points: &[DVec3], (min, max): (DVec3, DVec3), quantum: f64) -> Vec<u32> {
    // Cells packed in a u64, 21 bits an axis (x highest, so the packed order is (x, y, z)
    // order), one cell of margin on each side for the neighbours. A grid finer than that (a
    // tolerance below ~5e-7 of the extent) is coarsened to it: pairs are still found, and
    // merging within a cell then acts at that size.
    let extent = max - min;
    let side = (extent.max_element() / ((1 << 21) - 4) as f64).max(quantum);
    let cells: Vec<u64> = points
        .iter()
        .map(|&p| {
            let c = ((p - min) / side).floor() + 1.0;
            ((c.x as u64) << 42) | ((c.y as u64) << 21) | c.z as u64
        })
        .collect();
    let cell = |i: u32| cells[i as usize];
    let mut order: Vec<u32> = (0..points.len() as u32).collect();
    order.sort_unstable_by(|&a, &b| {
        let key = |i: u32| coordinate_key(points[i as usize]);
        (cell(a), key(a), a).cmp(&(cell(b), key(b), b))
    });
    // Each run of one cell: its cell and where it starts in `order` (in cell order).
    let mut runs: Vec<(u64, u32)> = Vec::with_capacity(points.len() + 1);
    for (at, &i) in order.iter().enumerate() {
        if runs.last().is_none_or(|&(c, _)| c != cell(i)) {
            runs.push((cell(i), at as u32));
        }
    }
    runs.push((u64::MAX, order.len() as u32));
    let run = |r: usize| &order[runs[r].1 as usize..runs[r + 1].1 as usize];

    // The 13 neighbours that follow a cell in (x, y, z) order lie at fixed positive offsets
    // in packed order, so each is found by a pointer that only moves forward: linear, and no
    // table of cells.
    let offsets = FORWARD.map(|(dx, dy, dz)| (dx << 42) + (dy << 21) + dz);
    let mut pointers = [0usize; 13];
    let mut groups = UnionFind::new(points);
    for r in 0..runs.len() - 1 {
        let here = run(r);
        for pair in here.windows(2) {
            groups.union(pair[0], pair[1]);
        }
        let packed = runs[r].0;
        for (pointer, &offset) in pointers.iter_mut().zip(&offsets) {
            let neighbour = packed.wrapping_add_signed(offset);
            while runs[*pointer].0 < neighbour {
                *pointer += 1;
            }
            if runs[*pointer].0 != neighbour {
                continue;
            }
            let other = run(*pointer);
            // Neighbouring cells crowded enough to make the pairwise test slow lie within
            // two cell diagonals of each other: merged without it.
            let close = here.len() * other.len() > MAX_PAIRS
                || here.iter().any(|&a| {
                    other.iter().any(|&b| {
                        points[a as usize].distance_squared(points[b as usize]) <= quantum * quantum
                    })
                });
            if close {
                groups.union(here[0], other[0]);
            }
        }
    }
    (0..points.len() as u32).map(|i| groups.find(i)).collect()
}

/// Pairwise distance tests allowed between two neighbouring cells.
const MAX_PAIRS: usize = 4096;

/// Offsets of the neighbouring cells after a cell in lexicographic order.
const FORWARD: [(i64, i64, i64); 13] = [
    (0, 0, 1),
    (0, 1, -1),
    (0, 1, 0),
    (0, 1, 1),
    (1, -1, -1),
    (1, -1, 0),
    (1, -1, 1),
    (1, 0, -1),
    (1, 0, 0),
    (1, 0, 1),
    (1, 1, -1),
    (1, 1, 0),
    (1, 1, 1),
];

/// Disjoint sets of vertices whose root is always the least member by [`coordinate_key`]
/// (ties by index), so the groups' representatives do not depend on the order of union.
struct UnionFind<'a> {
    parent: Vec<u32>,
    points: &'a [DVec3],
}

impl<'a> UnionFind<'a> {
    fn new(points: &'a [DVec3]) -> Self {
        Self {
            parent: (0..points.len() as u32).collect(),
            points,
        }
    }

    fn find(&mut self, mut i: u32) -> u32 {
        while self.parent[i as usize] != i {
            let grandparent = self.parent[self.parent[i as usize] as usize];
            self.parent[i as usize] = grandparent;
            i = grandparent;
        }
        i
    }

    fn union(&mut self, a: u32, b: u32) {
        let (a, b) = (self.find(a), self.find(b));
        let key = |i: u32| (coordinate_key(self.points[i as usize]), i);
        match key(a).cmp(&key(b)) {
            std::cmp::Ordering::Less => self.parent[b as usize] = a,
            std::cmp::Ordering::Greater => self.parent[a as usize] = b,
            std::cmp::Ordering::Equal => {}
        }
    }
}

/// A total order on positions (by x, then y, then z) that needs no float comparison.
fn coordinate_key(p: DVec3) -> [u64; 3] {
    // The IEEE bit pattern, with the sign folded in, orders like the numbers.
    p.to_array().map(|c| {
        let bits = c.to_bits();
        if bits >> 63 == 1 {
            !bits
        } else {
            bits | 1 << 63
        }
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
    let mut kept = Vec::with_capacity(used.iter().filter(|&&u| u).count());
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

    /// Two copies of a vertex a fifth of the tolerance either side of a grid line fall in
    /// different cells; they must still become one vertex.
    #[test]
    fn copies_either_side_of_a_cell_boundary_merge() {
        let tolerance = 1e-6;
        let corners = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(0.0, 0.0, 1.0),
        ];
        let (min, max) = bounds(&corners);
        let quantum = tolerance * (max - min).length();
        let line = min.x + 300_000.0 * quantum;
        let inner = |dx: f64| DVec3::new(line + dx, 0.2, 0.2);
        let (left, right) = (inner(-0.2 * quantum), inner(0.2 * quantum));
        assert_ne!(
            ((left - min) / quantum).floor().x,
            ((right - min) / quantum).floor().x
        );
        // A fan of four triangles around the inner vertex, each with its own copy of it.
        let mut raw = RawMesh {
            positions: corners.to_vec(),
            triangles: Vec::new(),
        };
        for (k, (a, b)) in [(0, 1), (1, 2), (2, 3), (3, 0)].into_iter().enumerate() {
            raw.positions.push(if k % 2 == 0 { left } else { right });
            let copy = raw.positions.len() as u32 - 1;
            raw.triangles.push([a, b, copy]);
        }
        let welded = weld(&raw, tolerance).unwrap();
        assert_eq!(welded.positions.len(), 5, "{:?}", welded.positions);
    }

    #[test]
    fn far_vertices_stay_apart_and_order_does_not_matter() {
        let raw = tetra_split();
        let mut shuffled = raw.clone();
        shuffled.positions.reverse();
        let n = shuffled.positions.len() as u32;
        for t in &mut shuffled.triangles {
            *t = t.map(|v| n - 1 - v);
        }
        assert_eq!(weld(&shuffled, 1e-6).unwrap(), weld(&raw, 1e-6).unwrap());
        // A tolerance below the corners' spacing keeps the four corners.
        assert_eq!(weld(&raw, 0.05).unwrap().positions.len(), 4);
    }
}

//! Splitting triangles, so that a cut along triangle centroids follows a curve closely
//! (`crate::mesh::cut`): on a low-poly model a triangle can be larger than the part.

use std::collections::HashMap;

use glam::DVec3;

use super::RawMesh;

/// `mesh` with every triangle that `split` asks for (given its corners) split at the midpoint
/// of its longest edge (`split` gets the corners and that edge's length), and the halves asked again, until none is. Midpoints are shared by
/// the triangles that split the same edge; a neighbour that does not split it keeps the edge
/// whole (a T-junction, which neither a cut nor surface sampling minds). Deterministic.
/// `split` must refuse a triangle whose longest edge is short enough, or this never ends.
pub fn refine(mesh: &RawMesh, split: impl Fn(&[DVec3; 3], f64) -> bool) -> RawMesh {
    let mut positions = mesh.positions.clone();
    let mut midpoints: HashMap<(u32, u32), u32> = HashMap::new();
    let mut triangles = Vec::with_capacity(mesh.triangles.len());
    let mut pending: Vec<[u32; 3]> = mesh.triangles.iter().rev().copied().collect();
    while let Some(t) = pending.pop() {
        let length = |k: usize| {
            positions[t[k] as usize].distance_squared(positions[t[(k + 1) % 3] as usize])
        };
        let longest = (0..3)
            .max_by(|&a, &b| length(a).total_cmp(&length(b)).then(b.cmp(&a)))
            .expect("three edges");
        let corners = t.map(|v| positions[v as usize]);
        if !split(&corners, length(longest).sqrt()) {
            triangles.push(t);
            continue;
        }
        let (a, b, c) = (t[longest], t[(longest + 1) % 3], t[(longest + 2) % 3]);
        let m = *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
            positions.push((positions[a as usize] + positions[b as usize]) / 2.0);
            positions.len() as u32 - 1
        });
        // Winding kept: (a, b, c) becomes (a, m, c) and (m, b, c).
        pending.push([m, b, c]);
        pending.push([a, m, c]);
    }
    RawMesh {
        positions,
        triangles,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_edges_are_split_with_the_area_and_winding_kept() {
        let mesh = RawMesh {
            positions: vec![
                DVec3::ZERO,
                DVec3::new(2.0, 0.0, 0.0),
                DVec3::new(0.0, 1.0, 0.0),
            ],
            triangles: vec![[0, 1, 2]],
        };
        let refined = refine(&mesh, |_, longest| longest > 0.25);
        let corners = |t: &[u32; 3]| t.map(|v| refined.positions[v as usize]);
        let mut area = 0.0;
        for t in &refined.triangles {
            let [a, b, c] = corners(t);
            let normal = (b - a).cross(c - a);
            assert!(normal.z > 0.0, "winding kept");
            area += normal.length() / 2.0;
            for (p, q) in [(a, b), (b, c), (c, a)] {
                assert!(p.distance(q) <= 0.25 + 1e-12);
            }
        }
        assert!((area - 1.0).abs() < 1e-12);
        // Shared midpoints: no position twice.
        let mut keys: Vec<[u64; 3]> = refined
            .positions
            .iter()
            .map(|p| p.to_array().map(f64::to_bits))
            .collect();
        keys.sort();
        keys.dedup();
        assert_eq!(keys.len(), refined.positions.len());
        // Nothing asked, nothing split.
        assert_eq!(refine(&mesh, |_, _| false), mesh);
    }
}

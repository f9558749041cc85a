//! Consistent outward orientation (SPEC §1.3).
//!
//! Waves are walked with the inside of the geodesic disk on their left as seen from the
//! outward side (SPEC §2.4), so the sign of every ECC value depends on the winding.

use std::collections::VecDeque;

use glam::DVec3;

use super::topology::{face_neighbours, NO_FACE};

/// What orientation found and changed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct OrientStats {
    /// Connected components (over manifold edges).
    pub components: usize,
    /// Components without boundary or non-manifold edges.
    pub closed_components: usize,
    /// Triangles whose winding was reversed.
    pub flipped_triangles: usize,
    /// Components in which no consistent winding exists (e.g. a Möbius strip).
    pub non_orientable_components: usize,
}

/// Makes the winding consistent across each component (BFS over shared manifold edges); a
/// closed component is then turned outward (positive signed volume), an open one keeps the
/// winding of the larger part (by area) of its input triangles.
pub fn orient(positions: &[DVec3], triangles: &mut [[u32; 3]]) -> OrientStats {
    let adjacency = face_neighbours(triangles);
    let mut stats = OrientStats::default();
    let mut flip = vec![false; triangles.len()];
    let mut seen = vec![false; triangles.len()];
    let mut queue = VecDeque::new();
    let centre = positions.iter().copied().sum::<DVec3>() / positions.len().max(1) as f64;

    for seed in 0..triangles.len() {
        if seen[seed] {
            continue;
        }
        stats.components += 1;
        let mut members = Vec::new();
        let mut closed = true;
        let mut consistent = true;
        seen[seed] = true;
        queue.push_back(seed);
        while let Some(f) = queue.pop_front() {
            members.push(f);
            for k in 0..3 {
                let g = adjacency.neighbour[f][k];
                if g == NO_FACE {
                    closed = false;
                    continue;
                }
                let g = g as usize;
                // Two faces agree when they walk their shared edge in opposite directions.
                let (a, b) = (triangles[f][k], triangles[f][(k + 1) % 3]);
                let same_direction =
                    (0..3).any(|j| triangles[g][j] == a && triangles[g][(j + 1) % 3] == b);
                let wanted = flip[f] ^ same_direction;
                if !seen[g] {
                    seen[g] = true;
                    flip[g] = wanted;
                    queue.push_back(g);
                } else if flip[g] != wanted {
                    consistent = false;
                }
            }
        }
        if !consistent {
            stats.non_orientable_components += 1;
        }
        let flip_all = if closed && consistent {
            stats.closed_components += 1;
            let volume: f64 = members
                .iter()
                .map(|&f| {
                    let [a, b, c] = triangles[f].map(|v| positions[v as usize] - centre);
                    let v = a.dot(b.cross(c));
                    if flip[f] {
                        -v
                    } else {
                        v
                    }
                })
                .sum();
            volume < 0.0
        } else {
            let (mut kept, mut turned) = (0.0, 0.0);
            for &f in &members {
                let [a, b, c] = triangles[f].map(|v| positions[v as usize]);
                let area = (b - a).cross(c - a).length();
                if flip[f] {
                    turned += area;
                } else {
                    kept += area;
                }
            }
            turned > kept
        };
        for &f in &members {
            if flip[f] ^ flip_all {
                triangles[f].swap(1, 2);
                stats.flipped_triangles += 1;
            }
        }
    }
    stats
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra() -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let p = vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z];
        (p, vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    }

    fn volume(p: &[DVec3], t: &[[u32; 3]]) -> f64 {
        t.iter()
            .map(|t| p[t[0] as usize].dot(p[t[1] as usize].cross(p[t[2] as usize])))
            .sum()
    }

    #[test]
    fn closed_mesh_is_made_consistent_and_outward() {
        let (p, good) = tetra();
        assert!(volume(&p, &good) > 0.0);
        let mut t = good.clone();
        t[2].swap(1, 2); // one face wrong
        let s = orient(&p, &mut t);
        assert_eq!(s.flipped_triangles, 1);
        assert_eq!(s.closed_components, 1);
        assert!(volume(&p, &t) > 0.0);
        let mut inside_out: Vec<_> = good.iter().map(|t| [t[0], t[2], t[1]]).collect();
        assert_eq!(orient(&p, &mut inside_out).flipped_triangles, 4);
        assert_eq!(inside_out, good);
    }

    #[test]
    fn open_mesh_keeps_the_majority_winding() {
        let (p, good) = tetra();
        let mut open = good[..3].to_vec();
        open[0].swap(1, 2);
        let s = orient(&p, &mut open);
        assert_eq!(s.closed_components, 0);
        assert_eq!(s.flipped_triangles, 1);
        assert_eq!(open, good[..3].to_vec());
    }
}

//! Bounding the mesh size (SPEC §1.5) with meshoptimizer's quadric-error edge collapse.
//!
//! Collapses move no vertex: the simplified mesh uses a subset of the input vertices, so the
//! positions reported in input coordinates stay exact. A mesh far larger than the bound (a
//! print file of millions of triangles) is first clustered down to [`PRE_PASS_FACTOR`] times
//! the target by meshoptimizer's sloppy simplifier, which is linear in the input and also
//! keeps a subset of the vertices; the collapses then work on that, so the cost stays linear
//! in the input instead of growing with the number of collapses.

use glam::DVec3;
use meshopt::{SimplifyOptions, VertexDataAdapter};

use super::weld::compact;

/// Simplifies to at most `max_vertices` vertices. Returns `None` when the mesh is already
/// small enough.
pub fn simplify(
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    max_vertices: usize,
) -> Option<(Vec<DVec3>, Vec<[u32; 3]>)> {
    if positions.len() <= max_vertices {
        return None;
    }
    let input = Input::new(positions);
    let pre_passed = input.clustered(triangles, PRE_PASS_FACTOR * 2 * max_vertices);
    let triangles = pre_passed.as_deref().unwrap_or(triangles);
    // meshoptimizer targets an index count; vertices follow triangles roughly 1:2, so aim in
    // proportion and tighten until the vertex bound holds (it converges in one or two rounds).
    let mut target = (3.0 * triangles.len() as f64 * max_vertices as f64
        / vertex_count(triangles, positions.len()).max(1) as f64) as usize;
    let mut best = None;
    for _ in 0..8 {
        let (p, t) = input.collapse(triangles, target);
        let within = p.len() <= max_vertices;
        let count = p.len();
        best = Some((p, t));
        if within {
            break;
        }
        target = (target as f64 * max_vertices as f64 / count as f64 * 0.98) as usize;
    }
    best
}

/// Simplifies to at most `max_triangles` triangles, as far as edge collapses can go: the
/// resolution levels of the robustness experiment are fractions of the face count (paper
/// §6.1, Table 2). Returns the mesh unchanged when it is already small enough.
pub fn simplify_to_triangles(
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    max_triangles: usize,
) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    if triangles.len() <= max_triangles {
        return compact(positions, triangles);
    }
    Input::new(positions).collapse(triangles, 3 * max_triangles)
}

/// The triangles left by collapsing edges down to at most `max_triangles`, over the input's
/// vertex indices (for a caller that carries per-vertex data along).
pub fn collapsed_triangles(
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    max_triangles: usize,
) -> Vec<[u32; 3]> {
    if triangles.len() <= max_triangles {
        return triangles.to_vec();
    }
    Input::new(positions).kept(triangles, 3 * max_triangles)
}

/// How many times the target's triangles the sloppy pre-pass leaves: enough that the edge
/// collapses, which decide the final shape, still choose among many candidates.
const PRE_PASS_FACTOR: usize = 40;

/// Vertices the triangles use.
fn vertex_count(triangles: &[[u32; 3]], vertices: usize) -> usize {
    let mut used = vec![false; vertices];
    for &i in triangles.iter().flatten() {
        used[i as usize] = true;
    }
    used.into_iter().filter(|&u| u).count()
}

/// The vertices in meshoptimizer's form; triangles are passed to it as they are (a print
/// file's are not copied).
struct Input<'a> {
    positions: &'a [DVec3],
    points: Vec<[f32; 3]>,
}

impl<'a> Input<'a> {
    fn new(positions: &'a [DVec3]) -> Self {
        Self {
            positions,
            points: positions.iter().map(|p| p.as_vec3().to_array()).collect(),
        }
    }

    fn vertices(&self) -> VertexDataAdapter<'_> {
        VertexDataAdapter::new(bytemuck::cast_slice(&self.points), 12, 0).expect("packed positions")
    }

    /// The triangles left by clustering down to about `max_triangles` (sloppy simplification:
    /// linear in the input), over the input's vertices; `None` when there are not many more
    /// than that already.
    fn clustered(&self, triangles: &[[u32; 3]], max_triangles: usize) -> Option<Vec<[u32; 3]>> {
        if triangles.len() <= 2 * max_triangles {
            return None;
        }
        let kept = meshopt::simplify_sloppy(
            bytemuck::cast_slice(triangles),
            &self.vertices(),
            3 * max_triangles,
            f32::MAX,
            None,
        );
        Some(kept.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
    }

    /// Quadric edge collapses down to `target` indices (no error bound), unused vertices
    /// dropped.
    fn collapse(&self, triangles: &[[u32; 3]], target: usize) -> (Vec<DVec3>, Vec<[u32; 3]>) {
        compact(self.positions, &self.kept(triangles, target))
    }

    /// The triangles left, over the input's vertices.
    fn kept(&self, triangles: &[[u32; 3]], target: usize) -> Vec<[u32; 3]> {
        let kept = meshopt::simplify(
            bytemuck::cast_slice(triangles),
            &self.vertices(),
            target.max(3),
            f32::MAX,
            SimplifyOptions::None,
            None,
        );
        kept.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reaches_the_vertex_bound_with_input_vertices() {
        // A 60 x 60 grid, 3600 vertices.
        let n = 60u32;
        let positions: Vec<DVec3> = (0..n * n)
            .map(|i| DVec3::new((i % n) as f64, (i / n) as f64, ((i % 7) as f64) * 0.1))
            .collect();
        let mut triangles = Vec::new();
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let v = y * n + x;
                triangles.push([v, v + 1, v + n + 1]);
                triangles.push([v, v + n + 1, v + n]);
            }
        }
        assert!(simplify(&positions, &triangles, 5000).is_none());
        let (p, t) = simplify(&positions, &triangles, 1000).unwrap();
        assert!(p.len() <= 1000 && p.len() > 500, "{} vertices", p.len());
        assert!(!t.is_empty());
        assert!(p.iter().all(|q| positions.contains(q)));

        let (p, t) = simplify_to_triangles(&positions, &triangles, 1000);
        assert!(t.len() <= 1000 && t.len() > 900, "{} triangles", t.len());
        assert!(p.iter().all(|q| positions.contains(q)));
    }
}

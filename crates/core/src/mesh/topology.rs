//! Connectivity the geodesic and wave code walks on: vertex neighbours with edge lengths
//! (Dijkstra, SPEC §2.1), the faces around each vertex and the face across each edge
//! (iso-line tracing, SPEC §2.2). Stored as flat arrays (CSR) so that the per-vertex loops of
//! extraction touch contiguous memory. Also the mesh's connected pieces, which a cut part
//! keeps the largest of and the duplicate check forgives a simplification for deleting.

use glam::DVec3;

/// Marks "no face across this edge": a boundary edge, or a non-manifold one (shared by more
/// than two faces), which waves do not cross (SPEC §1.3, §2.3).
pub const NO_FACE: u32 = u32::MAX;

/// The face across each edge of each triangle; edge `k` of face `f` runs from corner `k` to
/// corner `k + 1`.
#[derive(Debug, Clone)]
pub struct FaceNeighbours {
    pub neighbour: Vec<[u32; 3]>,
    pub boundary_edges: usize,
    pub non_manifold_edges: usize,
}

/// The connected piece of each triangle (triangles sharing a vertex are connected), named by
/// its smallest vertex, over `vertices` vertices. Union–find over the corners, written here:
/// ten lines against a graph crate's whole API.
pub fn pieces(vertices: usize, triangles: &[[u32; 3]]) -> Vec<u32> {
    let mut parent: Vec<u32> = (0..vertices as u32).collect();
    fn root(parent: &mut [u32], mut x: u32) -> u32 {
        while parent[x as usize] != x {
            parent[x as usize] = parent[parent[x as usize] as usize];
            x = parent[x as usize];
        }
        x
    }
    for t in triangles {
        for k in 1..3 {
            let (a, b) = (root(&mut parent, t[0]), root(&mut parent, t[k]));
            parent[a.max(b) as usize] = a.min(b);
        }
    }
    triangles.iter().map(|t| root(&mut parent, t[0])).collect()
}

/// Pairs up the faces sharing each undirected edge.
///
/// Half-edges are bucketed by their smaller vertex (a counting sort: linear, four bytes a
/// half-edge), and each bucket's few ordered by the other vertex: sorted as tuples, the edges
/// of a 4 M-triangle print file took 211 MB (`benches/big.rs`).
pub fn face_neighbours(triangles: &[[u32; 3]]) -> FaceNeighbours {
    // Half-edge `h` is edge `h % 3` of face `h / 3`, as (smaller, larger) vertex.
    let ends = |h: u32| {
        let t = triangles[(h / 3) as usize];
        let k = (h % 3) as usize;
        let (a, b) = (t[k], t[(k + 1) % 3]);
        (a.min(b), a.max(b))
    };
    let half_edges = u32::try_from(3 * triangles.len()).expect("fewer than 2^32 half-edges");
    let vertex_count = triangles
        .iter()
        .flatten()
        .max()
        .map_or(0, |&v| v as usize + 1);
    let mut start = vec![0u32; vertex_count + 1];
    for h in 0..half_edges {
        start[ends(h).0 as usize + 1] += 1;
    }
    for v in 0..vertex_count {
        start[v + 1] += start[v];
    }
    let mut order = vec![0u32; half_edges as usize];
    let mut next = start.clone();
    for h in 0..half_edges {
        let slot = &mut next[ends(h).0 as usize];
        order[*slot as usize] = h;
        *slot += 1;
    }
    drop(next);
    let mut neighbour = vec![[NO_FACE; 3]; triangles.len()];
    let (mut boundary_edges, mut non_manifold_edges) = (0, 0);
    for v in 0..vertex_count {
        let bucket = &mut order[start[v] as usize..start[v + 1] as usize];
        bucket.sort_unstable_by_key(|&h| (ends(h).1, h));
        for run in bucket.chunk_by(|&x, &y| ends(x) == ends(y)) {
            match *run {
                [x, y] => {
                    let (f, i, g, j) = (x / 3, x % 3, y / 3, y % 3);
                    neighbour[f as usize][i as usize] = g;
                    neighbour[g as usize][j as usize] = f;
                }
                [_] => boundary_edges += 1,
                _ => non_manifold_edges += 1,
            }
        }
    }
    FaceNeighbours {
        neighbour,
        boundary_edges,
        non_manifold_edges,
    }
}

/// Mesh connectivity for extraction.
#[derive(Debug, Clone)]
pub struct Topology {
    vertex_start: Vec<u32>,
    vertex_neighbours: Vec<u32>,
    edge_lengths: Vec<f64>,
    face_start: Vec<u32>,
    vertex_faces: Vec<u32>,
    /// The face across each edge (see [`FaceNeighbours`]).
    pub faces: FaceNeighbours,
    /// Area-weighted vertex normals, the orientation fallback of SPEC §2.4.
    pub vertex_normals: Vec<DVec3>,
}

impl Topology {
    pub fn new(positions: &[DVec3], triangles: &[[u32; 3]]) -> Self {
        let n = positions.len();
        let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(triangles.len() * 6);
        let mut incident: Vec<(u32, u32)> = Vec::with_capacity(triangles.len() * 3);
        let mut vertex_normals = vec![DVec3::ZERO; n];
        for (f, t) in triangles.iter().enumerate() {
            let [a, b, c] = t.map(|v| positions[v as usize]);
            let area_normal = (b - a).cross(c - a);
            for k in 0..3 {
                let (u, v) = (t[k], t[(k + 1) % 3]);
                pairs.push((u, v));
                pairs.push((v, u));
                incident.push((u, f as u32));
                vertex_normals[u as usize] += area_normal;
            }
        }
        pairs.sort_unstable();
        pairs.dedup();
        incident.sort_unstable();
        let (vertex_start, vertex_neighbours) = csr(n, &pairs);
        let edge_lengths = vertex_neighbours
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                let u = pairs[i].0;
                positions[u as usize].distance(positions[v as usize])
            })
            .collect();
        let (face_start, vertex_faces) = csr(n, &incident);
        Self {
            vertex_start,
            vertex_neighbours,
            edge_lengths,
            face_start,
            vertex_faces,
            faces: face_neighbours(triangles),
            vertex_normals: vertex_normals
                .into_iter()
                .map(|v| v.normalize_or_zero())
                .collect(),
        }
    }

    /// Neighbours of `v` with the lengths of the edges to them.
    pub fn neighbours(&self, v: u32) -> impl Iterator<Item = (u32, f64)> + '_ {
        let range =
            self.vertex_start[v as usize] as usize..self.vertex_start[v as usize + 1] as usize;
        self.vertex_neighbours[range.clone()]
            .iter()
            .copied()
            .zip(self.edge_lengths[range].iter().copied())
    }

    /// Faces incident to `v`.
    pub fn faces_of(&self, v: u32) -> &[u32] {
        &self.vertex_faces
            [self.face_start[v as usize] as usize..self.face_start[v as usize + 1] as usize]
    }

    /// Mean edge length, a measure of the mesh's resolution.
    pub fn mean_edge_length(&self) -> f64 {
        self.edge_lengths.iter().sum::<f64>() / self.edge_lengths.len().max(1) as f64
    }
}

/// Compressed rows from `(row, value)` pairs sorted by row.
fn csr(rows: usize, sorted_pairs: &[(u32, u32)]) -> (Vec<u32>, Vec<u32>) {
    let mut start = vec![0u32; rows + 1];
    for &(r, _) in sorted_pairs {
        start[r as usize + 1] += 1;
    }
    for r in 0..rows {
        start[r + 1] += start[r];
    }
    (start, sorted_pairs.iter().map(|&(_, v)| v).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pieces_join_triangles_through_shared_vertices() {
        // Two triangles sharing vertex 2, one apart, one reaching back to the first.
        let triangles = [[0, 1, 2], [5, 6, 7], [2, 3, 4], [8, 9, 3]];
        assert_eq!(pieces(10, &triangles), [0, 5, 0, 0]);
    }
}

//! Forstmann's Fast Quadric Mesh Simplification (sp4cerat/Fast-Quadric-Mesh-Simplification,
//! MIT), ported from its `Simplify.h`, function for function: what pyfqmr and pyvista's
//! fast_simplification wrap. Ported because the held-back benchmark of issue #38 found copies
//! made by these tools missed where [`super::quadric`]'s were found; no Rust crate carries it.

use glam::{DMat3, DVec3};
use salient_core::mesh::weld::compact;

use super::{Indexed, Quadric};

/// `Simplify.h`'s default "agressiveness": how fast the error threshold grows.
const AGGRESSIVENESS: f64 = 7.0;
/// Its sweeps at most, and every how many the triangles are compacted.
const SWEEPS: u32 = 100;
const COMPACT_EVERY: u32 = 5;

/// Simplifies to at most `target` triangles (or what 100 sweeps reach). Edges are collapsed in
/// sweeps under an absolute error threshold that grows each sweep (no queue), with unweighted
/// plane quadrics, no link condition and only a fold-over check — so thin parts and small
/// pieces collapse and vanish, as with the tools that run it.
pub fn fast_quadric(positions: &[DVec3], triangles: &[[u32; 3]], target: usize) -> Indexed {
    let mut mesh = Simplify::new(positions, triangles);
    mesh.simplify(target);
    mesh.compact()
}

struct Triangle {
    v: [usize; 3],
    /// Each edge's collapse error, and their least.
    error: [f64; 4],
    deleted: bool,
    dirty: bool,
    normal: DVec3,
}

struct Vertex {
    p: DVec3,
    /// This vertex's triangles: `refs[start..start + count]`.
    start: usize,
    count: usize,
    q: Quadric,
    border: bool,
}

struct Simplify {
    vertices: Vec<Vertex>,
    triangles: Vec<Triangle>,
    /// (triangle, corner) of each vertex's triangles.
    refs: Vec<(usize, usize)>,
}

/// `Simplify.h`'s normalising, NaN for a zero vector as there: a degenerate triangle's NaN
/// quadric freezes its vertices, and a NaN direction folds nothing over.
fn unit(v: DVec3) -> DVec3 {
    v / v.length()
}

impl Simplify {
    fn new(positions: &[DVec3], triangles: &[[u32; 3]]) -> Self {
        Self {
            vertices: positions
                .iter()
                .map(|&p| Vertex {
                    p,
                    start: 0,
                    count: 0,
                    q: Quadric::default(),
                    border: false,
                })
                .collect(),
            triangles: triangles
                .iter()
                .map(|t| Triangle {
                    v: t.map(|v| v as usize),
                    error: [0.0; 4],
                    deleted: false,
                    dirty: false,
                    normal: DVec3::ZERO,
                })
                .collect(),
            refs: Vec::new(),
        }
    }

    /// `simplify_mesh`.
    fn simplify(&mut self, target: usize) {
        let count = self.triangles.len();
        let mut deleted = 0;
        let (mut deleted0, mut deleted1) = (Vec::new(), Vec::new());
        for iteration in 0..SWEEPS {
            if count - deleted <= target {
                break;
            }
            if iteration % COMPACT_EVERY == 0 {
                self.update_mesh(iteration);
            }
            for t in &mut self.triangles {
                t.dirty = false;
            }
            let threshold = 1e-9 * f64::from(iteration + 3).powf(AGGRESSIVENESS);
            for i in 0..self.triangles.len() {
                let t = &self.triangles[i];
                if t.error[3] > threshold || t.deleted || t.dirty {
                    continue;
                }
                for j in 0..3 {
                    let t = &self.triangles[i];
                    let (i0, i1) = (t.v[j], t.v[(j + 1) % 3]);
                    if t.error[j] >= threshold
                        || self.vertices[i0].border != self.vertices[i1].border
                    {
                        continue;
                    }
                    let (_, p) = self.calculate_error(i0, i1);
                    if self.flipped(p, i0, i1, &mut deleted0)
                        || self.flipped(p, i1, i0, &mut deleted1)
                    {
                        continue;
                    }
                    self.vertices[i0].p = p;
                    self.vertices[i0].q = Quadric::sum(&self.vertices[i0].q, &self.vertices[i1].q);
                    let start = self.refs.len();
                    deleted += self.update_triangles(i0, i0, &deleted0);
                    deleted += self.update_triangles(i0, i1, &deleted1);
                    let count = self.refs.len() - start;
                    let v0 = &mut self.vertices[i0];
                    if count <= v0.count {
                        // Reuse `i0`'s room.
                        self.refs.copy_within(start.., v0.start);
                        self.refs.truncate(start);
                    } else {
                        v0.start = start;
                    }
                    v0.count = count;
                    break;
                }
                if count - deleted <= target {
                    break;
                }
            }
        }
    }

    /// `update_mesh`: the deleted triangles dropped (after the first sweep), each vertex's
    /// triangles listed again; before the first, the borders, quadrics and edge errors.
    fn update_mesh(&mut self, iteration: u32) {
        if iteration > 0 {
            self.triangles.retain(|t| !t.deleted);
        }
        for v in &mut self.vertices {
            v.count = 0;
        }
        for t in &self.triangles {
            for &v in &t.v {
                self.vertices[v].count += 1;
            }
        }
        let mut start = 0;
        for v in &mut self.vertices {
            v.start = start;
            start += v.count;
            v.count = 0;
        }
        self.refs = vec![(0, 0); self.triangles.len() * 3];
        for (i, t) in self.triangles.iter().enumerate() {
            for (corner, &v) in t.v.iter().enumerate() {
                let v = &mut self.vertices[v];
                self.refs[v.start + v.count] = (i, corner);
                v.count += 1;
            }
        }
        if iteration > 0 {
            return;
        }
        // A vertex is on the border when a neighbour shares only one of its triangles.
        for i in 0..self.vertices.len() {
            let mut seen: Vec<(usize, u32)> = Vec::new();
            for &(t, _) in self.around(i) {
                for &w in &self.triangles[t].v {
                    match seen.iter_mut().find(|(x, _)| *x == w) {
                        Some((_, n)) => *n += 1,
                        None => seen.push((w, 1)),
                    }
                }
            }
            for (w, n) in seen {
                if n == 1 {
                    self.vertices[w].border = true;
                }
            }
        }
        for t in &mut self.triangles {
            let [a, b, c] = t.v.map(|v| self.vertices[v].p);
            t.normal = unit((b - a).cross(c - a));
            let q = Quadric::plane(t.normal, a, 1.0);
            for &v in &t.v {
                self.vertices[v].q.add(&q);
            }
        }
        for i in 0..self.triangles.len() {
            self.edge_errors(i);
        }
    }

    fn around(&self, v: usize) -> &[(usize, usize)] {
        let v = &self.vertices[v];
        &self.refs[v.start..v.start + v.count]
    }

    fn edge_errors(&mut self, t: usize) {
        let v = self.triangles[t].v;
        let error: [f64; 3] = std::array::from_fn(|j| self.calculate_error(v[j], v[(j + 1) % 3]).0);
        self.triangles[t].error = [
            error[0],
            error[1],
            error[2],
            error[0].min(error[1]).min(error[2]),
        ];
    }

    /// `calculate_error`: the error of collapsing `a b`, and where to — the quadrics' optimum
    /// when their matrix is invertible and the edge not on the border, else the best of its
    /// ends and midpoint (the last of equals).
    fn calculate_error(&self, a: usize, b: usize) -> (f64, DVec3) {
        let (va, vb) = (&self.vertices[a], &self.vertices[b]);
        let q = Quadric::sum(&va.q, &vb.q);
        let [aa, ab, ac, ad, bb, bc, bd, cc, cd, _] = q.0;
        let m = DMat3::from_cols(
            DVec3::new(aa, ab, ac),
            DVec3::new(ab, bb, bc),
            DVec3::new(ac, bc, cc),
        );
        if m.determinant() != 0.0 && !(va.border && vb.border) {
            let p = m.inverse() * -DVec3::new(ad, bd, cd);
            return (q.error(p), p);
        }
        [va.p, vb.p, (va.p + vb.p) / 2.0]
            .into_iter()
            .map(|p| (q.error(p), p))
            .fold(
                (f64::INFINITY, va.p),
                |best, x| if x.0 <= best.0 { x } else { best },
            )
    }

    /// `flipped`: whether moving `a` to `p` (collapsing `a b`) turns one of `a`'s triangles
    /// over or flat; `deleted` marks those that hold `b` (the collapse deletes them).
    fn flipped(&self, p: DVec3, a: usize, b: usize, deleted: &mut Vec<bool>) -> bool {
        let around = self.around(a);
        deleted.clear();
        deleted.resize(around.len(), false);
        for (k, &(t, corner)) in around.iter().enumerate() {
            let t = &self.triangles[t];
            if t.deleted {
                continue;
            }
            let (id1, id2) = (t.v[(corner + 1) % 3], t.v[(corner + 2) % 3]);
            if id1 == b || id2 == b {
                deleted[k] = true;
                continue;
            }
            let (d1, d2) = (
                unit(self.vertices[id1].p - p),
                unit(self.vertices[id2].p - p),
            );
            if d1.dot(d2).abs() > 0.999 || unit(d1.cross(d2)).dot(t.normal) < 0.2 {
                return true;
            }
        }
        false
    }

    /// `update_triangles`: `v`'s triangles now hold `i0` (their errors made again, listed
    /// after the others), those `deleted` marks go; how many went.
    fn update_triangles(&mut self, i0: usize, v: usize, deleted: &[bool]) -> usize {
        let mut gone = 0;
        // `deleted` is as long as `v`'s triangles: `flipped` marked them.
        let start = self.vertices[v].start;
        for (k, &delete) in deleted.iter().enumerate() {
            let (t, corner) = self.refs[start + k];
            if self.triangles[t].deleted {
                continue;
            }
            if delete {
                self.triangles[t].deleted = true;
                gone += 1;
                continue;
            }
            self.triangles[t].v[corner] = i0;
            self.triangles[t].dirty = true;
            self.edge_errors(t);
            self.refs.push((t, corner));
        }
        gone
    }

    /// `compact_mesh`: the triangles left, over the vertices they use.
    fn compact(self) -> Indexed {
        let positions: Vec<DVec3> = self.vertices.iter().map(|v| v.p).collect();
        let kept: Vec<[u32; 3]> = self
            .triangles
            .iter()
            .filter(|t| !t.deleted)
            .map(|t| t.v.map(|v| v as u32))
            .collect();
        compact(&positions, &kept)
    }
}

//! The ways asset tools re-tessellate a mesh, as disguises for the duplicate benchmark
//! ([`super::duplicates`], issue #38): each *family* is one common tool's way of making the
//! same asset coarser or finer, and two (Loop's and Catmull–Clark's subdivision) ways of making
//! another asset.
//!
//! - [`edge_collapse`]: meshoptimizer's edge collapse, which keeps a subset of the vertices;
//! - [`quadric`]: Garland–Heckbert quadric edge collapse *with optimal placement*, which moves
//!   every merged vertex (Blender's Decimate "Collapse", Open3D);
//! - [`fast_quadric`]: Forstmann's fast quadric simplification (pyfqmr, fast_simplification),
//!   quadrics too but swept under a growing threshold without a manifold check, so thin parts
//!   and small pieces collapse;
//! - [`clustered`]: vertex clustering on a grid (Rossignac–Borrel, MeshLab's clustering
//!   decimation), each cell's vertices merged at their mean;
//! - [`retriangulated`]: the same vertices with quads' diagonals flipped, as a quad export
//!   re-triangulated by another tool;
//! - [`midpoint`]: linear subdivision, every triangle split in four at its edges' midpoints —
//!   the same surface with more triangles;
//! - [`loop_subdivided`]: Loop's smoothing subdivision, which moves the surface: a smoother,
//!   shrunken asset, *not* the same shape;
//! - [`catmull_clark`]: Catmull–Clark's, with its quads triangulated: the same, and what
//!   Blender's Subdivision Surface makes.
//!
//! The quadric simplifiers and the subdivisions are written here: meshoptimizer (the `meshopt`
//! crate) keeps input vertices by design, and no maintained Rust crate offers Garland–Heckbert
//! optimal placement or Loop's or Catmull–Clark's subdivision over an indexed mesh without bringing its own mesh
//! types and math stack for ~200 lines of work.

use std::cmp::Ordering;
use std::collections::{BTreeMap, BinaryHeap, HashMap};
use std::f64::consts::PI;

use glam::{DMat3, DVec3};
use salient_core::mesh::weld::compact;

mod fast_quadric;
pub use fast_quadric::fast_quadric;

/// An indexed triangle mesh: positions and triangles.
pub type Indexed = (Vec<DVec3>, Vec<[u32; 3]>);

/// The surface area of an indexed mesh: how much of its model a copy kept.
pub fn area(positions: &[DVec3], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|v| positions[v as usize]);
            (b - a).cross(c - a).length() / 2.0
        })
        .sum()
}

/// meshoptimizer's edge collapse down to `target` vertices (a subset of the input's).
pub fn edge_collapse(positions: &[DVec3], triangles: &[[u32; 3]], target: usize) -> Indexed {
    salient_core::mesh::simplify::simplify(positions, triangles, target)
        .unwrap_or_else(|| compact(positions, triangles))
}

/// A symmetric 4×4 quadric `Σ w (n·x + d)²` as its ten distinct entries, row by row of the
/// upper triangle: `aa ab ac ad bb bc bd cc cd dd` for the plane `(a, b, c, d)`.
#[derive(Debug, Clone, Copy, Default)]
struct Quadric([f64; 10]);

impl Quadric {
    fn plane(normal: DVec3, point: DVec3, weight: f64) -> Self {
        let [a, b, c] = normal.to_array();
        let d = -normal.dot(point);
        Self(
            [
                a * a,
                a * b,
                a * c,
                a * d,
                b * b,
                b * c,
                b * d,
                c * c,
                c * d,
                d * d,
            ]
            .map(|x| x * weight),
        )
    }

    fn add(&mut self, other: &Quadric) {
        for (x, y) in self.0.iter_mut().zip(other.0) {
            *x += y;
        }
    }

    fn sum(a: &Quadric, b: &Quadric) -> Quadric {
        let mut q = *a;
        q.add(b);
        q
    }

    fn error(&self, p: DVec3) -> f64 {
        let [aa, ab, ac, ad, bb, bc, bd, cc, cd, dd] = self.0;
        let DVec3 { x, y, z } = p;
        aa * x * x
            + 2.0 * ab * x * y
            + 2.0 * ac * x * z
            + 2.0 * ad * x
            + bb * y * y
            + 2.0 * bc * y * z
            + 2.0 * bd * y
            + cc * z * z
            + 2.0 * cd * z
            + dd
    }

    /// The point of least error (Garland–Heckbert §4: solve `A x = −b`) when `A` is well
    /// conditioned, else the best point of the segment `a b` (a flat or cylindrical
    /// neighbourhood leaves `A` singular: any point along it is as good).
    fn optimum(&self, a: DVec3, b: DVec3) -> DVec3 {
        let [aa, ab, ac, ad, bb, bc, bd, cc, cd, _] = self.0;
        let m = DMat3::from_cols(
            DVec3::new(aa, ab, ac),
            DVec3::new(ab, bb, bc),
            DVec3::new(ac, bc, cc),
        );
        let scale = (aa + bb + cc) / 3.0;
        let det = m.determinant();
        if scale > 0.0 && det.abs() > 1e-6 * scale * scale * scale {
            let p = m.inverse() * -DVec3::new(ad, bd, cd);
            if p.is_finite() {
                return p;
            }
        }
        // error(a + t e) = α t² + 2 β t + const.
        let e = b - a;
        let alpha = e.dot(m * e);
        let beta = e.dot(m * a + DVec3::new(ad, bd, cd));
        let t = if alpha > 1e-12 * e.length_squared() * scale.max(f64::MIN_POSITIVE) {
            (-beta / alpha).clamp(0.0, 1.0)
        } else {
            0.5
        };
        a + e * t
    }
}

/// A candidate collapse of the edge `u v` to `to`, ordered by error (least first), ties by
/// vertices so that the result does not depend on the heap's order.
struct Candidate {
    error: f64,
    u: u32,
    v: u32,
    stamps: (u32, u32),
    to: DVec3,
}

impl PartialEq for Candidate {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> Ordering {
        // Reversed: `BinaryHeap` pops the largest.
        other
            .error
            .total_cmp(&self.error)
            .then_with(|| (other.u, other.v).cmp(&(self.u, self.v)))
    }
}

/// Boundary edges keep their place: a plane through each, perpendicular to its face, weighted
/// this much more than a face of the edge's length squared (Garland–Heckbert §6.1).
const BOUNDARY_WEIGHT: f64 = 100.0;

/// Garland–Heckbert quadric edge collapse with optimal placement down to `target` vertices:
/// face quadrics weighted by area, boundaries held by perpendicular planes, collapses that
/// would break the manifold (the link condition) or fold a face over refused.
pub fn quadric(positions: &[DVec3], triangles: &[[u32; 3]], target: usize) -> Indexed {
    let (mut position, triangles) = compact(positions, triangles);
    let n = position.len();
    let mut faces = triangles;
    let mut alive = vec![true; faces.len()];
    let mut around: Vec<Vec<u32>> = vec![Vec::new(); n];
    let mut quadrics = vec![Quadric::default(); n];
    let mut edge_faces: BTreeMap<(u32, u32), Vec<u32>> = BTreeMap::new();
    for (f, t) in faces.iter().enumerate() {
        let [a, b, c] = t.map(|v| position[v as usize]);
        let cross = (b - a).cross(c - a);
        let area = cross.length() / 2.0;
        if area > 0.0 {
            let q = Quadric::plane(cross.normalize(), a, area);
            for &v in t {
                quadrics[v as usize].add(&q);
            }
        }
        for k in 0..3 {
            around[t[k] as usize].push(f as u32);
            let (x, y) = (t[k], t[(k + 1) % 3]);
            edge_faces
                .entry((x.min(y), x.max(y)))
                .or_default()
                .push(f as u32);
        }
    }
    for (&(x, y), fs) in &edge_faces {
        if let [f] = fs[..] {
            let [a, b, c] = faces[f as usize].map(|v| position[v as usize]);
            let normal = (b - a).cross(c - a);
            let (p, q) = (position[x as usize], position[y as usize]);
            let across = (q - p).cross(normal);
            if across.length() > 0.0 {
                let plane = Quadric::plane(
                    across.normalize(),
                    p,
                    BOUNDARY_WEIGHT * p.distance_squared(q),
                );
                quadrics[x as usize].add(&plane);
                quadrics[y as usize].add(&plane);
            }
        }
    }
    let mut stamps = vec![0u32; n];
    let mut removed = vec![false; n];
    let neighbours = |v: u32, faces: &[[u32; 3]], alive: &[bool], around: &[Vec<u32>]| {
        let mut out: Vec<u32> = around[v as usize]
            .iter()
            .filter(|&&f| alive[f as usize])
            .flat_map(|&f| faces[f as usize])
            .filter(|&w| w != v)
            .collect();
        out.sort_unstable();
        out.dedup();
        out
    };
    let candidate = |u: u32, v: u32, position: &[DVec3], quadrics: &[Quadric], stamps: &[u32]| {
        let (u, v) = (u.min(v), u.max(v));
        let q = Quadric::sum(&quadrics[u as usize], &quadrics[v as usize]);
        let to = q.optimum(position[u as usize], position[v as usize]);
        Candidate {
            error: q.error(to).max(0.0),
            u,
            v,
            stamps: (stamps[u as usize], stamps[v as usize]),
            to,
        }
    };
    let mut heap: BinaryHeap<Candidate> = edge_faces
        .keys()
        .map(|&(u, v)| candidate(u, v, &position, &quadrics, &stamps))
        .collect();
    let mut left = n;
    while left > target {
        let Some(c) = heap.pop() else { break };
        let (u, v) = (c.u, c.v);
        if removed[u as usize]
            || removed[v as usize]
            || c.stamps != (stamps[u as usize], stamps[v as usize])
        {
            continue;
        }
        // The link condition: the common neighbours of u and v are exactly the third
        // vertices of the faces on u v; otherwise the collapse pinches the surface.
        let (nu, nv) = (
            neighbours(u, &faces, &alive, &around),
            neighbours(v, &faces, &alive, &around),
        );
        let common = nu.iter().filter(|w| nv.binary_search(w).is_ok()).count();
        let shared: Vec<u32> = around[u as usize]
            .iter()
            .copied()
            .filter(|&f| alive[f as usize] && faces[f as usize].contains(&v))
            .collect();
        if common != shared.len() || shared.is_empty() {
            continue;
        }
        // No face around u or v may turn over or collapse to a sliver.
        let folds = [u, v].iter().any(|&w| {
            around[w as usize]
                .iter()
                .filter(|&&f| alive[f as usize] && !shared.contains(&f))
                .any(|&f| {
                    let t = faces[f as usize];
                    let before = t.map(|x| position[x as usize]);
                    let after = t.map(|x| {
                        if x == u || x == v {
                            c.to
                        } else {
                            position[x as usize]
                        }
                    });
                    let normal = |[a, b, c]: [DVec3; 3]| (b - a).cross(c - a);
                    let (n0, n1) = (normal(before), normal(after));
                    n1.length_squared() <= 1e-6 * n0.length_squared()
                        || n0.dot(n1) <= 0.2 * n0.length() * n1.length()
                })
        });
        if folds {
            continue;
        }
        for &f in &shared {
            alive[f as usize] = false;
        }
        // A face's third vertex left on no face (an isolated triangle collapsed away, a
        // tree's leaf) is gone too.
        for &f in &shared {
            for x in faces[f as usize] {
                if x != u
                    && x != v
                    && !removed[x as usize]
                    && !around[x as usize].iter().any(|&g| alive[g as usize])
                {
                    removed[x as usize] = true;
                    left -= 1;
                }
            }
        }
        let moved: Vec<u32> = around[v as usize]
            .iter()
            .copied()
            .filter(|&f| alive[f as usize])
            .collect();
        for f in moved {
            for x in &mut faces[f as usize] {
                if *x == v {
                    *x = u;
                }
            }
            around[u as usize].push(f);
        }
        around[v as usize].clear();
        removed[v as usize] = true;
        left -= 1;
        if !around[u as usize].iter().any(|&g| alive[g as usize]) {
            removed[u as usize] = true;
            left -= 1;
            continue;
        }
        position[u as usize] = c.to;
        let q = quadrics[v as usize];
        quadrics[u as usize].add(&q);
        stamps[u as usize] += 1;
        for w in neighbours(u, &faces, &alive, &around) {
            heap.push(candidate(u, w, &position, &quadrics, &stamps));
        }
    }
    let kept: Vec<[u32; 3]> = faces
        .iter()
        .zip(&alive)
        .filter(|(_, &a)| a)
        .map(|(&t, _)| t)
        .collect();
    compact(&position, &kept)
}

/// Vertex clustering: the bounding box cut into cubes sized (by bisection) so that about
/// `target` of them hold vertices; each cube's vertices merged at their mean, triangles left
/// with fewer than three cubes dropped, repeated ones kept once.
pub fn clustered(positions: &[DVec3], triangles: &[[u32; 3]], target: usize) -> Indexed {
    let (positions, triangles) = compact(positions, triangles);
    let (lo, hi) = salient_core::mesh::weld::bounds(&positions);
    let cell_of = |p: DVec3, size: f64| ((p - lo) / size).floor().as_i64vec3().to_array();
    let cells = |size: f64| {
        let mut seen: HashMap<[i64; 3], u32> = HashMap::new();
        let of: Vec<u32> = positions
            .iter()
            .map(|&p| {
                let next = seen.len() as u32;
                *seen.entry(cell_of(p, size)).or_insert(next)
            })
            .collect();
        (seen.len(), of)
    };
    let (mut small, mut large) = (lo.distance(hi) * 1e-6, lo.distance(hi));
    for _ in 0..40 {
        let middle = (small * large).sqrt();
        if cells(middle).0 > target {
            small = middle;
        } else {
            large = middle;
        }
    }
    let (count, of) = cells(large);
    let mut sum = vec![(DVec3::ZERO, 0usize); count];
    for (p, &c) in positions.iter().zip(&of) {
        sum[c as usize].0 += *p;
        sum[c as usize].1 += 1;
    }
    let merged: Vec<DVec3> = sum.iter().map(|&(s, k)| s / k as f64).collect();
    let mut seen = std::collections::HashSet::new();
    let kept: Vec<[u32; 3]> = triangles
        .iter()
        .map(|t| t.map(|v| of[v as usize]))
        .filter(|&[a, b, c]| a != b && b != c && a != c)
        .filter(|t| {
            let mut key = *t;
            key.sort_unstable();
            seen.insert(key)
        })
        .collect();
    compact(&merged, &kept)
}

/// The same vertices, triangulated again: of each pair of near-coplanar triangles (normals
/// within [`QUAD_ANGLE`]) that make a convex quad, taken greedily in order, the diagonal
/// flipped — what a quad-dominant export re-triangulated by another tool gives.
/// Two triangles whose normals are within this many degrees make a quad of an export.
pub const QUAD_ANGLE: f64 = 5.0;

pub fn retriangulated(positions: &[DVec3], triangles: &[[u32; 3]]) -> Indexed {
    let mut faces = triangles.to_vec();
    let mut on_edge: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
    for (f, t) in faces.iter().enumerate() {
        for k in 0..3 {
            let (x, y) = (t[k], t[(k + 1) % 3]);
            on_edge.entry((x.min(y), x.max(y))).or_default().push(f);
        }
    }
    let mut edges: Vec<((u32, u32), Vec<usize>)> = on_edge.into_iter().collect();
    edges.sort_unstable();
    let mut used = vec![false; faces.len()];
    for ((x, y), fs) in edges {
        let [f, g] = fs[..] else { continue };
        if used[f] || used[g] {
            continue;
        }
        let apex = |t: [u32; 3]| *t.iter().find(|&&v| v != x && v != y).expect("a triangle");
        let (p, q) = (apex(faces[f]), apex(faces[g]));
        // Keep f's orientation: f = (x, y, p) in its order.
        let k = (0..3).find(|&k| faces[f][k] == p).expect("the apex");
        let (a, b) = (faces[f][(k + 1) % 3], faces[f][(k + 2) % 3]);
        let flipped = [[p, a, q], [p, q, b]];
        let normal = |t: [u32; 3]| {
            let [a, b, c] = t.map(|v| positions[v as usize]);
            (b - a).cross(c - a)
        };
        let (nf, ng) = (normal(faces[f]), normal(faces[g]));
        let planar = nf.angle_between(ng).to_degrees() < QUAD_ANGLE;
        let before = nf + ng;
        if planar && p != q && flipped.iter().all(|&t| normal(t).dot(before) > 0.0) {
            faces[f] = flipped[0];
            faces[g] = flipped[1];
            used[f] = true;
            used[g] = true;
        }
    }
    (positions.to_vec(), faces)
}

/// The edges of a mesh, each with the triangles on it, and each triangle's three edges (as
/// indices into the first).
type Edges = (Vec<((u32, u32), Vec<u32>)>, Vec<[usize; 3]>);

fn edges(triangles: &[[u32; 3]]) -> Edges {
    let mut number: HashMap<(u32, u32), usize> = HashMap::new();
    let mut list: Vec<((u32, u32), Vec<u32>)> = Vec::new();
    let of = triangles
        .iter()
        .enumerate()
        .map(|(f, t)| {
            [0, 1, 2].map(|k| {
                let (x, y) = (t[k], t[(k + 1) % 3]);
                let key = (x.min(y), x.max(y));
                let e = *number.entry(key).or_insert_with(|| {
                    list.push((key, Vec::new()));
                    list.len() - 1
                });
                list[e].1.push(f as u32);
                e
            })
        })
        .collect();
    (list, of)
}

/// One step of a subdivision that splits every triangle in four at new edge points, the old
/// vertices first (moved by `vertex`), then one point per edge (`edge`).
fn split(
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    vertex: impl Fn(usize) -> DVec3,
    edge: impl Fn(&(u32, u32), &[u32]) -> DVec3,
) -> Indexed {
    let (list, of) = edges(triangles);
    let n = positions.len() as u32;
    let mut out: Vec<DVec3> = (0..positions.len()).map(vertex).collect();
    out.extend(list.iter().map(|(e, fs)| edge(e, fs)));
    let faces = triangles
        .iter()
        .zip(&of)
        .flat_map(|(&[a, b, c], e)| {
            let [ab, bc, ca] = e.map(|e| n + e as u32);
            [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
        })
        .collect();
    (out, faces)
}

/// Linear subdivision: every triangle in four at its edges' midpoints (the same surface).
pub fn midpoint(positions: &[DVec3], triangles: &[[u32; 3]]) -> Indexed {
    split(
        positions,
        triangles,
        |v| positions[v],
        |&(x, y), _| (positions[x as usize] + positions[y as usize]) / 2.0,
    )
}

/// One step of Loop subdivision (Loop 1987, with its boundary rules): edge points `3/8` of
/// their ends and `1/8` of the two apexes, old vertices pulled towards their neighbours by
/// Loop's `β(n)` — a smoothing that moves the surface.
pub fn loop_subdivided(positions: &[DVec3], triangles: &[[u32; 3]]) -> Indexed {
    let (list, _) = edges(triangles);
    let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); positions.len()];
    let mut boundary: Vec<Vec<u32>> = vec![Vec::new(); positions.len()];
    for ((x, y), fs) in &list {
        neighbours[*x as usize].push(*y);
        neighbours[*y as usize].push(*x);
        if fs.len() != 2 {
            boundary[*x as usize].push(*y);
            boundary[*y as usize].push(*x);
        }
    }
    let p = |v: u32| positions[v as usize];
    split(
        positions,
        triangles,
        |v| match boundary[v].as_slice() {
            [] => {
                let k = neighbours[v].len() as f64;
                if k == 0.0 {
                    return positions[v];
                }
                let beta = (0.625 - (0.375 + 0.25 * (2.0 * PI / k).cos()).powi(2)) / k;
                positions[v] * (1.0 - k * beta)
                    + neighbours[v].iter().map(|&w| p(w)).sum::<DVec3>() * beta
            }
            &[a, b] => positions[v] * 0.75 + (p(a) + p(b)) * 0.125,
            _ => positions[v],
        },
        |&(x, y), fs| match fs {
            &[f, g] => {
                let apex = |f: u32| {
                    triangles[f as usize]
                        .into_iter()
                        .find(|&v| v != x && v != y)
                        .map_or(DVec3::ZERO, p)
                };
                (p(x) + p(y)) * 0.375 + (apex(f) + apex(g)) * 0.125
            }
            _ => (p(x) + p(y)) / 2.0,
        },
    )
}

/// One step of Catmull–Clark subdivision (Catmull and Clark 1978; the boundary and crease rules
/// of Blender's Subdivision Surface): per triangle a face point at its centroid and three quads,
/// each cut along its shorter diagonal as an exporter triangulates them; edge points the mean
/// of their ends and faces' points, old vertices moved to `(Q + 2R + (n − 3)v) / n` — a
/// smoothing that moves the surface. Edges of one face or of more than two are creases.
pub fn catmull_clark(positions: &[DVec3], triangles: &[[u32; 3]]) -> Indexed {
    let (list, of) = edges(triangles);
    let centre = |t: &[u32; 3]| t.iter().map(|&v| positions[v as usize]).sum::<DVec3>() / 3.0;
    let face_points: Vec<DVec3> = triangles.iter().map(centre).collect();
    let middle = |(x, y): (u32, u32)| (positions[x as usize] + positions[y as usize]) / 2.0;
    // Per old vertex: its edges' midpoints and faces' points (sums and counts), and its
    // crease neighbours.
    let mut around = vec![(DVec3::ZERO, 0.0); positions.len()];
    for (t, f) in triangles.iter().zip(&face_points) {
        for &v in t {
            around[v as usize].0 += *f;
            around[v as usize].1 += 1.0;
        }
    }
    let mut middles = vec![(DVec3::ZERO, 0.0); positions.len()];
    let mut creases: Vec<Vec<u32>> = vec![Vec::new(); positions.len()];
    for &((x, y), ref fs) in &list {
        for (v, w) in [(x, y), (y, x)] {
            middles[v as usize].0 += middle((x, y));
            middles[v as usize].1 += 1.0;
            if fs.len() != 2 {
                creases[v as usize].push(w);
            }
        }
    }
    let p = |v: u32| positions[v as usize];
    let mut out: Vec<DVec3> = (0..positions.len())
        .map(|v| match creases[v].as_slice() {
            [] if middles[v].1 > 0.0 => {
                let n = middles[v].1;
                let (q, r) = (around[v].0 / around[v].1, middles[v].0 / n);
                (q + 2.0 * r + (n - 3.0) * positions[v]) / n
            }
            &[a, b] => positions[v] * 0.75 + (p(a) + p(b)) * 0.125,
            _ => positions[v],
        })
        .collect();
    out.extend(list.iter().map(|&((x, y), ref fs)| match fs[..] {
        [f, g] => (p(x) + p(y) + face_points[f as usize] + face_points[g as usize]) / 4.0,
        _ => middle((x, y)),
    }));
    let (n, first_face) = (
        positions.len() as u32,
        (positions.len() + list.len()) as u32,
    );
    out.extend(&face_points);
    let mut faces = Vec::with_capacity(6 * triangles.len());
    for (f, (&[a, b, c], e)) in triangles.iter().zip(&of).enumerate() {
        let [ab, bc, ca] = e.map(|e| n + e as u32);
        let centre = first_face + f as u32;
        for [o, next, previous] in [[a, ab, ca], [b, bc, ab], [c, ca, bc]] {
            let length = |x: u32, y: u32| out[x as usize].distance(out[y as usize]);
            faces.extend(if length(o, centre) <= length(next, previous) {
                [[o, next, centre], [o, centre, previous]]
            } else {
                [[o, next, previous], [next, centre, previous]]
            });
        }
    }
    (out, faces)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A UV sphere of radius 1: `rings` × `segments` quads, triangulated.
    fn sphere(rings: u32, segments: u32) -> Indexed {
        let mut positions = vec![DVec3::Z, -DVec3::Z];
        for r in 1..rings {
            let theta = PI * r as f64 / rings as f64;
            for s in 0..segments {
                let phi = 2.0 * PI * s as f64 / segments as f64;
                positions.push(DVec3::new(
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                ));
            }
        }
        let at = |r: u32, s: u32| 2 + (r - 1) * segments + s % segments;
        let mut triangles = Vec::new();
        for s in 0..segments {
            triangles.push([0, at(1, s), at(1, s + 1)]);
            triangles.push([1, at(rings - 1, s + 1), at(rings - 1, s)]);
            for r in 1..rings - 1 {
                triangles.push([at(r, s), at(r + 1, s), at(r + 1, s + 1)]);
                triangles.push([at(r, s), at(r + 1, s + 1), at(r, s + 1)]);
            }
        }
        (positions, triangles)
    }

    fn radii(mesh: &Indexed) -> (f64, f64) {
        mesh.0.iter().fold((f64::MAX, 0.0f64), |(lo, hi), p| {
            (lo.min(p.length()), hi.max(p.length()))
        })
    }

    /// At least half of `out`'s vertices are not `input`'s: placed anew, not kept.
    fn assert_half_moved(input: &Indexed, out: &Indexed) {
        let new = out.0.iter().filter(|p| !input.0.contains(p)).count();
        assert!(
            new * 2 >= out.0.len(),
            "only {new} of {} vertices moved",
            out.0.len()
        );
    }

    /// Each edge of a closed manifold mesh lies on exactly two triangles.
    fn closed(mesh: &Indexed) -> bool {
        edges(&mesh.1).0.iter().all(|(_, fs)| fs.len() == 2)
    }

    #[test]
    fn the_quadric_simplifier_halves_a_sphere_with_moved_vertices_near_it() {
        let input = sphere(24, 48);
        let n = input.0.len();
        let out = quadric(&input.0, &input.1, n / 2);
        assert!(
            out.0.len() <= n / 2 && out.0.len() > n / 2 - 5,
            "{}",
            out.0.len()
        );
        assert!(closed(&out));
        assert_half_moved(&input, &out);
        // Optimal placement keeps the vertices near the sphere (its tangent planes pull them
        // slightly outside).
        let (lo, hi) = radii(&out);
        assert!(lo > 0.99 && hi < 1.01, "{lo} {hi}");
    }

    #[test]
    fn the_fast_quadric_simplifier_halves_a_sphere_with_moved_vertices_near_it() {
        let input = sphere(24, 48);
        let target = input.1.len() / 2;
        let out = fast_quadric(&input.0, &input.1, target);
        assert!(
            out.1.len() <= target && out.1.len() > target * 9 / 10,
            "{} of {target}",
            out.1.len()
        );
        assert_half_moved(&input, &out);
        let (lo, hi) = radii(&out);
        assert!(lo > 0.98 && hi < 1.02, "{lo} {hi}");
    }

    #[test]
    fn clustering_merges_vertices_to_about_the_target() {
        let input = sphere(24, 48);
        let out = clustered(&input.0, &input.1, input.0.len() / 2);
        let ratio = out.0.len() as f64 / input.0.len() as f64;
        assert!((0.35..0.65).contains(&ratio), "{ratio}");
        assert_half_moved(&input, &out);
        let (lo, hi) = radii(&out);
        assert!(lo > 0.97 && hi <= 1.0 + 1e-9, "{lo} {hi}");
    }

    #[test]
    fn midpoint_subdivision_keeps_the_surface_and_loop_shrinks_it() {
        let input = sphere(8, 16);
        let linear = midpoint(&input.0, &input.1);
        assert_eq!(linear.1.len(), 4 * input.1.len());
        assert!(closed(&linear));
        // Midpoints lie on chords, inside the unit sphere but on the input's faces.
        assert!(radii(&linear).1 <= 1.0 + 1e-12);
        let smooth = loop_subdivided(&input.0, &input.1);
        assert_eq!(smooth.0.len(), linear.0.len());
        assert!(closed(&smooth));
        // Loop pulls the old vertices inside the sphere.
        assert!(smooth.0[..input.0.len()].iter().all(|p| p.length() < 0.999));
    }

    #[test]
    fn catmull_clark_makes_six_triangles_of_each_and_shrinks_the_sphere() {
        let input = sphere(8, 16);
        let smooth = catmull_clark(&input.0, &input.1);
        let edges = edges(&input.1).0.len();
        assert_eq!(smooth.0.len(), input.0.len() + edges + input.1.len());
        assert_eq!(smooth.1.len(), 6 * input.1.len());
        assert!(closed(&smooth));
        // Every face point lies inside the sphere, and the old vertices are pulled inside.
        assert!(smooth.0.iter().all(|p| p.length() < 1.0 + 1e-12));
        assert!(smooth.0[..input.0.len()].iter().all(|p| p.length() < 0.999));
        // Consistently oriented: each directed edge used once.
        let mut directed = std::collections::HashSet::new();
        for t in &smooth.1 {
            for k in 0..3 {
                assert!(directed.insert((t[k], t[(k + 1) % 3])));
            }
        }
    }

    #[test]
    fn retriangulating_keeps_the_vertices_and_flips_diagonals() {
        let input = sphere(8, 16);
        let out = retriangulated(&input.0, &input.1);
        assert_eq!(out.0, input.0);
        assert!(closed(&out));
        let changed = out.1.iter().zip(&input.1).filter(|(a, b)| a != b).count();
        assert!(changed * 2 > input.1.len(), "{changed}");
    }
}

//! Local geodesic distances (SPEC §2.1, paper §3.2.1): Dijkstra over the edge graph from one
//! source, or fast marching over the triangles (SPEC §9), stopped as soon as the smallest
//! tentative distance exceeds the local size `D_g`.
//!
//! Extraction runs this once per vertex, so the state lives in a [`GeodesicScratch`] reused
//! by each worker thread: only the entries touched by the previous run are reset.

use dary_heap::QuaternaryHeap;
use std::cmp::Reverse;

use glam::DVec3;

use crate::mesh::{PreparedMesh, Topology};
use crate::params::GeodesicRule;

/// The surface a run walks on.
#[derive(Debug, Clone, Copy)]
pub struct Surface<'a> {
    pub positions: &'a [DVec3],
    pub triangles: &'a [[u32; 3]],
    pub topology: &'a Topology,
}

impl<'a> Surface<'a> {
    pub fn new(mesh: &'a PreparedMesh, topology: &'a Topology) -> Self {
        Self {
            positions: &mesh.positions,
            triangles: &mesh.triangles,
            topology,
        }
    }
}

/// Reusable per-thread state of bounded runs.
#[derive(Debug, Clone)]
pub struct GeodesicScratch {
    rule: GeodesicRule,
    distance: Vec<f64>,
    touched: Vec<u32>,
    settled: Vec<u32>,
    /// Whether a vertex is settled in the current run (fast marching updates a triangle only
    /// from settled corners); reset from `settled`.
    known: Vec<bool>,
    heap: QuaternaryHeap<Reverse<(u64, u32)>>,
}

/// The result of one bounded run.
#[derive(Debug, Clone, Copy)]
pub struct LocalDistances<'a> {
    distance: &'a [f64],
    settled: &'a [u32],
}

impl LocalDistances<'_> {
    /// Distance of `v` from the source: exact (in Dijkstra's sense) up to the bound, the
    /// tentative value on the frontier just beyond it, infinite elsewhere.
    #[inline]
    pub fn get(&self, v: u32) -> f64 {
        self.distance[v as usize]
    }

    /// Vertices within the bound, in order of increasing distance.
    pub fn settled(&self) -> &[u32] {
        self.settled
    }
}

impl GeodesicScratch {
    pub fn new(vertex_count: usize, rule: GeodesicRule) -> Self {
        Self {
            rule,
            distance: vec![f64::INFINITY; vertex_count],
            touched: Vec::new(),
            settled: Vec::new(),
            known: vec![false; vertex_count],
            heap: QuaternaryHeap::new(),
        }
    }

    /// Distances from `source` up to `bound` (SPEC §2.1). Every neighbour of a settled vertex
    /// keeps its tentative distance, so each edge leaving the disk has finite values at both
    /// ends and the outermost wave can interpolate on it.
    ///
    /// The heap is keyed by the bits of the distance: for non-negative floats their order is
    /// the order of the numbers, and integer keys compare faster than floats.
    ///
    /// Fast marching settles vertices in the same order of distance; when a vertex settles,
    /// each of its triangles with a second settled corner also updates the third corner
    /// through the triangle ([`unfold`]), besides the edge update Dijkstra makes.
    pub fn run(&mut self, surface: Surface<'_>, source: u32, bound: f64) -> LocalDistances<'_> {
        for &v in &self.touched {
            self.distance[v as usize] = f64::INFINITY;
        }
        for &v in &self.settled {
            self.known[v as usize] = false;
        }
        self.touched.clear();
        self.settled.clear();
        self.heap.clear();
        let topology = surface.topology;

        self.distance[source as usize] = 0.0;
        self.touched.push(source);
        self.heap.push(Reverse((0, source)));
        while let Some(Reverse((bits, v))) = self.heap.pop() {
            let d = f64::from_bits(bits);
            if d > bound {
                break;
            }
            if d > self.distance[v as usize] || self.known[v as usize] {
                continue; // stale entry: v was reached by a shorter path since
            }
            self.settled.push(v);
            self.known[v as usize] = true;
            for (w, length) in topology.neighbours(v) {
                self.offer(w, d + length);
            }
            if self.rule == GeodesicRule::FastMarching {
                for &f in topology.faces_of(v) {
                    let t = surface.triangles[f as usize];
                    let k = t.iter().position(|&u| u == v).expect("a face of v has v");
                    let (a, b) = (t[(k + 1) % 3], t[(k + 2) % 3]);
                    for (known, open) in [(a, b), (b, a)] {
                        if self.known[known as usize] && !self.known[open as usize] {
                            let p = |u: u32| surface.positions[u as usize];
                            let (dv, dk) = (d, self.distance[known as usize]);
                            if let Some(through) = unfold([p(v), p(known), p(open)], dv, dk) {
                                self.offer(open, through);
                            }
                        }
                    }
                }
            }
        }
        LocalDistances {
            distance: &self.distance,
            settled: &self.settled,
        }
    }

    /// Lowers the tentative distance of `w` to `through` if that is shorter.
    #[inline]
    fn offer(&mut self, w: u32, through: f64) {
        let slot = &mut self.distance[w as usize];
        if through < *slot {
            if slot.is_infinite() {
                self.touched.push(w);
            }
            *slot = through;
            self.heap.push(Reverse((through.to_bits(), w)));
        }
    }
}

/// The distance at `c` of a planar front that reached `a` at `da` and `b` at `db`: unfold the
/// triangle into the plane, put the virtual source `S` at distances `da`, `db` from `a`, `b`
/// on the far side of the edge, and take `|S c|` if the ray from `S` to `c` enters the
/// triangle through the edge `ab` (Kimmel and Sethian 1998; exact for a source on a plane).
/// `None` otherwise, when the edge updates are the right ones: an obtuse triangle's far corner
/// is then reached along an edge, as in Dijkstra.
fn unfold([a, b, c]: [DVec3; 3], da: f64, db: f64) -> Option<f64> {
    let edge = b - a;
    let length = edge.length();
    if length == 0.0 {
        return None;
    }
    let along = edge / length;
    let ac = c - a;
    let (cx, cy) = (ac.dot(along), ac.reject_from_normalized(along).length());
    let sx = (da * da - db * db + length * length) / (2.0 * length);
    let sy_squared = da * da - sx * sx;
    if cy == 0.0 || sy_squared < 0.0 {
        return None;
    }
    let sy = -sy_squared.sqrt();
    // Where the segment from S to c crosses the line through a and b.
    let crossing = sx + (cx - sx) * (-sy / (cy - sy));
    let through = ((cx - sx).powi(2) + (cy - sy).powi(2)).sqrt();
    // Causality: the front reaches c after a and b, so vertices still settle in order of
    // distance (the wave sweep relies on it).
    ((0.0..=length).contains(&crossing) && through >= da.max(db)).then_some(through)
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;

    /// A unit-spaced strip of squares along x, two triangles each.
    fn strip(n: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let mut p = Vec::new();
        for x in 0..=n {
            p.push(DVec3::new(x as f64, 0.0, 0.0));
            p.push(DVec3::new(x as f64, 1.0, 0.0));
        }
        let t = (0..n)
            .flat_map(|i| {
                let v = 2 * i;
                [[v, v + 2, v + 3], [v, v + 3, v + 1]]
            })
            .collect();
        (p, t)
    }

    #[test]
    fn bounded_run_settles_the_disk_and_keeps_the_frontier() {
        let (p, t) = strip(10);
        let topo = Topology::new(&p, &t);
        for rule in [GeodesicRule::Dijkstra, GeodesicRule::FastMarching] {
            let surface = Surface {
                positions: &p,
                triangles: &t,
                topology: &topo,
            };
            let mut scratch = GeodesicScratch::new(p.len(), rule);
            let d = scratch.run(surface, 0, 2.5);
            // Along the bottom row distances are exact: 0, 1, 2; vertex (3,0) is frontier.
            assert_eq!(d.get(2), 1.0);
            assert_eq!(d.get(4), 2.0);
            assert_eq!(d.get(6), 3.0);
            assert!(d.get(8).is_infinite());
            assert!(d.settled().iter().all(|&v| d.get(v) <= 2.5));
            assert!(d.settled().windows(2).all(|w| d.get(w[0]) <= d.get(w[1])));
            // Reuse resets what the previous run touched.
            let d = scratch.run(surface, 20, 1.0);
            assert!(d.get(0).is_infinite());
            assert_eq!(d.get(20), 0.0);
        }
    }

    /// On a plane the true geodesic is the straight line. Dijkstra's paths along the edges of a
    /// grid are up to 8 % longer off the edge directions; fast marching is exact there.
    #[test]
    fn fast_marching_is_exact_on_a_plane() {
        let (p, t) = crate::mesh::grid(20);
        let topology = Topology::new(&p, &t);
        let surface = Surface {
            positions: &p,
            triangles: &t,
            topology: &topology,
        };
        let worst = |rule| {
            let mut scratch = GeodesicScratch::new(p.len(), rule);
            let d = scratch.run(surface, 0, f64::INFINITY);
            (1..p.len() as u32)
                .map(|v| d.get(v) / p[v as usize].length() - 1.0)
                .fold(0.0, f64::max)
        };
        let (dijkstra, marching) = (
            worst(GeodesicRule::Dijkstra),
            worst(GeodesicRule::FastMarching),
        );
        assert!(dijkstra > 0.07, "Dijkstra's worst excess {dijkstra}");
        assert!(marching < 1e-9, "fast marching's worst excess {marching}");
    }
}

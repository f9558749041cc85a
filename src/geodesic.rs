//! Local geodesic distances (SPEC §2.1, paper §3.2.1): Dijkstra over the edge graph from one
//! source, stopped as soon as the smallest tentative distance exceeds the local size `D_g`.
//!
//! Extraction runs this once per vertex, so the state lives in a [`GeodesicScratch`] reused
//! by each worker thread: only the entries touched by the previous run are reset.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use crate::mesh::Topology;

/// Reusable per-thread Dijkstra state.
#[derive(Debug, Clone)]
pub struct GeodesicScratch {
    distance: Vec<f64>,
    touched: Vec<u32>,
    settled: Vec<u32>,
    heap: BinaryHeap<Reverse<(u64, u32)>>,
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
    pub fn new(vertex_count: usize) -> Self {
        Self {
            distance: vec![f64::INFINITY; vertex_count],
            touched: Vec::new(),
            settled: Vec::new(),
            heap: BinaryHeap::new(),
        }
    }

    /// Distances from `source` up to `bound` (SPEC §2.1). Every neighbour of a settled vertex
    /// keeps its tentative distance, so each edge leaving the disk has finite values at both
    /// ends and the outermost wave can interpolate on it.
    ///
    /// The heap is keyed by the bits of the distance: for non-negative floats their order is
    /// the order of the numbers, and integer keys compare faster than floats.
    pub fn run(&mut self, topology: &Topology, source: u32, bound: f64) -> LocalDistances<'_> {
        for &v in &self.touched {
            self.distance[v as usize] = f64::INFINITY;
        }
        self.touched.clear();
        self.settled.clear();
        self.heap.clear();

        self.distance[source as usize] = 0.0;
        self.touched.push(source);
        self.heap.push(Reverse((0, source)));
        while let Some(Reverse((bits, v))) = self.heap.pop() {
            let d = f64::from_bits(bits);
            if d > bound {
                break;
            }
            if d > self.distance[v as usize] {
                continue; // stale entry: v was reached by a shorter path since
            }
            self.settled.push(v);
            for (w, length) in topology.neighbours(v) {
                let through = d + length;
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
        LocalDistances {
            distance: &self.distance,
            settled: &self.settled,
        }
    }
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
        let mut scratch = GeodesicScratch::new(p.len());
        let d = scratch.run(&topo, 0, 2.5);
        // Along the bottom row distances are exact: 0, 1, 2; vertex (3,0) is frontier.
        assert_eq!(d.get(2), 1.0);
        assert_eq!(d.get(4), 2.0);
        assert_eq!(d.get(6), 3.0);
        assert!(d.get(8).is_infinite());
        assert!(d.settled().iter().all(|&v| d.get(v) <= 2.5));
        assert!(d.settled().windows(2).all(|w| d.get(w[0]) <= d.get(w[1])));
        // Reuse resets what the previous run touched.
        let d = scratch.run(&topo, 20, 1.0);
        assert!(d.get(0).is_infinite());
        assert_eq!(d.get(20), 0.0);
    }
}

//! Salient regions (SPEC §3.3): the surface within geodesic distance `D` of a salient point,
//! clipped at the iso-line `D` — whole triangles alone can leave nothing when `D` is shorter
//! than an edge.

use glam::DVec3;

use crate::geodesic::{GeodesicScratch, Surface};
use crate::mesh::{PreparedMesh, Topology};

/// A salient region as a list of triangles in normalised coordinates.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Region {
    pub triangles: Vec<[DVec3; 3]>,
    pub area: f64,
}

/// The region of radius `size` around `vertex`. Distances are the same bounded geodesic
/// distances the waves used, so the region ends on the last wave.
pub fn region(
    mesh: &PreparedMesh,
    topology: &Topology,
    scratch: &mut GeodesicScratch,
    vertex: u32,
    size: f64,
) -> Region {
    let distances = scratch.run(Surface::new(mesh, topology), vertex, size);
    let mut faces: Vec<u32> = distances
        .settled()
        .iter()
        .flat_map(|&v| topology.faces_of(v).iter().copied())
        .collect();
    faces.sort_unstable();
    faces.dedup();

    let mut region = Region::default();
    let mut polygon: Vec<DVec3> = Vec::with_capacity(4);
    for f in faces {
        let t = mesh.triangles[f as usize];
        polygon.clear();
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let (da, db) = (distances.get(a), distances.get(b));
            let (pa, pb) = (mesh.positions[a as usize], mesh.positions[b as usize]);
            if da < size {
                polygon.push(pa);
            }
            if (da < size) != (db < size) {
                let s = (size - da) / (db - da);
                polygon.push(pa + (pb - pa) * s);
            }
        }
        for i in 1..polygon.len().saturating_sub(1) {
            let triangle = [polygon[0], polygon[i], polygon[i + 1]];
            region.area += area(&triangle);
            region.triangles.push(triangle);
        }
    }
    region
}

/// Area of a triangle.
pub fn area([a, b, c]: &[DVec3; 3]) -> f64 {
    (*b - *a).cross(*c - *a).length() / 2.0
}

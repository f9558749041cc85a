//! The weld (SPEC §1.2) on triangle soups: every copy of a vertex within the tolerance of
//! another becomes one vertex, wherever the copies fall on the grid, in any input order.

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use salient_core::mesh::load::NoResources;
use salient_core::mesh::weld::{bounds, weld};
use salient_core::mesh::{load_bytes, prepare, Format, RawMesh};
use salient_core::params::MeshParams;
use salient_core::Limits;

use crate::common::fixture;
use crate::shapes;

/// `mesh` as a soup (three fresh vertices per triangle), moved off the origin, each copy
/// jittered by up to `jitter` × the diagonal: float32 round-off does this to an export.
fn jittered_soup(mesh: &RawMesh, jitter: f64, seed: u64) -> RawMesh {
    let (min, max) = bounds(&mesh.positions);
    let step = jitter * (max - min).length();
    let offset = DVec3::new(12.5, -7.25, 3.0);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut soup = RawMesh::default();
    for t in &mesh.triangles {
        for &v in t {
            let shake = DVec3::new(
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
            ) * (step / 3f64.sqrt());
            soup.positions
                .push(mesh.positions[v as usize] + offset + shake);
        }
        let base = soup.positions.len() as u32 - 3;
        soup.triangles.push([base, base + 1, base + 2]);
    }
    soup
}

#[test]
fn jittered_soups_weld_to_the_true_vertex_count() {
    let sphere = shapes::icosphere(4);
    assert_eq!(sphere.positions.len(), 2562);
    for seed in 0..5 {
        let soup = jittered_soup(&sphere, 1e-7, seed);
        assert_eq!(soup.positions.len(), 3 * sphere.triangles.len());
        let welded = weld(&soup, 1e-6).unwrap();
        assert_eq!(welded.positions.len(), 2562, "seed {seed}");
        assert_eq!(
            welded.triangles.len(),
            sphere.triangles.len(),
            "seed {seed}"
        );
        // Closed again: every edge in exactly two triangles.
        let prepared = prepare(&soup, &MeshParams::default()).unwrap();
        assert_eq!(
            prepared.stats.orientation.closed_components, 1,
            "seed {seed}"
        );
    }
}

#[test]
fn the_weld_does_not_depend_on_the_order_of_the_soup() {
    let soup = jittered_soup(&shapes::icosphere(3), 1e-7, 9);
    let mut reversed = soup.clone();
    reversed.triangles.reverse();
    for t in &mut reversed.triangles {
        t.rotate_left(1);
    }
    assert_eq!(weld(&reversed, 1e-6).unwrap(), weld(&soup, 1e-6).unwrap());
}

#[test]
fn copies_farther_apart_than_the_tolerance_stay_apart() {
    // Jitter of 20 × the tolerance: the copies of a vertex must not be merged.
    let sphere = shapes::icosphere(2);
    let soup = jittered_soup(&sphere, 2e-5, 1);
    let welded = weld(&soup, 1e-6).unwrap();
    assert!(
        welded.positions.len() > 2 * sphere.positions.len(),
        "{}",
        welded.positions.len()
    );
}

/// Binary STL is a soup of float32 corners: the CAPOD horse written as one welds to the
/// vertex count of its OBJ.
#[test]
fn the_capod_horse_as_binary_stl_welds_to_its_obj() {
    let limits = Limits::default();
    let obj = std::fs::read(fixture("capod_horse_m155.obj")).unwrap();
    let mesh = load_bytes(&obj, Format::Obj, &NoResources, &limits).unwrap();
    let stl = salient_core::mesh::write::Export::BinaryStl.write(&mesh);
    let soup = load_bytes(&stl, Format::Stl, &NoResources, &limits).unwrap();
    let params = MeshParams::default();
    let (from_obj, from_stl) = (
        prepare(&mesh, &params).unwrap(),
        prepare(&soup, &params).unwrap(),
    );
    assert_eq!(from_obj.stats.welded_vertices, 346);
    assert_eq!(from_stl.stats.welded_vertices, 346);
    assert_eq!(from_stl.triangles.len(), from_obj.triangles.len());
}

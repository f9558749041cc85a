//! The geodesic distributions (`descriptor::geodesic`, SPEC §9): nearly unchanged by
//! bending, which moves the extrinsic D2; a model of several copies of a part is described
//! like one.

use glam::DVec3;
use salient_core::mesh::RawMesh;
use salient_core::rank::{distance, Method};
use salient_core::{Params, Signature};

use crate::shapes;

fn signature(mesh: &RawMesh) -> Signature {
    salient_core::pipeline::compute(mesh, &Params::default()).unwrap()
}

/// The tube bent along an arc of radius `radius` in the x–z plane: the axis keeps its
/// length, the sides stretch by at most the tube's radius over `radius`.
fn bent(mesh: &RawMesh, radius: f64) -> RawMesh {
    RawMesh {
        positions: mesh
            .positions
            .iter()
            .map(|p| {
                let angle = p.z / radius;
                let r = radius - p.x;
                DVec3::new(radius - r * angle.cos(), p.y, r * angle.sin())
            })
            .collect(),
        triangles: mesh.triangles.clone(),
    }
}

/// Two copies of `mesh`, side by side and apart.
fn twice(mesh: &RawMesh) -> RawMesh {
    let offset = DVec3::new(3.0, 0.0, 0.0);
    let n = mesh.positions.len() as u32;
    RawMesh {
        positions: mesh
            .positions
            .iter()
            .copied()
            .chain(mesh.positions.iter().map(|&p| p + offset))
            .collect(),
        triangles: mesh
            .triangles
            .iter()
            .copied()
            .chain(mesh.triangles.iter().map(|t| t.map(|v| v + n)))
            .collect(),
    }
}

#[test]
fn bending_moves_the_geodesic_distributions_far_less_than_d2() {
    let p = &Params::default().similarity;
    let straight = shapes::tube(0.15, 61, 16);
    let (s, b) = (signature(&straight), signature(&bent(&straight, 0.5)));
    let other = signature(&shapes::star(3, &shapes::five_tips()));
    let relative = |method| distance(method, &s, &b, p) / distance(method, &s, &other, p);
    let (geodesic, d2) = (relative(Method::Geodesic), relative(Method::D2));
    eprintln!("bent / other: geodesic {geodesic:.3}, d2 {d2:.3}");
    assert!(geodesic < 0.5 * d2, "geodesic {geodesic} vs d2 {d2}");
}

#[test]
fn two_copies_of_a_part_are_described_like_one() {
    let p = &Params::default().similarity;
    let one = shapes::cone(0.5, 12, 24);
    let (a, b) = (signature(&one), signature(&twice(&one)));
    let other = signature(&shapes::star(3, &shapes::five_tips()));
    let relative = |method| distance(method, &a, &b, p) / distance(method, &a, &other, p);
    let (geodesic, d2) = (relative(Method::Geodesic), relative(Method::D2));
    eprintln!("two copies / another shape: geodesic {geodesic:.3}, d2 {d2:.3}");
    // D2 measures across the gap and sees another shape; the geodesics stay within a copy.
    assert!(d2 > 1.0, "d2 {d2}");
    assert!(geodesic < 0.5, "geodesic {geodesic}");
    // Each histogram still sums to 1.
    let g = b.geodesic.unwrap();
    for h in [&g.distances, &g.eccentricity] {
        assert!((h.iter().sum::<f32>() - 1.0).abs() < 1e-5);
    }
}

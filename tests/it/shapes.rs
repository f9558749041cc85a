//! Generated meshes with closed-form ECC (SPEC §2.4), shared by the integration tests.

use std::collections::HashMap;
use std::f64::consts::PI;

use glam::{DMat4, DQuat, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use salient_core::mesh::RawMesh;

/// Unit icosphere with `subdivisions` midpoint subdivisions, outward winding, vertex 0 at the
/// north pole (0, 0, 1).
pub fn icosphere(subdivisions: u32) -> RawMesh {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut positions: Vec<DVec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| DVec3::new(x, y, z).normalize())
    .collect();
    let mut triangles: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    let to_pole = DQuat::from_rotation_arc(positions[0], DVec3::Z);
    for p in &mut positions {
        *p = to_pole * *p;
    }
    positions[0] = DVec3::Z;
    for _ in 0..subdivisions {
        let mut midpoints: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(triangles.len() * 4);
        let mut mid = |a: u32, b: u32, positions: &mut Vec<DVec3>| {
            *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
                positions.push((positions[a as usize] + positions[b as usize]).normalize());
                positions.len() as u32 - 1
            })
        };
        for [a, b, c] in triangles {
            let ab = mid(a, b, &mut positions);
            let bc = mid(b, c, &mut positions);
            let ca = mid(c, a, &mut positions);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        triangles = next;
    }
    RawMesh {
        positions,
        triangles,
    }
}

/// Reverses the winding of every triangle.
pub fn inverted(mut mesh: RawMesh) -> RawMesh {
    for t in &mut mesh.triangles {
        t.swap(1, 2);
    }
    mesh
}

/// The upper half (z >= 0) of a unit icosphere wound inward: a concave bowl, pole at vertex 0.
pub fn bowl(subdivisions: u32) -> RawMesh {
    let sphere = icosphere(subdivisions);
    let triangles = sphere
        .triangles
        .iter()
        .filter(|t| t.iter().all(|&v| sphere.positions[v as usize].z >= -1e-9))
        .map(|&[a, b, c]| [a, c, b])
        .collect();
    RawMesh {
        positions: sphere.positions,
        triangles,
    }
}

/// A flat square [-1, 1]² of `n` × `n` cells, interior vertices jittered by up to 30 % of a
/// cell so that waves are irregular, diagonals alternating.
pub fn plane(n: u32, seed: u64) -> RawMesh {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let h = 2.0 / n as f64;
    let mut positions = Vec::new();
    for y in 0..=n {
        for x in 0..=n {
            let interior = x > 0 && y > 0 && x < n && y < n;
            let jitter = if interior {
                DVec3::new(rng.gen_range(-0.3..0.3), rng.gen_range(-0.3..0.3), 0.0) * h
            } else {
                DVec3::ZERO
            };
            positions.push(DVec3::new(-1.0 + x as f64 * h, -1.0 + y as f64 * h, 0.0) + jitter);
        }
    }
    let mut triangles = Vec::new();
    let row = n + 1;
    for y in 0..n {
        for x in 0..n {
            let v = y * row + x;
            if (x + y) % 2 == 0 {
                triangles.extend([[v, v + 1, v + row + 1], [v, v + row + 1, v + row]]);
            } else {
                triangles.extend([[v, v + 1, v + row], [v + 1, v + row + 1, v + row]]);
            }
        }
    }
    RawMesh {
        positions,
        triangles,
    }
}

/// A closed right circular cone of half-angle `beta`, apex (vertex 0) at (0, 0, 1), base at
/// z = 0: `rings` rings of `segments` vertices along the slant, and a base fan.
pub fn cone(beta: f64, rings: u32, segments: u32) -> RawMesh {
    let radius = beta.tan();
    let mut positions = vec![DVec3::Z];
    for r in 1..=rings {
        let s = r as f64 / rings as f64;
        // Alternate rings are rotated by half a segment to make a regular triangulation.
        let shift = if r % 2 == 0 { 0.5 } else { 0.0 };
        for k in 0..segments {
            let phi = 2.0 * PI * (k as f64 + shift) / segments as f64;
            positions.push(DVec3::new(
                s * radius * phi.cos(),
                s * radius * phi.sin(),
                1.0 - s,
            ));
        }
    }
    let ring = |r: u32, k: u32| 1 + (r - 1) * segments + k % segments;
    let mut triangles = Vec::new();
    for k in 0..segments {
        triangles.push([0, ring(1, k), ring(1, k + 1)]);
    }
    for r in 1..rings {
        for k in 0..segments {
            let (a, b) = (ring(r, k), ring(r, k + 1));
            if r % 2 == 1 {
                // The next ring is shifted by +1/2: its vertex k lies between a and b.
                let (c, d) = (ring(r + 1, k), ring(r + 1, k + 1));
                triangles.extend([[a, c, b], [b, c, d]]);
            } else {
                // This ring is shifted: the next ring's vertex k + 1 lies between a and b.
                let (c, d) = (ring(r + 1, k), ring(r + 1, k + 1));
                triangles.extend([[a, d, b], [a, c, d]]);
            }
        }
    }
    positions.push(DVec3::ZERO);
    let centre = positions.len() as u32 - 1;
    for k in 0..segments {
        triangles.push([centre, ring(rings, k + 1), ring(rings, k)]);
    }
    RawMesh {
        positions,
        triangles,
    }
}

/// A random rotation, translation and uniform scale.
pub fn random_motion(seed: u64) -> DMat4 {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let axis = DVec3::new(rng.gen(), rng.gen(), rng.gen::<f64>() + 0.1).normalize();
    let rotation = DQuat::from_axis_angle(axis, rng.gen_range(0.0..2.0 * PI));
    let translation = DVec3::new(
        rng.gen_range(-50.0..50.0),
        rng.gen_range(-50.0..50.0),
        rng.gen_range(-50.0..50.0),
    );
    DMat4::from_scale_rotation_translation(
        DVec3::splat(rng.gen_range(0.01..100.0)),
        rotation,
        translation,
    )
}

pub fn transformed(mesh: &RawMesh, m: DMat4) -> RawMesh {
    RawMesh {
        positions: mesh
            .positions
            .iter()
            .map(|&p| m.transform_point3(p))
            .collect(),
        triangles: mesh.triangles.clone(),
    }
}

/// A closed tube along z: radius `radius`, length 2, `rings` × `segments` vertices, with flat
/// caps.
pub fn tube(radius: f64, rings: u32, segments: u32) -> RawMesh {
    let mut positions = Vec::new();
    for r in 0..rings {
        let z = -1.0 + 2.0 * r as f64 / (rings - 1) as f64;
        for k in 0..segments {
            let phi = 2.0 * PI * k as f64 / segments as f64;
            positions.push(DVec3::new(radius * phi.cos(), radius * phi.sin(), z));
        }
    }
    let at = |r: u32, k: u32| r * segments + k % segments;
    let mut triangles = Vec::new();
    for r in 0..rings - 1 {
        for k in 0..segments {
            let (a, b, c, d) = (at(r, k), at(r, k + 1), at(r + 1, k), at(r + 1, k + 1));
            triangles.extend([[a, b, d], [a, d, c]]);
        }
    }
    for (r, z, flip) in [(0, -1.0, true), (rings - 1, 1.0, false)] {
        positions.push(DVec3::new(0.0, 0.0, z));
        let centre = positions.len() as u32 - 1;
        for k in 0..segments {
            let (a, b) = (at(r, k), at(r, k + 1));
            triangles.push(if flip { [centre, b, a] } else { [centre, a, b] });
        }
    }
    RawMesh {
        positions,
        triangles,
    }
}

/// A sphere of radius 0.5 with a smooth spike towards each of `tips` (radius up to 1.3): a
/// "star" whose tips are the only salient places.
pub fn star(subdivisions: u32, tips: &[DVec3]) -> RawMesh {
    let mut mesh = icosphere(subdivisions);
    for p in &mut mesh.positions {
        let bump: f64 = tips
            .iter()
            .map(|t| {
                let angle = p.angle_between(t.normalize());
                (-(angle / 0.3).powi(2)).exp()
            })
            .sum();
        *p *= 0.5 + 0.8 * bump;
    }
    mesh
}

/// Five tip directions, well apart.
pub fn five_tips() -> Vec<DVec3> {
    vec![DVec3::X, -DVec3::X, DVec3::Y, -DVec3::Y, DVec3::Z]
}

/// A tree: a trunk (a tube of radius 0.12 along z) under a crown of `leaves` separate small
/// triangles (each about 0.15 % of the area, together about 18 %) scattered by `seed` over a
/// ball on top, of which only those `keep` takes. The same seed gives the same leaves, so a
/// tree with some leaves kept out is the tree with those leaves deleted.
pub fn tree(seed: u64, leaves: usize, keep: impl Fn(usize) -> bool) -> RawMesh {
    let mut mesh = tube(0.12, 20, 16);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for leaf in 0..leaves {
        let direction = DVec3::new(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        );
        let centre = DVec3::new(0.0, 0.0, 1.3) + direction * 0.6;
        let corners = [0.0, 2.1, 4.2].map(|phi: f64| {
            centre + DVec3::new(phi.cos(), phi.sin(), rng.gen_range(-0.5..0.5)) * 0.05
        });
        if keep(leaf) {
            let base = mesh.positions.len() as u32;
            mesh.positions.extend(corners);
            mesh.triangles.push([base, base + 1, base + 2]);
        }
    }
    mesh
}

/// Writes `mesh` as a Wavefront OBJ file.
pub fn write_obj(path: &std::path::Path, mesh: &RawMesh) {
    std::fs::write(path, salient_core::mesh::write::Export::Obj.write(mesh)).unwrap();
}

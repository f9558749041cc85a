//! Cutting a ball out of a mesh: the parts partial retrieval is evaluated on and the
//! patches its stored descriptors describe.

use glam::DVec3;

use super::refine::refine;
use super::RawMesh;

/// Triangles across a cut's sphere are split until their longest edge is at most this share
/// of its radius.
const CUT_EDGE: f64 = 1.0 / 16.0;

/// The piece of `raw` inside the ball of `radius` around `centre`, and of that its largest
/// connected component by area: a part as partial retrieval
/// ([`crate::partial`]) and the patch descriptors ([`crate::descriptor::patch`]) cut it. Triangles across the sphere are split until they
/// are small against the ball ([`refine`]), then those whose centroid is inside are kept, so
/// the cut follows the sphere on a low-poly model too while the inside keeps its triangles.
/// `None` when nothing is inside.
pub fn cut(raw: &RawMesh, centre: DVec3, radius: f64) -> Option<RawMesh> {
    let across = |corners: &[DVec3; 3], longest: f64| {
        let distances = corners.map(|p| p.distance(centre));
        longest > radius * CUT_EDGE
            && distances.iter().any(|&d| d < radius)
            && distances.iter().any(|&d| d > radius)
    };
    let refined = refine(&near(raw, centre, radius), across);
    let raw = &refined;
    let corners = |t: &[u32; 3]| t.map(|v| raw.positions[v as usize]);
    let inside: Vec<[u32; 3]> = raw
        .triangles
        .iter()
        .filter(|t| {
            let [a, b, c] = corners(t);
            ((a + b + c) / 3.0).distance(centre) <= radius
        })
        .copied()
        .collect();
    let pieces = super::topology::pieces(raw.positions.len(), &inside);
    let mut area = std::collections::BTreeMap::<u32, f64>::new();
    for (t, &piece) in inside.iter().zip(&pieces) {
        let [a, b, c] = corners(t);
        *area.entry(piece).or_default() += (b - a).cross(c - a).length();
    }
    let (&largest, _) = area.iter().max_by(|a, b| a.1.total_cmp(b.1))?;
    let kept: Vec<[u32; 3]> = inside
        .into_iter()
        .zip(pieces)
        .filter(|&(_, piece)| piece == largest)
        .map(|(t, _)| t)
        .collect();
    let (positions, triangles) = super::weld::compact(&raw.positions, &kept);
    Some(RawMesh {
        positions,
        triangles,
    })
}

/// The triangles of `raw` that may reach the ball of `radius` around `centre`, in their order,
/// with every position: none of a triangle is nearer the centre than its nearest corner less
/// its longest edge. [`cut`] of it is [`cut`] of `raw` (its midpoints get the same numbers),
/// at a fraction of the cost when the ball is small against the mesh.
pub fn near(raw: &RawMesh, centre: DVec3, radius: f64) -> RawMesh {
    RawMesh {
        positions: raw.positions.clone(),
        triangles: raw
            .triangles
            .iter()
            .filter(|t| {
                let [a, b, c] = t.map(|v| raw.positions[v as usize]);
                let longest = a.distance(b).max(b.distance(c)).max(c.distance(a));
                let nearest = a
                    .distance(centre)
                    .min(b.distance(centre))
                    .min(c.distance(centre));
                nearest - longest <= radius
            })
            .copied()
            .collect(),
    }
}

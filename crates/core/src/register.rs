//! Rigid registration of sampled points onto a triangle surface, shared by the near-duplicate
//! check ([`crate::duplicate`]) and partial retrieval's verification ([`crate::partial`]):
//! least-squares motions (Kabsch) and ICP against the surface's closest points.
//!
//! Point-to-surface queries come from parry3d's triangle mesh (a BVH); only the alignment is
//! written here. Types are glam's as parry re-exports them (`glamx`), f32 as parry's are.

use glamx::{DMat3, DSvd3, DVec3, Mat3, Vec3};
use parry3d::query::{PointQuery, PointQueryWithLocation};
use parry3d::shape::TriMesh;

use crate::{Error, Result};

/// A triangle surface to measure distances from and register onto.
pub struct Surface(TriMesh);

impl Surface {
    /// The surface of `triangles` over `positions`; an error when it has no triangle.
    pub fn new(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Result<Self> {
        TriMesh::new(positions, triangles)
            .map(Self)
            .map_err(|_| Error::NoTriangles)
    }

    pub fn vertices(&self) -> &[Vec3] {
        self.0.vertices()
    }

    pub fn triangles(&self) -> &[[u32; 3]] {
        self.0.indices()
    }

    /// The distance of `p` from the surface and the triangle closest to it.
    pub fn distance_and_triangle(&self, p: Vec3) -> (f32, u32) {
        let (projection, (triangle, _)) = self.0.project_local_point_and_get_location(p, false);
        ((projection.point - p).length(), triangle)
    }

    /// The point of the surface closest to `p`.
    pub fn closest(&self, p: Vec3) -> Vec3 {
        self.0.project_local_point(p, false).point
    }

    /// The distance of `p` from the surface, inside or out (parry signs it by the side when it
    /// can tell one; registration wants the distance alone).
    pub fn distance(&self, p: Vec3) -> f32 {
        (self.closest(p) - p).length()
    }

    /// The distance of `p` from the surface, or `cap` when it is farther (or not finite): the
    /// search prunes every part of the surface beyond `cap`, so a far point costs little.
    pub fn capped_distance(&self, p: Vec3, cap: f32) -> f32 {
        self.0
            .project_local_point_with_max_dist(p, false, cap)
            .map_or(cap, |projection| (projection.point - p).length().min(cap))
    }

    /// The mean distance of `points` from the surface, each capped at `cap` so that a few far
    /// points do not outweigh a good alignment elsewhere.
    pub fn mean_distance(&self, points: impl Iterator<Item = Vec3>, cap: f32) -> f32 {
        let (mut sum, mut count) = (0.0, 0usize);
        for p in points {
            sum += self.capped_distance(p, cap);
            count += 1;
        }
        sum / count.max(1) as f32
    }

    /// ICP: the motion that, after `rounds` rounds of matching each of `points` to its
    /// closest surface point and solving [`fit`], brings them onto the surface; a uniform
    /// scale too when `scaling`.
    pub fn icp(&self, points: &[Vec3], rounds: usize, scaling: bool) -> Motion {
        let mut motion = Motion::IDENTITY;
        let mut targets: Vec<Vec3> = Vec::new();
        for _ in 0..rounds {
            let matched: Vec<Vec3> = points
                .iter()
                .enumerate()
                .map(|(i, &p)| {
                    let p = motion.apply(p);
                    // The last round's match lies on the surface, so the closest point now is
                    // no farther than it: a bound that prunes most of the search once ICP
                    // moves little. A hair wider, lest rounding leave that match out.
                    targets
                        .get(i)
                        .and_then(|&last| {
                            let within = p.distance(last) * (1.0 + 1e-4) + f32::MIN_POSITIVE;
                            self.0.project_local_point_with_max_dist(p, false, within)
                        })
                        .map_or_else(|| self.closest(p), |projection| projection.point)
                })
                .collect();
            // The same matches give the same motion again, round after round.
            if matched == targets {
                break;
            }
            targets = matched;
            motion = fit(points, &targets, scaling);
        }
        motion
    }
}

/// `p ↦ scale · rotation · p + shift`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Motion {
    pub rotation: Mat3,
    pub scale: f32,
    pub shift: Vec3,
}

impl Motion {
    pub const IDENTITY: Motion = Motion {
        rotation: Mat3::IDENTITY,
        scale: 1.0,
        shift: Vec3::ZERO,
    };

    pub fn apply(&self, p: Vec3) -> Vec3 {
        self.rotation * p * self.scale + self.shift
    }

    /// This motion followed by `turn` about the origin.
    pub fn turned(&self, turn: Mat3) -> Motion {
        Motion {
            rotation: turn * self.rotation,
            scale: self.scale,
            shift: turn * self.shift,
        }
    }

    /// The motion undoing this one (`rotation` is a rotation or a reflection, so its
    /// inverse is its transpose).
    pub fn inverse(&self) -> Motion {
        let rotation = self.rotation.transpose();
        Motion {
            rotation,
            scale: 1.0 / self.scale,
            shift: -(rotation * self.shift) / self.scale,
        }
    }
}

/// The motion that moves `from` closest to `to` in least squares: Kabsch's rotation and
/// translation, and with `scaling` Umeyama's uniform scale (1991, Eq. 42). Solved in f64:
/// glamx's SVD goes through the eigenvectors of `HᵀH`, which squares the condition number,
/// and in f32 a flat point set's two smaller axes then mix (a thin model's vertices, fitted
/// onto themselves, turned 14°).
pub fn fit(from: &[Vec3], to: &[Vec3], scaling: bool) -> Motion {
    let wide = |v: &Vec3| DVec3::new(f64::from(v.x), f64::from(v.y), f64::from(v.z));
    let n = from.len() as f64;
    let (p, q) = (
        from.iter().map(wide).sum::<DVec3>() / n,
        to.iter().map(wide).sum::<DVec3>() / n,
    );
    let h = from.iter().zip(to).fold(DMat3::ZERO, |h, (a, b)| {
        let (a, b) = (wide(a) - p, wide(b) - q);
        h + DMat3::from_cols(a * b.x, a * b.y, a * b.z)
    });
    let svd = DSvd3::from_matrix(h);
    let v = svd.vt.transpose();
    let d = (v * svd.u.transpose()).determinant().signum();
    let rotation = v * DMat3::from_diagonal(DVec3::new(1.0, 1.0, d)) * svd.u.transpose();
    let spread: f64 = from.iter().map(|a| (wide(a) - p).length_squared()).sum();
    let scale = if scaling && spread > 0.0 {
        // The singular values, the smallest signed as the rotation's handedness needs.
        (svd.s.x + svd.s.y + d * svd.s.z) / spread
    } else {
        1.0
    };
    Motion {
        rotation: rotation.as_mat3(),
        scale: scale as f32,
        shift: (q - rotation * p * scale).as_vec3(),
    }
}

/// The 48 matrices that permute the axes and flip their signs: 24 rotations, 24 reflections.
/// Second moments fix neither the signs of principal axes nor, when two are near-equal,
/// their order, so alignments by principal axes start from each.
pub fn signed_permutations() -> impl Iterator<Item = Mat3> {
    const ORDERS: [[usize; 3]; 6] = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    ORDERS.into_iter().flat_map(|order| {
        (0..8).map(move |signs: u32| {
            let column = |i: usize| {
                let sign = if signs & (1 << i) == 0 { 1.0 } else { -1.0 };
                Vec3::AXES[order[i]] * sign
            };
            Mat3::from_cols(column(0), column(1), column(2))
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bounding each round's search by the last match, and stopping once the matches repeat,
    /// must give the motion that every round's full search gives.
    #[test]
    fn icp_with_bounded_searches_is_plain_icp() {
        // A bumpy height field, and points off it: some of its vertices turned and moved.
        let n = 24;
        let height = |x: f32, y: f32| 0.3 * (3.0 * x).sin() * (2.0 * y).cos();
        let positions: Vec<Vec3> = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f32 / n as f32, (i / n) as f32 / n as f32);
                Vec3::new(x, y, height(x, y))
            })
            .collect();
        let triangles: Vec<[u32; 3]> = (0..n - 1)
            .flat_map(|j| (0..n - 1).map(move |i| (i, j)))
            .flat_map(|(i, j)| {
                let v = (j * n + i) as u32;
                let n = n as u32;
                [[v, v + 1, v + n + 1], [v, v + n + 1, v + n]]
            })
            .collect();
        let surface = Surface::new(positions.clone(), triangles).unwrap();
        let turn = Mat3::from_axis_angle(Vec3::new(0.2, 1.0, 0.4).normalize(), 0.15);
        let points: Vec<Vec3> = positions
            .iter()
            .step_by(7)
            .map(|&p| turn * p * 1.1 + Vec3::new(0.05, -0.03, 0.02))
            .collect();
        for (rounds, scaling) in [(1, false), (10, true), (40, true)] {
            let mut plain = Motion::IDENTITY;
            for _ in 0..rounds {
                let targets: Vec<Vec3> = points
                    .iter()
                    .map(|&p| surface.closest(plain.apply(p)))
                    .collect();
                plain = fit(&points, &targets, scaling);
            }
            assert_eq!(surface.icp(&points, rounds, scaling), plain);
        }
    }

    #[test]
    fn fit_recovers_a_motion_and_a_scale() {
        let turn = glam::Quat::from_axis_angle(glam::Vec3::new(0.3, -1.0, 0.2).normalize(), 0.7);
        let rotation = Mat3::from_cols_array(&glam::Mat3::from_quat(turn).to_cols_array());
        let from: Vec<Vec3> = (0..20)
            .map(|i| {
                Vec3::new(
                    (i as f32).sin(),
                    (i * i) as f32 * 0.01,
                    (i as f32 * 0.3).cos(),
                )
            })
            .collect();
        for (scale, scaling) in [(1.0, false), (2.5, true)] {
            let to: Vec<Vec3> = from
                .iter()
                .map(|&p| rotation * p * scale + Vec3::new(1.0, 2.0, 3.0))
                .collect();
            let motion = fit(&from, &to, scaling);
            assert!((motion.rotation - rotation)
                .abs()
                .to_cols_array()
                .iter()
                .all(|&e| e < 1e-4));
            assert!((motion.scale - scale).abs() < 1e-4, "{motion:?}");
            assert!((motion.shift - Vec3::new(1.0, 2.0, 3.0)).length() < 1e-3);
        }
    }

    #[test]
    fn a_thin_flat_point_set_fits_onto_itself_unturned() {
        // Spreads 1, 0.3 and 0.003, as a guitar's vertices: HᵀH's two smaller eigenvalues
        // are then within f32's precision of 0 against the largest.
        let points: Vec<Vec3> = (0..1000)
            .map(|i| {
                let t = i as f32;
                Vec3::new(
                    (t * 0.37).sin(),
                    0.3 * (t * 0.61).cos(),
                    0.003 * (t * 1.3).sin(),
                )
            })
            .collect();
        for scaling in [false, true] {
            let motion = fit(&points, &points, scaling);
            let worst = points
                .iter()
                .map(|&p| (motion.apply(p) - p).length())
                .fold(0.0f32, f32::max);
            assert!(worst < 1e-5, "scaling {scaling}: {worst} {motion:?}");
        }
    }

    #[test]
    fn half_of_the_signed_permutations_are_rotations() {
        let all: Vec<Mat3> = signed_permutations().collect();
        assert_eq!(all.len(), 48);
        assert_eq!(all.iter().filter(|m| m.determinant() > 0.0).count(), 24);
    }
}

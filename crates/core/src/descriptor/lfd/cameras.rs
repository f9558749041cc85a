//! Where the light field's cameras stand (Chen et al. 2003, §3.1): on the 20 vertices of a
//! regular dodecahedron around the model, ten fixed turns of that camera system, and the 60
//! rotations of the dodecahedron that carry one system's cameras onto its own.
//!
//! An orthographic view from a vertex and from the opposite vertex shows mirror silhouettes,
//! whose (mirror-invariant) features are equal, so a camera system has 10 distinct views: one
//! per *axis* through two opposite vertices.

use std::sync::OnceLock;

use glam::{DMat3, DVec3};

/// Distinct views of one camera system (20 vertices, opposite ones paired).
pub const VIEWS: usize = 10;
/// Camera systems (light fields) per model.
pub const LIGHT_FIELDS: usize = 10;
/// Rotations of the dodecahedron (the icosahedral group).
pub const ROTATIONS: usize = 60;

/// The camera geometry, computed once.
#[derive(Debug)]
pub struct Cameras {
    /// Unit view directions of the base system, one per axis.
    pub axes: [DVec3; VIEWS],
    /// The dodecahedron's rotations as matrices (identity first).
    pub rotations: Vec<DMat3>,
    /// For each rotation, the axis each axis is carried to: view `v` of one light field is
    /// compared with view `permutations[r][v]` of the other.
    pub permutations: Vec<[u8; VIEWS]>,
    /// The turns of the camera system that make the ten light fields (identity first).
    pub systems: [DMat3; LIGHT_FIELDS],
}

impl Cameras {
    /// The shared instance.
    pub fn get() -> &'static Cameras {
        static CAMERAS: OnceLock<Cameras> = OnceLock::new();
        CAMERAS.get_or_init(Cameras::build)
    }

    /// View direction of view `view` of light field `system`.
    pub fn direction(&self, system: usize, view: usize) -> DVec3 {
        self.systems[system] * self.axes[view]
    }

    fn build() -> Self {
        let vertices = dodecahedron();
        let axes = axes(&vertices);
        let rotations = rotations(&vertices);
        let permutations = rotations
            .iter()
            .map(|r| {
                axes.map(|a| {
                    let image = *r * a;
                    axis_index(&axes, image).expect("a symmetry maps axes to axes") as u8
                })
            })
            .collect();
        let systems = SYSTEMS.map(|m| DMat3::from_cols_array(&m));
        Self {
            axes,
            rotations,
            permutations,
            systems,
        }
    }

    /// The smallest angle (radians) between two of the 100 view axes of all light fields: how
    /// evenly the ten camera systems cover the directions.
    pub fn min_axis_angle(&self) -> f64 {
        let all: Vec<DVec3> = (0..LIGHT_FIELDS)
            .flat_map(|s| (0..VIEWS).map(move |v| (s, v)))
            .map(|(s, v)| self.direction(s, v))
            .collect();
        let mut largest_cos: f64 = 0.0;
        for (i, a) in all.iter().enumerate() {
            for b in &all[i + 1..] {
                largest_cos = largest_cos.max(a.dot(*b).abs());
            }
        }
        largest_cos.min(1.0).acos()
    }
}

/// The 20 vertices of a regular dodecahedron, on the unit sphere.
pub fn dodecahedron() -> Vec<DVec3> {
    let phi = (1.0 + 5f64.sqrt()) / 2.0;
    let inv = 1.0 / phi;
    let mut vertices = Vec::with_capacity(20);
    for sx in [-1.0, 1.0] {
        for sy in [-1.0, 1.0] {
            vertices.push(DVec3::new(sx, sy, -1.0));
            vertices.push(DVec3::new(sx, sy, 1.0));
            vertices.push(DVec3::new(0.0, sx * inv, sy * phi));
            vertices.push(DVec3::new(sx * inv, sy * phi, 0.0));
            vertices.push(DVec3::new(sx * phi, 0.0, sy * inv));
        }
    }
    vertices.into_iter().map(DVec3::normalize).collect()
}

/// One representative of each pair of opposite vertices, in vertex order.
fn axes(vertices: &[DVec3]) -> [DVec3; VIEWS] {
    let mut axes = Vec::with_capacity(VIEWS);
    for &v in vertices {
        if axis_index(&axes, v).is_none() {
            axes.push(v);
        }
    }
    axes.try_into().expect("a dodecahedron has 10 axes")
}

/// The axis through `direction` (either sign), if there is one.
fn axis_index(axes: &[DVec3], direction: DVec3) -> Option<usize> {
    axes.iter()
        .position(|a| a.dot(direction).abs() > 1.0 - 1e-9)
}

/// All 60 rotations mapping the dodecahedron onto itself: the group acts simply transitively
/// on directed edges, so there is exactly one carrying a fixed edge `(v₀, n₀)` to each of the
/// 60 directed edges `(w, w')`.
fn rotations(vertices: &[DVec3]) -> Vec<DMat3> {
    let edge = vertices
        .iter()
        .map(|v| vertices[0].distance(*v))
        .filter(|&d| d > 1e-9)
        .fold(f64::INFINITY, f64::min);
    let neighbours = |i: usize| {
        (0..vertices.len())
            .filter(move |&j| (vertices[i].distance(vertices[j]) - edge).abs() < 1e-9)
    };
    let frame = |a: DVec3, b: DVec3| {
        let b = (b - a * a.dot(b)).normalize();
        DMat3::from_cols(a, b, a.cross(b))
    };
    let n0 = neighbours(0).next().expect("a vertex has neighbours");
    let base = frame(vertices[0], vertices[n0]).transpose();
    let mut rotations: Vec<DMat3> = (0..vertices.len())
        .flat_map(|w| neighbours(w).map(move |n| (w, n)))
        .map(|(w, n)| frame(vertices[w], vertices[n]) * base)
        .collect();
    // Identity first, so that light fields compared view for view are rotation 0.
    let identity = rotations
        .iter()
        .position(|r| r.abs_diff_eq(DMat3::IDENTITY, 1e-9))
        .expect("the identity maps edge 0 to itself");
    rotations.swap(0, identity);
    rotations
}

/// The ten camera systems, column-major: what the search in this file's tests computes (they
/// check it bit for bit), written out because the search takes ~0.1 s, which every process that
/// extracts a signature paid once.
const SYSTEMS: [[f64; 9]; LIGHT_FIELDS] = [
    [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
    [
        0.2685286289397413,
        -0.72526130536205,
        0.6339466968005101,
        0.7629207935115874,
        -0.24165868636535182,
        -0.5996273360444988,
        0.5880852304448672,
        0.6446682233899137,
        0.488424654868998,
    ],
    [
        0.805403019930422,
        0.3994888159726735,
        -0.4378751664569571,
        -0.3811366397323128,
        0.9148177684338185,
        0.1335788621426678,
        0.45393924410709163,
        0.05930545059705756,
        0.8890568183130718,
    ],
    [
        -0.43364930814475455,
        -0.8870273698070111,
        -0.15852672569264395,
        0.8937528507716411,
        -0.44580617666843536,
        0.04962554364271919,
        -0.11469140893344773,
        -0.12016363034432202,
        0.9861067805564131,
    ],
    [
        0.46971429505698037,
        0.09507905480646822,
        -0.8776835730240327,
        0.7256156414651098,
        0.5246946547587439,
        0.44517127055637784,
        0.5028423429667606,
        -0.8459642383722322,
        0.17746573053687742,
    ],
    [
        -0.574861126165936,
        -0.22275897505948863,
        -0.7873456195684827,
        -0.5977259955596468,
        0.771448364963179,
        0.2181537403481014,
        0.5588007872716902,
        0.5960250491599189,
        -0.5766245059988824,
    ],
    [
        -0.42310494719087566,
        0.5284840978477592,
        -0.7359937241475952,
        0.3276066106836705,
        0.8465570248984443,
        0.41954155006560756,
        0.8447816950543877,
        -0.06360630406755902,
        -0.5313173494098429,
    ],
    [
        0.1968935472411555,
        -0.7317525298287822,
        -0.6525114298952713,
        -0.8677472678649104,
        -0.43984219801562197,
        0.23141633468225437,
        -0.45634154990289655,
        0.5206506275171123,
        -0.7215783491058048,
    ],
    [
        -0.43696502366928036,
        0.03667123339773424,
        -0.8987306541621877,
        0.10538494024056369,
        -0.9901998671070182,
        -0.09164189845117637,
        -0.8932835957635167,
        -0.13475698060706096,
        0.42881811262756897,
    ],
    [
        0.23470230556770888,
        -0.8528726583840933,
        0.4663936709927054,
        -0.2833215901264295,
        -0.5189829238660626,
        -0.8064648791507691,
        0.9298621964191434,
        0.057139770005513346,
        -0.36344372653037205,
    ],
];

#[cfg(test)]
mod tests {
    use glam::DQuat;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    /// Candidate turns drawn for each camera system after the first.
    const CANDIDATES: usize = 2000;
    /// Rounds of replacing one system by a better candidate.
    const REFINEMENTS: usize = 4;
    /// Seed of the candidate turns: the camera systems are part of the descriptor's definition.
    const SEED: u64 = 0x1f0d_2003;

    /// Ten turns of the camera system spread so that no two of the 100 view axes are close
    /// (Chen et al. use ten "evenly distributed" rotations): greedily, each next turn is the
    /// candidate whose axes stay farthest from all axes placed so far; then each turn in turn is
    /// replaced by the candidate best against all the others while that helps. Candidates are
    /// uniform unit quaternions by rejection sampling, which needs only arithmetic and square
    /// roots, so the systems are bit-identical on every platform.
    fn spread_systems(axes: &[DVec3; VIEWS]) -> [DMat3; LIGHT_FIELDS] {
        let mut rng = ChaCha8Rng::seed_from_u64(SEED);
        let candidates: Vec<DMat3> = std::iter::repeat_with(|| {
            let q = DQuat::from_xyzw(
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
            );
            let norm = q.length_squared();
            (norm > 1e-6 && norm <= 1.0).then(|| DMat3::from_quat(q.normalize()))
        })
        .flatten()
        .take(CANDIDATES)
        .collect();
        let best_against = |others: &[DMat3]| {
            let placed = placed_axes(axes, others);
            candidates
                .iter()
                .map(|r| (closeness(axes, &placed, r), *r))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .expect("there are candidates")
        };
        let mut systems = vec![DMat3::IDENTITY];
        while systems.len() < LIGHT_FIELDS {
            systems.push(best_against(&systems).1);
        }
        for _ in 0..REFINEMENTS {
            let mut improved = false;
            for j in 1..LIGHT_FIELDS {
                let mut others = systems.clone();
                let current = others.remove(j);
                let (close, candidate) = best_against(&others);
                if close < closeness(axes, &placed_axes(axes, &others), &current) {
                    systems[j] = candidate;
                    improved = true;
                }
            }
            if !improved {
                break;
            }
        }
        systems.try_into().expect("ten systems")
    }

    /// The axes of the systems `others`, turned once for all candidates compared with them.
    fn placed_axes(axes: &[DVec3; VIEWS], others: &[DMat3]) -> Vec<DVec3> {
        others
            .iter()
            .flat_map(|o| axes.iter().map(move |b| *o * *b))
            .collect()
    }

    /// The largest `|cos|` between an axis turned by `r` and one of the `placed` axes: smaller is
    /// farther apart.
    fn closeness(axes: &[DVec3; VIEWS], placed: &[DVec3], r: &DMat3) -> f64 {
        let mut largest: f64 = 0.0;
        for a in axes {
            let a = *r * *a;
            for b in placed {
                largest = largest.max(a.dot(*b).abs());
            }
        }
        largest
    }

    #[test]
    fn the_written_out_systems_are_the_spread_ones() {
        let cameras = Cameras::get();
        let spread = spread_systems(&cameras.axes);
        for (written, computed) in cameras.systems.iter().zip(&spread) {
            assert_eq!(written.to_cols_array(), computed.to_cols_array());
        }
    }

    #[test]
    fn axes_are_ten_distinct_lines() {
        let cameras = Cameras::get();
        for (i, a) in cameras.axes.iter().enumerate() {
            assert!((a.length() - 1.0).abs() < 1e-12);
            for b in &cameras.axes[i + 1..] {
                assert!(a.dot(*b).abs() < 0.75, "axes {a} and {b} too close");
            }
        }
    }
}

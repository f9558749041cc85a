//! The Light Field Descriptor baseline (SPEC §6; Chen et al. 2003) on generated shapes with
//! known answers: invariances of its image features, the camera geometry, and distances.

use crate::shapes;

use glam::{DMat3, DVec3};
use salient_core::descriptor::lfd::zernike::orders;
use salient_core::descriptor::lfd::{
    fourier_descriptors, zernike_magnitudes, Cameras, ImageFeatures, LfdQuery,
    LightFieldDescriptor, Silhouette, COEFFICIENTS, IMAGE_SIZE, LIGHT_FIELDS, PACKED, ROTATIONS,
    VIEWS,
};
use salient_core::mesh::{prepare, PreparedMesh, RawMesh};
use salient_core::params::MeshParams;

fn prepared(raw: &RawMesh) -> PreparedMesh {
    prepare(raw, &MeshParams::default()).expect("generated meshes prepare")
}

fn lfd(raw: &RawMesh) -> LightFieldDescriptor {
    LightFieldDescriptor::compute(&prepared(raw))
}

/// An asymmetric star: tips of different lengths in directions no symmetry relates.
fn lopsided_star() -> RawMesh {
    shapes::star(
        4,
        &[
            DVec3::new(1.0, 0.2, 0.1),
            DVec3::new(-0.3, 1.0, 0.2),
            DVec3::new(0.1, -0.4, 1.0),
        ],
    )
}

/// The silhouette of `raw` along `axis`.
fn silhouette(raw: &RawMesh, axis: DVec3) -> Silhouette {
    let mesh = prepared(raw);
    Silhouette::render(&mesh.positions, &mesh.triangles, axis.normalize())
}

/// `image` turned by `angle` about the image centre (nearest pixel).
fn rotated(image: &Silhouette, angle: f64) -> Silhouette {
    let c = IMAGE_SIZE as f64 / 2.0 - 0.5;
    let (sin, cos) = angle.sin_cos();
    Silhouette::from_fn(|x, y| {
        let (dx, dy) = (x as f64 - c, y as f64 - c);
        let (sx, sy) = (c + cos * dx + sin * dy, c - sin * dx + cos * dy);
        sx >= 0.0 && sy >= 0.0 && image.get(sx.round() as usize, sy.round() as usize)
    })
}

/// Direct summation of `Σ R_nm(ρ) e^{−imθ} / area` over the foreground pixels in the unit disk,
/// with the factorial formula: an independent check of the moment expansion.
fn zernike_direct(image: &Silhouette) -> Vec<f64> {
    let factorial = |n: usize| (1..=n).map(|k| k as f64).product::<f64>();
    let half = IMAGE_SIZE as f64 / 2.0;
    let mut sums = vec![(0.0, 0.0); orders().count()];
    let mut area = 0.0;
    for y in 0..IMAGE_SIZE {
        for x in 0..IMAGE_SIZE {
            let (xn, yn) = (
                (x as f64 + 0.5 - half) / half,
                (y as f64 + 0.5 - half) / half,
            );
            let rho = xn.hypot(yn);
            if !image.get(x, y) || rho > 1.0 {
                continue;
            }
            area += 1.0;
            let theta = yn.atan2(xn);
            for (sum, (n, m)) in sums.iter_mut().zip(orders()) {
                let radial: f64 = (0..=(n - m) / 2)
                    .map(|s| {
                        let sign = if s % 2 == 0 { 1.0 } else { -1.0 };
                        sign * factorial(n - s)
                            / (factorial(s)
                                * factorial((n + m) / 2 - s)
                                * factorial((n - m) / 2 - s))
                            * rho.powi((n - 2 * s) as i32)
                    })
                    .sum();
                sum.0 += radial * (m as f64 * theta).cos();
                sum.1 -= radial * (m as f64 * theta).sin();
            }
        }
    }
    sums.iter().map(|(re, im)| re.hypot(*im) / area).collect()
}

#[test]
fn zernike_moments_match_direct_summation() {
    let image = silhouette(&lopsided_star(), DVec3::new(0.3, 0.5, 0.8));
    let direct = zernike_direct(&image);
    let fast = zernike_magnitudes(&image);
    assert!(image.area() > 1000, "{image:?}");
    for ((a, b), order) in fast.iter().zip(&direct).zip(orders()) {
        assert!((a - b).abs() < 1e-9, "order {order:?}: {a} vs {b}");
    }
}

#[test]
fn zernike_magnitudes_are_invariant_to_image_rotation() {
    let image = silhouette(&lopsided_star(), DVec3::new(0.3, 0.5, 0.8));
    let other = silhouette(&shapes::tube(0.3, 12, 24), DVec3::new(0.3, 0.5, 0.8));
    let reference = zernike_magnitudes(&image);
    let l1 = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>();
    let to_other = l1(&reference, &zernike_magnitudes(&other));
    for degrees in [17.0, 45.0, 90.0, 133.0, 250.0] {
        let turned = zernike_magnitudes(&rotated(&image, f64::to_radians(degrees)));
        let worst = reference
            .iter()
            .zip(&turned)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        // Resampling moves boundary pixels: a few hundredths at most, on magnitudes ≤ 1.
        assert!(worst < 0.02, "{degrees}°: worst difference {worst}");
        assert!(
            l1(&reference, &turned) < 0.1 * to_other,
            "{degrees}°: {} vs {to_other} to a tube",
            l1(&reference, &turned)
        );
    }
    // Quantised, the rotation moves each coefficient by a step or two at most.
    let q = ImageFeatures::of(&image);
    let turned = ImageFeatures::of(&rotated(&image, f64::to_radians(45.0)));
    let steps: Vec<i32> = q
        .coefficients()
        .iter()
        .zip(turned.coefficients())
        .map(|(&a, &b)| (a as i32 - b as i32).abs())
        .collect();
    assert!(steps[..35].iter().all(|&s| s <= 4), "{steps:?}");
}

#[test]
fn fourier_descriptors_of_a_disc_vanish_and_of_a_square_show_its_symmetry() {
    let c = IMAGE_SIZE as f64 / 2.0 - 0.5;
    let disc = Silhouette::from_fn(|x, y| (x as f64 - c).hypot(y as f64 - c) < 80.0);
    assert!(fourier_descriptors(&disc).iter().all(|&f| f < 0.01));
    let square = Silhouette::from_fn(|x, y| (60..200).contains(&x) && (60..200).contains(&y));
    let fd = fourier_descriptors(&square);
    // The centroid distance of a square repeats four times around it: F_4 and F_8 only.
    for (k, &f) in fd.iter().enumerate().map(|(i, f)| (i + 1, f)) {
        if k % 4 == 0 {
            assert!(f > 0.01, "F_{k} = {f}");
        } else {
            assert!(f < 0.005, "F_{k} = {f}");
        }
    }
    // Invariant to turning and to the largest component's company.
    let turned = fourier_descriptors(&rotated(&square, 0.5));
    assert!(
        fd.iter().zip(&turned).all(|(a, b)| (a - b).abs() < 0.01),
        "{fd:?} vs {turned:?}"
    );
    let with_speck =
        Silhouette::from_fn(|x, y| square.get(x, y) || (x, y) == (10, 10) || (x, y) == (11, 11));
    assert_eq!(fourier_descriptors(&with_speck), fd);
    let empty = Silhouette::from_fn(|_, _| false);
    assert_eq!(fourier_descriptors(&empty), [0.0; 10]);
    assert_eq!(zernike_magnitudes(&empty), [0.0; 35]);
}

#[test]
fn the_60_rotations_form_a_group_permuting_the_views() {
    let cameras = Cameras::get();
    assert_eq!(cameras.rotations.len(), ROTATIONS);
    let find = |m: DMat3| {
        cameras
            .rotations
            .iter()
            .position(|r| r.abs_diff_eq(m, 1e-9))
    };
    assert_eq!(find(DMat3::IDENTITY), Some(0));
    for (i, a) in cameras.rotations.iter().enumerate() {
        assert!((a.determinant() - 1.0).abs() < 1e-12);
        assert!(find(a.transpose()).is_some(), "inverse of {i}");
        for b in &cameras.rotations {
            assert!(find(*a * *b).is_some(), "closure");
        }
    }
    // Distinct rotations permute the ten views differently, and each is a permutation.
    let mut permutations = cameras.permutations.clone();
    for p in &permutations {
        let mut sorted = *p;
        sorted.sort_unstable();
        assert_eq!(sorted, [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]);
    }
    permutations.sort_unstable();
    permutations.dedup();
    assert_eq!(permutations.len(), ROTATIONS);
    // Each maps the dodecahedron onto itself.
    let vertices = salient_core::descriptor::lfd::cameras::dodecahedron();
    for r in &cameras.rotations {
        for v in &vertices {
            assert!(vertices.iter().any(|w| (*r * *v).distance(*w) < 1e-9));
        }
    }
}

#[test]
fn the_ten_camera_systems_are_spread_out() {
    let cameras = Cameras::get();
    assert_eq!(cameras.systems.len(), LIGHT_FIELDS);
    // 100 view axes on the half sphere (area 2π) are ~14° apart at best; a random choice
    // typically leaves two within 2°.
    let angle = cameras.min_axis_angle().to_degrees();
    assert!(angle > 8.0, "closest view axes {angle:.2}° apart");
}

#[test]
fn a_spheres_silhouettes_are_all_equal() {
    let d = lfd(&shapes::icosphere(4));
    let first = d.light_field(0)[0];
    for field in 0..LIGHT_FIELDS {
        for image in d.light_field(field) {
            let worst = image
                .coefficients()
                .iter()
                .zip(first.coefficients())
                .map(|(&a, &b)| a.abs_diff(b))
                .max();
            assert!(worst <= Some(1), "{image:?} vs {first:?}");
        }
    }
    assert!(d.distance(&d) == 0.0);
}

#[test]
fn a_rotated_copy_is_near_and_other_shapes_are_far() {
    let models = [
        ("star", lopsided_star()),
        ("five-star", shapes::star(4, &shapes::five_tips())),
        ("tube", shapes::tube(0.25, 16, 24)),
        ("cone", shapes::cone(0.5, 12, 32)),
        ("bowl", shapes::bowl(4)),
    ];
    let descriptors: Vec<_> = models.iter().map(|(_, m)| lfd(m)).collect();
    for (seed, ((name, mesh), d)) in models.iter().zip(&descriptors).enumerate() {
        let copy = lfd(&shapes::transformed(
            mesh,
            shapes::random_motion(seed as u64 + 7),
        ));
        let to_copy = d.distance(&copy);
        let to_others = descriptors
            .iter()
            .filter(|o| *o != d)
            .map(|o| d.distance(o))
            .fold(f64::INFINITY, f64::min);
        assert!(to_copy < 0.02, "{name}: {to_copy}");
        assert!(
            to_copy < 0.35 * to_others,
            "{name}: {to_copy} vs {to_others}"
        );
        assert!(
            (d.distance(&copy) - copy.distance(d)).abs() < 1e-15,
            "symmetric"
        );
        // The ranking bound never exceeds the distance, and is not trivially 0 between shapes.
        for other in descriptors.iter().chain([&copy]) {
            let bound = d.summary().lower_bound(&other.summary());
            let distance = d.distance(other);
            assert!(bound <= distance, "{name}");
            // The sketch, coarser, is never above the summary's bound.
            assert!(d.sketch().lower_bound(&other.sketch()) <= bound, "{name}");
            // Prepared once as a ranking's query: the same distance, or `None` just past a
            // cutoff.
            let query = LfdQuery::new(d);
            let with = |cutoff| query.distance_within(other, &other.summary(), cutoff);
            assert_eq!(with(f64::INFINITY), Some(distance), "{name}");
            assert_eq!(with(distance), Some(distance), "{name}");
            if distance > 0.0 {
                assert_eq!(with(distance * (1.0 - 1e-9)), None, "{name}");
            }
            if other != d && other != &copy {
                assert!(
                    bound > 0.2 * d.distance(other),
                    "{name}: weak bound {bound}"
                );
            }
        }
    }
}

/// The LFD distance by its definition: every light-field pair, every rotation, every image's
/// L1 distance summed in full.
fn brute_distance(a: &LightFieldDescriptor, b: &LightFieldDescriptor) -> f64 {
    let l1 = |x: &ImageFeatures, y: &ImageFeatures| -> u32 {
        let (x, y) = (x.coefficients(), y.coefficients());
        x.iter().zip(y).map(|(&p, &q)| p.abs_diff(q) as u32).sum()
    };
    let mut best = u32::MAX;
    for p in 0..LIGHT_FIELDS {
        for q in 0..LIGHT_FIELDS {
            let (rows, columns) = (a.light_field(p), b.light_field(q));
            for permutation in &Cameras::get().permutations {
                let sum = (0..VIEWS)
                    .map(|v| l1(&rows[v], &columns[permutation[v] as usize]))
                    .sum();
                best = best.min(sum);
            }
        }
    }
    best as f64 / (VIEWS * COEFFICIENTS * 255) as f64
}

#[test]
fn the_pruned_distance_is_the_least_over_every_pair_and_rotation() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2003);
    let random = |rng: &mut rand_chacha::ChaCha8Rng| {
        let mut bytes = [0u8; PACKED];
        rng.fill(&mut bytes[..]);
        bytes
    };
    let permutations = &Cameras::get().permutations;
    for trial in 0..40 {
        let a = random(&mut rng);
        // `b`: one of `a`'s light fields with its views turned by a rotation and nudged, the
        // others unrelated — the least is that pair's, which the bounds must not prune —
        // or, every fourth trial, no relation at all.
        let mut b = random(&mut rng);
        if trial % 4 != 0 {
            let (p, q) = (
                rng.gen_range(0..LIGHT_FIELDS),
                rng.gen_range(0..LIGHT_FIELDS),
            );
            let rotation = &permutations[rng.gen_range(0..ROTATIONS)];
            for v in 0..VIEWS {
                for c in 0..COEFFICIENTS {
                    let from = a[(p * VIEWS + v) * COEFFICIENTS + c];
                    let nudge = rng.gen_range(0..=trial as u8);
                    b[(q * VIEWS + rotation[v] as usize) * COEFFICIENTS + c] =
                        from.saturating_add(nudge);
                }
            }
        }
        let (a, b) = (
            LightFieldDescriptor::unpacked(&a),
            LightFieldDescriptor::unpacked(&b),
        );
        let brute = brute_distance(&a, &b);
        assert_eq!(a.distance(&b), brute, "trial {trial}");
        assert_eq!(b.distance(&a), brute, "trial {trial}");
        // A cutoff at the distance keeps it; one just below gives none.
        let query = LfdQuery::new(&a);
        let with = |cutoff| query.distance_within(&b, &b.summary(), cutoff);
        assert_eq!(with(brute), Some(brute), "trial {trial}");
        assert_eq!(with(brute * (1.0 - 1e-9)), None, "trial {trial}");
        // Below the summaries' bound no light-field pair is left to visit, so a ranking
        // need not read `b`; at the bound one is.
        let bound = a.summary().lower_bound(&b.summary());
        assert!(query.pairs(&b.summary(), bound).is_some(), "trial {trial}");
        if bound > 0.0 {
            let below = query.pairs(&b.summary(), bound * (1.0 - 1e-9));
            assert!(below.is_none(), "trial {trial}");
        }
    }
}

#[test]
fn the_descriptor_is_deterministic_across_thread_counts() {
    let mesh = prepared(&lopsided_star());
    let pool = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    };
    let one = pool(1).install(|| LightFieldDescriptor::compute(&mesh));
    let two = pool(2).install(|| LightFieldDescriptor::compute(&mesh));
    assert_eq!(one, two);
    assert_eq!(one.light_field(0).len(), VIEWS);
}

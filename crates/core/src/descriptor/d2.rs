//! D2 shape distributions (SPEC §4, §6; paper §4.2 and Osada et al. 2002): the histogram of
//! distances between all pairs of points sampled uniformly by area on a surface.

use glam::DVec3;
use rand::Rng;

/// `samples` points uniformly by area on `triangles`; `None` for a surface of no area.
pub fn sample_surface(
    triangles: &[[DVec3; 3]],
    samples: usize,
    rng: &mut impl Rng,
) -> Option<Vec<DVec3>> {
    let mut cumulative = Vec::with_capacity(triangles.len());
    let mut total = 0.0;
    for [a, b, c] in triangles {
        total += (*b - *a).cross(*c - *a).length();
        cumulative.push(total);
    }
    if total <= 0.0 {
        return None;
    }
    Some(
        (0..samples)
            .map(|_| {
                let target = rng.gen::<f64>() * total;
                let t = cumulative
                    .partition_point(|&c| c <= target)
                    .min(triangles.len() - 1);
                let [a, b, c] = triangles[t];
                // Uniform on a triangle: the square root keeps the density flat (Osada §4).
                let (r1, r2) = (rng.gen::<f64>().sqrt(), rng.gen::<f64>());
                a * (1.0 - r1) + b * (r1 * (1.0 - r2)) + c * (r1 * r2)
            })
            .collect(),
    )
}

/// Samples `samples` points uniformly by area on `triangles`, measures all pairs and returns
/// a `bins`-bin histogram over `[0, range]` normalised to sum 1 (longer distances fall in the
/// last bin). An empty surface gives all zeros.
pub fn d2_histogram(
    triangles: &[[DVec3; 3]],
    samples: usize,
    bins: usize,
    range: f64,
    rng: &mut impl Rng,
) -> Vec<f32> {
    let mut histogram = vec![0.0; bins];
    let Some(points) = sample_surface(triangles, samples, rng) else {
        return histogram;
    };
    let mut counts = vec![0u64; bins];
    let scale = bins as f64 / range;
    // Coordinates apart and the bins of a row computed before they are counted, so that the
    // distances vectorise; the arithmetic is `DVec3::distance`'s, in its order.
    let [xs, ys, zs] = [0, 1, 2].map(|k| points.iter().map(|p| p[k]).collect::<Vec<f64>>());
    let last = (bins - 1) as u32;
    let mut row = Vec::with_capacity(samples);
    let mut lanes = vec![vec![0u64; bins]; 4];
    for i in 0..points.len() {
        let (x, y, z) = (xs[i], ys[i], zs[i]);
        let rest = [&xs[i + 1..], &ys[i + 1..], &zs[i + 1..]];
        bins_of_row(rest, (x, y, z), (scale, last), &mut row);
        // Four sets of counters: neighbouring pairs often share a bin, and one set would
        // make each increment wait for the last.
        let mut quads = row.chunks_exact(4);
        for quad in &mut quads {
            for (lane, &bin) in quad.iter().enumerate() {
                lanes[lane][bin as usize] += 1;
            }
        }
        for &bin in quads.remainder() {
            lanes[0][bin as usize] += 1;
        }
    }
    for lane in &lanes {
        for (c, l) in counts.iter_mut().zip(lane) {
            *c += l;
        }
    }
    let pairs = (samples * (samples - 1) / 2) as f64;
    for (h, c) in histogram.iter_mut().zip(counts) {
        *h = (c as f64 / pairs) as f32;
    }
    histogram
}

/// The bins of the distances from `(x, y, z)` to the points `rest` (coordinates apart), into
/// `row`. Built for AVX2 too and chosen at run time: four square roots at once instead of
/// two, each exactly rounded whatever the width, so the bins are the same.
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn bins_of_row(
    [xs, ys, zs]: [&[f64]; 3],
    (x, y, z): (f64, f64, f64),
    (scale, last): (f64, u32),
    row: &mut Vec<u32>,
) {
    row.clear();
    row.extend(xs.iter().zip(ys).zip(zs).map(|((&qx, &qy), &qz)| {
        let (dx, dy, dz) = (qx - x, qy - y, qz - z);
        let d = (dx * dx + dy * dy + dz * dz).sqrt();
        ((d * scale) as u32).min(last)
    }));
}

/// Half the L1 distance of two normalised histograms, in [0, 1] (SPEC §5's `d_SD`), summed in
/// f64 whatever the bins are stored in.
pub fn histogram_l1<T: Copy + Into<f64>>(a: &[T], b: &[T]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (x.into() - y.into()).abs())
        .sum::<f64>()
        / 2.0
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;

    #[test]
    fn unit_square_distances_follow_the_known_distribution() {
        // Two triangles of the unit square. The mean distance between random points of a unit
        // square is (2 + √2 + 5 ln(1 + √2)) / 15 ≈ 0.5214.
        let (a, b, c, d) = (DVec3::ZERO, DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Y);
        let square = [[a, b, c], [a, c, d]];
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let h = d2_histogram(&square, 2000, 100, 2.0, &mut rng);
        assert!((h.iter().map(|&p| p as f64).sum::<f64>() - 1.0).abs() < 1e-6);
        let mean: f64 = h
            .iter()
            .enumerate()
            .map(|(i, &p)| (i as f64 + 0.5) * 0.02 * p as f64)
            .sum();
        assert!((mean - 0.5214).abs() < 0.01, "mean {mean}");
        // Nothing beyond the diagonal √2.
        assert!(h[71..].iter().all(|&p| p == 0.0));
        assert_eq!(histogram_l1(&h, &h), 0.0);
    }
}

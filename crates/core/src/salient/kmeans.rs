//! k-means with k-means++ seeding and Lloyd iterations (SPEC §3.1).
//!
//! Written here rather than taken from `linfa-clustering`: the whole job is ~80 lines over a
//! flat array we already have, and doing each run sequentially in a fixed order makes the
//! result bit-identical on every run and thread count (SPEC §4), which a parallel reduction
//! would not guarantee.
//!
//! Two choices make the clustering a function of the *set* of points alone, so that a mesh
//! whose vertices come in another order (a rotated copy sorts differently) gets the same
//! salient points: points are clustered in lexicographic order of their coordinates, and
//! several seeded restarts are run, keeping the one of least inertia, so that one unlucky
//! k-means++ draw does not decide which vertices are candidates.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// The result of clustering `n` points of dimension `dim`.
#[derive(Debug, Clone, PartialEq)]
pub struct Clustering {
    /// `k × dim` cluster centres (fewer than requested when there are fewer distinct points).
    pub centres: Vec<Vec<f64>>,
    /// The cluster of each point.
    pub labels: Vec<u32>,
    /// Lloyd iterations of the kept run until no label changed.
    pub iterations: usize,
    /// Sum of squared distances of the points to their centres.
    pub inertia: f64,
}

/// Upper bound on Lloyd iterations; convergence normally takes a few dozen.
const MAX_ITERATIONS: usize = 500;

/// Clusters the rows of `data` (`n × dim`, row-major) into at most `k` clusters, keeping the
/// best of `restarts` runs.
pub fn kmeans(data: &[f64], dim: usize, k: usize, restarts: usize, seed: u64) -> Clustering {
    let n = data.len() / dim;
    let row = |i: usize| &data[i * dim..(i + 1) * dim];
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| {
        row(a)
            .iter()
            .zip(row(b))
            .map(|(x, y)| x.total_cmp(y))
            .find(|o| o.is_ne())
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let sorted: Vec<f64> = order.iter().flat_map(|&i| row(i).iter().copied()).collect();
    let best = (0..restarts.max(1) as u64)
        .into_par_iter()
        .map(|run| lloyd(&sorted, dim, k, seed.wrapping_add(run)))
        .min_by(|a, b| a.inertia.total_cmp(&b.inertia))
        .expect("at least one run");
    let mut labels = vec![0; n];
    for (position, &i) in order.iter().enumerate() {
        labels[i] = best.labels[position];
    }
    Clustering { labels, ..best }
}

/// One k-means++ seeding followed by Lloyd iterations until no label changes.
fn lloyd(data: &[f64], dim: usize, k: usize, seed: u64) -> Clustering {
    let n = data.len() / dim;
    let point = |i: usize| &data[i * dim..(i + 1) * dim];
    let mut centres = seed_plus_plus(data, dim, k, seed);
    let mut labels = vec![u32::MAX; n];
    let mut iterations = 0;
    while iterations < MAX_ITERATIONS {
        iterations += 1;
        let mut changed = false;
        for (i, label) in labels.iter_mut().enumerate() {
            let nearest = nearest(&centres, point(i));
            if *label != nearest {
                *label = nearest;
                changed = true;
            }
        }
        if !changed {
            break;
        }
        let mut sums = vec![vec![0.0; dim]; centres.len()];
        let mut counts = vec![0usize; centres.len()];
        for (i, &label) in labels.iter().enumerate() {
            counts[label as usize] += 1;
            for (s, x) in sums[label as usize].iter_mut().zip(point(i)) {
                *s += x;
            }
        }
        for ((centre, sum), count) in centres.iter_mut().zip(sums).zip(counts) {
            if count > 0 {
                *centre = sum.into_iter().map(|s| s / count as f64).collect();
            }
        }
    }
    let inertia = labels
        .iter()
        .enumerate()
        .map(|(i, &l)| squared(point(i), &centres[l as usize]))
        .sum();
    Clustering {
        centres,
        labels,
        iterations,
        inertia,
    }
}

/// k-means++: the first centre uniformly, each next one with probability proportional to the
/// squared distance to the nearest centre chosen so far.
fn seed_plus_plus(data: &[f64], dim: usize, k: usize, seed: u64) -> Vec<Vec<f64>> {
    let n = data.len() / dim;
    let point = |i: usize| &data[i * dim..(i + 1) * dim];
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    if n == 0 || k == 0 {
        return Vec::new();
    }
    let mut centres = vec![point(rng.gen_range(0..n)).to_vec()];
    let mut weight: Vec<f64> = (0..n).map(|i| squared(point(i), &centres[0])).collect();
    while centres.len() < k {
        let total: f64 = weight.iter().sum();
        if total <= 0.0 {
            break; // fewer distinct points than clusters
        }
        let mut target = rng.gen::<f64>() * total;
        let chosen = weight
            .iter()
            .position(|&w| {
                target -= w;
                target < 0.0
            })
            .unwrap_or_else(|| weight.iter().rposition(|&w| w > 0.0).unwrap_or(0));
        let centre = point(chosen).to_vec();
        for (i, w) in weight.iter_mut().enumerate() {
            *w = w.min(squared(point(i), &centre));
        }
        centres.push(centre);
    }
    centres
}

fn nearest(centres: &[Vec<f64>], p: &[f64]) -> u32 {
    let mut best = (f64::INFINITY, 0);
    for (c, centre) in centres.iter().enumerate() {
        let d = squared(p, centre);
        if d < best.0 {
            best = (d, c as u32);
        }
    }
    best.1
}

fn squared(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn separates_well_spread_groups() {
        // Three tight groups of 50 points in 2-D.
        let mut data = Vec::new();
        for (cx, cy) in [(0.0, 0.0), (10.0, 0.0), (0.0, 10.0)] {
            for i in 0..50 {
                let t = i as f64 / 50.0;
                data.extend([cx + t.sin() * 0.3, cy + t.cos() * 0.3]);
            }
        }
        let c = kmeans(&data, 2, 3, 4, 1);
        assert_eq!(c.centres.len(), 3);
        for group in c.labels.chunks(50) {
            assert!(group.iter().all(|&l| l == group[0]));
        }
        let mut distinct: Vec<u32> = c.labels.chunks(50).map(|g| g[0]).collect();
        distinct.dedup();
        assert_eq!(distinct.len(), 3);
        assert_eq!(kmeans(&data, 2, 3, 4, 1), c, "deterministic");
        // The same points in another order get the same clusters.
        let reversed: Vec<f64> = data.chunks(2).rev().flatten().copied().collect();
        let r = kmeans(&reversed, 2, 3, 4, 1);
        let mut back = r.labels.clone();
        back.reverse();
        assert_eq!(back, c.labels);
    }

    #[test]
    fn fewer_distinct_points_than_clusters() {
        let data = [1.0, 1.0, 1.0, 1.0, 2.0, 2.0];
        let c = kmeans(&data, 2, 5, 1, 0);
        assert_eq!(c.centres.len(), 2);
        assert_eq!(c.labels[0], c.labels[1]);
        assert_ne!(c.labels[0], c.labels[2]);
    }
}

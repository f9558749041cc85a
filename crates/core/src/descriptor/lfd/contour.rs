//! Fourier descriptors of a silhouette's outer contour (Chen et al. 2003, §4.1, after Zhang
//! and Lu): the contour-shape half of an image's features.
//!
//! The outer boundary of the largest 8-connected foreground component is traced (Moore
//! neighbourhood), resampled at [`SAMPLES`] points evenly spaced along its length, and
//! described by its distance to the component's centroid, `r(t)`. The magnitudes of the first
//! ten Fourier coefficients of `r`, divided by the mean (`|F_0|`), are invariant to rotation,
//! mirroring, the contour's starting point and scale.
//!
//! The transform is a direct sum: ten coefficients of 128 samples are ~1 300 multiply-adds,
//! less than setting up an FFT crate's plan.

use std::f64::consts::TAU;
use std::sync::OnceLock;

use glam::DVec2;
use num_complex::Complex64;

use super::silhouette::{Silhouette, IMAGE_SIZE};

/// Fourier descriptors kept per image (coefficients 1 to 10).
pub const FOURIER_COUNT: usize = 10;
/// Points the contour is resampled to.
pub const SAMPLES: usize = 128;

/// `|F_k| / |F_0|` for `k = 1..=10` of the centroid distance of the outer contour; all zero
/// for an empty image or a single pixel.
pub fn fourier_descriptors(image: &Silhouette) -> [f64; FOURIER_COUNT] {
    let mut out = [0.0; FOURIER_COUNT];
    let components = Components::of(image);
    let Some(largest) = components.largest() else {
        return out;
    };
    let contour = outer_contour(components.first_pixel(largest), |x, y| {
        components.label(x, y) == Some(largest)
    });
    let centroid = components.centroid(largest);
    let r: Vec<f64> = resample(&contour, SAMPLES)
        .iter()
        .map(|p| p.distance(centroid))
        .collect();
    let twiddles = twiddles();
    let coefficient = |k: usize| -> Complex64 {
        r.iter()
            .enumerate()
            .map(|(j, &rj)| twiddles[(j * k) % SAMPLES] * rj)
            .sum()
    };
    let mean = coefficient(0).norm();
    if mean <= f64::EPSILON {
        return out;
    }
    for (k, value) in out.iter_mut().enumerate() {
        *value = coefficient(k + 1).norm() / mean;
    }
    out
}

/// `e^{−2πi j / SAMPLES}` for each `j`.
fn twiddles() -> &'static [Complex64] {
    static TWIDDLES: OnceLock<Vec<Complex64>> = OnceLock::new();
    TWIDDLES.get_or_init(|| {
        (0..SAMPLES)
            .map(|j| Complex64::from_polar(1.0, -TAU * j as f64 / SAMPLES as f64))
            .collect()
    })
}

/// 8-connected foreground components, labelled by union–find over row runs: a few hundred
/// runs instead of 65 536 pixels per image.
struct Components {
    /// Runs `(y, start, end)` in row order; `row_start[y]..row_start[y + 1]` are row `y`'s.
    runs: Vec<(usize, usize, usize)>,
    row_start: Vec<usize>,
    /// Component of each run (a run index, the component's first run in row order).
    root: Vec<usize>,
}

impl Components {
    fn of(image: &Silhouette) -> Self {
        let mut runs = Vec::new();
        let mut row_start = vec![0];
        for y in 0..IMAGE_SIZE {
            runs.extend(image.runs(y).map(|(start, end)| (y, start, end)));
            row_start.push(runs.len());
        }
        let mut parent: Vec<usize> = (0..runs.len()).collect();
        fn find(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        for y in 1..IMAGE_SIZE {
            let (above, here) = (
                row_start[y - 1]..row_start[y],
                row_start[y]..row_start[y + 1],
            );
            let mut j = above.start;
            for i in here {
                let (_, start, end) = runs[i];
                // Diagonal contact counts: runs touch when [start − 1, end + 1) overlaps.
                while j < above.end && runs[j].2 < start {
                    j += 1;
                }
                let mut k = j;
                while k < above.end && runs[k].1 < end + 1 {
                    let (a, b) = (find(&mut parent, i), find(&mut parent, k));
                    // The smaller index is the earlier run in row order.
                    parent[a.max(b)] = a.min(b);
                    k += 1;
                }
            }
        }
        let root = (0..runs.len()).map(|i| find(&mut parent, i)).collect();
        Self {
            runs,
            row_start,
            root,
        }
    }

    /// The component with most pixels; the first in row order wins a tie.
    fn largest(&self) -> Option<usize> {
        let mut size = vec![0usize; self.runs.len()];
        for (i, &(_, start, end)) in self.runs.iter().enumerate() {
            size[self.root[i]] += end - start;
        }
        (0..size.len())
            .filter(|&i| size[i] > 0)
            .max_by(|&a, &b| size[a].cmp(&size[b]).then(b.cmp(&a)))
    }

    /// The component's first pixel in row order.
    fn first_pixel(&self, component: usize) -> (usize, usize) {
        let (y, start, _) = self.runs[component];
        (start, y)
    }

    fn centroid(&self, component: usize) -> DVec2 {
        let (mut sum, mut count) = (DVec2::ZERO, 0.0);
        for (i, &(y, start, end)) in self.runs.iter().enumerate() {
            if self.root[i] == component {
                let n = (end - start) as f64;
                sum += DVec2::new((start + end - 1) as f64 / 2.0 * n, y as f64 * n);
                count += n;
            }
        }
        sum / count
    }

    /// The component of pixel `(x, y)`, if it is foreground.
    fn label(&self, x: i64, y: i64) -> Option<usize> {
        if x < 0 || y < 0 || y as usize >= IMAGE_SIZE {
            return None;
        }
        let (x, y) = (x as usize, y as usize);
        let row = &self.runs[self.row_start[y]..self.row_start[y + 1]];
        let i = row
            .partition_point(|&(_, start, _)| start <= x)
            .checked_sub(1)?;
        (x < row[i].2).then(|| self.root[self.row_start[y] + i])
    }
}

/// The eight neighbours clockwise (image `y` points down), starting east.
const NEIGHBOURS: [(i64, i64); 8] = [
    (1, 0),
    (1, 1),
    (0, 1),
    (-1, 1),
    (-1, 0),
    (-1, -1),
    (0, -1),
    (1, -1),
];

/// Moore-neighbourhood tracing of the outer boundary from `start`, the component's first
/// pixel in row order (so its west, north-west, north and north-east neighbours are
/// background). Stops when the first step is about to repeat (Jacob's criterion), so thin
/// parts crossed twice are traced on both sides.
fn outer_contour(start: (usize, usize), inside: impl Fn(i64, i64) -> bool) -> Vec<DVec2> {
    let start = (start.0 as i64, start.1 as i64);
    let step = |(x, y): (i64, i64), from: usize| -> Option<((i64, i64), usize)> {
        // Sweep clockwise from the direction two turns back from the one we arrived in.
        (0..8).map(|i| (from + 6 + i) % 8).find_map(|d| {
            let (dx, dy) = NEIGHBOURS[d];
            inside(x + dx, y + dy).then_some(((x + dx, y + dy), d))
        })
    };
    let mut contour = vec![DVec2::new(start.0 as f64, start.1 as f64)];
    let Some(first) = step(start, 0) else {
        return contour;
    };
    let (mut at, mut from) = first;
    // Every boundary pixel is entered at most once from each of 8 directions.
    for _ in 0..8 * IMAGE_SIZE * IMAGE_SIZE {
        let next = step(at, from).expect("a traced pixel has the pixel it came from");
        if at == start && next == first {
            break;
        }
        contour.push(DVec2::new(at.0 as f64, at.1 as f64));
        (at, from) = next;
    }
    contour
}

/// `count` points evenly spaced along the closed polygon `points`.
fn resample(points: &[DVec2], count: usize) -> Vec<DVec2> {
    let n = points.len();
    let lengths: Vec<f64> = (0..n)
        .map(|i| points[i].distance(points[(i + 1) % n]))
        .collect();
    let total: f64 = lengths.iter().sum();
    if total <= 0.0 {
        return vec![points[0]; count];
    }
    let mut out = Vec::with_capacity(count);
    let (mut segment, mut walked) = (0, 0.0);
    for j in 0..count {
        let target = total * j as f64 / count as f64;
        while walked + lengths[segment] < target && segment + 1 < n {
            walked += lengths[segment];
            segment += 1;
        }
        let t = if lengths[segment] > 0.0 {
            ((target - walked) / lengths[segment]).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out.push(points[segment].lerp(points[(segment + 1) % n], t));
    }
    out
}

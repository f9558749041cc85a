//! Triangle scan conversion shared by the pictures of [`crate::render`] and the silhouettes of
//! the light field descriptor: which pixel centres a projected triangle covers.
//!
//! Hand-written because it is a few dozen lines; the crates that rasterise (tiny-skia, raqote)
//! draw anti-aliased paths, where a silhouette needs exact, binary pixel-centre coverage.

use std::ops::RangeInclusive;

use glam::DVec2;

/// Calls `cover(x, y, weights)` for every pixel of a `size`-pixel square whose centre — at
/// integer coordinates `(x, y)` — lies in the triangle `t` (edges included, so triangles that
/// share an edge leave no gap), with the centre's barycentric weights. A triangle of no area
/// covers nothing.
pub fn fill_triangle(t: [DVec2; 3], size: u32, mut cover: impl FnMut(u32, u32, [f64; 3])) {
    let [a, b, c] = t;
    let area = edge(a, b, c);
    fill_spans(t, size, |y, xs| {
        for x in xs {
            let p = DVec2::new(x as f64, y as f64);
            let weights = [
                edge(b, c, p) / area,
                edge(c, a, p) / area,
                edge(a, b, p) / area,
            ];
            cover(x, y, weights);
        }
    });
}

/// Calls `cover(y, xs)` for every row `y` of a `size`-pixel square with the pixels `xs` whose
/// centres lie in `t`: the pixels [`fill_triangle`] covers, a row at a time.
///
/// A pixel is in when its centre's three edge functions have the area's sign (or are zero);
/// that is when its barycentric weights are not negative, without their divisions. Along a
/// row each edge function, evaluated in floating point as it is here, is monotone in `x`
/// (a subtraction and a product by a constant are), so the pixels in form one run. Its ends
/// are computed from where the edges cross the row, and only pixels within [`MARGIN`] of an
/// end get that exact test: the run is the one a test of every pixel finds (the silhouettes'
/// pixel loop was ~15 % of an upload's extraction).
pub fn fill_spans(t: [DVec2; 3], size: u32, mut cover: impl FnMut(u32, RangeInclusive<u32>)) {
    let [a, b, c] = t;
    let area = edge(a, b, c);
    if area.abs() < 1e-12 {
        return;
    }
    let max = size as f64 - 1.0;
    let (x0, x1) = (
        a.x.min(b.x).min(c.x).max(0.0),
        a.x.max(b.x).max(c.x).min(max),
    );
    let (y0, y1) = (
        a.y.min(b.y).min(c.y).max(0.0),
        a.y.max(b.y).max(c.y).min(max),
    );
    if x0 > x1 || y0 > y1 {
        return;
    }
    // The box's, exact: its corners are not negative, where a cast is `floor`.
    let ceil = |v: f64| v as u32 + u32::from((v as u32 as f64) < v);
    let (first, last) = (ceil(x0), x1 as u32);
    // Each edge as `(from, to)` in the order the weights evaluate them.
    let edges = [(b, c), (c, a), (a, b)];
    let sign = area.signum();
    let inside = |x: u32, y: f64| {
        let p = DVec2::new(x as f64, y);
        edges
            .iter()
            .all(|&(from, to)| sign * edge(from, to, p) >= 0.0)
    };
    // Where each edge crosses a row, `from.x + (y − from.y) · dx/dy`, and whether the pixels
    // in lie left of it (`sign · dy > 0`). The test evaluates an edge function within
    // `2⁻⁵⁰ · m · (|dx| + |dy|)` of its value, `m` the largest coordinate, so the crossing it
    // sees lies within that over `|dy|` of this one: under [`MARGIN`] for edges no flatter
    // than `STEEP`, which the test alone decides.
    let m = [a, b, c]
        .iter()
        .fold(size as f64, |m, p| m.max(p.x.abs()).max(p.y.abs()));
    let crossings = edges.map(|(from, to)| {
        let (dx, dy) = (to.x - from.x, to.y - from.y);
        (dy.abs() >= STEEP * m * (dx.abs() + dy.abs())).then(|| (from, dx / dy, sign * dy > 0.0))
    });
    // `floor` by a cast, which truncates, of the value shifted positive: the baseline x86-64
    // has no rounding instruction (`f64::floor` is a libm call). At most one above `floor`,
    // which only widens the run the test then trims.
    let floor = |v: f64| (v + SHIFT) as i64 - SHIFT as i64;
    let flat = crossings.iter().any(Option::is_none);
    for y in ceil(y0)..=y1 as u32 {
        let row = y as f64;
        // Pixels in `sure` lie inside every edge by more than the margin; pixels outside
        // `maybe` lie outside one by more. The exact test decides those between.
        let (mut maybe, mut sure) = ((first as i64, last as i64), (first as i64, last as i64));
        for &(from, slope, left) in crossings.iter().flatten() {
            let crossing = from.x + (row - from.y) * slope;
            if left {
                maybe.1 = maybe.1.min(floor(crossing + MARGIN));
                sure.1 = sure.1.min(floor(crossing - 2.0 * MARGIN));
            } else {
                maybe.0 = maybe.0.max(-floor(MARGIN - crossing));
                sure.0 = sure.0.max(-floor(-2.0 * MARGIN - crossing));
            }
        }
        if maybe.0 > maybe.1 {
            continue;
        }
        let (mut lo, mut hi) = (maybe.0 as u32, maybe.1 as u32);
        if flat || sure.0 > sure.1 {
            // Trimmed to the run by the exact test.
            while lo <= hi && !inside(lo, row) {
                lo += 1;
            }
            while hi > lo && !inside(hi, row) {
                hi -= 1;
            }
        } else {
            let (first_sure, last_sure) = (sure.0 as u32, sure.1 as u32);
            lo = (lo..first_sure)
                .find(|&x| inside(x, row))
                .unwrap_or(first_sure);
            hi = (last_sure + 1..=hi)
                .rev()
                .find(|&x| inside(x, row))
                .unwrap_or(last_sure);
        }
        if lo <= hi {
            cover(y, lo..=hi);
        }
    }
}

/// Added before [`fill_spans`]' casts.
const SHIFT: f64 = (1u64 << 20) as f64;
/// How far, in pixels, [`fill_spans`] widens a run computed from the edges' crossings before
/// the exact test trims it: far above their error, far below a pixel.
const MARGIN: f64 = 1e-3;
/// The least `|dy| / (m · (|dx| + |dy|))` of an edge whose crossings [`fill_spans`] computes:
/// `2⁻⁵⁰ / STEEP` is under half of [`MARGIN`].
const STEEP: f64 = 4e-12;

/// Twice the signed area of `(a, b, p)`.
fn edge(a: DVec2, b: DVec2, p: DVec2) -> f64 {
    (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::*;

    /// The definition: every pixel of the bounding box tested by its barycentric weights.
    fn covered_by_weights(t: [DVec2; 3], size: u32) -> Vec<(u32, u32)> {
        let [a, b, c] = t;
        let area = edge(a, b, c);
        if area.abs() < 1e-12 {
            return Vec::new();
        }
        let mut pixels = Vec::new();
        for y in 0..size {
            for x in 0..size {
                let p = DVec2::new(x as f64, y as f64);
                let weights = [edge(b, c, p), edge(c, a, p), edge(a, b, p)].map(|e| e / area);
                if weights.iter().all(|&w| w >= 0.0) {
                    pixels.push((x, y));
                }
            }
        }
        pixels
    }

    #[test]
    fn the_runs_cover_exactly_the_pixels_whose_weights_are_not_negative() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let size = 24;
        let point = |rng: &mut rand_chacha::ChaCha8Rng| {
            // Half the corners on pixel centres or half-pixels, so that edges pass through
            // centres and rows hit corners exactly; the others anywhere, some outside.
            if rng.gen_bool(0.5) {
                DVec2::new(
                    rng.gen_range(-4..28) as f64 / 2.0,
                    rng.gen_range(-4..28) as f64 / 2.0,
                )
            } else {
                DVec2::new(rng.gen_range(-3.0..27.0), rng.gen_range(-3.0..27.0))
            }
        };
        let mut nonempty = 0;
        for _ in 0..3000 {
            let mut t = [point(&mut rng), point(&mut rng), point(&mut rng)];
            if rng.gen_bool(0.1) {
                // A sliver: the third corner near the line through the others.
                t[2] = t[0] + (t[1] - t[0]) * rng.gen_range(-0.5..1.5) + DVec2::splat(1e-3);
            }
            let mut spans = Vec::new();
            fill_spans(t, size, |y, xs| spans.extend(xs.map(|x| (x, y))));
            spans.sort_by_key(|&(x, y)| (y, x));
            assert_eq!(spans, covered_by_weights(t, size), "triangle {t:?}");
            nonempty += usize::from(!spans.is_empty());
        }
        assert!(nonempty > 1000, "{nonempty} triangles covered a pixel");
    }
}

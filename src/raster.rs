//! Triangle scan conversion shared by the pictures of [`crate::render`] and the silhouettes of
//! the light field descriptor: which pixel centres a projected triangle covers.
//!
//! Hand-written because it is a dozen lines; the crates that rasterise (tiny-skia, raqote)
//! draw anti-aliased paths, where a silhouette needs exact, binary pixel-centre coverage.

use glam::DVec2;

/// Calls `cover(x, y, weights)` for every pixel of a `size`-pixel square whose centre — at
/// integer coordinates `(x, y)` — lies in the triangle `t` (edges included, so triangles that
/// share an edge leave no gap), with the centre's barycentric weights. A triangle of no area
/// covers nothing.
pub fn fill_triangle(t: [DVec2; 3], size: u32, mut cover: impl FnMut(u32, u32, [f64; 3])) {
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
    for y in y0.ceil() as u32..=y1.floor() as u32 {
        for x in x0.ceil() as u32..=x1.floor() as u32 {
            let p = DVec2::new(x as f64, y as f64);
            let weights = [
                edge(b, c, p) / area,
                edge(c, a, p) / area,
                edge(a, b, p) / area,
            ];
            if weights.iter().all(|&w| w >= 0.0) {
                cover(x, y, weights);
            }
        }
    }
}

/// Twice the signed area of `(a, b, p)`.
fn edge(a: DVec2, b: DVec2, p: DVec2) -> f64 {
    (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
}

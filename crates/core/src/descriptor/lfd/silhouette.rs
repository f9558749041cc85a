//! Orthographic binary silhouettes (Chen et al. 2003, §3.1): what a camera far away along an
//! axis sees of the normalised model, as foreground/background pixels.

use glam::{DVec2, DVec3};

use crate::raster::fill_spans;

/// Width and height of a silhouette, as in the paper.
pub const IMAGE_SIZE: usize = 256;

/// A square binary image, row by row, `true` where the model is. The unit disk around the
/// image centre is the unit sphere the model is normalised into (SPEC §1.4), so any view of
/// the model fits and the model's centre is the image centre.
#[derive(Clone, PartialEq, Eq)]
pub struct Silhouette {
    pixels: Vec<bool>,
}

impl std::fmt::Debug for Silhouette {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Silhouette({} of {} pixels)",
            self.area(),
            self.pixels.len()
        )
    }
}

impl Silhouette {
    /// The image whose pixel `(x, y)` is `inside(x, y)`.
    pub fn from_fn(mut inside: impl FnMut(usize, usize) -> bool) -> Self {
        let pixels = (0..IMAGE_SIZE * IMAGE_SIZE)
            .map(|i| inside(i % IMAGE_SIZE, i / IMAGE_SIZE))
            .collect();
        Self { pixels }
    }

    /// The model's shadow along `axis`: every triangle projected onto the plane through the
    /// origin perpendicular to `axis` and filled. `positions` are normalised (inside the unit
    /// sphere). The in-plane orientation is arbitrary: the features are rotation invariant.
    pub fn render(positions: &[DVec3], triangles: &[[u32; 3]], axis: DVec3) -> Self {
        let u = axis.any_orthonormal_vector();
        let w = axis.cross(u);
        let half = IMAGE_SIZE as f64 / 2.0;
        // Pixel centres are at integer coordinates for the rasteriser, at x + ½ here.
        let projected: Vec<DVec2> = positions
            .iter()
            .map(|p| DVec2::new(half - 0.5 + p.dot(u) * half, half - 0.5 - p.dot(w) * half))
            .collect();
        let mut pixels = vec![false; IMAGE_SIZE * IMAGE_SIZE];
        for t in triangles {
            let corners = t.map(|v| projected[v as usize]);
            fill_spans(corners, IMAGE_SIZE as u32, |y, xs| {
                let row = y as usize * IMAGE_SIZE;
                pixels[row + *xs.start() as usize..=row + *xs.end() as usize].fill(true);
            });
        }
        Self { pixels }
    }

    /// Whether pixel `(x, y)` is foreground; outside the image is background.
    pub fn get(&self, x: usize, y: usize) -> bool {
        x < IMAGE_SIZE && y < IMAGE_SIZE && self.pixels[y * IMAGE_SIZE + x]
    }

    /// Foreground pixels.
    pub fn area(&self) -> usize {
        self.pixels.iter().filter(|&&p| p).count()
    }

    /// Runs of foreground pixels in row `y`, as half-open column ranges.
    pub fn runs(&self, y: usize) -> impl Iterator<Item = (usize, usize)> + '_ {
        let row = &self.pixels[y * IMAGE_SIZE..(y + 1) * IMAGE_SIZE];
        let mut x = 0;
        std::iter::from_fn(move || {
            let start = x + row[x..].iter().position(|&p| p)?;
            let end = start
                + row[start..]
                    .iter()
                    .position(|&p| !p)
                    .unwrap_or(IMAGE_SIZE - start);
            x = end;
            Some((start, end))
        })
    }
}

/// Unit-disk coordinates of the centre of pixel column (or row) `i`: the image's inscribed
/// disk is the unit disk.
pub fn disk_coordinate(i: usize) -> f64 {
    let half = IMAGE_SIZE as f64 / 2.0;
    (i as f64 + 0.5 - half) / half
}

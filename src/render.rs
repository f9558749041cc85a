//! Pictures of what the method found on a mesh, like the paper's Fig. 10: the normalised mesh
//! from a few viewpoints side by side, shaded, with each salient region in its own colour and
//! each salient point as a red dot.
//!
//! A small software rasteriser (orthographic camera, z-buffer, flat two-sided Lambert shading),
//! so that a picture needs neither a GPU nor a display.

use std::path::Path;

use glam::{DMat3, DVec3};
use image::{Rgb, RgbImage};

use crate::pipeline::Extraction;
use crate::raster::fill_triangle;
use crate::salient::SalientPoint;
use crate::{Error, Result};

/// The colour of salient points.
pub const POINT_COLOUR: Rgb<u8> = Rgb([230, 20, 20]);

/// Region colours, in point order and repeating; none is red, so points stay visible.
const REGION_COLOURS: [[f64; 3]; 6] = [
    [1.0, 0.85, 0.2],
    [0.25, 0.75, 0.95],
    [0.45, 0.85, 0.35],
    [0.7, 0.5, 0.95],
    [1.0, 0.6, 0.2],
    [0.3, 0.9, 0.8],
];
const SURFACE: [f64; 3] = [0.78, 0.78, 0.8];
const BACKGROUND: Rgb<u8> = Rgb([250, 250, 250]);

/// An orthographic view of the unit sphere the mesh is normalised into (SPEC §1.4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// World to view: the view looks along −z, with +y up.
    rotation: DMat3,
}

impl Camera {
    /// A camera turned `yaw` radians about the vertical axis and tilted `pitch` radians down.
    pub fn new(yaw: f64, pitch: f64) -> Self {
        Self {
            rotation: DMat3::from_rotation_x(pitch) * DMat3::from_rotation_y(yaw),
        }
    }

    /// The three default views: around the model every 120°, from 25° above.
    pub fn around() -> [Camera; 3] {
        let pitch = 25f64.to_radians();
        [0.0, 120.0, 240.0].map(|yaw: f64| Camera::new(yaw.to_radians(), pitch))
    }

    /// Pixel coordinates in a `size`-pixel square tile and depth (larger is nearer) of a point
    /// in normalised coordinates.
    pub fn project(&self, p: DVec3, size: u32) -> DVec3 {
        let v = self.rotation * p;
        // A margin of 5 % keeps the unit sphere inside the tile.
        let half = size as f64 / 2.0;
        DVec3::new(half + v.x * half * 0.95, half - v.y * half * 0.95, v.z)
    }
}

/// A z-buffered RGB tile.
struct Tile {
    size: u32,
    colour: Vec<[f64; 3]>,
    depth: Vec<f64>,
}

/// How far in front of the surface an overlay may be hidden: regions lie on the surface, so
/// they pass a depth test against it with this tolerance (normalised units).
const OVERLAY_TOLERANCE: f64 = 1e-3;
/// A salient point on the far side of a thin part stays hidden; one merely behind its own
/// neighbourhood's facets shows.
const POINT_TOLERANCE: f64 = 0.02;

impl Tile {
    fn new(size: u32) -> Self {
        let n = (size * size) as usize;
        Self {
            size,
            colour: vec![[0.0; 3]; n],
            depth: vec![f64::NEG_INFINITY; n],
        }
    }

    /// Fills the projected triangle with `base` shaded by its normal (two-sided, so open and
    /// inconsistently wound meshes shade too). Pixels whose depth is below the buffer's minus
    /// `tolerance` are hidden.
    fn triangle(&mut self, camera: &Camera, t: [DVec3; 3], base: [f64; 3], tolerance: f64) {
        let normal = (camera.rotation * (t[1] - t[0]).cross(t[2] - t[0])).normalize_or_zero();
        let light = DVec3::new(-0.3, 0.4, 1.0).normalize();
        let shade = 0.3 + 0.7 * normal.dot(light).abs();
        let [a, b, c] = t.map(|p| camera.project(p, self.size));
        let size = self.size;
        fill_triangle(
            [a, b, c].map(|p| p.truncate()),
            size,
            |x, y, [wa, wb, wc]| {
                let z = wa * a.z + wb * b.z + wc * c.z;
                let i = (y * size + x) as usize;
                if z + tolerance >= self.depth[i] {
                    self.depth[i] = self.depth[i].max(z);
                    self.colour[i] = base.map(|c| c * shade);
                }
            },
        );
    }

    /// A disc of `radius` pixels at the point's pixel, if the point is not hidden.
    fn point(&mut self, camera: &Camera, p: DVec3, radius: f64) {
        let q = camera.project(p, self.size);
        let (x, y) = (q.x.round(), q.y.round());
        if x < 0.0 || y < 0.0 || x >= self.size as f64 || y >= self.size as f64 {
            return;
        }
        if q.z + POINT_TOLERANCE < self.depth[(y as u32 * self.size + x as u32) as usize] {
            return;
        }
        let r = radius.ceil() as i64;
        for dy in -r..=r {
            for dx in -r..=r {
                let (px, py) = (x as i64 + dx, y as i64 + dy);
                let inside =
                    (0..self.size as i64).contains(&px) && (0..self.size as i64).contains(&py);
                if inside && ((dx * dx + dy * dy) as f64) <= radius * radius {
                    let i = (py as u32 * self.size + px as u32) as usize;
                    self.colour[i] = POINT_COLOUR.0.map(|c| c as f64 / 255.0);
                    self.depth[i] = f64::INFINITY;
                }
            }
        }
    }
}

/// The mesh of `extraction` seen by each of `cameras` in `size`-pixel tiles side by side, with
/// `points`' regions coloured and the points marked.
pub fn render(
    extraction: &Extraction,
    points: &[SalientPoint],
    cameras: &[Camera],
    size: u32,
) -> RgbImage {
    let mesh = &extraction.mesh;
    let radius = (size as f64 / 90.0).max(2.5);
    let mut image = RgbImage::from_pixel(size * cameras.len() as u32, size, BACKGROUND);
    for (k, camera) in cameras.iter().enumerate() {
        let mut tile = Tile::new(size);
        for t in &mesh.triangles {
            tile.triangle(camera, t.map(|v| mesh.positions[v as usize]), SURFACE, 0.0);
        }
        for (i, point) in points.iter().enumerate() {
            let colour = REGION_COLOURS[i % REGION_COLOURS.len()];
            for t in &point.region.triangles {
                tile.triangle(camera, *t, colour, OVERLAY_TOLERANCE);
            }
        }
        for point in points {
            tile.point(camera, mesh.positions[point.vertex as usize], radius);
        }
        for (i, (&c, &z)) in tile.colour.iter().zip(&tile.depth).enumerate() {
            if z > f64::NEG_INFINITY {
                let (x, y) = (i as u32 % size, i as u32 / size);
                let rgb = c.map(|v| (v * 255.0).round().clamp(0.0, 255.0) as u8);
                image.put_pixel(k as u32 * size + x, y, Rgb(rgb));
            }
        }
    }
    image
}

/// Saves a picture as PNG.
pub fn save_png(image: &RgbImage, path: &Path) -> Result<()> {
    image
        .save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| Error::Report {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
}

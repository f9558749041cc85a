//! Pictures of what the method found on a mesh, like the paper's Fig. 10: the normalised mesh
//! from a few viewpoints side by side, shaded, with each salient region in its own colour and
//! each salient point as a red dot.
//!
//! A small software rasteriser (orthographic camera, z-buffer, flat two-sided Lambert shading),
//! so that a picture needs neither a GPU nor a display.

use std::path::Path;

use glam::{DMat3, DVec3};
use image::codecs::png::PngEncoder;
use image::imageops::FilterType;
use image::{ImageEncoder, Rgb, RgbImage};

use crate::display::{region_colour, UpAxis, SURFACE};
use crate::extraction::Extraction;
use crate::preview::{Preview, NO_REGION};
use crate::raster::fill_triangle;
use crate::salient::SalientPoint;
use crate::similarity::Match;
use crate::{Error, Result};

/// The colour of salient points.
pub const POINT_COLOUR: Rgb<u8> = Rgb([230, 20, 20]);

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
        Self::upright(yaw, pitch, UpAxis::Y)
    }

    /// [`Camera::new`] for a model whose up axis is `up`.
    pub fn upright(yaw: f64, pitch: f64, up: UpAxis) -> Self {
        Self {
            rotation: DMat3::from_rotation_x(pitch) * DMat3::from_rotation_y(yaw) * up.upright(),
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

/// What a picture shows, in normalised coordinates: coloured triangles, each hidden only
/// behind what is more than its tolerance in front of it, then salient points on top.
#[derive(Default)]
struct Scene {
    triangles: Vec<([DVec3; 3], [f64; 3], f64)>,
    points: Vec<DVec3>,
}

impl Scene {
    /// `size`-pixel tiles of the scene, one per camera, side by side.
    fn picture(&self, cameras: &[Camera], size: u32) -> RgbImage {
        let radius = (size as f64 / 90.0).max(2.5);
        let mut image = RgbImage::from_pixel(size * cameras.len() as u32, size, BACKGROUND);
        for (k, camera) in cameras.iter().enumerate() {
            let mut tile = Tile::new(size);
            for &(t, colour, tolerance) in &self.triangles {
                tile.triangle(camera, t, colour, tolerance);
            }
            for &p in &self.points {
                tile.point(camera, p, radius);
            }
            tile.paste(&mut image, k as u32 * size);
        }
        image
    }

    /// A preview's triangles coloured by `colour` of their region.
    fn of_preview(preview: &Preview, colour: impl Fn(u16) -> [f64; 3], points: bool) -> Self {
        let corner = |v: u32| preview.normalised(preview.positions[v as usize]);
        Scene {
            triangles: preview
                .triangles
                .iter()
                .zip(preview.triangle_regions())
                .map(|(t, region)| (t.map(corner), colour(region), 0.0))
                .collect(),
            points: if points {
                preview
                    .points
                    .iter()
                    .map(|&p| preview.normalised(p))
                    .collect()
            } else {
                Vec::new()
            },
        }
    }
}

impl Tile {
    /// Copies the covered pixels into `image` at column `x0`.
    fn paste(&self, image: &mut RgbImage, x0: u32) {
        for (i, (&c, &z)) in self.colour.iter().zip(&self.depth).enumerate() {
            if z > f64::NEG_INFINITY {
                let (x, y) = (i as u32 % self.size, i as u32 / self.size);
                let rgb = c.map(|v| (v * 255.0).round().clamp(0.0, 255.0) as u8);
                image.put_pixel(x0 + x, y, Rgb(rgb));
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
    let surface = mesh
        .triangles
        .iter()
        .map(|t| (t.map(|v| mesh.positions[v as usize]), SURFACE, 0.0));
    let regions = points.iter().enumerate().flat_map(|(i, point)| {
        point
            .region
            .triangles
            .iter()
            .map(move |t| (*t, region_colour(i), OVERLAY_TOLERANCE))
    });
    Scene {
        triangles: surface.chain(regions).collect(),
        points: points
            .iter()
            .map(|p| mesh.positions[p.vertex as usize])
            .collect(),
    }
    .picture(cameras, size)
}

/// The view of thumbnails: a three-quarter view from slightly above.
fn thumbnail_camera(up: UpAxis) -> Camera {
    Camera::upright(35f64.to_radians(), 20f64.to_radians(), up)
}

/// Pictures up to this size are drawn at twice it and scaled down, which smooths edges.
const SUPERSAMPLED_UP_TO: u32 = 512;

/// `draw` at `size`, supersampled when small enough.
fn smooth(size: u32, width: u32, draw: impl Fn(u32) -> RgbImage) -> RgbImage {
    if size > SUPERSAMPLED_UP_TO {
        return draw(size);
    }
    let large = draw(2 * size);
    image::imageops::resize(&large, width * size, size, FilterType::Triangle)
}

/// A `size`-pixel picture of a preview; with `features`, its regions coloured and salient
/// points marked.
pub fn thumbnail(preview: &Preview, size: u32, features: bool, up: UpAxis) -> RgbImage {
    let scene = Scene::of_preview(
        preview,
        |region| match region {
            NO_REGION => SURFACE,
            r if features => region_colour(r as usize),
            _ => SURFACE,
        },
        features,
    );
    smooth(size, 1, |s| scene.picture(&[thumbnail_camera(up)], s))
}

/// Two models side by side, `size` pixels each, matched regions in the same colours: `a`'s
/// region `i` in colour `i`, `b`'s region `j` in the colour of the region of `a` that sent it
/// the most mass (`matches` are the EMD's flows from `a`'s features to `b`'s).
pub fn comparison(
    (a, b): (&Preview, &Preview),
    matches: &[Match],
    size: u32,
    (up_a, up_b): (UpAxis, UpAxis),
) -> RgbImage {
    let mut best: Vec<(f64, usize)> = vec![(0.0, usize::MAX); b.points.len()];
    for m in matches {
        if m.q < best.len() && m.mass > best[m.q].0 {
            best[m.q] = (m.mass, m.p);
        }
    }
    let left = Scene::of_preview(
        a,
        |r| match r {
            NO_REGION => SURFACE,
            r => region_colour(r as usize),
        },
        true,
    );
    let right = Scene::of_preview(
        b,
        |r| match best.get(r as usize) {
            Some(&(_, i)) if i != usize::MAX => region_colour(i),
            _ => SURFACE,
        },
        true,
    );
    smooth(size, 2, |s| {
        let mut image = RgbImage::new(2 * s, s);
        // Each model stands on its own up axis.
        let left = left.picture(&[thumbnail_camera(up_a)], s);
        let right = right.picture(&[thumbnail_camera(up_b)], s);
        image::imageops::replace(&mut image, &left, 0, 0);
        image::imageops::replace(&mut image, &right, s as i64, 0);
        image
    })
}

/// A picture as PNG bytes.
pub fn png(image: &RgbImage) -> Vec<u8> {
    let mut bytes = Vec::new();
    PngEncoder::new(&mut bytes)
        .write_image(
            image.as_raw(),
            image.width(),
            image.height(),
            image::ColorType::Rgb8,
        )
        .expect("encoding a picture in memory cannot fail");
    bytes
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

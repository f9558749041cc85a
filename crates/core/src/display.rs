//! How a model is shown, the same in pictures ([`crate::render`]) and in the display meshes of
//! the 3D view ([`crate::preview`]): which of its axes is up, and the colours of its surface
//! and salient regions.

use crate::format::Format;
use glam::DMat3;
use serde::{Deserialize, Serialize};

/// Region colours, in point order and repeating; none is red, so points stay visible.
const REGION_COLOURS: [[f64; 3]; 6] = [
    [1.0, 0.85, 0.2],
    [0.25, 0.75, 0.95],
    [0.45, 0.85, 0.35],
    [0.7, 0.5, 0.95],
    [1.0, 0.6, 0.2],
    [0.3, 0.9, 0.8],
];
/// The colour of the surface outside salient regions.
pub const SURFACE: [f64; 3] = [0.78, 0.78, 0.8];
/// Which of a model's axes points up. Only pictures turn by it, never signatures. glTF's is
/// +y by its specification, and 3MF and STL are +z by convention (3D printing, CAD); other
/// formats do not say ([`UpAxis::of_format`]), so a library chooses for its own, and for each
/// model when it must.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    #[default]
    Y,
    Z,
}

impl UpAxis {
    /// Turns the model so that its up axis is +y.
    pub fn upright(self) -> DMat3 {
        match self {
            UpAxis::Y => DMat3::IDENTITY,
            UpAxis::Z => DMat3::from_rotation_x(-std::f64::consts::FRAC_PI_2),
        }
    }

    pub const ALL: [UpAxis; 2] = [UpAxis::Y, UpAxis::Z];

    /// The up axis a format fixes by specification or convention; `None` where it is the
    /// library's choice (OBJ, PLY, OFF).
    pub fn of_format(format: Format) -> Option<UpAxis> {
        match format {
            Format::Gltf | Format::Glb => Some(UpAxis::Y),
            Format::Stl | Format::ThreeMf => Some(UpAxis::Z),
            Format::Obj | Format::Ply | Format::Off => None,
        }
    }

    /// `y` or `z`.
    pub fn parse(name: &str) -> Option<UpAxis> {
        UpAxis::ALL.into_iter().find(|up| up.as_str() == name)
    }

    pub fn as_str(self) -> &'static str {
        match self {
            UpAxis::Y => "y",
            UpAxis::Z => "z",
        }
    }
}

/// The colour of salient region `i` (regions in feature order, the palette repeating).
pub fn region_colour(i: usize) -> [f64; 3] {
    REGION_COLOURS[i % REGION_COLOURS.len()]
}

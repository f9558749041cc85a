//! Shape descriptors other than ECC: the D2 shape distribution (Osada et al.), used for the
//! salient regions (SPEC §4) and as the global baseline (SPEC §6), the Light Field
//! Descriptor (Chen et al.), the view-based baseline (SPEC §6), and the geodesic
//! distributions, an intrinsic part of the hybrid (SPEC §9).

pub mod d2;
pub mod geodesic;
pub mod lfd;
pub mod patch;

pub use d2::{d2_histogram, histogram_l1};
pub use geodesic::GeodesicDescriptor;
pub use lfd::LightFieldDescriptor;

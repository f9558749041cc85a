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

/// `Σ term(aᵢ, bᵢ)` over single-precision vectors, accumulated in eight lanes and the lanes
/// added in double precision: a plain sum is a chain of dependent additions (floating-point
/// addition is not associative, so the compiler keeps its order), the lanes vectorise. For
/// the distances and bounds every entry of a ranking computes.
pub(crate) fn lane_sum(a: &[f32], b: &[f32], term: impl Fn(f32, f32) -> f32) -> f64 {
    let mut lanes = [0.0f32; 8];
    let (x, y) = (a.chunks_exact(8), b.chunks_exact(8));
    let rest = x.remainder().iter().zip(y.remainder());
    for (x, y) in x.zip(y) {
        for ((lane, &x), &y) in lanes.iter_mut().zip(x).zip(y) {
            *lane += term(x, y);
        }
    }
    lanes.iter().map(|&s| s as f64).sum::<f64>()
        + rest.map(|(&x, &y)| term(x, y) as f64).sum::<f64>()
}

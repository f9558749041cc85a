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

/// The least and the greatest of each coordinate over a set of vectors of one length: a box
/// holding them all. The box's point nearest to a query bounds the query's distance to each
/// of them ([`Span::lane_sum`]), which is how a ranking rejects a block of entries at once.
#[derive(Debug, Clone, PartialEq)]
pub struct Span {
    least: Box<[f32]>,
    greatest: Box<[f32]>,
}

/// The longest vector [`Span::lane_sum`] bounds; a longer span bounds by 0.
const SPAN_MAX: usize = 64;

impl Span {
    pub fn of(values: &[f32]) -> Self {
        Self {
            least: values.into(),
            greatest: values.into(),
        }
    }

    /// Widens the box to hold `values`; false when their length is not the box's.
    pub fn widen(&mut self, values: &[f32]) -> bool {
        if values.len() != self.least.len() {
            return false;
        }
        for ((least, greatest), &x) in self.least.iter_mut().zip(&mut self.greatest).zip(values) {
            *least = least.min(x);
            *greatest = greatest.max(x);
        }
        true
    }

    /// [`lane_sum`] of `query` and the box's point nearest to it, so never above
    /// `lane_sum(query, v, term)` for a `v` in the box when `term(q, x)` grows with `|q − x|`:
    /// each coordinate of the nearest point is no farther from the query's, also in floating
    /// point (a difference is monotone in each operand), and the sum is taken in the same
    /// order.
    pub fn lane_sum(&self, query: &[f32], term: impl Fn(f32, f32) -> f32) -> f64 {
        let n = query.len().min(self.least.len());
        if n > SPAN_MAX {
            return 0.0;
        }
        let mut nearest = [0.0f32; SPAN_MAX];
        for (((near, &q), &least), &greatest) in nearest
            .iter_mut()
            .zip(query)
            .zip(&self.least)
            .zip(&self.greatest)
        {
            // Not `clamp`, which panics on a NaN.
            *near = q.max(least).min(greatest);
        }
        lane_sum(query, &nearest[..n], term)
    }
}

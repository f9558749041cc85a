//! A model as vectors whose L1 distance orders models like the hybrid's bound: the first
//! stage of a ranking kept outside the in-memory index (pgvector, issue #40), whose
//! candidates are then ranked by their exact distance.
//!
//! Each part of the hybrid's first bound ([`super::fuse`] of its parts' bounds) is an L1
//! distance of a few numbers, once scaled by the part's weight over its scale: the geodesic
//! distance is the L1 distance of cumulative sums
//! ([`crate::descriptor::geodesic::Cumulative`]); the light field bound the least over pairs
//! of light fields of the L1 distance of their view sums
//! ([`crate::descriptor::lfd::LfdSummary::lower_bound`]); the global D2 distance is half an L1. The
//! ECC part's centroid bound ([`crate::similarity::centroid_bound`]) is an L2 distance of mean
//! ECC values, of which the L1 distance over the waves' count is a lower bound (`‖x‖₂ ≥
//! ‖x‖₁/√n` and its `1/√n`), plus an L1 distance of mean region D2 bins.
//!
//! A model is one row per light field ([`Layout::PerLightField`]), each with the other parts
//! repeated: the least L1 distance over a query's and a model's rows is then the hybrid's
//! bound, a minimum over rotations no single vector can hold. Or one row, its light fields
//! pooled ([`Layout::Pooled`]): their mean, nearly the same for any rotation as the views
//! cover the sphere, which orders models close to the bound at a tenth of the rows.

use crate::descriptor::geodesic::{self, GeodesicDescriptor};
use crate::descriptor::lfd::COEFFICIENTS;
use crate::params::{Params, SimilarityParams, Term};
use crate::signature::Signature;
use crate::similarity::Features;

/// How a model's light fields become rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// One row per light field.
    PerLightField,
    /// One row, the light fields' mean.
    Pooled,
}

/// The rows of `signature` under the hybrid's weights in `params`, all of one length for one
/// set of extraction parameters; `None` for a signature without a light field or geodesic
/// descriptor (made before they existed: stale, and ranked once re-extracted).
pub fn rows(
    signature: &Signature,
    params: &SimilarityParams,
    layout: Layout,
) -> Option<Vec<Vec<f32>>> {
    let h = &params.hybrid;
    let unit = |term: Term| term.weight / term.scale;
    let fields: Vec<[f32; COEFFICIENTS]> = signature.lfd.as_ref()?.summary().fields().collect();
    let geodesic: &GeodesicDescriptor = signature.geodesic.as_ref()?;
    // The parts every row repeats.
    let mut common = Vec::new();
    let cumulative = geodesic.cumulative();
    let values = cumulative.values();
    let scale = unit(h.geodesic) / values.len() as f64;
    common.extend(values.iter().map(|&v| (f64::from(v) * scale) as f32));
    let scale = unit(h.d2) / 2.0;
    common.extend(signature.d2.iter().map(|&v| (f64::from(v) * scale) as f32));
    // Zeros for a model without features: every row of one extraction is as long.
    let (ecc, d2) = Features::of(&signature.features).centroid();
    let extraction = &signature.params;
    let padded = |v: Vec<f32>, len: usize| v.into_iter().chain(std::iter::repeat(0.0)).take(len);
    let w = params.ecc_weight;
    let waves = extraction.ecc.waves;
    let scale = unit(h.ecc) * w / waves as f64;
    common.extend(padded(ecc, waves).map(|v| (f64::from(v) * scale) as f32));
    let scale = unit(h.ecc) * (1.0 - w) / 2.0;
    common.extend(padded(d2, extraction.d2.bins).map(|v| (f64::from(v) * scale) as f32));

    let scale = unit(h.lfd);
    let row = |field: &[f32]| -> Vec<f32> {
        field
            .iter()
            .map(|&v| (f64::from(v) * scale) as f32)
            .chain(common.iter().copied())
            .collect()
    };
    Some(match layout {
        Layout::PerLightField => fields.iter().map(|f| row(f)).collect(),
        Layout::Pooled => {
            let n = fields.len() as f32;
            let mean: Vec<f32> = (0..fields[0].len())
                .map(|c| fields.iter().map(|f| f[c]).sum::<f32>() / n)
                .collect();
            vec![row(&mean)]
        }
    })
}

/// The length of the rows of signatures extracted with `params`.
pub fn dimensions(params: &Params) -> usize {
    COEFFICIENTS + 2 * geodesic::BINS + 2 * params.d2.bins + params.ecc.waves
}

/// The L1 distance of two rows.
fn l1(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| f64::from((x - y).abs()))
        .sum()
}

/// The least L1 distance over pairs of rows: the first stage's distance of two models.
pub fn distance(a: &[Vec<f32>], b: &[Vec<f32>]) -> f64 {
    a.iter()
        .flat_map(|x| b.iter().map(move |y| l1(x, y)))
        .fold(f64::INFINITY, f64::min)
}

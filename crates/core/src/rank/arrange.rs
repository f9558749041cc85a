//! The order of an index's entries ([`super::Index::arrange`]): entries near each other by
//! the hybrid's first bound in the same blocks ([`BLOCK`]), so that a block's boxes
//! ([`super::columns::BlockSpan`]) are small and a ranking rejects all of a block at once.
//! The order is a k-d tree's leaves: each node splits its entries, at a multiple of `BLOCK`,
//! along the coordinate on which they spread the most in the bound's units.

use std::cmp::Reverse;
use std::collections::BTreeMap;

use super::columns::{Columns, BLOCK};
use crate::params::SimilarityParams;

/// Entries of a node its widest coordinate is chosen on.
const SAMPLE: usize = 64;

/// The arranged order: the entry to put at each place. Entries whose parts differ (one lacks
/// a part, or has it at another length) go to separate groups, the largest first: it starts
/// at a block's start, so its tree's leaves are whole blocks.
pub fn order(entries: &Columns, params: &SimilarityParams) -> Vec<usize> {
    let mut groups: BTreeMap<_, Vec<usize>> = BTreeMap::new();
    for (i, entry) in entries.iter().enumerate() {
        let parts = entry.parts();
        let lengths = parts.vectors.map(|v| v.map_or(0, <[f32]>::len));
        groups
            .entry((lengths, parts.sketch.is_some()))
            .or_default()
            .push(i);
    }
    let mut groups: Vec<Vec<usize>> = groups.into_values().collect();
    groups.sort_by_key(|group| Reverse(group.len()));
    let units = units(params);
    for group in &mut groups {
        split(entries, group, &units);
    }
    groups.concat()
}

/// What a change of one coordinate of each of the vectors of
/// [`super::columns::Parts`] adds to the hybrid's bound, per unit: the geodesic distance is a
/// mean over its values, the ECC centroid's a root mean square (taken here as a mean) and its
/// D2 half an L1 distance.
fn units(params: &SimilarityParams) -> [f32; 3] {
    let terms = params.hybrid.terms();
    let part = |k: usize| (terms[k].weight / terms[k].scale) as f32;
    let w = params.ecc_weight as f32;
    [part(3), part(0) * w, part(0) * (1.0 - w) / 2.0]
}

fn split(entries: &Columns, node: &mut [usize], units: &[f32; 3]) {
    if node.len() <= BLOCK {
        return;
    }
    let coordinate =
        |i: usize, (k, c): (usize, usize)| entries.get(i).parts().vectors[k].map_or(0.0, |v| v[c]);
    let lengths = (entries.get(node[0]).parts().vectors).map(|v| v.map_or(0, <[f32]>::len));
    let step = node.len().div_ceil(SAMPLE);
    let spread = |d: (usize, usize)| {
        let (least, greatest) = node
            .iter()
            .step_by(step)
            .map(|&i| coordinate(i, d))
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, g), x| {
                (l.min(x), g.max(x))
            });
        (greatest - least) * units[d.0] / lengths[d.0] as f32
    };
    let widest = (0..3)
        .flat_map(|k| (0..lengths[k]).map(move |c| (k, c)))
        .max_by(|&a, &b| spread(a).total_cmp(&spread(b)));
    let Some(widest) = widest else {
        return;
    };
    let middle = (node.len() / 2).div_ceil(BLOCK) * BLOCK;
    node.select_nth_unstable_by(middle, |&a, &b| {
        coordinate(a, widest)
            .total_cmp(&coordinate(b, widest))
            .then(a.cmp(&b))
    });
    let (left, right) = node.split_at_mut(middle);
    rayon::join(
        || split(entries, left, units),
        || split(entries, right, units),
    );
}

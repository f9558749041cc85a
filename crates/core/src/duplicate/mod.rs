//! Near-duplicates (`docs/results/duplicates/`): models that are one asset whatever file, format, position,
//! size, orientation or triangulation they came in — what a file hash misses.
//!
//! Finding them is filter and verify. Candidates are models close by the global descriptors
//! the ranking index already holds: the light field distance (every disguised copy of the
//! tuning halves was within 0.020 of its model, and few other models are) after the cheap D2
//! distance and the LFD's lower bounds — by a ranking for one upload, by a sweep over the
//! index for a whole library ([`crate::rank::Index::near_pairs`]), never all pairs. Each
//! candidate is then verified on the meshes themselves ([`Shape`]): a retrieval distance
//! cannot tell "the same class" from "the same shape". Another pose of an articulated model
//! moves a limb farther than [`DuplicateParams::largest`] allows, so it is another asset; a
//! morph of one mesh (the same faces, vertices moved) moves the vertices of a remeshed copy
//! off the other surface ([`DuplicateParams::vertices_per_edge`]). A smoothing subdivision
//! (Loop's) moves a surface less than a simplification does, and is told by its mesh instead
//! (`subdivision`).

mod shape;
mod subdivision;

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

pub use shape::{Alignment, Deviation, Distances, Reach, Shape, Spread};

use crate::params::DuplicateParams;

/// Why two models are taken for one asset, strongest first (the order of the variants).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Evidence {
    /// The same bytes (the upload's content hash).
    IdenticalFile,
    /// The same welded mesh, up to translation, uniform scale and float round-off: another
    /// export, another format, other units.
    IdenticalGeometry,
    /// The same surface up to rigid motion, uniform scale and remeshing.
    SameShape,
    /// The same surface seen in a mirror (and not the same under any rotation): a left part
    /// and its right counterpart, usually two assets.
    Mirrored,
}

impl Evidence {
    pub const ALL: [Evidence; 4] = [
        Evidence::IdenticalFile,
        Evidence::IdenticalGeometry,
        Evidence::SameShape,
        Evidence::Mirrored,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Evidence::IdenticalFile => "identical_file",
            Evidence::IdenticalGeometry => "identical_geometry",
            Evidence::SameShape => "same_shape",
            Evidence::Mirrored => "mirrored",
        }
    }
}

impl fmt::Display for Evidence {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Evidence {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Evidence::ALL
            .into_iter()
            .find(|e| e.as_str() == s)
            .ok_or_else(|| {
                format!("unknown evidence {s:?}: identical_file, identical_geometry, same_shape or mirrored")
            })
    }
}

/// What verification found between two models.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    pub evidence: Evidence,
    /// 1 for identical, falling to 0 at the evidence's threshold: `1 − d / threshold`, `d`
    /// the deviation the evidence was judged on ([`DuplicateParams`]).
    pub score: f64,
}

impl Verdict {
    pub const IDENTICAL_FILE: Verdict = Verdict {
        evidence: Evidence::IdenticalFile,
        score: 1.0,
    };
}

/// Whether `a` and `b` (two different files) are one asset, and on what evidence.
pub fn verify(a: &Shape, b: &Shape, params: &DuplicateParams) -> Option<Verdict> {
    judge(
        (a.geometry_deviation(b, params.geometry), a.split_of(b)),
        |reach, surfaces_pass| a.align(b, reach, surfaces_pass),
        a.coarser(b),
        params,
    )
}

/// The verdict on a geometry deviation within `params.geometry` ([`Shape::geometry_deviation`];
/// `None` when beyond) and whether either mesh is the other's triangles split in four
/// ([`Shape::split_of`]), and, when these do not decide, an alignment ([`Shape::align`], the
/// costly part, made only then and told how far a sample may lie and which surface
/// statistics pass), `spacing` the coarser mesh's typical triangle size ([`Shape::coarser`]).
/// The score is 1 less the largest share of its limit a statistic used.
pub fn judge(
    (deviation, split): (Option<f64>, bool),
    alignment: impl FnOnce(Reach, &dyn Fn(&Deviation) -> bool) -> Alignment,
    spacing: f64,
    params: &DuplicateParams,
) -> Option<Verdict> {
    if let Some(d) = deviation {
        return Some(Verdict {
            evidence: Evidence::IdenticalGeometry,
            score: 1.0 - d / params.geometry,
        });
    }
    // Each limit is met in either unit ([`Distances`]): the mean within its limit in RMS radii
    // (or the coarser mesh's typical triangle size), or within `mean_per_triangle` sizes of
    // the triangles where the samples lie and `mean_at_most` RMS radii; every sample within
    // its [`Reach`], chosen per sample.
    let mean = params.surface_limits(spacing).0;
    let within = |s: &Distances| {
        let mean = (s.absolute.mean / mean).min(
            (s.local.mean / params.mean_per_triangle).max(s.absolute.mean / params.mean_at_most),
        );
        mean.max(s.reached.max)
    };
    // A simplification may delete small pieces whole (a tree's leaves): forgiven when they
    // are few, and only for a copy whose every vertex lies on the other surface — two designs
    // that differ by a small part (CAPOD's guitars m109 and m119) have vertices off it.
    let forgivable = |d: &Deviation| d.deleted <= params.deleted;
    let surfaces = |d: &Deviation| {
        if forgivable(d) && d.vertices.max <= params.vertices_per_edge {
            within(&d.kept)
        } else {
            within(&d.surfaces)
        }
    };
    let verdict = |evidence, d: Deviation| {
        // A split that moved the surface is a smoothing subdivision: another asset, however
        // little it moved (`subdivision`).
        if split && d.vertices.max > params.split_vertices_per_edge {
            return None;
        }
        let used = surfaces(&d).max(d.vertices.p90 / params.vertices_per_edge);
        (used <= 1.0).then_some(Verdict {
            evidence,
            score: 1.0 - used,
        })
    };
    let Alignment { rotated, mirrored } = alignment(Reach::new(params, spacing), &|d| {
        within(&d.surfaces) <= 1.0 || (forgivable(d) && within(&d.kept) <= 1.0)
    });
    // One mesh edited — the coarser the finer's own triangles less some parts, or the same
    // mesh with vertices moved — is another design, whatever its mirror image (a symmetric
    // model's fits as well) says.
    let edited = |d: &Deviation| d.added > params.added || d.moved > params.moved;
    if edited(&rotated) {
        return None;
    }
    verdict(Evidence::SameShape, rotated)
        .or_else(|| (!edited(&mirrored)).then(|| verdict(Evidence::Mirrored, mirrored))?)
}

/// Two models found to be one asset.
#[derive(Debug, Clone, PartialEq)]
pub struct Link<Id> {
    pub a: Id,
    pub b: Id,
    pub verdict: Verdict,
}

/// Models linked, directly or through others, by evidence at least as strong as asked.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Group<Id> {
    /// In order.
    pub ids: Vec<Id>,
    /// The weakest evidence that holds the group together: each member is joined to the
    /// others by links at least this strong.
    pub evidence: Evidence,
    /// For each of `ids`, the best score of its links within the group.
    pub scores: Vec<f64>,
}

/// The groups that `links` of evidence `min` or stronger make, in the order of their first
/// ids. Strongest links join first (Kruskal), so a group's evidence is the weakest link its
/// members need, not the weakest link among them.
pub fn groups<Id: Ord + Clone>(links: &[Link<Id>], min: Evidence) -> Vec<Group<Id>> {
    let mut kept: Vec<&Link<Id>> = links.iter().filter(|l| l.verdict.evidence <= min).collect();
    kept.sort_by(|x, y| {
        (x.verdict.evidence, y.verdict.score, &x.a, &x.b)
            .partial_cmp(&(y.verdict.evidence, x.verdict.score, &y.a, &y.b))
            .expect("scores are finite")
    });
    let mut number: BTreeMap<&Id, usize> = BTreeMap::new();
    for l in &kept {
        for id in [&l.a, &l.b] {
            let n = number.len();
            number.entry(id).or_insert(n);
        }
    }
    let mut parent: Vec<usize> = (0..number.len()).collect();
    let mut weakest: Vec<Option<Evidence>> = vec![None; number.len()];
    let mut best = vec![0.0f64; number.len()];
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for l in &kept {
        let (i, j) = (number[&l.a], number[&l.b]);
        best[i] = best[i].max(l.verdict.score);
        best[j] = best[j].max(l.verdict.score);
        let (ri, rj) = (root(&mut parent, i), root(&mut parent, j));
        if ri != rj {
            parent[rj] = ri;
            let joined = [weakest[ri], weakest[rj], Some(l.verdict.evidence)];
            weakest[ri] = joined.into_iter().flatten().max();
        }
    }
    let mut members: HashMap<usize, Vec<(&Id, f64)>> = HashMap::new();
    for (&id, &i) in &number {
        let r = root(&mut parent, i);
        members.entry(r).or_default().push((id, best[i]));
    }
    let mut groups: Vec<Group<Id>> = members
        .into_iter()
        .map(|(r, mut m)| {
            m.sort_by(|x, y| x.0.cmp(y.0));
            Group {
                ids: m.iter().map(|(id, _)| (*id).clone()).collect(),
                evidence: weakest[r].expect("a group has a link"),
                scores: m.iter().map(|&(_, s)| s).collect(),
            }
        })
        .collect();
    groups.sort_by(|x, y| x.ids[0].cmp(&y.ids[0]));
    groups
}

#[cfg(test)]
mod tests {
    use super::*;

    fn link(a: &str, b: &str, evidence: Evidence, score: f64) -> Link<String> {
        Link {
            a: a.into(),
            b: b.into(),
            verdict: Verdict { evidence, score },
        }
    }

    #[test]
    fn groups_join_through_links_and_keep_the_weakest_needed() {
        let links = [
            link("c", "a", Evidence::IdenticalGeometry, 0.9),
            link("a", "d", Evidence::SameShape, 0.5),
            link("c", "d", Evidence::IdenticalFile, 1.0),
            link("x", "y", Evidence::Mirrored, 0.7),
        ];
        let all = groups(&links, Evidence::Mirrored);
        assert_eq!(all.len(), 2);
        assert_eq!(all[0].ids, ["a", "c", "d"]);
        // a–c (geometry) and c–d (file) join all three; a–d (shape) is not needed.
        assert_eq!(all[0].evidence, Evidence::IdenticalGeometry);
        assert_eq!(all[0].scores, [0.9, 1.0, 1.0]);
        assert_eq!(all[1].ids, ["x", "y"]);
        let strong = groups(&links, Evidence::IdenticalGeometry);
        assert_eq!(strong.len(), 1);
        assert_eq!(groups(&links, Evidence::IdenticalFile)[0].ids, ["c", "d"]);
    }

    #[test]
    fn evidence_reads_and_orders() {
        assert_eq!("same_shape".parse::<Evidence>(), Ok(Evidence::SameShape));
        assert!("same".parse::<Evidence>().is_err());
        assert!(Evidence::IdenticalFile < Evidence::Mirrored);
    }
}

//! `salient eval partial`: how well a piece of a model finds its source (`docs/results/partial/`). Every
//! model of a half gets three parts — each the surface inside a ball of 30–50 % of its radius
//! around a random surface point, its largest connected piece ([`cut`]) — queried against the
//! whole collection: by salient features ([`salient_core::rank::Query::Part`]), the same with its best
//! `similarity.partial.verified` registered into each model's surface ([`Probe::residual`]:
//! what `mode=partial` serves), as a whole model (the default method, as `/v1/search` without
//! `mode`), and by patch descriptors ([`salient_core::descriptor::patch`]) alone and verified (not
//! stored or served). Reported: how often the source ranks first and within the top 5, and
//! how often the first result is of the source's class.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::time::Instant;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use super::report::{score, write, write_json, Table};
use super::retrieval::signatures;
use super::study::Half;
use super::{LabelledCollection, Progress};
use salient_core::collection::SignatureCache;
use salient_core::descriptor::d2::sample_surface;
use salient_core::descriptor::patch::{Layout, Packed};
use salient_core::mesh::cut::cut;
use salient_core::mesh::prepare::normalisation;
use salient_core::mesh::{load_path, RawMesh};
use salient_core::params::{Limits, Params, PartialParams};
use salient_core::partial::{by_residual, nearest_first, stored_patches, Part, Probe, Target};
use salient_core::pipeline::compute;
use salient_core::rank::{Hit, Index, Method, Ranking, Request, Search};
use salient_core::salient::area as triangle_area;
use salient_core::Result;

/// Results within which the source's rank is recorded.
const DEPTH: usize = 10;

/// The ball around the cut point, as a fraction of the model's radius (SPEC §1.4's).
const BALL: std::ops::Range<f64> = 0.3..0.5;

/// Parts cut from each model: one would leave the rates at the mercy of a few cuts.
const PARTS: usize = 3;

/// Random cut points tried per part before giving up on it.
const ATTEMPTS: usize = 8;

/// A part keeps at least this share of its model's area, and at most this share: a sliver
/// says nothing, and a ball that swallows the model is not a part.
const AREA_SHARE: std::ops::RangeInclusive<f64> = 0.02..=0.8;

/// What the benchmark found.
#[derive(Debug, Clone, Serialize)]
pub struct PartialReport {
    pub collection: String,
    pub half: String,
    pub models: usize,
    pub params: PartialParams,
    /// One row per search mode: `partial` and `whole`.
    pub modes: Vec<ModeResult>,
    /// Per class of the source, the partial mode's rates.
    pub per_class: BTreeMap<String, ModeResult>,
    pub parts: Vec<PartResult>,
    /// Models no part could be cut from (every attempt outside [`AREA_SHARE`]).
    pub uncut: Vec<String>,
    pub seconds: Seconds,
}

/// The rates of one search mode over the parts.
#[derive(Debug, Clone, Serialize)]
pub struct ModeResult {
    pub mode: String,
    pub parts: usize,
    pub source_first: f64,
    pub source_top5: f64,
    pub class_first: f64,
}

/// One part and where each mode ranked its source.
#[derive(Debug, Clone, Serialize)]
pub struct PartResult {
    pub source: String,
    pub class: String,
    /// The ball's radius over the model's.
    pub ball: f64,
    /// The part's share of the model's area, and its radius over the model's.
    pub area_share: f64,
    pub size: f64,
    pub vertices: usize,
    /// Salient features at each size the part was described at.
    pub features: Vec<(f64, usize)>,
    /// What each mode found.
    pub partial: Found,
    pub whole: Found,
    pub patches: Found,
    /// The fit's own best verified (what was served before patches were stored).
    pub fit_verified: Found,
    /// What `mode=partial` serves.
    pub verified: Found,
    /// The part's registration residual in its source, when a ranking verified it.
    pub source_residual: Option<f64>,
    /// The size the part fitted its source at, when ranked.
    pub fitted_scale: Option<f64>,
}

/// What one search mode found for a part.
#[derive(Debug, Clone, Serialize)]
pub struct Found {
    /// The source's rank (1 = first) within the first [`DEPTH`].
    pub rank: Option<usize>,
    /// The first result.
    pub first: String,
}

impl Found {
    fn of(hits: &[Hit], source: &str) -> Self {
        Self {
            rank: hits.iter().position(|h| h.id == source).map(|r| r + 1),
            first: hits.first().map(|h| h.id.clone()).unwrap_or_default(),
        }
    }
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct Seconds {
    pub signatures: f64,
    /// Describing the parts at every size, and as whole models.
    pub describe_parts: f64,
    pub search: f64,
}

/// A cut part and what it was cut from.
struct Cut {
    source: usize,
    ball: f64,
    area_share: f64,
    size: f64,
    raw: RawMesh,
}

/// Runs the benchmark on `half` of `collection`, against all of it. Deterministic: the cut of
/// each model is seeded by its position.
pub fn run(
    collection: &LabelledCollection,
    half: Half,
    params: &Params,
    cache: &SignatureCache,
    limits: &Limits,
    progress: &dyn Progress,
) -> Result<PartialReport> {
    let clock = Instant::now();
    let (stored, _) = signatures(collection, cache, params, limits, None, progress)?;
    let mut index = Index::new(params.similarity.clone());
    for (model, signature) in collection.models.iter().zip(&stored) {
        index
            .insert(model.id.as_str(), signature)
            .map_err(|e| salient_core::Error::Io {
                path: std::env::temp_dir(),
                source: e,
            })?;
    }
    progress.start("patches", collection.models.len());
    let targets: Vec<(Target, Packed)> = collection
        .models
        .par_iter()
        .map(|m| {
            let raw = load_path(&m.path, limits)?;
            progress.advance(&m.id);
            Ok((
                Target::new(&raw, &params.mesh)?,
                stored_patches(&raw, &params.mesh)?,
            ))
        })
        .collect::<Result<_>>()?;
    progress.finish();
    let signatures_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let chosen = half.models(collection);
    progress.start("parts", chosen.len());
    let cuts: Vec<Vec<Cut>> = chosen
        .par_iter()
        .map(|&i| {
            let raw = load_path(&collection.models[i].path, limits)?;
            progress.advance(&collection.models[i].id);
            Ok(cut_parts(i, &raw))
        })
        .collect::<Result<_>>()?;
    progress.finish();
    let uncut = chosen
        .iter()
        .zip(&cuts)
        .filter(|(_, c)| c.is_empty())
        .map(|(&i, _)| collection.models[i].id.clone())
        .collect();
    let cuts: Vec<Cut> = cuts.into_iter().flatten().collect();
    let scales = &params.similarity.partial.scales;
    progress.start("describe", cuts.len());
    let described = cuts
        .par_iter()
        .map(|c| {
            let part = Part::extract(&c.raw, params, scales, &params.similarity)?;
            let whole = compute(&c.raw, params)?;
            progress.advance(&collection.models[c.source].id);
            Ok((part, whole, Probe::new(&c.raw)))
        })
        .collect::<Result<Vec<_>>>()?;
    progress.finish();
    let describe_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let io = |e| salient_core::Error::Io {
        path: std::env::temp_dir(),
        source: e,
    };
    let position: BTreeMap<&str, usize> = collection
        .models
        .iter()
        .enumerate()
        .map(|(i, m)| (m.id.as_str(), i))
        .collect();
    let mut parts = Vec::with_capacity(cuts.len());
    for (c, (part, whole, probe)) in cuts.iter().zip(&described) {
        let model = &collection.models[c.source];
        let verified_count = params.similarity.partial.verified;
        // The stored patches of every model, nearest the part first (a library whose patches
        // are all made); none for a part without area.
        let by_patch: Vec<(f64, String)> = nearest_first(
            probe
                .as_ref()
                .map(|p| {
                    let part = Packed::piece(p.description());
                    collection
                        .models
                        .iter()
                        .zip(&targets)
                        .map(|(m, (_, packed))| (packed.nearest(&part), m.id.clone()))
                        .collect()
                })
                .unwrap_or_default(),
        );
        // What is served, and the same with the fit's own candidates (no model patched).
        let served = index
            .search(&Request::part(part, &by_patch, verified_count, DEPTH))
            .map_err(io)?;
        let fit = index
            .search(&Request::part(part, &[], verified_count, DEPTH))
            .map_err(io)?;
        let whole = index
            .search(&Request::model(whole, Method::default(), DEPTH))
            .map_err(io)?;
        // Each candidate of either ranking registered once.
        let candidates: BTreeSet<usize> = [&served, &fit]
            .into_iter()
            .flat_map(|r| r.hits.iter().take(r.candidates))
            .map(|h| position[h.id.as_str()])
            .collect();
        let residuals: BTreeMap<usize, f64> = candidates
            .into_par_iter()
            .map(|i| {
                let residual = probe
                    .as_ref()
                    .map_or(f64::INFINITY, |p| p.residual(&targets[i].0));
                (i, residual)
            })
            .collect();
        let residual = |h: &Hit| residuals[&position[h.id.as_str()]];
        let verify = |ranked: &Ranking| {
            let mut verified = ranked.hits.clone();
            by_residual(&mut verified[..ranked.candidates], |h| Some(residual(h)));
            verified.truncate(DEPTH);
            verified
        };
        // The fit alone: its own ranking, the candidates taken from the fit.
        let fit_alone = &fit.hits[..DEPTH.min(fit.hits.len())];
        let patches_alone: Vec<Hit> = by_patch
            .iter()
            .take(DEPTH)
            .map(|(distance, id)| Hit {
                id: id.clone(),
                distance: *distance,
                part_scale: None,
            })
            .collect();
        let found = Found::of(fit_alone, &model.id);
        parts.push(PartResult {
            source: model.id.clone(),
            class: model.class.clone(),
            ball: c.ball,
            area_share: c.area_share,
            size: c.size,
            vertices: c.raw.positions.len(),
            features: part.sizes().collect(),
            fitted_scale: found.rank.and_then(|r| fit.hits[r - 1].part_scale),
            partial: found,
            whole: Found::of(&whole.hits, &model.id),
            patches: Found::of(&patches_alone, &model.id),
            fit_verified: Found::of(&verify(&fit), &model.id),
            verified: Found::of(&verify(&served), &model.id),
            source_residual: residuals.get(&c.source).copied(),
        });
    }
    let search_seconds = clock.elapsed().as_secs_f64();

    let class_of: BTreeMap<&str, &str> = collection
        .models
        .iter()
        .map(|m| (m.id.as_str(), m.class.as_str()))
        .collect();
    let rates = |mode: &str, of: &[&PartResult], found: fn(&PartResult) -> &Found| {
        let share = |hits: usize| hits as f64 / of.len().max(1) as f64;
        let ranks = || of.iter().map(|p| found(p).rank);
        ModeResult {
            mode: mode.to_string(),
            parts: of.len(),
            source_first: share(ranks().filter(|&r| r == Some(1)).count()),
            source_top5: share(ranks().filter(|r| r.is_some_and(|r| r <= 5)).count()),
            class_first: share(
                of.iter()
                    .filter(|p| class_of.get(found(p).first.as_str()) == Some(&p.class.as_str()))
                    .count(),
            ),
        }
    };
    let all: Vec<&PartResult> = parts.iter().collect();
    let modes = vec![
        rates("partial", &all, |p| &p.partial),
        rates("whole", &all, |p| &p.whole),
        rates("patches", &all, |p| &p.patches),
        rates("fit, verified", &all, |p| &p.fit_verified),
        rates("verified", &all, |p| &p.verified),
    ];
    let mut by_class = BTreeMap::<&str, Vec<&PartResult>>::new();
    for p in &parts {
        by_class.entry(p.class.as_str()).or_default().push(p);
    }
    let per_class = by_class
        .into_iter()
        .map(|(class, of)| (class.to_string(), rates("partial", &of, |p| &p.partial)))
        .collect();
    Ok(PartialReport {
        collection: collection.root.display().to_string(),
        half: format!("{half:?}"),
        models: collection.models.len(),
        params: params.similarity.partial.clone(),
        modes,
        per_class,
        parts,
        uncut,
        seconds: Seconds {
            signatures: signatures_seconds,
            describe_parts: describe_seconds,
            search: search_seconds,
        },
    })
}

/// The parts of model `source`: [`PARTS`] balls of [`BALL`] × the model's radius around
/// random points of its surface, [`ATTEMPTS`] tries each for a part within [`AREA_SHARE`].
fn cut_parts(source: usize, raw: &RawMesh) -> Vec<Cut> {
    let mut rng = ChaCha8Rng::seed_from_u64(0x9a27 ^ source as u64);
    let (radius, area) = extent(raw);
    let triangles: Vec<[DVec3; 3]> = raw
        .triangles
        .iter()
        .map(|t| t.map(|v| raw.positions[v as usize]))
        .collect();
    let mut parts = Vec::with_capacity(PARTS);
    for _ in 0..ATTEMPTS * PARTS {
        if parts.len() == PARTS {
            break;
        }
        let Some(point) = sample_surface(&triangles, 1, &mut rng) else {
            break;
        };
        let point = point[0];
        let ball = rng.gen_range(BALL);
        let Some(part) = cut(raw, point, ball * radius) else {
            continue;
        };
        let (part_radius, part_area) = extent(&part);
        let area_share = part_area / area;
        if AREA_SHARE.contains(&area_share) {
            parts.push(Cut {
                source,
                ball,
                area_share,
                size: part_radius / radius,
                raw: part,
            });
        }
    }
    parts
}

/// The radius SPEC §1.4 normalises by, and the area.
fn extent(raw: &RawMesh) -> (f64, f64) {
    let (_, scale) = normalisation(&raw.positions, &raw.triangles);
    let area = raw
        .triangles
        .iter()
        .map(|t| triangle_area(&t.map(|v| raw.positions[v as usize])))
        .sum();
    (1.0 / scale, area)
}

impl PartialReport {
    pub fn markdown(&self) -> String {
        let mut modes = Table::new([
            "mode",
            "parts",
            "source first",
            "source in top 5",
            "class first",
        ]);
        for m in &self.modes {
            modes.row([
                m.mode.clone(),
                m.parts.to_string(),
                score(m.source_first),
                score(m.source_top5),
                score(m.class_first),
            ]);
        }
        let mut classes = Table::new([
            "class",
            "parts",
            "source first",
            "source in top 5",
            "class first",
        ]);
        for (class, m) in &self.per_class {
            classes.row([
                class.clone(),
                m.parts.to_string(),
                score(m.source_first),
                score(m.source_top5),
                score(m.class_first),
            ]);
        }
        let sizes: Vec<f64> = self.parts.iter().map(|p| p.size).collect();
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
        };
        format!(
            "# Partial retrieval: {} ({} half)\n\n\
             Three parts per model of the half (each the surface inside a ball of 30–50 % of the model's \
             radius around a random surface point, its largest piece), queried against all {} \
             models as a part by salient features (`partial`: sizes {:?}), by the stored patch \
             descriptors (`patches`: each model described by pieces cut around {} surface \
             points at {:?} of its radius, the part as one piece), as a whole model (`whole`: \
             the default method), and with the best {} registered into each model's surface and \
             re-ranked by residual: the fit's best (`fit, verified`) or the patches' best \
             (`verified`: what `mode=partial` serves). Median part size {:.2} of its model's \
             radius, median share of its area {:.2}; {} models gave no part.\n\n{}\n\n## Partial mode per class\n\n{}\n\n\
             Seconds: signatures {:.1}, describing the parts {:.1}, searching {:.1}.\n",
            self.collection,
            self.half,
            self.models,
            self.params.scales,
            Layout::STORED.centres,
            Layout::STORED.radii,
            self.params.verified,
            median(sizes),
            median(self.parts.iter().map(|p| p.area_share).collect()),
            self.uncut.len(),
            modes.markdown(),
            classes.markdown(),
            self.seconds.signatures,
            self.seconds.describe_parts,
            self.seconds.search,
        )
    }

    pub fn write(&self, dir: &Path) -> Result<()> {
        write_json(&dir.join("partial.json"), self)?;
        write(&dir.join("partial.md"), self.markdown())
    }
}

//! `salient eval partial`: how well a piece of a model finds its source (`docs/results/partial/`).
//! Parts are cut from every model of a half by two protocols: today's (three balls of 30–50 %
//! of the model's radius around random surface points, [`Protocol::Ball`]) and one part per
//! share of the surface ([`Protocol::Share`]: 5, 15, 30 and 50 %), each its largest connected
//! piece ([`cut`]). Each is queried against the whole collection by [`part_search::search`] (what
//! `mode=partial` serves), and, for today's protocol, also by its salient-feature fit alone,
//! its stored patches alone and as a whole model. Reported per protocol: how often the source
//! ranks first and within the top 5, and how often the first result is of the source's class;
//! featureless parts apart too: plain ones, within 2 % of their size of a plane or a sphere
//! ([`salient_core::partial::Probe::is_plain`]). (Extraction finds a salient feature on any
//! piece, a flat one too, so "no salient feature detected" would count none.)

use std::collections::BTreeMap;
use std::convert::Infallible;
use std::path::Path;
use std::sync::Arc;
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
use salient_core::descriptor::patch::{Layout, Packed, PackedPiece};
use salient_core::mesh::cut::cut;
use salient_core::mesh::prepare::normalisation;
use salient_core::mesh::{load_path, RawMesh};
use salient_core::params::{Limits, Params, PartialParams};
use salient_core::part_search::{self, Library, PartQuery, SearchError};
use salient_core::partial::{stored_patches, Target};
use salient_core::pipeline::compute;
use salient_core::rank::{Index, Method, Request, Scope, Search};
use salient_core::salient::area as triangle_area;
use salient_core::Result;

/// Results within which the source's rank is recorded.
const DEPTH: usize = 10;

/// Today's protocol: the ball around the cut point, as a fraction of the model's radius
/// (SPEC §1.4's), three parts a model.
const BALL: std::ops::Range<f64> = 0.3..0.5;
const BALL_PARTS: usize = 3;

/// The shares of the surface parts are cut to, one part a model each.
const SHARES: [f64; 4] = [0.05, 0.15, 0.3, 0.5];

/// A part cut to a share keeps between these multiples of it.
const SHARE_TOLERANCE: std::ops::RangeInclusive<f64> = 0.8..=1.25;

/// Bisection steps on the ball's radius for a share.
const BISECTIONS: usize = 16;

/// Random cut points tried per part before giving up on it.
const ATTEMPTS: usize = 8;

/// A ball part keeps at least this share of its model's area, and at most this share: a
/// sliver says nothing, and a ball that swallows the model is not a part.
const AREA_SHARE: std::ops::RangeInclusive<f64> = 0.02..=0.8;

/// How a part was cut.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Protocol {
    /// A ball of [`BALL`] × the model's radius around a random surface point.
    Ball,
    /// The share of the model's surface, within [`SHARE_TOLERANCE`].
    Share(f64),
}

impl Protocol {
    fn all() -> impl Iterator<Item = Self> {
        std::iter::once(Self::Ball).chain(SHARES.map(Self::Share))
    }

    fn name(self) -> String {
        match self {
            Self::Ball => "ball 30–50 % of the radius".to_string(),
            Self::Share(share) => format!("{:.0} % of the surface", share * 100.0),
        }
    }
}

/// What the benchmark found.
#[derive(Debug, Clone, Serialize)]
pub struct PartialReport {
    pub collection: String,
    pub half: String,
    pub models: usize,
    pub params: PartialParams,
    /// Per protocol, what `mode=partial` serves: all parts, and the featureless ones.
    pub protocols: Vec<ProtocolResult>,
    /// Parts of at least 15 % of the surface together (the shares' protocols).
    pub from_15_percent: Rates,
    /// Today's protocol by each search mode.
    pub modes: Vec<Rates>,
    /// Per class of the source, what is served for parts of at least 15 % of the surface.
    pub per_class: BTreeMap<String, Rates>,
    pub parts: Vec<PartResult>,
    /// Per protocol, models no part could be cut from.
    pub uncut: Vec<(Protocol, Vec<String>)>,
    pub seconds: Seconds,
}

/// What is served for one protocol's parts.
#[derive(Debug, Clone, Serialize)]
pub struct ProtocolResult {
    pub protocol: Protocol,
    pub all: Rates,
    pub featureless: Rates,
    /// The median of the parts' area shares.
    pub median_share: f64,
    /// Parts the search refused (counted as misses).
    pub refused: usize,
}

/// The rates of one search over a set of parts.
#[derive(Debug, Clone, Serialize)]
pub struct Rates {
    pub mode: String,
    pub parts: usize,
    pub source_first: f64,
    pub source_top5: f64,
    pub class_first: f64,
}

/// One part and where each search ranked its source.
#[derive(Debug, Clone, Serialize)]
pub struct PartResult {
    pub source: String,
    pub class: String,
    pub protocol: Protocol,
    /// The ball's radius over the model's.
    pub ball: f64,
    /// The part's share of the model's area, and its radius over the model's.
    pub area_share: f64,
    pub size: f64,
    pub vertices: usize,
    /// Salient features at each size the part was described at.
    pub features: Vec<(f64, usize)>,
    /// Plain: near a plane or a sphere.
    pub featureless: bool,
    /// What `mode=partial` serves ([`part_search::search`]), and its wall time.
    pub verified: Found,
    pub search_ms: f64,
    /// The part's registration residual in its source, when it was verified.
    pub source_residual: Option<f64>,
    /// Today's protocol only: the salient-feature fit alone, the stored patches alone, the
    /// part as a whole model.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub compared: Option<Compared>,
    /// Why the part could not be searched (a miss in every rate).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refused: Option<String>,
}

/// The other searches of a part of today's protocol.
#[derive(Debug, Clone, Serialize)]
pub struct Compared {
    pub partial: Found,
    pub patches: Found,
    pub whole: Found,
}

/// What one search found for a part.
#[derive(Debug, Clone, Serialize)]
pub struct Found {
    /// The source's rank (1 = first) within the first [`DEPTH`].
    pub rank: Option<usize>,
    /// The first result.
    pub first: String,
}

impl Found {
    fn of<'a>(ids: impl IntoIterator<Item = &'a str>, source: &str) -> Self {
        let ids: Vec<&str> = ids.into_iter().take(DEPTH).collect();
        Self {
            rank: ids.iter().position(|&id| id == source).map(|r| r + 1),
            first: ids.first().map(|id| id.to_string()).unwrap_or_default(),
        }
    }
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct Seconds {
    pub signatures: f64,
    /// Describing the parts at every size, and as whole models.
    pub describe_parts: f64,
    pub search: f64,
    /// The median and 90th percentile of one served search, wall.
    pub search_p50: f64,
    pub search_p90: f64,
}

/// A cut part and what it was cut from.
struct Cut {
    source: usize,
    protocol: Protocol,
    ball: f64,
    area_share: f64,
    size: f64,
    raw: RawMesh,
}

/// The collection as the evaluation holds it: every model's target and stored patches.
struct Loaded<'a> {
    collection: &'a LabelledCollection,
    targets: BTreeMap<&'a str, (Arc<Target>, Packed)>,
}

impl Library for Loaded<'_> {
    type Error = Infallible;

    fn nearest(
        &self,
        piece: &PackedPiece,
    ) -> std::result::Result<Vec<(Vec<f64>, String)>, Infallible> {
        Ok(self
            .targets
            .iter()
            .map(|(id, (_, packed))| (packed.nearest(piece), id.to_string()))
            .collect())
    }

    fn target(&self, id: &str) -> std::result::Result<Option<Arc<Target>>, Infallible> {
        Ok(self.targets.get(id).map(|(t, _)| t.clone()))
    }
}

impl Loaded<'_> {
    /// Every model by its stored patches, in the order a search takes its candidates.
    fn by_patch(&self, query: &PartQuery) -> Vec<(f64, &str)> {
        let Some(probe) = &query.probe else {
            return Vec::new();
        };
        let piece = Packed::piece(probe.description());
        part_search::candidates(
            self.collection
                .models
                .iter()
                .map(|m| (self.targets[m.id.as_str()].1.nearest(&piece), m.id.as_str()))
                .collect(),
        )
    }
}

/// Runs the benchmark on `half` of `collection`, against all of it. Deterministic: the cuts of
/// each model are seeded by its position.
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
    let io = |e| salient_core::Error::Io {
        path: std::env::temp_dir(),
        source: e,
    };
    let mut index = Index::new(params.similarity.clone());
    for (model, signature) in collection.models.iter().zip(&stored) {
        index.insert(model.id.as_str(), signature).map_err(io)?;
    }
    progress.start("patches", collection.models.len());
    let targets = collection
        .models
        .par_iter()
        .map(|m| {
            let raw = load_path(&m.path, limits)?;
            progress.advance(&m.id);
            let target = Target::new(&raw, &params.mesh)?;
            Ok((
                m.id.as_str(),
                (Arc::new(target), stored_patches(&raw, &params.mesh)?),
            ))
        })
        .collect::<Result<_>>()?;
    let library = Loaded {
        collection,
        targets,
    };
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
            Ok(Protocol::all()
                .flat_map(|p| cut_parts(i, &raw, p))
                .collect())
        })
        .collect::<Result<_>>()?;
    progress.finish();
    let uncut = Protocol::all()
        .map(|p| {
            let models = chosen
                .iter()
                .zip(&cuts)
                .filter(|(_, c)| !c.iter().any(|c| c.protocol == p))
                .map(|(&i, _)| collection.models[i].id.clone());
            (p, models.collect())
        })
        .collect();
    let cuts: Vec<Cut> = cuts.into_iter().flatten().collect();
    let scales = &params.similarity.partial.scales;
    progress.start("describe", cuts.len());
    // A part the service would refuse (too few vertices once welded: a low-poly model's
    // triangle or two) is a miss, its error kept.
    let described: Vec<std::result::Result<_, String>> = cuts
        .par_iter()
        .map(|c| {
            let described = PartQuery::extract(&c.raw, params, scales).and_then(|query| {
                let whole = match c.protocol {
                    Protocol::Ball => Some(compute(&c.raw, params)?),
                    Protocol::Share(_) => None,
                };
                Ok((query, whole))
            });
            progress.advance(&collection.models[c.source].id);
            described.map_err(|e| e.to_string())
        })
        .collect();
    progress.finish();
    let describe_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let verified_count = params.similarity.partial.verified;
    let mut parts = Vec::with_capacity(cuts.len());
    progress.start("search", cuts.len());
    for (c, described) in cuts.iter().zip(&described) {
        let model = &collection.models[c.source];
        let mut result = PartResult {
            source: model.id.clone(),
            class: model.class.clone(),
            protocol: c.protocol,
            ball: c.ball,
            area_share: c.area_share,
            size: c.size,
            vertices: c.raw.positions.len(),
            features: Vec::new(),
            featureless: false,
            verified: Found::of([], &model.id),
            search_ms: 0.0,
            source_residual: None,
            compared: None,
            refused: None,
        };
        let (query, whole) = match described {
            Ok(described) => described,
            Err(error) => {
                result.refused = Some(error.clone());
                result.compared = (c.protocol == Protocol::Ball).then(|| Compared {
                    partial: Found::of([], &model.id),
                    patches: Found::of([], &model.id),
                    whole: Found::of([], &model.id),
                });
                progress.advance(&model.id);
                parts.push(result);
                continue;
            }
        };
        let started = Instant::now();
        let served = part_search::search(
            query,
            &index,
            Scope::default(),
            &library,
            verified_count,
            DEPTH,
        )
        .map_err(|e| match e {
            SearchError::Index(e) => io(e),
        })?;
        result.search_ms = started.elapsed().as_secs_f64() * 1e3;
        if let Some(whole) = whole {
            let fit = index
                .search(&Request::part(&query.part, &[], 0, DEPTH))
                .map_err(io)?;
            let whole = index
                .search(&Request::model(whole, Method::default(), DEPTH))
                .map_err(io)?;
            result.compared = Some(Compared {
                partial: Found::of(fit.hits.iter().map(|h| h.id.as_str()), &model.id),
                patches: Found::of(
                    library.by_patch(query).into_iter().map(|(_, id)| id),
                    &model.id,
                ),
                whole: Found::of(whole.hits.iter().map(|h| h.id.as_str()), &model.id),
            });
        }
        result.features = query.part.sizes().collect();
        result.featureless = query.probe.as_ref().is_none_or(|p| p.is_plain());
        result.verified = Found::of(served.hits.iter().map(|h| h.id.as_str()), &model.id);
        result.source_residual = served
            .hits
            .iter()
            .find(|h| h.id == model.id)
            .and_then(|h| h.residual());
        progress.advance(&model.id);
        parts.push(result);
    }
    progress.finish();
    let search_seconds = clock.elapsed().as_secs_f64();

    let class_of: BTreeMap<&str, &str> = collection
        .models
        .iter()
        .map(|m| (m.id.as_str(), m.class.as_str()))
        .collect();
    let rates = |mode: &str, of: &[&PartResult], found: &dyn Fn(&PartResult) -> &Found| {
        let share = |hits: usize| hits as f64 / of.len().max(1) as f64;
        let ranks = || of.iter().map(|p| found(p).rank);
        Rates {
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
    let protocols = Protocol::all()
        .map(|protocol| {
            let of: Vec<&PartResult> = parts.iter().filter(|p| p.protocol == protocol).collect();
            let featureless: Vec<&PartResult> =
                of.iter().copied().filter(|p| p.featureless).collect();
            ProtocolResult {
                protocol,
                all: rates("served", &of, &served),
                featureless: rates("served, featureless", &featureless, &served),
                median_share: median(of.iter().map(|p| p.area_share).collect()),
                refused: of.iter().filter(|p| p.refused.is_some()).count(),
            }
        })
        .collect();
    let large: Vec<&PartResult> = parts
        .iter()
        .filter(|p| matches!(p.protocol, Protocol::Share(s) if s >= 0.15))
        .collect();
    let ball: Vec<&PartResult> = parts
        .iter()
        .filter(|p| p.protocol == Protocol::Ball)
        .collect();
    let modes = vec![
        rates("partial", &ball, &|p| &compared(p).partial),
        rates("whole", &ball, &|p| &compared(p).whole),
        rates("patches", &ball, &|p| &compared(p).patches),
        rates("verified", &ball, &served),
    ];
    let mut by_class = BTreeMap::<&str, Vec<&PartResult>>::new();
    for &p in &large {
        by_class.entry(p.class.as_str()).or_default().push(p);
    }
    let per_class = by_class
        .into_iter()
        .map(|(class, of)| (class.to_string(), rates("served", &of, &served)))
        .collect();
    let times: Vec<f64> = parts
        .iter()
        .filter(|p| p.refused.is_none())
        .map(|p| p.search_ms / 1e3)
        .collect();
    Ok(PartialReport {
        collection: collection.root.display().to_string(),
        half: format!("{half:?}"),
        models: collection.models.len(),
        params: params.similarity.partial.clone(),
        protocols,
        from_15_percent: rates("served", &large, &served),
        modes,
        per_class,
        uncut,
        seconds: Seconds {
            signatures: signatures_seconds,
            describe_parts: describe_seconds,
            search: search_seconds,
            search_p50: median(times.clone()),
            search_p90: quantile(times, 0.9),
        },
        parts,
    })
}

/// What `mode=partial` serves for a part.
fn served(p: &PartResult) -> &Found {
    &p.verified
}

/// The other searches of a part of today's protocol.
fn compared(p: &PartResult) -> &Compared {
    p.compared.as_ref().expect("ball parts are compared")
}

fn median(values: Vec<f64>) -> f64 {
    quantile(values, 0.5)
}

fn quantile(mut values: Vec<f64>, q: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    let at = ((values.len() as f64 - 1.0) * q).round() as usize;
    values.get(at).copied().unwrap_or(f64::NAN)
}

/// The parts of model `source` by `protocol`: [`BALL_PARTS`] balls of [`BALL`] × the
/// model's radius, or one part of the share; [`ATTEMPTS`] random surface points each.
fn cut_parts(source: usize, raw: &RawMesh, protocol: Protocol) -> Vec<Cut> {
    let seed = match protocol {
        // Today's seeds: the same parts as the reports before the shares.
        Protocol::Ball => 0x9a27 ^ source as u64,
        Protocol::Share(share) => 0x5a3e ^ source as u64 ^ ((share * 100.0) as u64) << 32,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (radius, area) = extent(raw);
    let triangles: Vec<[DVec3; 3]> = raw
        .triangles
        .iter()
        .map(|t| t.map(|v| raw.positions[v as usize]))
        .collect();
    let wanted = match protocol {
        Protocol::Ball => BALL_PARTS,
        Protocol::Share(_) => 1,
    };
    let mut parts = Vec::with_capacity(wanted);
    for _ in 0..ATTEMPTS * wanted {
        if parts.len() == wanted {
            break;
        }
        let Some(point) = sample_surface(&triangles, 1, &mut rng) else {
            break;
        };
        let point = point[0];
        let cut_at = |ball: f64| {
            let part = cut(raw, point, ball * radius)?;
            let (part_radius, part_area) = extent(&part);
            Some(Cut {
                source,
                protocol,
                ball,
                area_share: part_area / area,
                size: part_radius / radius,
                raw: part,
            })
        };
        let part = match protocol {
            Protocol::Ball => {
                cut_at(rng.gen_range(BALL)).filter(|c| AREA_SHARE.contains(&c.area_share))
            }
            Protocol::Share(share) => to_share(share, cut_at),
        };
        parts.extend(part);
    }
    parts
}

/// The cut whose share of the surface is within [`SHARE_TOLERANCE`] of `share`, by bisection
/// on the ball's radius (its largest piece grows with it); `None` when the point's piece
/// never reaches it (a model in many small pieces).
fn to_share(share: f64, cut_at: impl Fn(f64) -> Option<Cut>) -> Option<Cut> {
    let (mut low, mut high) = (0.0, 2.0);
    for _ in 0..BISECTIONS {
        let ball = (low + high) / 2.0;
        match cut_at(ball) {
            Some(c) if SHARE_TOLERANCE.contains(&(c.area_share / share)) => return Some(c),
            Some(c) if c.area_share > share => high = ball,
            _ => low = ball,
        }
    }
    None
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
        let header = [
            "parts",
            "count",
            "source first",
            "source in top 5",
            "class first",
        ];
        let row = |table: &mut Table, name: String, r: &Rates| {
            table.row([
                name,
                r.parts.to_string(),
                score(r.source_first),
                score(r.source_top5),
                score(r.class_first),
            ])
        };
        let mut protocols = Table::new(header);
        for p in &self.protocols {
            let refused = match p.refused {
                0 => String::new(),
                n => format!(", {n} refused"),
            };
            let name = format!(
                "{} (median {:.2}{refused})",
                p.protocol.name(),
                p.median_share
            );
            row(&mut protocols, name, &p.all);
            if p.featureless.parts > 0 {
                row(&mut protocols, "… featureless".to_string(), &p.featureless);
            }
        }
        row(
            &mut protocols,
            "**≥ 15 % of the surface**".to_string(),
            &self.from_15_percent,
        );
        let mut modes = Table::new(header);
        for m in &self.modes {
            row(&mut modes, m.mode.clone(), m);
        }
        let mut classes = Table::new(header);
        for (class, m) in &self.per_class {
            row(&mut classes, class.clone(), m);
        }
        let uncut: Vec<String> = self
            .uncut
            .iter()
            .filter(|(_, models)| !models.is_empty())
            .map(|(p, models)| format!("{}: {}", p.name(), models.len()))
            .collect();
        format!(
            "# Partial retrieval: {} ({} half)\n\n\
             Parts of every model of the half, searched against all {} models as \
             `mode=partial` serves them (sizes {:?}; the {} models nearest by stored patches, \
             {} pieces of {:?} of the radius each, registered and ranked by residual). Today's \
             protocol cuts three balls of 30–50 % of the model's radius a model; the others one \
             part a model of the share of the surface named (within 0.8–1.25 of it). \
             Featureless: within 2 % of the part's size of a plane or a sphere (RMS). A part the search refuses (too few vertices) counts as a miss. Models without a part: {}.\n\n{}\n\n\
             ## Today's protocol by search\n\n\
             `partial`: the salient-feature fit alone; `whole`: the part as a whole model (the \
             default method); `patches`: the stored patches alone; `verified`: served.\n\n{}\n\n\
             ## Parts of ≥ 15 % of the surface per class\n\n{}\n\n\
             Seconds: signatures {:.1}, describing the parts {:.1}, searching {:.1}; one search \
             p50 {:.2}, p90 {:.2} (wall, 2 threads).\n",
            self.collection,
            self.half,
            self.models,
            self.params.scales,
            self.params.verified,
            Layout::STORED.centres,
            Layout::STORED.radii,
            if uncut.is_empty() {
                "none".to_string()
            } else {
                uncut.join(", ")
            },
            protocols.markdown(),
            modes.markdown(),
            classes.markdown(),
            self.seconds.signatures,
            self.seconds.describe_parts,
            self.seconds.search,
            self.seconds.search_p50,
            self.seconds.search_p90,
        )
    }

    pub fn write(&self, dir: &Path) -> Result<()> {
        write_json(&dir.join("partial.json"), self)?;
        write(&dir.join("partial.md"), self.markdown())
    }
}

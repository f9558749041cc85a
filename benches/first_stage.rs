//! How well a first stage of vectors ([`salient_core::rank::vectors`]) finds the hybrid's top
//! 10 (issue #40): for each layout and oversampling `o`, the `10·o` models nearest a query by
//! the vectors' distance (exact, by brute force: the vectors' own recall, before an
//! approximate index such as pgvector's HNSW loses any), ranked by their exact distance, against
//! the exact ranking of the whole catalogue. Written to `target/salient-bench/first_stage.json`.
//!
//! `cargo bench --bench first_stage` (minutes on 2 cores). Needs the load bench's base store
//! (`cargo bench --bench load` makes it once) and `../shared/data` for the held-out queries
//! (every fifth model of both collections, whose copies are not stored). Two catalogues: the
//! load bench's, `SALIENT_FIRST_STAGE_SIZE` (100 000) perturbed copies of the base's models,
//! the hard case (among a model's ~217 near copies the top 10 is decided by the features' EMD,
//! which no bound orders: ~1000 candidates for 0.98); and the base itself, where no model has a
//! near copy. `SALIENT_FIRST_STAGE_DUMP=DIR` also writes the pooled vectors
//! and each query's exact top 10 as JSON lines, to try pgvector's indexes on them.
//! `SALIENT_FIRST_STAGE_QUERIES=tuning` asks with every fourth model of the base instead, against
//! copies of the others only: the protocol to choose vectors by.

#[path = "support/corpus.rs"]
mod corpus;

use std::collections::HashSet;
use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use salient_core::mesh::load::load_path;
use salient_core::params::Limits;
use salient_core::params::SimilarityParams;
use salient_core::pipeline::{signature_of_mesh, Extent};
use salient_core::rank::vectors::{self, Layout};
use salient_core::rank::{distance, hybrid_parts, Index, Method, Request, Search};
use salient_core::{Params, Signature};
use serde_json::{json, Value};

const K: usize = 10;
const OVERSAMPLING: [usize; 8] = [1, 2, 3, 5, 10, 20, 50, 100];
/// The layouts compared, each with its parts' weights as the hybrid's or calibrated.
const LAYOUTS: [(Layout, bool, &str); 3] = [
    (Layout::PerLightField, false, "per_light_field"),
    (Layout::Pooled, false, "pooled"),
    (Layout::Pooled, true, "pooled_calibrated"),
];

/// The similarity parameters whose weights make each part's vector distance its typical
/// exact distance rather than a bound of it: each weight times the median, over pairs of
/// `models`, of the part's exact distance over its pooled vectors' distance.
fn calibrated(models: &[(String, Signature)], params: &SimilarityParams) -> SimilarityParams {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let pairs: Vec<(usize, usize)> = (0..2000)
        .map(|_| {
            (
                rng.gen_range(0..models.len()),
                rng.gen_range(0..models.len()),
            )
        })
        .filter(|(a, b)| a != b)
        .collect();
    let mut out = params.clone();
    for k in 0..4 {
        if params.hybrid.terms()[k].weight == 0.0 {
            continue;
        }
        // Rows of this part alone: the others weigh nothing.
        let mut alone = params.clone();
        for (j, term) in alone.hybrid.terms_mut().into_iter().enumerate() {
            if j != k {
                term.weight = 0.0;
            }
        }
        let rows: Vec<Vec<Vec<f32>>> = models
            .par_iter()
            .map(|(_, s)| vectors::rows(s, &alone, Layout::Pooled).expect("current"))
            .collect();
        let mut ratios: Vec<f64> = pairs
            .par_iter()
            .filter_map(|&(a, b)| {
                let exact = hybrid_parts(&models[a].1, &models[b].1, params)[k]?;
                let term = params.hybrid.terms()[k];
                let vector = vectors::distance(&rows[a], &rows[b]) * term.scale / term.weight;
                (vector > 0.0).then(|| exact / vector)
            })
            .collect();
        ratios.sort_by(f64::total_cmp);
        let ratio = ratios[ratios.len() / 2];
        eprintln!("part {k}: exact over vector distance, median {ratio:.3}");
        out.hybrid.terms_mut()[k].weight *= ratio;
    }
    out
}

/// The held-out models of both collections (every fifth), extracted here.
fn queries(params: &Params) -> Vec<Signature> {
    let data = corpus::data_dir();
    let mut paths = Vec::new();
    for set in ["shrec07-watertight", "capod"] {
        let root = data.join(set);
        let labels = std::fs::read_to_string(root.join("labels.tsv")).unwrap_or_else(|e| {
            panic!("{}: {e}: the shared collections are needed", root.display())
        });
        for (i, line) in labels.lines().skip(1).enumerate() {
            if i % 5 == 4 {
                paths.push(root.join(line.split('\t').next().expect("a path")));
            }
        }
    }
    paths
        .iter()
        .map(|path: &std::path::PathBuf| {
            let raw = load_path(Path::new(path), &Limits::unlimited()).expect("loads");
            signature_of_mesh(raw, (params, Extent::Full)).expect("extracts")
        })
        .collect()
}

/// Recall@10 of the first stage at each oversampling, per layout, over `catalogue`.
fn measure(
    name: &str,
    catalogue: &[(String, Signature)],
    queries: &[Signature],
    (params, calibrated): (&Params, &SimilarityParams),
) -> Value {
    let similarity = &params.similarity;
    let dump = std::env::var_os("SALIENT_FIRST_STAGE_DUMP").map(std::path::PathBuf::from);
    let mut index = Index::new(similarity.clone());
    for (id, s) in catalogue {
        index.insert(id.as_str(), s).expect("shelved");
    }
    let truth: Vec<Vec<String>> = queries
        .iter()
        .map(|q| {
            let ranking = index
                .search(&Request::model(q, Method::Hybrid, K))
                .expect("ranks");
            ranking.hits.into_iter().map(|h| h.id).collect()
        })
        .collect();
    let mut out = serde_json::Map::new();
    for (layout, calibrate, layout_name) in LAYOUTS {
        let weights = if calibrate { calibrated } else { similarity };
        let rows: Vec<Vec<Vec<f32>>> = catalogue
            .par_iter()
            .map(|(_, s)| vectors::rows(s, weights, layout).expect("current signatures"))
            .collect();
        let most = K * OVERSAMPLING[OVERSAMPLING.len() - 1];
        // Per query: the catalogue's positions by the vectors' distance, nearest first.
        let nearest: Vec<Vec<usize>> = queries
            .iter()
            .map(|q| {
                let q = vectors::rows(q, weights, layout).expect("current");
                let mut scored: Vec<(f64, usize)> = rows
                    .par_iter()
                    .enumerate()
                    .map(|(i, r)| (vectors::distance(&q, r), i))
                    .collect();
                let cut = most.min(scored.len());
                scored.select_nth_unstable_by(cut - 1, |a, b| a.0.total_cmp(&b.0));
                scored.truncate(cut);
                scored.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                scored.into_iter().map(|(_, i)| i).collect()
            })
            .collect();
        if let (Some(dir), Layout::Pooled, false) = (&dump, layout, calibrate) {
            dump_vectors(
                &dir.join(name.replace(' ', "-")),
                catalogue,
                (&rows, weights),
                queries,
                &truth,
            );
        }
        let mut curve = Vec::new();
        for o in OVERSAMPLING {
            let recall: f64 = queries
                .par_iter()
                .zip(&nearest)
                .zip(&truth)
                .map(|((q, near), truth)| {
                    let mut ranked: Vec<(f64, &str)> = near
                        .iter()
                        .take(K * o)
                        .map(|&i| {
                            let (id, s) = &catalogue[i];
                            (distance(Method::Hybrid, q, s, similarity), id.as_str())
                        })
                        .collect();
                    ranked.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(b.1)));
                    let found: HashSet<&str> = ranked.iter().take(K).map(|r| r.1).collect();
                    truth
                        .iter()
                        .filter(|id| found.contains(id.as_str()))
                        .count() as f64
                        / truth.len().max(1) as f64
                })
                .sum::<f64>()
                / queries.len() as f64;
            eprintln!("{name:>10} {layout_name:>16} oversampling {o:>3} ({:>5} candidates): recall@10 {recall:.4}", K * o);
            curve.push(json!({"oversampling": o, "candidates": K * o, "recall_at_10": recall}));
        }
        out.insert(layout_name.to_string(), json!(curve));
    }
    json!({"models": catalogue.len(), "queries": queries.len(), "layouts": out})
}

/// `SALIENT_FIRST_STAGE_DUMP=DIR`: the pooled vectors of the catalogue and the queries, and
/// the exact top 10 of each query, as JSON lines in `DIR/<catalogue>/`, for trying approximate
/// indexes (pgvector's HNSW and IVFFlat) outside this bench: a query's recall@10 after exact
/// reranking is the share of its top 10 among the candidates an index returns.
fn dump_vectors(
    dir: &Path,
    catalogue: &[(String, Signature)],
    (rows, weights): (&[Vec<Vec<f32>>], &SimilarityParams),
    queries: &[Signature],
    truth: &[Vec<String>],
) {
    use std::io::Write;
    std::fs::create_dir_all(dir).expect("creates");
    let mut out = std::io::BufWriter::new(
        std::fs::File::create(dir.join("catalogue.jsonl")).expect("creates"),
    );
    for ((id, _), rows) in catalogue.iter().zip(rows) {
        writeln!(out, "{}", json!({"id": id, "v": rows[0]})).expect("writes");
    }
    out.flush().expect("writes");
    let mut out =
        std::io::BufWriter::new(std::fs::File::create(dir.join("queries.jsonl")).expect("creates"));
    for (q, truth) in queries.iter().zip(truth) {
        let v = vectors::rows(q, weights, Layout::Pooled).expect("current");
        writeln!(out, "{}", json!({"v": v[0], "truth": truth})).expect("writes");
    }
    out.flush().expect("writes");
}

fn main() {
    let params = Params::default();
    let base_path = corpus::base_store_path(true);
    assert!(
        base_path.with_extension("complete").exists(),
        "{} is missing: run `cargo bench --bench load` once to make the base store",
        base_path.display()
    );
    let base: Vec<(String, Signature)> = corpus::load_base(&base_path)
        .into_iter()
        .map(|(record, signature, _)| (record.id.to_string(), signature))
        .collect();
    let size: usize = std::env::var("SALIENT_FIRST_STAGE_SIZE").map_or(100_000, |s| {
        s.parse().expect("SALIENT_FIRST_STAGE_SIZE: a count")
    });
    // `tuning`: every fourth model of the base as a query, against copies of the others, to
    // choose among vectors without looking at the held-out models.
    let (queries, base) = match std::env::var("SALIENT_FIRST_STAGE_QUERIES").as_deref() {
        Ok("tuning") => {
            let (queries, rest): (Vec<_>, Vec<_>) =
                base.into_iter().enumerate().partition(|(i, _)| i % 4 == 0);
            let queries = queries.into_iter().map(|(_, (_, s))| s).collect();
            (queries, rest.into_iter().map(|(_, model)| model).collect())
        }
        Ok("held-out") | Err(_) => {
            eprintln!("extracting the held-out queries…");
            (queries(&params), base)
        }
        Ok(other) => panic!("SALIENT_FIRST_STAGE_QUERIES: held-out or tuning, not {other}"),
    };
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let copies: Vec<(String, Signature)> = (0..size)
        .map(|i| {
            let (_, s) = &base[i % base.len()];
            (format!("m{i:06}"), corpus::perturbed(s, &mut rng, 0.15))
        })
        .collect();
    // On the base: the held-out queries' models are not among them.
    let calibrated = calibrated(&base, &params.similarity);
    let report = json!({
        "calibration": calibrated.hybrid.terms().iter().zip(params.similarity.hybrid.terms())
            .map(|(c, t)| if t.weight > 0.0 { c.weight / t.weight } else { 0.0 })
            .collect::<Vec<f64>>(),
        "no_copies": measure("no copies", &base, &queries, (&params, &calibrated)),
        "copies": measure("copies", &copies, &queries, (&params, &calibrated)),
    });
    let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/salient-bench/first_stage.json");
    std::fs::write(&out, serde_json::to_string_pretty(&report).expect("JSON")).expect("writes");
    eprintln!("written to {}", out.display());
}

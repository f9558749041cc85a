//! Ranking with the centroid bound returns exactly the top k of a full scan (SPEC §5), and
//! the hybrid distance is the weighted sum of its parts (SPEC §9).

use crate::shapes;
use crate::synthetic;

use salient_core::params::{HybridParams, Term};
use salient_core::rank::{distance, fuse, Index, Method, Ranking, Request, Scope, Search};
use salient_core::similarity::{centroid_bound, lower_bound, Features, Summary};
use salient_core::{Params, Signature};

/// Checks that `index`'s pruned ranking of `query` is a full scan's, every entry counted as
/// evaluated or pruned; returns how many were pruned.
fn pruned_as_a_full_scan(
    index: &Index,
    query: &Signature,
    (k, method): (usize, Method),
    setting: &str,
) -> usize {
    let fast = index
        .search(&Request::model(query, method, k))
        .expect("ranks");
    let full = index
        .search(&Request::model(query, method, k).exhaustive())
        .expect("ranks");
    assert_eq!(fast.hits, full.hits, "{setting}");
    assert_eq!(fast.evaluated + fast.pruned, index.len());
    fast.pruned
}

#[test]
fn pruning_never_changes_the_top_k() {
    let collection = synthetic::collection(3000, 40, 1);
    let queries = synthetic::collection(12, 40, 2);
    let mut params = Params::default().similarity;
    let mut pruned = 0;
    for (penalty, w) in [(true, 0.5), (false, 0.5), (true, 0.9), (true, 0.0)] {
        params.penalty = penalty;
        params.ecc_weight = w;
        let mut index = Index::new(params.clone());
        for (id, s) in &collection {
            index.insert(id.clone(), s).expect("shelved");
        }
        for (_, query) in &queries {
            for k in [1, 5, 10, 50] {
                let setting = format!("k = {k}, penalty {penalty}, W = {w}");
                pruned += pruned_as_a_full_scan(&index, query, (k, Method::Ecc), &setting);
            }
        }
    }
    // The bound does work on a clustered collection: most entries are never solved.
    let total = 4 * queries.len() * 4 * collection.len();
    eprintln!("pruned {pruned} of {total}");
    assert!(pruned * 2 > total, "pruned only {pruned} of {total}");
}

#[test]
fn ties_are_broken_by_id_and_methods_agree_on_self() {
    let collection = synthetic::collection(50, 5, 3);
    let params = Params::default().similarity;
    let mut index = Index::new(params);
    let query = collection[7].1.clone();
    // Two copies of the query under ids that sort before and after it.
    index.insert("zz-copy", &query).expect("shelved");
    for (id, s) in &collection {
        index.insert(id.clone(), s).expect("shelved");
    }
    index.insert("aa-copy", &query).expect("shelved");
    for method in [Method::Ecc, Method::D2] {
        let ranking = index
            .search(&Request::model(&query, method, 3))
            .expect("ranks");
        let ids: Vec<&str> = ranking.hits.iter().map(|h| h.id.as_str()).collect();
        assert_eq!(ids, ["aa-copy", "m000007", "zz-copy"], "{method}");
        assert!(ranking.hits.iter().all(|h| h.distance == 0.0));
    }
    assert!(index
        .search(&Request::model(&query, Method::Ecc, 0))
        .expect("ranks")
        .hits
        .is_empty());
    let everything = index
        .search(&Request::model(&query, Method::Ecc, 1000))
        .expect("ranks");
    assert_eq!(everything.hits.len(), index.len());
    // `within` keeps the hits at most that far, in the same order.
    let cutoff = everything.hits[10].distance;
    let near = index
        .search(&Request::model(&query, Method::Ecc, 1000).within(cutoff))
        .expect("ranks");
    let expected: Vec<_> = everything
        .hits
        .iter()
        .filter(|h| h.distance <= cutoff)
        .collect();
    assert!(expected.len() >= 11 && expected.len() < everything.hits.len());
    assert_eq!(near.hits.iter().collect::<Vec<_>>(), expected);
}

/// The LFD method ranks by the light field distance and leaves out signatures without a
/// descriptor (stored before it existed) instead of ranking them last.
#[test]
fn lfd_ranks_by_light_field_distance_and_skips_signatures_without_one() {
    let params = Params::default();
    let signatures = generated_signatures(&params);
    let mut index = Index::new(params.similarity.clone());
    for (id, s) in &signatures {
        index.insert(*id, s).expect("shelved");
    }
    let mut old = signatures[3].1.clone();
    old.lfd = None;
    index.insert("old-bowl", &old).expect("shelved");
    let query = &signatures[0].1;
    let ranking = index
        .search(&Request::model(query, Method::Lfd, 10))
        .expect("ranks");
    let expected = in_order(signatures.iter().map(|(id, s)| {
        let lfd = query.lfd.as_ref().unwrap();
        (lfd.distance(s.lfd.as_ref().unwrap()), *id)
    }));
    let got = hits(&ranking);
    assert_eq!(got, expected);
    assert_eq!(got[0], (0.0, "cone"));
    assert_eq!(ranking.evaluated, 4);
    // The bound-pruned ranking is the full scan's for every k and query.
    for (_, query) in &signatures {
        for k in 1..=4 {
            let fast = index
                .search(&Request::model(query, Method::Lfd, k))
                .expect("ranks");
            let full = index
                .search(&Request::model(query, Method::Lfd, k).exhaustive())
                .expect("ranks");
            assert_eq!(fast.hits, full.hits, "k = {k}");
            assert_eq!(fast.evaluated + fast.pruned, 4);
        }
    }
    // A query without a descriptor ranks nothing.
    let mut bare = signatures[0].1.clone();
    bare.lfd = None;
    assert!(index
        .search(&Request::model(&bare, Method::Lfd, 3))
        .expect("ranks")
        .hits
        .is_empty());
}

fn generated_signatures(params: &Params) -> Vec<(&'static str, Signature)> {
    [
        ("cone", shapes::cone(0.5, 12, 24)),
        ("tube", shapes::tube(0.25, 12, 24)),
        ("star", shapes::star(3, &shapes::five_tips())),
        ("bowl", shapes::bowl(3)),
    ]
    .into_iter()
    .map(|(id, m)| (id, salient_core::pipeline::compute(&m, params).unwrap()))
    .collect()
}

/// `hybrid` is `Σ wᵢ dᵢ / sᵢ` over ECC, D2, LFD and geodesic; a part one side lacks is left out and the
/// rest scaled to the full weight; and the fused bounds of the parts never exceed it.
#[test]
fn hybrid_is_the_weighted_sum_of_its_parts_and_its_bound_never_exceeds_it() {
    let mut params = Params::default();
    params.similarity.hybrid = HybridParams {
        ecc: Term {
            weight: 1.0,
            scale: 0.2,
        },
        d2: Term {
            weight: 0.5,
            scale: 0.05,
        },
        lfd: Term {
            weight: 2.0,
            scale: 0.04,
        },
        geodesic: Term {
            weight: 0.5,
            scale: 0.1,
        },
        penalty_power: 1.0,
    };
    let p = &params.similarity;
    let features = |s: &Signature| Features::of(&s.features);
    let summary = |s: &Signature| Summary::of(&features(s), p);
    let signatures = generated_signatures(&params);
    for (a, sa) in &signatures {
        for (b, sb) in &signatures {
            let (ecc, d2, lfd, geodesic) = (
                distance(Method::Ecc, sa, sb, p),
                distance(Method::D2, sa, sb, p),
                distance(Method::Lfd, sa, sb, p),
                distance(Method::Geodesic, sa, sb, p),
            );
            let by_hand = ecc / 0.2 + 0.5 * d2 / 0.05 + 2.0 * lfd / 0.04 + 0.5 * geodesic / 0.1;
            let hybrid = distance(Method::Hybrid, sa, sb, p);
            assert!(
                (hybrid - by_hand).abs() <= 1e-12 * by_hand.max(1.0),
                "{a}–{b}"
            );

            let (summary_a, summary_b) = (summary(sa), summary(sb));
            let (ca, cb) = (features(sa).centroid(), features(sb).centroid());
            let (ca, cb) = (
                (&ca.0[..], &ca.1[..], summary_a.features()),
                (&cb.0[..], &cb.1[..], summary_b.features()),
            );
            let bound = fuse(
                &p.hybrid,
                [
                    Some(lower_bound((&summary_a, ca), (&summary_b, cb), p)),
                    Some(d2),
                    Some(
                        sa.lfd
                            .as_ref()
                            .unwrap()
                            .summary()
                            .lower_bound(&sb.lfd.as_ref().unwrap().summary()),
                    ),
                    Some(geodesic),
                ],
            );
            assert!(bound <= hybrid + 1e-12, "{a}–{b}: bound {bound} > {hybrid}");
            // The first pass's bound, from single-precision means, is never above the ECC
            // distance it bounds.
            assert!(centroid_bound(ca, cb, p) <= ecc, "{a}–{b}");

            let mut old = sb.clone();
            old.lfd = None;
            let without = (ecc / 0.2 + 0.5 * d2 / 0.05 + 0.5 * geodesic / 0.1) * 4.0 / 2.0;
            let partial = distance(Method::Hybrid, sa, &old, p);
            assert!(
                (partial - without).abs() <= 1e-12 * without.max(1.0),
                "{a}–{b}"
            );
            assert!(Method::Hybrid.ranks(&old) && !Method::Hybrid.ranks_fully(&old));
        }
    }
}

/// The weights come from the parameters (a configuration file), and bad ones are refused.
#[test]
fn hybrid_weights_load_from_parameters() {
    let d2_only: Params = serde_json::from_str(
        r#"{"similarity": {"hybrid": {"ecc": {"weight": 0, "scale": 1},
            "d2": {"weight": 1, "scale": 0.25}, "lfd": {"weight": 0, "scale": 1},
            "geodesic": {"weight": 0, "scale": 1}}}}"#,
    )
    .unwrap();
    d2_only.validate().unwrap();
    let signatures = generated_signatures(&d2_only);
    let mut index = Index::new(d2_only.similarity.clone());
    for (id, s) in &signatures {
        index.insert(*id, s).expect("shelved");
    }
    for (_, query) in &signatures {
        let hybrid = index
            .search(&Request::model(query, Method::Hybrid, 4))
            .expect("ranks");
        let d2 = index
            .search(&Request::model(query, Method::D2, 4))
            .expect("ranks");
        let ids = |r: &salient_core::rank::Ranking| {
            r.hits.iter().map(|h| h.id.clone()).collect::<Vec<_>>()
        };
        assert_eq!(ids(&hybrid), ids(&d2));
        for (h, d) in hybrid.hits.iter().zip(&d2.hits) {
            assert!((h.distance - d.distance / 0.25).abs() < 1e-12);
        }
    }
    for bad in [
        r#"{"similarity": {"hybrid": {"lfd": {"weight": -1, "scale": 1}}}}"#,
        r#"{"similarity": {"hybrid": {"ecc": {"weight": 1, "scale": 0}}}}"#,
        r#"{"similarity": {"hybrid": {"ecc": {"weight": 0, "scale": 1},
            "d2": {"weight": 0, "scale": 1}, "lfd": {"weight": 0, "scale": 1},
            "geodesic": {"weight": 0, "scale": 1}}}}"#,
        r#"{"similarity": {"penalty_power": -0.5}}"#,
        r#"{"similarity": {"hybrid": {"penalty_power": 5}}}"#,
    ] {
        let params: Params = serde_json::from_str(bad).unwrap();
        assert!(params.validate().is_err(), "{bad}");
    }
}

/// The default weights and three others, some leaving parts out (weight 0).
fn weightings() -> [HybridParams; 4] {
    let term = |weight, scale| Term { weight, scale };
    [
        HybridParams::default(),
        HybridParams {
            ecc: term(1.0, 0.3),
            d2: term(1.0, 0.1),
            lfd: term(1.0, 0.04),
            geodesic: term(0.5, 0.05),
            penalty_power: 0.5,
        },
        HybridParams {
            ecc: term(0.0, 1.0),
            d2: term(0.2, 0.1),
            lfd: term(1.0, 0.04),
            geodesic: term(0.0, 1.0),
            penalty_power: 1.0,
        },
        HybridParams {
            ecc: term(1.0, 0.3),
            d2: term(0.0, 1.0),
            lfd: term(0.0, 1.0),
            geodesic: term(1.0, 0.05),
            penalty_power: 0.0,
        },
    ]
}

/// The hybrid's bound-pruned ranking is the full scan's, whatever the weights, also over
/// entries that lack a light field descriptor.
#[test]
fn hybrid_pruning_never_changes_the_top_k() {
    let mut collection = synthetic::collection(1000, 20, 4);
    synthetic::with_descriptors(&mut collection, 20, 5);
    for (_, s) in collection.iter_mut().step_by(17) {
        s.lfd = None;
    }
    let mut queries = synthetic::collection(5, 20, 6);
    synthetic::with_descriptors(&mut queries, 20, 7);
    let mut pruned = 0;
    for hybrid in weightings() {
        let mut params = Params::default().similarity;
        params.hybrid = hybrid.clone();
        let mut index = Index::new(params);
        for (id, s) in &collection {
            index.insert(id.clone(), s).expect("shelved");
        }
        assert_eq!(
            index.coverage(Method::Hybrid, &Scope::default()).partial,
            1000usize.div_ceil(17)
        );
        // In insertion order, then arranged as the service does after a load (its blocks'
        // bounds reject most of them).
        for arranged in [false, true] {
            if arranged {
                index.arrange();
            }
            for (_, query) in &queries {
                for k in [1, 10, 50] {
                    let setting = format!("k = {k}, {hybrid:?}, arranged {arranged}");
                    pruned += pruned_as_a_full_scan(&index, query, (k, Method::Hybrid), &setting);
                }
            }
        }
    }
    let total = 2 * 4 * queries.len() * 3 * collection.len();
    eprintln!("pruned {pruned} of {total}");
    assert!(pruned * 2 > total, "pruned only {pruned} of {total}");
}

/// The default weights are those `salient eval tune` chose (`docs/results/tune/`).
#[test]
fn hybrid_defaults_are_the_tuned_setting() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/results/tune/params.json");
    let tuned: Params = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    assert_eq!(tuned.similarity.hybrid, HybridParams::default());
}

/// The index keeps its entries by column in chunks of 1 024 (and blocks of 32): arranging,
/// then inserting, replacing and removing across chunk boundaries keeps every entry findable
/// and every ranking equal to a full scan, and a scope leaves out the model asked about and
/// what its filter refuses.
#[test]
fn entries_survive_changes_across_chunks() {
    let mut collection = synthetic::collection(2600, 30, 8);
    synthetic::with_descriptors(&mut collection, 30, 9);
    let mut index = Index::new(Params::default().similarity);
    for (n, (id, s)) in collection.iter().enumerate() {
        if n == 2000 {
            index.arrange();
        }
        index.insert(id.clone(), s).expect("shelved");
    }
    // Removed: the first, the last, and a run across the first chunk boundary.
    let removed: Vec<&str> = [0, collection.len() - 1]
        .into_iter()
        .chain(1000..1060)
        .map(|i| collection[i].0.as_str())
        .collect();
    for id in &removed {
        assert!(index.remove(id));
        assert!(!index.remove(id), "{id} removed once");
    }
    // Replaced: an entry of the last chunk takes another's signature.
    let (replaced, with) = (&collection[2100].0, &collection[6].1);
    index.insert(replaced.clone(), with).expect("shelved");
    assert_eq!(index.len(), collection.len() - removed.len());
    for (n, (id, s)) in collection.iter().enumerate() {
        let kept = index.contains(id);
        assert_eq!(kept, !removed.contains(&id.as_str()), "{id}");
        // What an entry holds: its own signature is at distance 0 from it.
        if kept && n % 97 == 0 {
            let held = if id == replaced { with } else { s };
            let only = |other: &str| other == id;
            let scope = Scope {
                without: None,
                keep: Some(&only),
            };
            let found = index
                .search(&Request::model(held, Method::Hybrid, 1).scope(scope))
                .expect("ranks");
            assert_eq!(found.hits[0].distance, 0.0, "{id}");
        }
    }
    let query = &collection[6].1;
    for method in Method::ALL {
        let fast = index
            .search(&Request::model(query, method, 10))
            .expect("ranks");
        let full = index
            .search(&Request::model(query, method, 10).exhaustive())
            .expect("ranks");
        assert_eq!(fast.hits, full.hits, "{method}");
    }
    // `similar` of model 6 leaves it out, not its copy under another id.
    let even = |id: &str| id.ends_with(['0', '2', '4', '6', '8']);
    let asked = collection[6].0.as_str();
    let scope = Scope {
        without: Some(asked),
        keep: Some(&even),
    };
    let ranking = index
        .search(&Request::model(query, Method::Hybrid, 10).scope(scope))
        .expect("ranks");
    assert_eq!(ranking.hits[0].id, *replaced);
    assert_eq!(ranking.hits[0].distance, 0.0);
    assert!(ranking.hits.iter().all(|h| even(&h.id) && h.id != asked));
    let in_scope = collection
        .iter()
        .filter(|(id, _)| even(id) && id != asked && !removed.contains(&id.as_str()))
        .count();
    assert_eq!(ranking.evaluated + ranking.pruned, in_scope);
}

/// Light field descriptors live on the index's shelf (a file): an older copy of the index
/// keeps ranking with the descriptors of entries removed from a newer one, and slots freed
/// when the last copy goes are reused without mixing descriptors up.
#[test]
fn shelved_light_fields_outlive_the_entries_removed_from_newer_copies() {
    let mut collection = synthetic::collection(400, 20, 21);
    synthetic::with_descriptors(&mut collection, 20, 22);
    let (first, second) = collection.split_at(200);
    let params = Params::default().similarity;
    let mut index = Index::new(params.clone());
    for (id, s) in first {
        index.insert(id.clone(), s).expect("shelved");
    }
    let agrees = |index: &Index, members: &[(String, Signature)], query: &Signature| {
        let ranking = index
            .search(&Request::model(query, Method::Lfd, 5))
            .expect("ranks");
        let expected = in_order(
            members
                .iter()
                .map(|(id, s)| (distance(Method::Lfd, query, s, &params), id.as_str())),
        );
        assert_eq!(hits(&ranking), expected[..5]);
    };
    let older = index.clone();
    for (id, _) in &first[..100] {
        index.remove(id);
    }
    for (id, s) in &second[..100] {
        index.insert(id.clone(), s).expect("shelved");
    }
    let newer: Vec<_> = first[100..].iter().chain(&second[..100]).cloned().collect();
    for query in [&first[3].1, &second[5].1, &first[150].1] {
        agrees(&older, first, query);
        agrees(&index, &newer, query);
    }
    // The older copy's slots are free now; the next descriptors take them.
    drop(older);
    for (id, s) in &second[100..] {
        index.insert(id.clone(), s).expect("shelved");
    }
    let newest: Vec<_> = first[100..].iter().chain(second).cloned().collect();
    for query in [&first[3].1, &second[150].1, &first[120].1] {
        agrees(&index, &newest, query);
    }
}

/// A shelf that cannot be written is an error, not a panic.
#[test]
fn an_unwritable_shelf_is_an_error() {
    let mut collection = synthetic::collection(3, 1, 23);
    synthetic::with_descriptors(&mut collection, 1, 24);
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing");
    let mut index = Index::shelved_in(Params::default().similarity, missing);
    assert!(index.insert("a", &collection[0].1).is_err());
    assert!(index.is_empty());
}

/// Distances and ids sorted as a ranking orders them: by distance, ties by id.
fn in_order<'a>(scored: impl Iterator<Item = (f64, &'a str)>) -> Vec<(f64, &'a str)> {
    let mut scored: Vec<_> = scored.collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(b.1)));
    scored
}

/// A ranking's distances and ids.
fn hits(ranking: &Ranking) -> Vec<(f64, &str)> {
    ranking
        .hits
        .iter()
        .map(|h| (h.distance, h.id.as_str()))
        .collect()
}

/// The boxes a ranking bounds a block of entries by never bound a query above its bound to any
/// of the entries (so a block past the k-th distance holds no entry within it): the geodesic
/// distance, the ECC centroid bound (with the count penalty) and the LFD sketch bound. Among
/// the queries are the entries themselves, whose bounds are 0; the box of one entry bounds as
/// the entry does, exactly.
#[test]
fn block_boxes_never_bound_above_their_entries() {
    use salient_core::descriptor::lfd::SketchSpan;
    use salient_core::descriptor::Span;
    use salient_core::similarity::centroid_span_bound;

    let mut collection = synthetic::collection(256, 8, 31);
    synthetic::with_descriptors(&mut collection, 8, 32);
    let mut params = Params::default().similarity;
    params.penalty_power = 1.5;
    let spanned = |mut vectors: Vec<&[f32]>| {
        let mut span = Span::of(vectors.pop().expect("a block"));
        assert!(vectors.into_iter().all(|v| span.widen(v)));
        span
    };
    let (mut checked, mut positive) = (0, 0);
    let mut rest = &collection[..];
    for size in [1, 2, 32].into_iter().cycle() {
        if rest.is_empty() {
            break;
        }
        let block;
        (block, rest) = rest.split_at(size.min(rest.len()));
        let cumulative: Vec<_> = (block.iter())
            .map(|(_, s)| s.geodesic.as_ref().expect("made").cumulative())
            .collect();
        let geodesic = spanned(cumulative.iter().map(|c| c.values()).collect());
        let features: Vec<Features> = block
            .iter()
            .map(|(_, s)| Features::of(&s.features))
            .collect();
        let centroids: Vec<_> = features.iter().map(Features::centroid).collect();
        let ecc = spanned(centroids.iter().map(|c| &c.0[..]).collect());
        let d2 = spanned(centroids.iter().map(|c| &c.1[..]).collect());
        let counts = features.iter().map(Features::len);
        let counts = (counts.clone().min().unwrap(), counts.max().unwrap());
        let sketches: Vec<_> = (block.iter())
            .map(|(_, s)| s.lfd.as_ref().expect("made").sketch())
            .collect();
        let mut sketch = SketchSpan::of(&sketches[0]);
        sketches.iter().for_each(|s| sketch.widen(s));
        for (_, query) in collection.iter().step_by(7) {
            let q = query.geodesic.as_ref().expect("made").cumulative();
            let boxed = q.distance_to(&geodesic);
            let q_features = Features::of(&query.features);
            let q_centroid = q_features.centroid();
            let q_centroid = (&q_centroid.0[..], &q_centroid.1[..], q_features.len());
            let centroid_boxed = centroid_span_bound(q_centroid, (&ecc, &d2), counts, &params);
            let q_sketch = query.lfd.as_ref().expect("made").sketch();
            let sketch_boxed = q_sketch.span_bound(&sketch);
            for (n, c) in cumulative.iter().enumerate() {
                let (f, m) = (&features[n], &centroids[n]);
                let centroid = centroid_bound(q_centroid, (&m.0, &m.1, f.len()), &params);
                let bounds = [
                    (boxed, q.distance(c)),
                    (centroid_boxed, centroid),
                    (sketch_boxed, q_sketch.lower_bound(&sketches[n])),
                ];
                for (k, (boxed, each)) in bounds.into_iter().enumerate() {
                    assert!(boxed <= each, "part {k}: {boxed} > {each}");
                    assert!(
                        block.len() > 1 || boxed == each,
                        "part {k}: {boxed} < {each}"
                    );
                    checked += 1;
                    positive += usize::from(boxed > 0.0);
                }
            }
        }
    }
    // The boxes do bound: many are above 0 (blocks of entries of every class).
    assert!(positive * 4 > checked, "{positive} of {checked} above 0");
}

/// The first stage's vectors (#40): every row as long as `dimensions` says, with features or
/// without, and per light field their least L1 distance never exceeds the hybrid distance,
/// whatever the weights: a first stage ordered by it may stop at an exact bound.
#[test]
fn first_stage_rows_bound_the_hybrid_distance() {
    use salient_core::rank::vectors::{self, Layout};
    let mut collection = synthetic::collection(60, 6, 21);
    synthetic::with_descriptors(&mut collection, 6, 22);
    for hybrid in weightings() {
        let mut params = Params::default().similarity;
        params.hybrid = hybrid;
        let rows: Vec<Vec<Vec<f32>>> = collection
            .iter()
            .map(|(_, s)| vectors::rows(s, &params, Layout::PerLightField).expect("current"))
            .collect();
        for ((_, p), a) in collection.iter().zip(&rows).step_by(7) {
            assert!(a.iter().all(|r| r.len() == vectors::dimensions(&p.params)));
            for ((_, q), b) in collection.iter().zip(&rows) {
                let bound = vectors::distance(a, b);
                let exact = distance(Method::Hybrid, p, q, &params);
                assert!(bound <= exact + 1e-6, "{bound} > {exact}");
            }
        }
    }
    let mut featureless = collection[0].1.clone();
    featureless.features.clear();
    let params = Params::default();
    let pooled = vectors::rows(&featureless, &params.similarity, Layout::Pooled).expect("current");
    assert_eq!(pooled.len(), 1);
    assert_eq!(pooled[0].len(), vectors::dimensions(&params));
    featureless.geodesic = None;
    assert!(vectors::rows(&featureless, &params.similarity, Layout::Pooled).is_none());
}

/// An index of the first stage's candidates in their compact form (#40), its light field
/// descriptors fetched when a ranking needs them, ranks as an index of the whole signatures,
/// in at most three round trips a ranking, leaving out those its bounds reject.
#[test]
fn compact_rows_with_descriptors_away_rank_as_whole_signatures() {
    use salient_core::descriptor::LightFieldDescriptor;
    use salient_core::rank::compact;
    use std::collections::HashMap;
    use std::sync::{Arc, Mutex};

    let mut collection = synthetic::collection(800, 20, 31);
    synthetic::with_descriptors(&mut collection, 20, 32);
    // As stored: the compact form is made from stored signatures, quantised.
    let stored: Vec<(String, Signature)> = collection
        .into_iter()
        .map(|(id, s)| (id, Signature::from_bytes(&s.to_bytes()).expect("reads")))
        .collect();
    let mut queries = synthetic::collection(6, 20, 33);
    synthetic::with_descriptors(&mut queries, 20, 34);
    let params = Params::default().similarity;
    let mut whole = Index::new(params.clone());
    for (id, s) in &stored {
        whole.insert(id.as_str(), s).expect("shelved");
    }
    let descriptors: HashMap<Arc<str>, LightFieldDescriptor> = stored
        .iter()
        .map(|(id, s)| (Arc::from(id.as_str()), s.lfd.clone().expect("made")))
        .collect();
    let batches: Arc<Mutex<Vec<usize>>> = Arc::default();
    let fetch: salient_core::rank::Fetch = {
        let batches = batches.clone();
        Arc::new(move |ids: &[Arc<str>]| {
            batches.lock().unwrap().push(ids.len());
            Ok(ids
                .iter()
                .map(|id| (id.clone(), descriptors[id].clone()))
                .collect())
        })
    };
    let (first_id, first) = &stored[0];
    let form = compact::of(first);
    assert!(
        form.len() * 2 < first.to_bytes().len(),
        "{} bytes",
        form.len()
    );
    let away = Index::away(params.clone(), fetch.clone());
    for broken in [&form[..form.len() / 2], b"not a compact form"] {
        assert!(away.compact_row(first_id.as_str(), broken).is_err());
    }
    for (_, query) in &queries {
        let mut away = Index::away(params.clone(), fetch.clone());
        for (id, s) in &stored {
            let row = away
                .compact_row(id.as_str(), &compact::of(s))
                .expect("reads");
            away.put(row);
        }
        let request = Request::model(query, Method::Hybrid, 10);
        let (expected, ranked) = (whole.search(&request), away.search(&request));
        assert_eq!(
            hits(&ranked.expect("ranks")),
            hits(&expected.expect("ranks"))
        );
    }
    let batches = batches.lock().unwrap();
    let fetched: usize = batches.iter().sum();
    // The first look's seeds, the first pass's seeds, then every candidate the visit may read.
    assert!(batches.len() <= 3 * queries.len(), "{batches:?}");
    assert!(
        fetched * 20 < queries.len() * stored.len() * 19,
        "fetched {fetched} descriptors for {} queries of {}",
        queries.len(),
        stored.len()
    );
}

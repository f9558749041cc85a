//! Ranking with the centroid bound returns exactly the top k of a full scan (SPEC §5).

use crate::shapes;
use crate::synthetic;

use salient::rank::{Index, Method};
use salient::Params;

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
            index.insert(id.clone(), s.clone());
        }
        for (_, query) in &queries {
            for k in [1, 5, 10, 50] {
                let fast = index.search(query, k, Method::Ecc);
                let full = index.search_exhaustive(query, k, Method::Ecc);
                assert_eq!(fast.hits, full.hits, "k = {k}, penalty {penalty}, W = {w}");
                assert_eq!(fast.evaluated + fast.pruned, collection.len());
                pruned += fast.pruned;
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
    index.insert("zz-copy", query.clone());
    for (id, s) in &collection {
        index.insert(id.clone(), s.clone());
    }
    index.insert("aa-copy", query.clone());
    for method in [Method::Ecc, Method::D2] {
        let ranking = index.search(&query, 3, method);
        let ids: Vec<&str> = ranking.hits.iter().map(|h| h.id.as_str()).collect();
        assert_eq!(ids, ["aa-copy", "m000007", "zz-copy"], "{method}");
        assert!(ranking.hits.iter().all(|h| h.distance == 0.0));
    }
    assert!(index.search(&query, 0, Method::Ecc).hits.is_empty());
    let everything = index.search(&query, 1000, Method::Ecc);
    assert_eq!(everything.hits.len(), index.len());
}

/// The LFD method ranks by the light field distance and leaves out signatures without a
/// descriptor (stored before it existed) instead of ranking them last.
#[test]
fn lfd_ranks_by_light_field_distance_and_skips_signatures_without_one() {
    let params = Params::default();
    let meshes = [
        ("cone", shapes::cone(0.5, 12, 24)),
        ("tube", shapes::tube(0.25, 12, 24)),
        ("star", shapes::star(3, &shapes::five_tips())),
        ("bowl", shapes::bowl(3)),
    ];
    let signatures: Vec<_> = meshes
        .iter()
        .map(|(id, m)| (*id, salient::pipeline::compute(m, &params).unwrap()))
        .collect();
    let mut index = Index::new(params.similarity.clone());
    for (id, s) in &signatures {
        index.insert(*id, s.clone());
    }
    let mut old = signatures[3].1.clone();
    old.lfd = None;
    index.insert("old-bowl", old);
    let query = &signatures[0].1;
    let ranking = index.search(query, 10, Method::Lfd);
    let mut expected: Vec<(f64, &str)> = signatures
        .iter()
        .map(|(id, s)| {
            (
                query
                    .lfd
                    .as_ref()
                    .unwrap()
                    .distance(s.lfd.as_ref().unwrap()),
                *id,
            )
        })
        .collect();
    expected.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(b.1)));
    let got: Vec<(f64, &str)> = ranking
        .hits
        .iter()
        .map(|h| (h.distance, h.id.as_str()))
        .collect();
    assert_eq!(got, expected);
    assert_eq!(got[0], (0.0, "cone"));
    assert_eq!(ranking.evaluated, 4);
    // The bound-pruned ranking is the full scan's for every k and query.
    for (_, query) in &signatures {
        for k in 1..=4 {
            let fast = index.search(query, k, Method::Lfd);
            let full = index.search_exhaustive(query, k, Method::Lfd);
            assert_eq!(fast.hits, full.hits, "k = {k}");
            assert_eq!(fast.evaluated + fast.pruned, 4);
        }
    }
    // A query without a descriptor ranks nothing.
    let mut bare = signatures[0].1.clone();
    bare.lfd = None;
    assert!(index.search(&bare, 3, Method::Lfd).hits.is_empty());
}

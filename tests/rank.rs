//! Ranking with the centroid bound returns exactly the top k of a full scan (SPEC §5).

mod synthetic;

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

//! Retrieval measures (SPEC §7) against rankings worked out by hand: the Princeton Shape
//! Benchmark's NN, FT, ST, E, DCG, AP and the 11-point interpolated precision–recall curve.

use crate::synthetic;

use salient_core::rank::{distance, Method};
use salient_core::Params;
use salient_eval::metrics::Scores;
use salient_eval::retrieval::{evaluate, DistanceMatrix};

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-12
}

fn assert_scores(s: &Scores, expected: [f64; 6], pr: [f64; 11]) {
    for ((name, g), e) in s.measures().into_iter().zip(expected) {
        assert!(close(g, e), "{name}: {g} != {e}");
    }
    for (level, (g, e)) in s.pr.iter().zip(pr).enumerate() {
        assert!(close(*g, e), "precision at recall {level}/10: {g} != {e}");
    }
}

const R: bool = true;
const N: bool = false;

#[test]
fn relevant_first_and_third_of_five() {
    // Class of 3: two relevant models, found at ranks 1 and 3.
    let s = Scores::of_query(&[R, N, R, N, N], 2).unwrap();
    let dcg = (1.0 + 1.0 / 3f64.log2()) / (1.0 + 1.0 / 2f64.log2());
    let e = 2.0 / (32.0 / 2.0 + 2.0 / 2.0); // 2 / (1/P + 1/R), P = 2/32, R = 1
    let two_thirds = 2.0 / 3.0;
    assert_scores(
        &s,
        [1.0, 0.5, 1.0, e, dcg, (1.0 + two_thirds) / 2.0],
        // Recall 0.5 at precision 1, recall 1 at precision 2/3.
        [
            1.0, 1.0, 1.0, 1.0, 1.0, 1.0, two_thirds, two_thirds, two_thirds, two_thirds,
            two_thirds,
        ],
    );
}

#[test]
fn relevant_second_and_fourth() {
    let s = Scores::of_query(&[N, R, N, R], 2).unwrap();
    // DCG: 1/log2(2) + 1/log2(4) = 1.5 of an ideal 2; AP: (1/2 + 2/4) / 2.
    assert_scores(&s, [0.0, 0.5, 1.0, 4.0 / 34.0, 0.75, 0.5], [0.5; 11]);
}

#[test]
fn interpolation_takes_the_best_precision_at_higher_recall() {
    // Four relevant at ranks 2, 3, 4, 10: precisions 1/2, 2/3, 3/4, 4/10 at recall .25 … 1.
    let mut list = [N; 10];
    for rank in [2, 3, 4, 10] {
        list[rank - 1] = R;
    }
    let s = Scores::of_query(&list, 4).unwrap();
    let pr = [
        0.75, 0.75, 0.75, 0.75, 0.75, 0.75, 0.75, 0.75, 0.4, 0.4, 0.4,
    ];
    for (g, e) in s.pr.iter().zip(pr) {
        assert!(close(*g, e), "{:?}", s.pr);
    }
    // FT: 3 of the first 4; ST: rank 10 is beyond the first 8, so still 3 of 4.
    assert!(close(s.first_tier, 0.75) && close(s.second_tier, 0.75));
    assert!(close(s.map, (0.5 + 2.0 / 3.0 + 0.75 + 0.4) / 4.0));
    assert_eq!(s.e_measure, 2.0 * 4.0 / 36.0);
}

#[test]
fn a_class_of_one_has_no_scores_and_means_average_queries() {
    assert_eq!(Scores::of_query(&[N, N, N], 0), None);
    assert_eq!(Scores::mean([]), None);
    let a = Scores::of_query(&[R, N, R, N, N], 2).unwrap();
    let b = Scores::of_query(&[N, R, N, R], 2).unwrap();
    let mean = Scores::mean([&a, &b]).unwrap();
    assert!(close(mean.map, (a.map + b.map) / 2.0));
    assert!(close(mean.nearest_neighbour, 0.5));
    assert!(close(mean.pr[10], (2.0 / 3.0 + 0.5) / 2.0));
}

#[test]
fn leave_one_out_with_ties_and_a_singleton_class() {
    let ids = ["a1", "a2", "b1", "b2", "c1"].map(String::from).to_vec();
    let classes = ["a", "a", "b", "b", "c"];
    let pairs = [
        (0, 1, 1.0),
        (0, 2, 1.0), // ties with a1–a2: broken by id, a2 first
        (0, 3, 3.0),
        (0, 4, 2.0),
        (1, 2, 0.5),
        (1, 3, 2.0),
        (1, 4, 4.0),
        (2, 3, 2.0),
        (2, 4, 3.0),
        (3, 4, 1.0),
    ];
    let mut values = vec![0.0; 25];
    for (i, j, d) in pairs {
        values[i * 5 + j] = d;
        values[j * 5 + i] = d;
    }
    let matrix = DistanceMatrix::new(ids, values);
    assert_eq!(matrix.ranking(0, &[0, 1, 2, 3, 4]), [1, 2, 4, 3]);
    // b2: c1 (1), then a2 and b1 tied at 2 in id order, then a1.
    assert_eq!(matrix.ranking(3, &[0, 1, 2, 3, 4]), [4, 1, 2, 0]);

    let e = evaluate(&matrix, &classes, &[0, 1, 2, 3, 4]);
    assert_eq!((e.queries, e.skipped_queries), (4, 1));
    // a1: hit at 1; a2: hit at 2; b1 and b2: hit at 3. One relevant model each.
    let third = 1.0 / 3f64.log2();
    assert!(close(e.scores.nearest_neighbour, 0.25));
    assert!(close(e.scores.first_tier, 0.25));
    assert!(close(e.scores.second_tier, 0.5));
    assert!(close(e.scores.e_measure, 2.0 / 33.0));
    assert!(close(e.scores.dcg, (1.0 + 1.0 + third + third) / 4.0));
    assert!(close(
        e.scores.map,
        (1.0 + 0.5 + 1.0 / 3.0 + 1.0 / 3.0) / 4.0
    ));
    assert_eq!(e.per_class.len(), 2, "the singleton class has no scores");
    assert!(close(e.per_class["a"].map, 0.75));
    assert!(close(e.per_class["b"].pr[0], 1.0 / 3.0));

    // Within a subset, only its members rank: a1 and b1 alone have no relevant partner.
    let half = evaluate(&matrix, &classes, &[0, 1, 2]);
    assert_eq!((half.queries, half.skipped_queries), (2, 1));
    assert!(close(half.per_class["a"].nearest_neighbour, 0.5));
}

#[test]
fn the_distance_matrix_holds_every_pair_once_and_symmetrically() {
    let collection = synthetic::collection(24, 4, 7);
    let ids: Vec<String> = collection.iter().map(|(id, _)| id.clone()).collect();
    let signatures: Vec<_> = collection.into_iter().map(|(_, s)| s).collect();
    let params = Params::default().similarity;
    for method in [Method::Ecc, Method::D2] {
        let rows = std::sync::atomic::AtomicUsize::new(0);
        let matrix = DistanceMatrix::compute(ids.clone(), &signatures, method, &params, || {
            rows.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        });
        assert_eq!(rows.into_inner(), 24);
        for i in 0..24 {
            assert_eq!(matrix.get(i, i), 0.0);
            for j in i + 1..24 {
                let d = distance(method, &signatures[i], &signatures[j], &params);
                assert_eq!(matrix.get(i, j), d);
                assert_eq!(matrix.get(j, i), d);
            }
        }
        let csv = matrix.to_csv();
        assert_eq!(csv.lines().count(), 25);
        assert!(csv.starts_with("id,m000000,m000001,"));
    }
}

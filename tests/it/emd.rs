//! The EMD solver against brute force, and the laws an EMD obeys (SPEC §5).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use salient_core::emd::{emd, emd_uniform};

fn random_costs(rng: &mut ChaCha8Rng, m: usize, n: usize) -> Vec<Vec<f64>> {
    (0..m)
        .map(|_| (0..n).map(|_| rng.gen_range(0.0..10.0)).collect())
        .collect()
}

/// All permutations of 0..n (Heap's algorithm).
fn permutations(n: usize) -> Vec<Vec<usize>> {
    fn heap(k: usize, a: &mut Vec<usize>, out: &mut Vec<Vec<usize>>) {
        if k <= 1 {
            out.push(a.clone());
            return;
        }
        for i in 0..k {
            heap(k - 1, a, out);
            let j = if k.is_multiple_of(2) { i } else { 0 };
            a.swap(j, k - 1);
        }
    }
    let mut out = Vec::new();
    heap(n, &mut (0..n).collect(), &mut out);
    out
}

/// With equal sizes and weights the optimum is a permutation (Birkhoff–von Neumann), so the
/// EMD is the best assignment's mean cost.
#[test]
fn equal_sizes_match_the_best_assignment() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for n in 1..=7 {
        let perms = permutations(n);
        for _ in 0..20 {
            let c = random_costs(&mut rng, n, n);
            let brute = perms
                .iter()
                .map(|p| (0..n).map(|i| c[i][p[i]]).sum::<f64>() / n as f64)
                .fold(f64::INFINITY, f64::min);
            let solved = emd_uniform(n, n, |i, j| c[i][j]);
            assert!(
                (solved - brute).abs() < 1e-9,
                "n = {n}: {solved} vs {brute}"
            );
        }
    }
}

/// Every integer flow (row-major `m × n`) with the given row and column sums; the
/// transportation polytope's vertices are integral, so the cheapest of these is the optimum.
fn all_flows(rows: &[u64], cols: &[u64]) -> Vec<Vec<u64>> {
    fn fill(
        k: usize,
        rows: &mut [u64],
        cols: &mut [u64],
        flow: &mut Vec<u64>,
        out: &mut Vec<Vec<u64>>,
    ) {
        let n = cols.len();
        if k == flow.len() {
            if rows.iter().chain(cols.iter()).all(|&x| x == 0) {
                out.push(flow.clone());
            }
            return;
        }
        let (i, j) = (k / n, k % n);
        // The last cell of a row takes what the row has left.
        let low = if j == n - 1 { rows[i] } else { 0 };
        for x in low..=rows[i].min(cols[j]) {
            rows[i] -= x;
            cols[j] -= x;
            flow[k] = x;
            fill(k + 1, rows, cols, flow, out);
            rows[i] += x;
            cols[j] += x;
        }
        flow[k] = 0;
    }
    let mut out = Vec::new();
    let mut flow = vec![0; rows.len() * cols.len()];
    fill(
        0,
        &mut rows.to_vec(),
        &mut cols.to_vec(),
        &mut flow,
        &mut out,
    );
    out
}

/// Cost of a row-major flow, per unit of mass.
fn flow_cost(flow: &[u64], c: &[Vec<f64>], total: f64) -> f64 {
    let n = c[0].len();
    flow.iter()
        .enumerate()
        .map(|(k, &f)| f as f64 * c[k / n][k % n])
        .sum::<f64>()
        / total
}

#[test]
fn unequal_sizes_match_exhaustive_flows() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    for (m, n) in [(1, 3), (2, 3), (3, 2), (2, 4), (4, 3), (3, 4), (1, 5)] {
        let supply = vec![n as u64; m];
        let demand = vec![m as u64; n];
        let flows = all_flows(&supply, &demand);
        assert!(!flows.is_empty());
        for _ in 0..10 {
            let c = random_costs(&mut rng, m, n);
            let total = (m * n) as f64;
            let brute = flows
                .iter()
                .map(|f| flow_cost(f, &c, total))
                .fold(f64::INFINITY, f64::min);
            let solved = emd_uniform(m, n, |i, j| c[i][j]);
            assert!(
                (solved - brute).abs() < 1e-9,
                "{m}x{n}: {solved} vs {brute}"
            );
        }
    }
    // Non-uniform masses too.
    let c = random_costs(&mut rng, 3, 3);
    let (supply, demand) = ([5, 1, 2], [2, 2, 4]);
    let brute = all_flows(&supply, &demand)
        .iter()
        .map(|f| flow_cost(f, &c, 8.0))
        .fold(f64::INFINITY, f64::min);
    assert!((emd(&supply, &demand, |i, j| c[i][j]) - brute).abs() < 1e-9);
}

fn points(rng: &mut ChaCha8Rng, count: usize) -> Vec<[f64; 3]> {
    (0..count)
        .map(|_| [rng.gen(), rng.gen(), rng.gen()])
        .collect()
}

fn euclid(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

fn emd_points(p: &[[f64; 3]], q: &[[f64; 3]]) -> f64 {
    emd_uniform(p.len(), q.len(), |i, j| euclid(&p[i], &q[j]))
}

#[test]
fn identity_symmetry_and_triangle_inequality() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for _ in 0..200 {
        let sizes: Vec<usize> = (0..3).map(|_| rng.gen_range(1..12)).collect();
        let p = points(&mut rng, sizes[0]);
        let q = points(&mut rng, sizes[1]);
        let r = points(&mut rng, sizes[2]);
        assert!(emd_points(&p, &p).abs() < 1e-12);
        let (pq, qp) = (emd_points(&p, &q), emd_points(&q, &p));
        assert!((pq - qp).abs() < 1e-9, "symmetry {pq} {qp}");
        let (qr, pr) = (emd_points(&q, &r), emd_points(&p, &r));
        assert!(pr <= pq + qr + 1e-9, "triangle: {pr} > {pq} + {qr}");
    }
}

/// Degenerate problems (many ties, zero costs) must still terminate at the optimum.
#[test]
fn degenerate_costs_terminate() {
    for n in 1..=30 {
        assert_eq!(emd_uniform(n, n, |_, _| 1.0), 1.0);
        assert_eq!(
            emd_uniform(n, 2 * n, |i, j| if j / 2 == i { 0.0 } else { 1.0 }),
            0.0
        );
        let e = emd_uniform(n, n + 1, |i, j| (i as f64 - j as f64).abs());
        assert!(e.is_finite());
    }
}

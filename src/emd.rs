//! Exact Earth Mover's Distance (SPEC §5, paper Eq. 9–10) by the transportation simplex.
//!
//! Hand-written because no Rust crate solves this well today: `emd` leaks memory and only
//! takes uniform weights, `rust-optimal-transport` is an unmaintained C++ binding, and an
//! approximation (Sinkhorn) would change rankings. Masses are integers — a model's `m`
//! features of weight `1/m` against `n` of weight `1/n` become supplies of `n` and demands
//! of `m` — so feasibility and degeneracy are exact, and only costs are floating point.
//!
//! The method is the textbook one (Hitchcock; Dantzig's transportation simplex, as in Rubner's
//! reference EMD code): a north-west-corner basis spanning the `m + n` nodes, potentials
//! `u_i + v_j = c_ij` on basic cells, the most negative reduced cost enters, the cycle it
//! closes in the basis tree gives the leaving cell. After a run of degenerate pivots the
//! choice falls back to Bland's smallest-index rule, which cannot cycle.

/// Minimum total cost of moving `supply` onto `demand` (equal totals) at `cost(i, j)` per
/// unit, divided by the total mass: the EMD of Eq. 10.
///
/// # Panics
/// If the totals differ or are zero: callers build balanced problems.
pub fn emd(supply: &[u64], demand: &[u64], cost: impl Fn(usize, usize) -> f64) -> f64 {
    let total: u64 = supply.iter().sum();
    assert!(
        total > 0 && total == demand.iter().sum::<u64>(),
        "EMD needs equal, non-zero total masses"
    );
    let (m, n) = (supply.len(), demand.len());
    let c: Vec<f64> = (0..m * n).map(|k| cost(k / n, k % n)).collect();
    let flow = Transport::new(m, n, &c).solve(supply, demand);
    let work: f64 = flow.iter().map(|&(i, j, f)| f as f64 * c[i * n + j]).sum();
    work / total as f64
}

/// EMD between `m` and `n` equally weighted items (SPEC §5, Eq. 12).
pub fn emd_uniform(m: usize, n: usize, cost: impl Fn(usize, usize) -> f64) -> f64 {
    emd(&vec![n as u64; m], &vec![m as u64; n], cost)
}

struct Transport<'a> {
    m: usize,
    n: usize,
    cost: &'a [f64],
}

/// A basic cell and its flow.
#[derive(Clone, Copy)]
struct Cell {
    i: usize,
    j: usize,
    flow: u64,
}

impl Transport<'_> {
    fn new(m: usize, n: usize, cost: &[f64]) -> Transport<'_> {
        Transport { m, n, cost }
    }

    /// Returns the basic cells `(i, j, flow)` of an optimal solution.
    fn solve(&self, supply: &[u64], demand: &[u64]) -> Vec<(usize, usize, u64)> {
        let (m, n) = (self.m, self.n);
        let mut basis = north_west(supply, demand);
        let scale = self.cost.iter().fold(0.0f64, |a, &c| a.max(c.abs()));
        let tolerance = 1e-12 * scale.max(f64::MIN_POSITIVE);
        let mut u = vec![0.0; m];
        let mut v = vec![0.0; n];
        let mut degenerate_run = 0;
        // Each pivot either lowers the cost or is degenerate; Bland's rule bounds the latter.
        for _ in 0..100 * (m + n) * (m + n) {
            self.potentials(&basis, &mut u, &mut v);
            let bland = degenerate_run > m + n;
            let Some((ei, ej)) = self.entering(&basis, &u, &v, tolerance, bland) else {
                break;
            };
            let cycle = cycle(&basis, m, ei, ej);
            // Cells at odd positions of the cycle lose flow; the first smallest one leaves.
            let (leave, theta) = cycle
                .iter()
                .skip(1)
                .step_by(2)
                .map(|&b| (b, basis[b].flow))
                .min_by_key(|&(b, flow)| {
                    (
                        flow,
                        if bland {
                            (basis[b].i, basis[b].j)
                        } else {
                            (0, 0)
                        },
                    )
                })
                .expect("a cycle has at least one losing cell");
            for (k, &b) in cycle.iter().enumerate().skip(1) {
                if k % 2 == 1 {
                    basis[b].flow -= theta;
                } else {
                    basis[b].flow += theta;
                }
            }
            basis[leave] = Cell {
                i: ei,
                j: ej,
                flow: theta,
            };
            degenerate_run = if theta == 0 { degenerate_run + 1 } else { 0 };
        }
        basis.iter().map(|c| (c.i, c.j, c.flow)).collect()
    }

    /// Solves `u_i + v_j = c_ij` over the basis tree, rooted at `u_0 = 0`.
    fn potentials(&self, basis: &[Cell], u: &mut [f64], v: &mut [f64]) {
        let (m, n) = (self.m, self.n);
        let mut known = vec![false; m + n];
        known[0] = true;
        u[0] = 0.0;
        let mut remaining = basis.len();
        let mut done = vec![false; basis.len()];
        // The basis is a spanning tree: each sweep fixes at least one more node.
        while remaining > 0 {
            for (b, cell) in basis.iter().enumerate() {
                if done[b] {
                    continue;
                }
                let c = self.cost[cell.i * n + cell.j];
                if known[cell.i] {
                    v[cell.j] = c - u[cell.i];
                    known[m + cell.j] = true;
                } else if known[m + cell.j] {
                    u[cell.i] = c - v[cell.j];
                    known[cell.i] = true;
                } else {
                    continue;
                }
                done[b] = true;
                remaining -= 1;
            }
        }
    }

    /// The non-basic cell with the most negative reduced cost (or, under Bland's rule, the
    /// first negative one), if any.
    fn entering(
        &self,
        basis: &[Cell],
        u: &[f64],
        v: &[f64],
        tolerance: f64,
        bland: bool,
    ) -> Option<(usize, usize)> {
        let n = self.n;
        let mut is_basic = vec![false; self.m * n];
        for c in basis {
            is_basic[c.i * n + c.j] = true;
        }
        let mut best: Option<(f64, usize, usize)> = None;
        for i in 0..self.m {
            for j in 0..n {
                if is_basic[i * n + j] {
                    continue;
                }
                let reduced = self.cost[i * n + j] - u[i] - v[j];
                if reduced < -tolerance && best.is_none_or(|(r, _, _)| reduced < r) {
                    best = Some((reduced, i, j));
                    if bland {
                        return Some((i, j));
                    }
                }
            }
        }
        best.map(|(_, i, j)| (i, j))
    }
}

/// North-west-corner rule: a feasible basis of exactly `m + n - 1` cells forming a spanning
/// tree (degenerate zero cells included), because each step advances exactly one index.
fn north_west(supply: &[u64], demand: &[u64]) -> Vec<Cell> {
    let (m, n) = (supply.len(), demand.len());
    let (mut a, mut b) = (supply.to_vec(), demand.to_vec());
    let (mut i, mut j) = (0, 0);
    let mut basis = Vec::with_capacity(m + n - 1);
    loop {
        let flow = a[i].min(b[j]);
        basis.push(Cell { i, j, flow });
        a[i] -= flow;
        b[j] -= flow;
        if i == m - 1 && j == n - 1 {
            break;
        }
        if (a[i] == 0 && i < m - 1) || j == n - 1 {
            i += 1;
        } else {
            j += 1;
        }
    }
    basis
}

/// The cycle that entering cell `(ei, ej)` closes in the basis tree, as indices into `basis`
/// after a placeholder for the entering cell itself: `[entering, −, +, −, …, −]`, walking from
/// column `ej` back to row `ei`.
fn cycle(basis: &[Cell], m: usize, ei: usize, ej: usize) -> Vec<usize> {
    // Nodes: rows 0..m, columns m..; breadth-first search from row ei for column ej.
    let nodes = m + basis.iter().map(|c| c.j + 1).max().unwrap_or(0).max(ej + 1);
    let mut adjacent: Vec<Vec<(usize, usize)>> = vec![Vec::new(); nodes];
    for (b, c) in basis.iter().enumerate() {
        adjacent[c.i].push((m + c.j, b));
        adjacent[m + c.j].push((c.i, b));
    }
    let mut parent: Vec<Option<(usize, usize)>> = vec![None; nodes];
    let mut queue = std::collections::VecDeque::from([ei]);
    let mut seen = vec![false; nodes];
    seen[ei] = true;
    while let Some(node) = queue.pop_front() {
        if node == m + ej {
            break;
        }
        for &(next, b) in &adjacent[node] {
            if !seen[next] {
                seen[next] = true;
                parent[next] = Some((node, b));
                queue.push_back(next);
            }
        }
    }
    let mut path = vec![usize::MAX];
    let mut node = m + ej;
    while let Some((previous, b)) = parent[node] {
        path.push(b);
        node = previous;
    }
    path
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_by_two_by_hand() {
        // Moving 1 → a costs 1, 1 → b costs 3, 2 → a costs 4, 2 → b costs 1: the diagonal.
        let c = [[1.0, 3.0], [4.0, 1.0]];
        assert_eq!(emd_uniform(2, 2, |i, j| c[i][j]), 1.0);
        // One supply against two demands: everything is shipped, half each way.
        assert_eq!(emd_uniform(1, 2, |_, j| [2.0, 4.0][j]), 3.0);
    }
}

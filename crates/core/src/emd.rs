//! Exact Earth Mover's Distance (SPEC §5, paper Eq. 9–10) by the transportation simplex.
//!
//! Hand-written because no Rust crate solves this well today: `emd` leaks memory and only
//! takes uniform weights, `rust-optimal-transport` is an unmaintained C++ binding, and an
//! approximation (Sinkhorn) would change rankings. Masses are integers — a model's `m`
//! features of weight `1/m` against `n` of weight `1/n` become supplies of `n` and demands
//! of `m` — so feasibility and degeneracy are decided exactly; only costs are floating point.
//!
//! The method is the textbook one (Dantzig's transportation simplex, as in Rubner's reference
//! EMD code): a least-cost initial basis completed to a spanning tree of the `m + n` nodes,
//! potentials `u_i + v_j = c_ij` on the tree, the most negative reduced cost enters, the cycle
//! it closes in the tree gives the leaving cell. After a run of degenerate pivots the choice
//! falls back to Bland's smallest-index rule, which cannot cycle.

/// Minimum total cost of moving `supply` onto `demand` (equal totals) at `cost(i, j)` per
/// unit, divided by the total mass: the EMD of Eq. 10.
///
/// # Panics
/// If the totals differ or are zero: callers build balanced problems.
pub fn emd(supply: &[u64], demand: &[u64], cost: impl Fn(usize, usize) -> f64) -> f64 {
    let n = demand.len();
    let matrix: Vec<f64> = (0..supply.len() * n).map(|k| cost(k / n, k % n)).collect();
    emd_matrix(supply, demand, &matrix)
}

/// EMD between `m` and `n` equally weighted items (SPEC §5, Eq. 12).
pub fn emd_uniform(m: usize, n: usize, cost: impl Fn(usize, usize) -> f64) -> f64 {
    emd(&vec![n as u64; m], &vec![m as u64; n], cost)
}

/// [`emd`] with the costs given as a row-major `supply.len() × demand.len()` matrix.
pub fn emd_matrix(supply: &[u64], demand: &[u64], cost: &[f64]) -> f64 {
    optimise(supply, demand, cost).0
}

/// One cell of an optimal transport plan: `mass` (a fraction of the total) moves from
/// supply `from` to demand `to`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Flow {
    pub from: usize,
    pub to: usize,
    pub mass: f64,
}

/// [`emd_matrix`] and the optimal plan behind it: which supply went where (the flows `f_ij`
/// of Eq. 9), each cell with flow, in row then column order.
pub fn emd_flows(supply: &[u64], demand: &[u64], cost: &[f64]) -> (f64, Vec<Flow>) {
    let (emd, simplex, total) = optimise(supply, demand, cost);
    let mut flows: Vec<Flow> = simplex
        .basis
        .iter()
        .filter(|c| c.flow > 0)
        .map(|c| Flow {
            from: c.i,
            to: c.j,
            mass: c.flow as f64 / total as f64,
        })
        .collect();
    flows.sort_by_key(|f| (f.from, f.to));
    (emd, flows)
}

#[cfg(test)]
thread_local! {
    /// Transportation problems solved on this thread: lets a unit test count the EMDs a
    /// computation solves.
    pub(crate) static SOLVED: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// The solved simplex, its EMD and the total mass.
fn optimise<'a>(supply: &[u64], demand: &[u64], cost: &'a [f64]) -> (f64, Simplex<'a>, u64) {
    #[cfg(test)]
    SOLVED.with(|n| n.set(n.get() + 1));
    let total: u64 = supply.iter().sum();
    assert!(
        total > 0
            && total == demand.iter().sum::<u64>()
            && cost.len() == supply.len() * demand.len(),
        "EMD needs equal, non-zero total masses and an m × n cost matrix"
    );
    let mut simplex = Simplex::new(supply, demand, cost);
    simplex.solve();
    (simplex.work() / total as f64, simplex, total)
}

/// A basic cell and its flow.
#[derive(Debug, Clone, Copy)]
struct Cell {
    i: usize,
    j: usize,
    flow: u64,
}

/// Tree nodes are rows `0..m` and columns `m..m + n`.
struct Simplex<'a> {
    m: usize,
    n: usize,
    cost: &'a [f64],
    basis: Vec<Cell>,
    /// Potentials of rows then columns, and the tree rooted at row 0: each node's parent and
    /// the basis cell linking them, and its depth.
    potential: Vec<f64>,
    parent: Vec<(usize, usize)>,
    depth: Vec<usize>,
    adjacent: Vec<Vec<(usize, usize)>>,
    queue: Vec<usize>,
    is_basic: Vec<bool>,
}

impl<'a> Simplex<'a> {
    fn new(supply: &[u64], demand: &[u64], cost: &'a [f64]) -> Self {
        let (m, n) = (supply.len(), demand.len());
        let mut simplex = Simplex {
            m,
            n,
            cost,
            basis: Vec::with_capacity(m + n - 1),
            potential: vec![0.0; m + n],
            parent: vec![(usize::MAX, usize::MAX); m + n],
            depth: vec![0; m + n],
            adjacent: vec![Vec::new(); m + n],
            queue: Vec::with_capacity(m + n),
            is_basic: vec![false; m * n],
        };
        simplex.least_cost_basis(supply, demand);
        simplex
    }

    /// Least-cost method: fill the cheapest cells first. Each allocation exhausts a row or a
    /// column, so the cells form a forest; zero-flow cells, cheapest first, then join its
    /// trees into the spanning tree a basis needs (`m + n − 1` cells).
    fn least_cost_basis(&mut self, supply: &[u64], demand: &[u64]) {
        let (m, n) = (self.m, self.n);
        let mut order: Vec<usize> = (0..m * n).collect();
        order.sort_by(|&a, &b| self.cost[a].total_cmp(&self.cost[b]).then(a.cmp(&b)));
        let (mut a, mut b) = (supply.to_vec(), demand.to_vec());
        let mut component: Vec<usize> = (0..m + n).collect();
        fn root(component: &mut [usize], mut x: usize) -> usize {
            while component[x] != x {
                component[x] = component[component[x]];
                x = component[x];
            }
            x
        }
        for &k in &order {
            let (i, j) = (k / n, k % n);
            if a[i] > 0 && b[j] > 0 {
                let flow = a[i].min(b[j]);
                a[i] -= flow;
                b[j] -= flow;
                self.add(Cell { i, j, flow });
                let (ri, rj) = (root(&mut component, i), root(&mut component, m + j));
                component[ri] = rj;
            }
        }
        for &k in &order {
            if self.basis.len() == m + n - 1 {
                break;
            }
            let (i, j) = (k / n, k % n);
            let (ri, rj) = (root(&mut component, i), root(&mut component, m + j));
            if ri != rj {
                component[ri] = rj;
                self.add(Cell { i, j, flow: 0 });
            }
        }
    }

    fn add(&mut self, cell: Cell) {
        self.is_basic[cell.i * self.n + cell.j] = true;
        self.basis.push(cell);
    }

    fn work(&self) -> f64 {
        self.basis
            .iter()
            .map(|c| c.flow as f64 * self.cost[c.i * self.n + c.j])
            .sum()
    }

    fn solve(&mut self) {
        let (m, n) = (self.m, self.n);
        let scale = self.cost.iter().fold(0.0f64, |a, &c| a.max(c.abs()));
        let tolerance = 1e-12 * scale.max(f64::MIN_POSITIVE);
        let mut degenerate_run = 0;
        // Bland's rule guarantees termination; the bound only guards against a bug.
        for _ in 0..100 * (m + n) * (m + n) {
            self.build_tree();
            let bland = degenerate_run > m + n;
            let Some((ei, ej)) = self.entering(tolerance, bland) else {
                return;
            };
            let cycle = self.cycle(ei, ej);
            // Cells at odd positions lose flow; the first smallest one leaves.
            let (leave, theta) = cycle
                .iter()
                .skip(1)
                .step_by(2)
                .map(|&b| (b, self.basis[b].flow))
                .min_by_key(|&(b, flow)| {
                    let cell = self.basis[b];
                    (flow, if bland { (cell.i, cell.j) } else { (0, 0) })
                })
                .expect("a cycle has a losing cell");
            for (k, &b) in cycle.iter().enumerate().skip(1) {
                if k % 2 == 1 {
                    self.basis[b].flow -= theta;
                } else {
                    self.basis[b].flow += theta;
                }
            }
            let old = self.basis[leave];
            self.is_basic[old.i * n + old.j] = false;
            self.is_basic[ei * n + ej] = true;
            self.basis[leave] = Cell {
                i: ei,
                j: ej,
                flow: theta,
            };
            degenerate_run = if theta == 0 { degenerate_run + 1 } else { 0 };
        }
    }

    /// Roots the basis tree at row 0 and solves `u_i + v_j = c_ij` along it (`u_0 = 0`).
    fn build_tree(&mut self) {
        let m = self.m;
        for list in &mut self.adjacent {
            list.clear();
        }
        for (b, c) in self.basis.iter().enumerate() {
            self.adjacent[c.i].push((m + c.j, b));
            self.adjacent[m + c.j].push((c.i, b));
        }
        self.queue.clear();
        self.queue.push(0);
        self.parent[0] = (usize::MAX, usize::MAX);
        self.depth[0] = 0;
        self.potential[0] = 0.0;
        let mut head = 0;
        while head < self.queue.len() {
            let node = self.queue[head];
            head += 1;
            for &(next, b) in &self.adjacent[node] {
                if next == self.parent[node].0 {
                    continue;
                }
                let c = self.cost[self.basis[b].i * self.n + self.basis[b].j];
                self.potential[next] = c - self.potential[node];
                self.parent[next] = (node, b);
                self.depth[next] = self.depth[node] + 1;
                self.queue.push(next);
            }
        }
    }

    /// The non-basic cell of most negative reduced cost `c_ij − u_i − v_j` (under Bland's rule
    /// the first negative one), if any.
    fn entering(&self, tolerance: f64, bland: bool) -> Option<(usize, usize)> {
        let (m, n) = (self.m, self.n);
        let mut best: Option<(f64, usize, usize)> = None;
        for i in 0..m {
            let row = &self.cost[i * n..(i + 1) * n];
            let u = self.potential[i];
            for (j, (&c, &v)) in row.iter().zip(&self.potential[m..]).enumerate() {
                let reduced = c - u - v;
                if reduced < -tolerance
                    && !self.is_basic[i * n + j]
                    && best.is_none_or(|(r, _, _)| reduced < r)
                {
                    if bland {
                        return Some((i, j));
                    }
                    best = Some((reduced, i, j));
                }
            }
        }
        best.map(|(_, i, j)| (i, j))
    }

    /// The cycle entering cell `(ei, ej)` closes in the tree, as basis indices after a
    /// placeholder for the entering cell: `[entering, −, +, −, …, −]`, from column `ej` round
    /// to row `ei` through their lowest common ancestor.
    fn cycle(&self, ei: usize, ej: usize) -> Vec<usize> {
        let (mut a, mut b) = (self.m + ej, ei);
        let mut from_column = vec![usize::MAX];
        let mut from_row = Vec::new();
        while self.depth[a] > self.depth[b] {
            from_column.push(self.parent[a].1);
            a = self.parent[a].0;
        }
        while self.depth[b] > self.depth[a] {
            from_row.push(self.parent[b].1);
            b = self.parent[b].0;
        }
        while a != b {
            from_column.push(self.parent[a].1);
            a = self.parent[a].0;
            from_row.push(self.parent[b].1);
            b = self.parent[b].0;
        }
        from_column.extend(from_row.into_iter().rev());
        from_column
    }
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

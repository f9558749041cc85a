//! Zernike moment magnitudes of a silhouette (Chen et al. 2003, §4.1): the region-shape half
//! of an image's features, invariant to rotation about the image centre and to mirroring.
//!
//! `A_nm = Σ_pixels V*_nm(x, y)` over the foreground in the unit disk, for orders `n ≤ 10`,
//! `0 ≤ m ≤ n`, `n − m` even: 36 moments. Each is divided by the foreground area `A_00`, which
//! bounds it by 1 (`|V_nm| ≤ 1` on the disk, so the 8-bit scale is fixed) and leaves the 35
//! others.
//!
//! Summing a 36-term basis over every foreground pixel of 100 images costs ~0.2 s a model, so
//! instead: `V*_nm` is a polynomial in `x, y` of degree `n`, hence a fixed combination of the
//! 66 geometric moments `m_pq = Σ x^p y^q` (`p + q ≤ 10`), and those are sums over rows of
//! `y^q · Σ_run x^p`, where a run's `Σ x^p` is a difference of prefix sums. An image then
//! costs a few thousand operations. f64 keeps the cancellation in the expansion harmless
//! (coefficients ≤ ~10⁴, moments ≤ 6.6·10⁴: absolute error ~10⁻⁷ of the area).

use std::sync::OnceLock;

use num_complex::Complex64;

use super::silhouette::{disk_coordinate, Silhouette, IMAGE_SIZE};

/// Highest order.
pub const MAX_ORDER: usize = 10;
/// Moments kept per image: all `(n, m)` up to [`MAX_ORDER`] except `(0, 0)`.
pub const ZERNIKE_COUNT: usize = 35;

const DEGREES: usize = MAX_ORDER + 1;

/// The orders `(n, m)` of the kept moments, in their order in the feature vector.
pub fn orders() -> impl Iterator<Item = (usize, usize)> {
    (1..=MAX_ORDER).flat_map(|n| (n % 2..=n).step_by(2).map(move |m| (n, m)))
}

/// `|A_nm| / A_00` for each of [`orders`]; all zero for an empty image.
pub fn zernike_magnitudes(image: &Silhouette) -> [f64; ZERNIKE_COUNT] {
    let tables = Tables::get();
    let moments = geometric_moments(image, tables);
    let area = moments[0][0];
    let mut out = [0.0; ZERNIKE_COUNT];
    if area <= 0.0 {
        return out;
    }
    for (value, terms) in out.iter_mut().zip(&tables.basis) {
        let a: Complex64 = terms.iter().map(|&(p, q, c)| c * moments[p][q]).sum();
        *value = a.norm() / area;
    }
    out
}

/// `m_pq = Σ x^p y^q` over the foreground pixel centres inside the unit disk, `p + q ≤ 10`.
fn geometric_moments(image: &Silhouette, tables: &Tables) -> [[f64; DEGREES]; DEGREES] {
    let mut moments = [[0.0; DEGREES]; DEGREES];
    for y in 0..IMAGE_SIZE {
        let (first, last) = tables.disk_span[y];
        let mut row = [0.0; DEGREES];
        for (start, end) in image.runs(y) {
            let (start, end) = (start.max(first), end.min(last));
            if start < end {
                for (p, sum) in row.iter_mut().enumerate() {
                    *sum += tables.prefix[p][end] - tables.prefix[p][start];
                }
            }
        }
        if row[0] == 0.0 {
            continue;
        }
        let yn = disk_coordinate(y);
        for (p, (moment, &sum)) in moments.iter_mut().zip(&row).enumerate() {
            let mut power = 1.0;
            for m in &mut moment[..DEGREES - p] {
                *m += sum * power;
                power *= yn;
            }
        }
    }
    moments
}

/// What every image shares.
struct Tables {
    /// `prefix[p][x] = Σ_{x' < x} x'^p` in disk coordinates.
    prefix: Vec<Vec<f64>>,
    /// Per row, the half-open column range of pixel centres inside the unit disk.
    disk_span: Vec<(usize, usize)>,
    /// Per kept order, `V*_nm` as terms `c · x^p y^q`.
    basis: Vec<Vec<(usize, usize, Complex64)>>,
}

impl Tables {
    fn get() -> &'static Tables {
        static TABLES: OnceLock<Tables> = OnceLock::new();
        TABLES.get_or_init(|| Tables {
            prefix: (0..DEGREES)
                .map(|p| {
                    let mut sums = vec![0.0; IMAGE_SIZE + 1];
                    for x in 0..IMAGE_SIZE {
                        sums[x + 1] = sums[x] + disk_coordinate(x).powi(p as i32);
                    }
                    sums
                })
                .collect(),
            disk_span: (0..IMAGE_SIZE)
                .map(|y| {
                    let yn = disk_coordinate(y);
                    let inside = |x: &usize| {
                        let xn = disk_coordinate(*x);
                        xn * xn + yn * yn <= 1.0
                    };
                    let first = (0..IMAGE_SIZE).find(inside).unwrap_or(IMAGE_SIZE);
                    let last = (0..IMAGE_SIZE).rev().find(inside).map_or(first, |x| x + 1);
                    (first, last)
                })
                .collect(),
            basis: orders().map(|(n, m)| basis_polynomial(n, m)).collect(),
        })
    }
}

/// A polynomial in `x, y` with complex coefficients, `[p][q]` for `x^p y^q`.
type Polynomial = [[Complex64; DEGREES]; DEGREES];

/// `V*_nm(x, y) = R_nm(ρ) e^{−imθ} = (x − iy)^m Σ_s c_s (x² + y²)^{(n−m)/2 − s}`, with the
/// radial coefficients `c_s = (−1)^s (n−s)! / (s! ((n+m)/2−s)! ((n−m)/2−s)!)`.
fn basis_polynomial(n: usize, m: usize) -> Vec<(usize, usize, Complex64)> {
    let zero = Complex64::new(0.0, 0.0);
    let mut radial: Polynomial = [[zero; DEGREES]; DEGREES];
    for s in 0..=(n - m) / 2 {
        let sign = if s % 2 == 0 { 1.0 } else { -1.0 };
        let c = sign * factorial(n - s)
            / (factorial(s) * factorial((n + m) / 2 - s) * factorial((n - m) / 2 - s));
        let j = (n - m) / 2 - s;
        // (x² + y²)^j = Σ_l C(j, l) x^{2(j−l)} y^{2l}
        for l in 0..=j {
            radial[2 * (j - l)][2 * l] += c * binomial(j, l);
        }
    }
    // (x − iy)^m = Σ_k C(m, k) x^{m−k} (−i)^k y^k
    let mut angular: Polynomial = [[zero; DEGREES]; DEGREES];
    let mut minus_i_power = Complex64::new(1.0, 0.0);
    for k in 0..=m {
        angular[m - k][k] = minus_i_power * binomial(m, k);
        minus_i_power *= Complex64::new(0.0, -1.0);
    }
    let mut terms = Vec::new();
    for p in 0..DEGREES {
        for q in 0..DEGREES - p {
            let mut c = zero;
            for (a, row) in radial.iter().enumerate().take(p + 1) {
                for (b, r) in row.iter().enumerate().take(q + 1) {
                    c += r * angular[p - a][q - b];
                }
            }
            if c != zero {
                terms.push((p, q, c));
            }
        }
    }
    terms
}

fn factorial(n: usize) -> f64 {
    (1..=n).map(|k| k as f64).product()
}

fn binomial(n: usize, k: usize) -> f64 {
    factorial(n) / (factorial(k) * factorial(n - k))
}

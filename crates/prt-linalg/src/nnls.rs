//! Non-negative least squares by the Lawson-Hanson active-set method.
//!
//! Minimises `||a x - b||^2` subject to `x >= 0` through its normal equations
//! `G = a^T a`, `c = a^T b` (the form sphere-basis fitting already has, and the one scipy >= 1.12
//! uses): repeatedly free the variable with the largest positive negative-gradient
//! `w = c - G x`, solve the unconstrained problem on the free ("passive") set, and step back
//! along the segment to stay feasible when that solution has non-positive entries. At the end
//! the KKT conditions hold: `x >= 0`, `g = G x - c >= 0`, and `g_i = 0` wherever `x_i > 0`.
//! Working on `G` squares the condition number of `a`, which is harmless for the small, well
//! conditioned designs it is meant for (use [`crate::lstsq`] first if in doubt).

use ndarray::{Array1, ArrayView1, ArrayView2};

use crate::LinalgError;
use crate::dense::check_finite;

/// The solution of a non-negative least-squares problem.
#[derive(Debug, Clone, PartialEq)]
pub struct Nnls {
    /// The minimiser, all entries `>= 0`.
    pub x: Array1<f64>,
    /// The gradient `G x - a^T b` at `x` (half the gradient of the squared residual): the KKT
    /// multipliers, `>= 0` everywhere and zero (to rounding) where `x > 0`.
    pub gradient: Array1<f64>,
    /// Passive-set solves performed (outer plus inner iterations).
    pub iterations: usize,
}

/// Non-negative least squares `min ||a x - b||^2, x >= 0` for the `m x n` matrix `a`.
///
/// Forms `a^T a` and `a^T b` (in f64) and calls [`nnls_gram`].
///
/// # Errors
/// [`LinalgError::Empty`] if `a` has no rows or columns, [`LinalgError::ShapeMismatch`] if
/// `b.len() != a.nrows()`, [`LinalgError::NonFinite`] for NaN/Inf, and whatever
/// [`nnls_gram`] returns.
pub fn nnls(a: ArrayView2<'_, f64>, b: ArrayView1<'_, f64>) -> Result<Nnls, LinalgError> {
    if a.is_empty() {
        return Err(LinalgError::Empty { what: "a" });
    }
    if b.len() != a.nrows() {
        return Err(LinalgError::ShapeMismatch {
            what: "length of b",
            expected: a.nrows(),
            got: b.len(),
        });
    }
    check_finite("a", a)?;
    check_finite("b", b.insert_axis(ndarray::Axis(1)))?;
    let gram = a.t().dot(&a);
    let atb = a.t().dot(&b);
    nnls_gram(gram.view(), atb.view())
}

/// Non-negative least squares in normal-equations form: minimises `x^T G x / 2 - c^T x` subject
/// to `x >= 0`, for a symmetric positive semidefinite `G = gram` and `c = atb`.
///
/// Extremes: `c <= 0` everywhere gives `x = 0` with no solve; when the unconstrained minimiser is
/// already non-negative it is returned (to rounding); a semidefinite `G` is handled (the
/// passive-set solves fall back to a minimum-norm least-squares solve when Cholesky fails).
///
/// # Errors
/// [`LinalgError::Empty`] for a 0 x 0 `gram`, [`LinalgError::ShapeMismatch`] for a non-square
/// `gram` or an `atb` of the wrong length, [`LinalgError::NonFinite`] for NaN/Inf, and
/// [`LinalgError::NoConvergence`] after `3 n + 10` outer iterations (cycling through rounding,
/// not seen on well-posed problems).
pub fn nnls_gram(gram: ArrayView2<'_, f64>, atb: ArrayView1<'_, f64>) -> Result<Nnls, LinalgError> {
    let n = gram.nrows();
    if gram.ncols() != n {
        return Err(LinalgError::ShapeMismatch {
            what: "gram is square",
            expected: n,
            got: gram.ncols(),
        });
    }
    if n == 0 {
        return Err(LinalgError::Empty { what: "gram" });
    }
    if atb.len() != n {
        return Err(LinalgError::ShapeMismatch {
            what: "length of atb",
            expected: n,
            got: atb.len(),
        });
    }
    check_finite("gram", gram)?;
    check_finite("atb", atb.insert_axis(ndarray::Axis(1)))?;

    let g: Vec<f64> = gram.iter().copied().collect();
    let c: Vec<f64> = atb.to_vec();
    let scale = g.iter().chain(&c).fold(0.0f64, |m, v| m.max(v.abs()));
    let tol = 10.0 * n as f64 * f64::EPSILON * scale;

    let mut x = vec![0.0; n];
    let mut passive = vec![false; n];
    // Variables whose freeing produced no progress (rounding); retried after the next change.
    let mut banned = vec![false; n];
    let mut w = c.clone();
    let mut s = vec![0.0; n];
    let mut work = SubproblemWork::new(n);
    let max_outer = 3 * n + 10;
    let mut iterations = 0;
    let mut outer = 0;

    loop {
        let entering = (0..n)
            .filter(|&j| !passive[j] && !banned[j] && w[j] > tol)
            .max_by(|&i, &j| w[i].total_cmp(&w[j]).then(j.cmp(&i)));
        let Some(j) = entering else { break };
        outer += 1;
        if outer > max_outer {
            return Err(LinalgError::NoConvergence {
                what: "NNLS",
                iterations,
            });
        }
        passive[j] = true;
        iterations += 1;
        work.solve(&g, &c, &passive, &mut s);
        if s[j] <= 0.0 {
            passive[j] = false;
            banned[j] = true;
            continue;
        }
        // Inner loop: step back towards x until the passive solution is feasible.
        while (0..n).any(|i| passive[i] && s[i] <= 0.0) {
            let (mut alpha, mut blocking) = (f64::INFINITY, j);
            for i in 0..n {
                if passive[i] && s[i] <= 0.0 {
                    let step = x[i] / (x[i] - s[i]);
                    if step < alpha {
                        (alpha, blocking) = (step, i);
                    }
                }
            }
            for i in 0..n {
                if passive[i] {
                    x[i] += alpha * (s[i] - x[i]);
                    if i == blocking || x[i] <= 0.0 {
                        x[i] = 0.0;
                        passive[i] = false;
                    }
                }
            }
            iterations += 1;
            if iterations > max_outer * (n + 1) {
                return Err(LinalgError::NoConvergence {
                    what: "NNLS",
                    iterations,
                });
            }
            work.solve(&g, &c, &passive, &mut s);
        }
        for i in 0..n {
            x[i] = if passive[i] { s[i] } else { 0.0 };
        }
        banned.fill(false);
        for i in 0..n {
            w[i] = c[i] - (0..n).map(|k| g[i * n + k] * x[k]).sum::<f64>();
        }
    }

    let gradient =
        Array1::from_iter((0..n).map(|i| (0..n).map(|k| g[i * n + k] * x[k]).sum::<f64>() - c[i]));
    Ok(Nnls {
        x: Array1::from(x),
        gradient,
        iterations,
    })
}

/// Scratch space for the passive-set solves `G_PP s_P = c_P`.
struct SubproblemWork {
    index: Vec<usize>,
    factor: Vec<f64>,
    rhs: Vec<f64>,
}

impl SubproblemWork {
    fn new(n: usize) -> Self {
        Self {
            index: Vec::with_capacity(n),
            factor: vec![0.0; n * n],
            rhs: vec![0.0; n],
        }
    }

    /// Writes the passive-set solution into `s` (zero outside the passive set).
    fn solve(&mut self, g: &[f64], c: &[f64], passive: &[bool], s: &mut [f64]) {
        let n = passive.len();
        self.index.clear();
        self.index.extend((0..n).filter(|&i| passive[i]));
        let p = self.index.len();
        s.fill(0.0);
        for (a, &i) in self.index.iter().enumerate() {
            self.rhs[a] = c[i];
            for (b, &k) in self.index.iter().enumerate() {
                self.factor[a * p + b] = g[i * n + k];
            }
        }
        let solved = cholesky_in_place(&mut self.factor[..p * p], &mut self.rhs[..p], p);
        if !solved {
            // Dependent passive columns: minimum-norm least squares on the sub-Gram matrix.
            let sub = ndarray::Array2::from_shape_fn((p, p), |(a, b)| {
                g[self.index[a] * n + self.index[b]]
            });
            let rhs = ndarray::Array2::from_shape_fn((p, 1), |(a, _)| c[self.index[a]]);
            match crate::lstsq(sub.view(), rhs.view(), 0.0) {
                Ok(sol) => {
                    for a in 0..p {
                        self.rhs[a] = sol[[a, 0]];
                    }
                }
                Err(_) => self.rhs[..p].fill(0.0),
            }
        }
        for (a, &i) in self.index.iter().enumerate() {
            s[i] = self.rhs[a];
        }
    }
}

/// Solves `m y = r` in place for a symmetric positive definite `p x p` row-major `m` by
/// Cholesky; returns `false` (leaving garbage) if a pivot is not safely positive.
fn cholesky_in_place(m: &mut [f64], r: &mut [f64], p: usize) -> bool {
    let max_diag = (0..p).map(|i| m[i * p + i].abs()).fold(0.0, f64::max);
    let pivot_floor = max_diag * p as f64 * f64::EPSILON * 16.0;
    for j in 0..p {
        let mut d = m[j * p + j];
        for k in 0..j {
            d -= m[j * p + k] * m[j * p + k];
        }
        if d.is_nan() || d <= pivot_floor {
            return false;
        }
        let d = d.sqrt();
        m[j * p + j] = d;
        for i in j + 1..p {
            let mut v = m[i * p + j];
            for k in 0..j {
                v -= m[i * p + k] * m[j * p + k];
            }
            m[i * p + j] = v / d;
        }
    }
    for i in 0..p {
        let mut v = r[i];
        for k in 0..i {
            v -= m[i * p + k] * r[k];
        }
        r[i] = v / m[i * p + i];
    }
    for i in (0..p).rev() {
        let mut v = r[i];
        for k in i + 1..p {
            v -= m[k * p + i] * r[k];
        }
        r[i] = v / m[i * p + i];
    }
    true
}

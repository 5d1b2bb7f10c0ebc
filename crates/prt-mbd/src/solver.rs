//! The stochastic quasi-Newton solver of the MBD paper (section 3.3) and its initialisation.

use std::time::Instant;

use glam::Vec3;
use ndarray::{Array2, Array3, ArrayView2, ArrayViewMut2, linalg::general_mat_mul};
use prt_core::{Aabb, CoreError, GridField, KernelWeights, Progress, SpatialKernels};
use rayon::prelude::*;

pub use crate::objective::Preconditioner;
use crate::objective::{Evaluation, Problem, Samples};
use crate::subspace::{cholesky_in_place, cholesky_solve_in_place, principal_subspace};
use crate::{MbdError, MbdModel};

/// Options of the stochastic quasi-Newton solver ([`crate::Mbd::solver`], [`solve`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SolverOptions {
    /// Ridge weight λ on the coefficients (`λ/2 ‖c‖²`), default 1e-4. It removes the scale
    /// ambiguity `c_l b_l = (s c_l)(b_l / s)`.
    pub lambda: f32,
    /// Iteration cap (default 128).
    pub max_iterations: usize,
    /// [`solve`] stops when the held-out data term ([`IterationRecord::held_out`]) fell by less
    /// than this per iteration, relative to its current value, over the last `patience`
    /// iterations (default 1e-3; 0 runs all `max_iterations`).
    pub tolerance: f64,
    /// See `tolerance` (default 8).
    pub patience: usize,
    /// Step halvings tried by the backtracking line search before an iteration is rejected
    /// (default 12).
    pub max_halvings: usize,
    /// Seed of the sample positions.
    pub seed: u64,
    /// Diagonal scaling of the step (default [`Preconditioner::Block`]; the paper's is
    /// [`Preconditioner::Diagonal`]).
    pub preconditioner: Preconditioner,
    /// Jitter the samples inside their voxels (default true). Without jitter every iteration
    /// uses the voxel centres, which fits the grid values only.
    pub jitter: bool,
    /// Iterations over which the returned model averages the iterates (default 16; 0 returns
    /// the last iterate). Each iteration fits its own samples, so the iterates scatter around
    /// the optimum of the continuous loss; their running mean does not. At the end the solver
    /// returns the average or the last iterate, whichever has the lower loss on the held-out
    /// samples.
    pub average_window: usize,
    /// Heavy-ball momentum of the basis, in [0, 1): the trial step adds this times the last
    /// accepted basis displacement (default 0.9; 0 is the paper's step). The line search halves
    /// the whole step, and a rejected iteration resets the momentum.
    pub momentum_basis: f32,
    /// The same for the coefficients (default 0.6: each voxel's coefficients see one sample per
    /// iteration, so more momentum carries more of that sample's noise).
    pub momentum_coefficients: f32,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            lambda: 1e-4,
            max_iterations: 128,
            tolerance: 1e-3,
            patience: 8,
            max_halvings: 12,
            seed: 0x5EED,
            preconditioner: Preconditioner::Block,
            jitter: true,
            average_window: 16,
            momentum_basis: 0.9,
            momentum_coefficients: 0.6,
        }
    }
}

/// One iteration of the solver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IterationRecord {
    /// Loss estimate at the start of the iteration.
    pub loss_before: f64,
    /// Its data term. The iteration's samples are fresh (independent of the parameters, which
    /// were fitted to earlier samples), so this is an unbiased estimate of the continuous data
    /// loss at the parameters entering the iteration.
    pub data_before: f64,
    /// Loss estimate after the accepted step, on the same samples (equal to `loss_before` when
    /// no step was accepted).
    pub loss_after: f64,
    /// Relative squared error `Σ‖f − f̂‖² / Σ‖f‖²` of the averaged iterates (see
    /// [`SolverOptions::average_window`]) on a fixed set of held-out samples, one jittered sample
    /// per voxel drawn once per solve: an estimate of [`crate::evaluate`]'s relative MSE whose
    /// changes between iterations carry no sampling noise. The stopping rule watches it.
    /// Measured every [`HELD_OUT_INTERVAL`] iterations and at the last one (`None` in between:
    /// the pass costs about a fifth of an iteration).
    pub held_out: Option<f64>,
    /// The accepted step length (1 = the full quasi-Newton step, 0 = rejected).
    pub step: f32,
    /// Seconds since the solve started (initialisation included).
    pub elapsed: f64,
}

/// What happened during a solve.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SolveReport {
    /// Seconds spent in the initialisation.
    pub init_seconds: f64,
    /// One record per iteration.
    pub history: Vec<IterationRecord>,
    /// Whether the stopping rule fired before the iteration cap.
    pub converged: bool,
    /// Seconds spent in the solves of [`crate::Mbd::coarse_start`] before this one (0 without
    /// a coarse start); not part of `init_seconds` nor of the history's `elapsed`.
    pub coarse_seconds: f64,
}

impl SolveReport {
    /// Seconds of this solve: the initialisation and every iteration (the coarse start's
    /// solves not included).
    pub fn total_seconds(&self) -> f64 {
        self.history
            .last()
            .map_or(self.init_seconds, |record| record.elapsed)
    }
}

/// Fits a rank-`rank` MBD with the given kernels to `field` (the target `f(x)` is the field's
/// trilinear interpolation), by the stochastic quasi-Newton method of the paper:
///
/// 1. initialise every basis node with the global principal subspace, coefficients by ridge
///    least squares;
/// 2. each iteration draw one jittered sample per voxel, estimate loss, gradient and diagonal
///    Hessian, take the diagonal Newton step `Δ = −g / h` for coefficients and basis together
///    (beyond the paper: block curvature, [`Preconditioner::Block`], and heavy-ball momentum,
///    [`SolverOptions::momentum_basis`]), and halve it while the loss on the same samples
///    (common random numbers) is above the starting loss;
/// 3. average the iterates over the last [`SolverOptions::average_window`] iterations (beyond
///    the paper) and measure the average on a fixed held-out sample set;
/// 4. stop when that held-out loss fell by less than `tolerance` per iteration over the last
///    `patience` iterations, or at `max_iterations`; return the average or the last iterate,
///    whichever is lower on the held-out samples.
///
/// Why not the paper's rule on the iteration's own loss decrease: each iteration refits its
/// own samples, so that decrease stays at several % long after the continuous error has
/// stopped falling.
///
/// Deterministic for a seed on any number of threads. Progress reports one unit per iteration
/// and the loss as message; cancellation is checked every few cells.
///
/// # Errors
/// [`MbdError::InvalidRank`] (rank 0 or > D), [`MbdError::InvalidKernels`] (an empty family),
/// [`MbdError::KernelsDoNotCover`] (a point of the field's box without kernel support),
/// [`MbdError::InvalidOption`], cancellation, and [`MbdError::Diverged`] if a non-finite value
/// appears.
pub fn solve<C: SpatialKernels, B: SpatialKernels>(
    field: &GridField,
    coefficient_kernels: C,
    basis_kernels: B,
    rank: usize,
    options: &SolverOptions,
    progress: &dyn Progress,
) -> Result<(MbdModel<C, B>, SolveReport), MbdError> {
    solve_with(
        field,
        None,
        coefficient_kernels,
        basis_kernels,
        Start::GlobalPca { rank },
        options,
        progress,
    )
}

/// [`solve`] on the valid voxels of `field` only (`valid[v]`, x-fastest voxels): samples lie in
/// valid voxels, the target blends valid voxels only, and the start is the valid voxels'
/// principal subspace, so the fit does not depend on the invalid voxels' values. Coefficient
/// kernels that no valid voxel's sample reaches stay exactly zero.
///
/// # Errors
/// As [`solve`], and [`MbdError::ShapeMismatch`] when `valid` does not have one entry per voxel,
/// [`MbdError::InvalidOption`] when no voxel is valid.
pub fn solve_masked<C: SpatialKernels, B: SpatialKernels>(
    field: &GridField,
    valid: &[bool],
    coefficient_kernels: C,
    basis_kernels: B,
    rank: usize,
    options: &SolverOptions,
    progress: &dyn Progress,
) -> Result<(MbdModel<C, B>, SolveReport), MbdError> {
    check_mask(field, valid)?;
    solve_with(
        field,
        Some(valid),
        coefficient_kernels,
        basis_kernels,
        Start::GlobalPca { rank },
        options,
        progress,
    )
}

/// [`solve`] from a given basis (`N × L × D`, e.g. a previous fit's or a clustering's; its
/// `L` is the rank) instead of the global principal subspace; the coefficients start from the
/// same ridge least-squares fit.
///
/// # Errors
/// As [`solve`], and [`MbdError::InvalidOption`] when `initial_basis` does not have one
/// `L × D` block per basis kernel or holds a non-finite value.
pub fn solve_from_basis<C: SpatialKernels, B: SpatialKernels>(
    field: &GridField,
    coefficient_kernels: C,
    basis_kernels: B,
    initial_basis: &Array3<f32>,
    options: &SolverOptions,
    progress: &dyn Progress,
) -> Result<(MbdModel<C, B>, SolveReport), MbdError> {
    let rank = initial_basis.dim().1;
    let expected = (basis_kernels.len(), rank, field.dim());
    if initial_basis.dim() != expected || rank == 0 {
        return Err(MbdError::InvalidOption {
            what: "initial_basis",
            why: format!(
                "shape {:?}, the kernels and rank need {expected:?}",
                initial_basis.dim()
            ),
        });
    }
    if let Some(index) = initial_basis.iter().position(|x| !x.is_finite()) {
        return Err(MbdError::InvalidOption {
            what: "initial_basis",
            why: format!("non-finite value at flat index {index}"),
        });
    }
    solve_with(
        field,
        None,
        coefficient_kernels,
        basis_kernels,
        Start::Basis(initial_basis),
        options,
        progress,
    )
}

/// A validity mask must have one entry per voxel and a valid voxel.
pub(crate) fn check_mask(field: &GridField, valid: &[bool]) -> Result<(), MbdError> {
    if valid.len() != field.num_voxels() {
        return Err(MbdError::ShapeMismatch {
            what: "validity mask",
            expected: vec![field.num_voxels()],
            got: vec![valid.len()],
        });
    }
    if !valid.contains(&true) {
        return Err(MbdError::InvalidOption {
            what: "validity mask",
            why: "no voxel is valid".into(),
        });
    }
    Ok(())
}

/// Where [`solve_with`] starts.
pub(crate) enum Start<'a> {
    /// Every basis node at the global rank-`rank` principal subspace (the paper's start).
    GlobalPca { rank: usize },
    /// A given basis, `N × L × D`.
    Basis(&'a Array3<f32>),
}

pub(crate) fn solve_with<C: SpatialKernels, B: SpatialKernels>(
    field: &GridField,
    mask: Option<&[bool]>,
    coefficient_kernels: C,
    basis_kernels: B,
    start_from: Start<'_>,
    options: &SolverOptions,
    progress: &dyn Progress,
) -> Result<(MbdModel<C, B>, SolveReport), MbdError> {
    let start = Instant::now();
    let rank = match start_from {
        Start::GlobalPca { rank } => rank,
        Start::Basis(given) => given.dim().1,
    };
    validate(field, &coefficient_kernels, &basis_kernels, rank, options)?;
    let problem = Problem {
        field,
        mask,
        coefficient_kernels: &coefficient_kernels,
        basis_kernels: &basis_kernels,
        rank,
        lambda: options.lambda,
        preconditioner: options.preconditioner,
    };
    let (mut coefficients, mut basis) = match start_from {
        Start::Basis(given) => {
            let basis: Vec<f32> = given.iter().copied().collect();
            (fit_coefficients(&problem, &basis)?, basis)
        }
        Start::GlobalPca { .. } => initialise(&problem)?,
    };
    let mut report = SolveReport {
        init_seconds: start.elapsed().as_secs_f64(),
        ..SolveReport::default()
    };
    progress.set_len(options.max_iterations as u64);
    let mut held_out = Samples::draw_masked(
        field,
        mask,
        &basis_kernels,
        options.seed,
        HELD_OUT_STREAM,
        options.jitter,
    );
    problem.prepare(&mut held_out)?;
    let held_out_energy = problem.target_energy(&held_out, progress)?;
    let mut average = IterateAverage::new(options.average_window, &coefficients, &basis);
    let mut trial_c = vec![0.0f32; coefficients.len()];
    let mut trial_b = vec![0.0f32; basis.len()];
    let mut velocity_c = vec![0.0f32; coefficients.len()];
    let mut velocity_b = vec![0.0f32; basis.len()];
    let mut previous_samples = None;
    for iteration in 0..options.max_iterations {
        progress.check()?;
        let mut samples = Samples::draw_masked(
            field,
            mask,
            &basis_kernels,
            options.seed,
            iteration as u64,
            options.jitter,
        );
        if let Some(previous) = previous_samples.take() {
            samples.recycle(previous);
        }
        // Evaluated at least twice (gradient, then the line search).
        problem.prepare(&mut samples)?;
        let eval = problem.evaluate(&samples, &coefficients, &basis, true, progress)?;
        let loss_before = eval.loss();
        if !loss_before.is_finite() {
            return Err(MbdError::Diverged {
                what: "loss",
                iteration,
            });
        }
        let (dir_c, dir_b) = newton_directions(&eval, rank, field.dim(), options.preconditioner);
        let mut step = 1.0f32;
        let mut accepted = None;
        if loss_before > 0.0 {
            for _ in 0..=options.max_halvings {
                let (mc, mb) = (
                    options.momentum_coefficients as f64,
                    options.momentum_basis as f64,
                );
                for (((t, &x), &dx), &u) in trial_c
                    .iter_mut()
                    .zip(&coefficients)
                    .zip(&dir_c)
                    .zip(&velocity_c)
                {
                    *t = x + (step as f64 * (mc * u as f64 - dx)) as f32;
                }
                for (((t, &x), &dx), &u) in
                    trial_b.iter_mut().zip(&basis).zip(&dir_b).zip(&velocity_b)
                {
                    *t = x + (step as f64 * (mb * u as f64 - dx)) as f32;
                }
                let trial = problem.evaluate(&samples, &trial_c, &trial_b, false, progress)?;
                if trial.loss() <= loss_before {
                    accepted = Some(trial.loss());
                    break;
                }
                step *= 0.5;
            }
        }
        previous_samples = Some(samples);
        let loss_after = match accepted {
            Some(loss) => {
                for ((u, &new), &old) in velocity_c.iter_mut().zip(&trial_c).zip(&coefficients) {
                    *u = new - old;
                }
                for ((u, &new), &old) in velocity_b.iter_mut().zip(&trial_b).zip(&basis) {
                    *u = new - old;
                }
                std::mem::swap(&mut coefficients, &mut trial_c);
                std::mem::swap(&mut basis, &mut trial_b);
                loss
            }
            None => {
                velocity_c.fill(0.0);
                velocity_b.fill(0.0);
                step = 0.0;
                loss_before
            }
        };
        let (model_c, model_b) = average.update(&coefficients, &basis);
        let held_out_loss = if (iteration + 1) % HELD_OUT_INTERVAL == 0
            || iteration + 1 == options.max_iterations
        {
            let data = problem
                .evaluate(&held_out, model_c, model_b, false, progress)?
                .data_loss;
            Some(relative_to(data, held_out_energy))
        } else {
            None
        };
        report.history.push(IterationRecord {
            loss_before,
            data_before: eval.data_loss,
            loss_after,
            held_out: held_out_loss,
            step,
            elapsed: start.elapsed().as_secs_f64(),
        });
        progress.inc(1);
        progress.message(&format!("iteration {iteration}: loss {loss_after:.6e}"));
        if held_out_converged(&report.history, options) {
            report.converged = true;
            break;
        }
    }
    if let Some(average_held_out) = report.history.last().and_then(|r| r.held_out)
        && average.is_active()
    {
        let iterate = relative_to(
            problem
                .evaluate(&held_out, &coefficients, &basis, false, progress)?
                .data_loss,
            held_out_energy,
        );
        if average_held_out < iterate {
            coefficients = std::mem::take(&mut average.coefficients);
            basis = std::mem::take(&mut average.basis);
        }
    }
    let (m, l) = (coefficient_kernels.len(), rank);
    let n = basis_kernels.len();
    let coefficients = Array2::from_shape_vec((m, l), coefficients).map_err(shape_error)?;
    let basis = Array3::from_shape_vec((n, l, field.dim()), basis).map_err(shape_error)?;
    let model = MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis)?;
    Ok((model, report))
}

/// `data / energy`, or `data` for a zero field.
pub(crate) fn relative_to(data: f64, energy: f64) -> f64 {
    if energy > 0.0 { data / energy } else { data }
}

/// Iterations between two measurements of the held-out error.
pub const HELD_OUT_INTERVAL: usize = 4;

/// Sample stream of the held-out samples (the iterations use streams `0..max_iterations`).
const HELD_OUT_STREAM: u64 = u64::MAX - 1;

/// The stopping rule of [`solve`], decided at each held-out measurement: the held-out error
/// (fixed samples, so its changes are the model's, not sampling noise) fell by less than
/// `tolerance` per iteration, relative to its current value, since the latest measurement at
/// least `patience` iterations earlier; or it is zero. Tolerance 0 never stops.
pub(crate) fn held_out_converged(history: &[IterationRecord], options: &SolverOptions) -> bool {
    if options.tolerance == 0.0 {
        return false;
    }
    let Some(last) = history.last().and_then(|r| r.held_out) else {
        return false;
    };
    if last == 0.0 {
        return true;
    }
    let k = history.len() - 1;
    let patience = options.patience.max(1);
    let earlier = history[..(k + 1).saturating_sub(patience)]
        .iter()
        .enumerate()
        .rev()
        .find_map(|(j, r)| r.held_out.map(|h| (j, h)));
    let Some((j, before)) = earlier else {
        return false;
    };
    before - last < options.tolerance * (k - j) as f64 * last
}

/// The running mean of the iterates over (about) the last `window` iterations: iterate `k`
/// enters with weight `1 / min(k, window)`, so the first `window` iterates are averaged
/// equally and older ones are then forgotten geometrically.
struct IterateAverage {
    window: usize,
    count: usize,
    coefficients: Vec<f32>,
    basis: Vec<f32>,
}

impl IterateAverage {
    /// An average over `window` iterations (0: none, the model is the last iterate).
    fn new(window: usize, coefficients: &[f32], basis: &[f32]) -> Self {
        let keep = |x: &[f32]| if window > 0 { x.to_vec() } else { Vec::new() };
        Self {
            window,
            count: 0,
            coefficients: keep(coefficients),
            basis: keep(basis),
        }
    }

    fn is_active(&self) -> bool {
        self.window > 0
    }

    /// Takes in the next iterate and returns the model to report: the average, or the iterate
    /// itself when averaging is off.
    fn update<'a>(
        &'a mut self,
        coefficients: &'a [f32],
        basis: &'a [f32],
    ) -> (&'a [f32], &'a [f32]) {
        if !self.is_active() {
            return (coefficients, basis);
        }
        self.count += 1;
        let w = 1.0 / self.count.min(self.window) as f32;
        for (a, &x) in self.coefficients.iter_mut().zip(coefficients) {
            *a += w * (x - *a);
        }
        for (a, &x) in self.basis.iter_mut().zip(basis) {
            *a += w * (x - *a);
        }
        (&self.coefficients, &self.basis)
    }
}

/// Levenberg-Marquardt floor added to every kernel's curvature, relative to its mean diagonal
/// entry (`κ tr(H_k) / L`).
///
/// At ranks above the field's local rank the coefficients seen by one basis node span fewer than
/// L directions, so its block is singular in exact arithmetic (condition numbers 1e10-1e16 at
/// L = 16 on the synthetic field). Accumulated in f32, those eigenvalues become rounding noise:
/// either negative (Cholesky fails and the node freezes) or tiny and positive, and then the
/// rounding error of the gradient divided by them is a huge step along a direction the samples
/// barely see. The line search accepts it on the iteration's samples; on the next samples it is
/// error (rank 16 ended 60× worse than rank 8 before this floor). The floor sits above f32
/// accumulation noise (`√S · 2⁻²⁴ ≈ 2e-6` for cells of 10³ samples): measured on the
/// synthetic field, 1e-8 diverges, 1e-7 degrades over 64 iterations, 1e-6 and 1e-5 are equal,
/// 1e-4 slows rank 8 by 40%.
pub(crate) const CURVATURE_FLOOR: f64 = 1e-5;

/// The quasi-Newton directions `H⁻¹ g` for the coefficients (`M × L`) and the basis
/// (`N × L × D`), with `H` the preconditioner's curvature plus [`CURVATURE_FLOOR`]. Kernels that
/// no sample touched (zero curvature) do not move.
fn newton_directions(
    eval: &Evaluation,
    l: usize,
    d: usize,
    preconditioner: Preconditioner,
) -> (Vec<f64>, Vec<f64>) {
    let mut dir_c = eval.grad_c.clone();
    let mut dir_b = eval.grad_b.clone();
    if preconditioner.width(l) == 1 {
        // Per kernel, L diagonal entries; the basis ones apply to all D components.
        let floor = |h: &[f64]| CURVATURE_FLOOR * h.iter().sum::<f64>() / l as f64;
        let inverse = |v: f64, floor: f64| {
            if v + floor > 0.0 {
                1.0 / (v + floor)
            } else {
                0.0
            }
        };
        for (g, h) in dir_c.chunks_mut(l).zip(eval.hess_c.chunks(l)) {
            let f = floor(h);
            for (g, &v) in g.iter_mut().zip(h) {
                *g *= inverse(v, f);
            }
        }
        for (g, h) in dir_b.chunks_mut(l * d).zip(eval.hess_b.chunks(l)) {
            let f = floor(h);
            for (row, &v) in g.chunks_mut(d).zip(h) {
                let inv = inverse(v, f);
                row.iter_mut().for_each(|x| *x *= inv);
            }
        }
        return (dir_c, dir_b);
    }
    // One L × L system per kernel: the coefficient gradient is one right-hand side, the basis
    // gradient D of them (node n's `L × D` block, row l = basis vector l).
    let solve_blocks = |dir: &mut [f64], hess: &[f64], cols: usize| {
        dir.par_chunks_mut(l * cols)
            .zip(hess.par_chunks(l * l))
            .for_each_init(
                || vec![0.0f64; l * l],
                |a, (g, h)| {
                    a.copy_from_slice(h);
                    let trace: f64 = (0..l).map(|i| a[i * l + i]).sum();
                    for i in 0..l {
                        a[i * l + i] += CURVATURE_FLOOR * trace / l as f64;
                    }
                    if trace > 0.0 && cholesky_in_place(a, l) {
                        cholesky_solve_in_place(a, g, l, cols);
                    } else {
                        g.fill(0.0);
                    }
                },
            );
    };
    solve_single_rhs_blocks(&mut dir_c, &eval.hess_c, l);
    solve_blocks(&mut dir_b, &eval.hess_b, d);
    (dir_c, dir_b)
}

/// Systems solved side by side by [`solve_single_rhs_blocks`].
const LANES: usize = 4;

/// The coefficients' systems (one `L × L` block and one right-hand side per kernel, M of them)
/// as `solve_blocks` in [`newton_directions`] solves them, [`LANES`] kernels at a time: one
/// kernel's tiny factorisation is a chain of dependent divisions and square roots, several side
/// by side fill the vector units. Every lane performs the operations of `cholesky_in_place` and
/// `cholesky_solve_in_place` in the same order, so the directions are bit-identical to solving
/// the kernels one by one; a lane whose trace is not positive or whose factorisation fails gets
/// a zero direction, as there.
fn solve_single_rhs_blocks(dir: &mut [f64], hess: &[f64], l: usize) {
    type Lanes = [f64; LANES];
    dir.par_chunks_mut(l * LANES)
        .zip(hess.par_chunks(l * l * LANES))
        .for_each_init(
            || (vec![[0.0; LANES]; l * l], vec![[0.0; LANES]; l]),
            |(a, x), (g, h)| {
                let used = g.len() / l;
                // Unused lanes of the last chunk solve the identity.
                for (e, lanes) in a.iter_mut().enumerate() {
                    for (lane, v) in lanes.iter_mut().enumerate() {
                        *v = match h.get(lane * l * l + e) {
                            Some(&v) if lane < used => v,
                            _ => f64::from(u8::from(e % (l + 1) == 0)),
                        };
                    }
                }
                for (i, lanes) in x.iter_mut().enumerate() {
                    for (lane, v) in lanes.iter_mut().enumerate() {
                        *v = if lane < used { g[lane * l + i] } else { 0.0 };
                    }
                }
                let mut trace: Lanes = [-0.0; LANES];
                for i in 0..l {
                    for (t, &v) in trace.iter_mut().zip(&a[i * l + i]) {
                        *t += v;
                    }
                }
                let mut ok = trace.map(|t| t > 0.0);
                for i in 0..l {
                    for (v, &t) in a[i * l + i].iter_mut().zip(&trace) {
                        *v += CURVATURE_FLOOR * t / l as f64;
                    }
                }
                // cholesky_in_place, lane by lane.
                for j in 0..l {
                    let mut diag = a[j * l + j];
                    for k in 0..j {
                        let r = a[j * l + k];
                        for (d, &v) in diag.iter_mut().zip(&r) {
                            *d -= v * v;
                        }
                    }
                    for (ok, &d) in ok.iter_mut().zip(&diag) {
                        *ok &= d > 0.0 && d.is_finite();
                    }
                    let diag = diag.map(f64::sqrt);
                    a[j * l + j] = diag;
                    for i in j + 1..l {
                        let mut v = a[i * l + j];
                        for k in 0..j {
                            let (p, q) = (a[i * l + k], a[j * l + k]);
                            for lane in 0..LANES {
                                v[lane] -= p[lane] * q[lane];
                            }
                        }
                        for lane in 0..LANES {
                            v[lane] /= diag[lane];
                        }
                        a[i * l + j] = v;
                    }
                }
                // cholesky_solve_in_place with one column, lane by lane.
                for i in 0..l {
                    for k in 0..i {
                        let (f, xk) = (a[i * l + k], x[k]);
                        for lane in 0..LANES {
                            x[i][lane] -= f[lane] * xk[lane];
                        }
                    }
                    for lane in 0..LANES {
                        x[i][lane] /= a[i * l + i][lane];
                    }
                }
                for i in (0..l).rev() {
                    for k in i + 1..l {
                        let (f, xk) = (a[k * l + i], x[k]);
                        for lane in 0..LANES {
                            x[i][lane] -= f[lane] * xk[lane];
                        }
                    }
                    for lane in 0..LANES {
                        x[i][lane] /= a[i * l + i][lane];
                    }
                }
                for (lane, g) in g.chunks_exact_mut(l).enumerate() {
                    for (i, v) in g.iter_mut().enumerate() {
                        *v = if ok[lane] { x[i][lane] } else { 0.0 };
                    }
                }
            },
        );
}

fn shape_error(e: ndarray::ShapeError) -> MbdError {
    MbdError::InvalidOption {
        what: "tensor shape",
        why: e.to_string(),
    }
}

/// Checks rank, kernels and options against the field.
pub(crate) fn validate<C: SpatialKernels, B: SpatialKernels>(
    field: &GridField,
    coefficient_kernels: &C,
    basis_kernels: &B,
    rank: usize,
    options: &SolverOptions,
) -> Result<(), MbdError> {
    field.check_finite()?;
    let dim = field.dim();
    if rank == 0 || rank > dim {
        return Err(MbdError::InvalidRank { rank, dim });
    }
    if !(options.lambda >= 0.0 && options.lambda.is_finite()) {
        return Err(MbdError::InvalidOption {
            what: "lambda",
            why: format!("{} is not a finite non-negative number", options.lambda),
        });
    }
    for (what, m) in [
        ("momentum_basis", options.momentum_basis),
        ("momentum_coefficients", options.momentum_coefficients),
    ] {
        if !(0.0..1.0).contains(&m) {
            return Err(MbdError::InvalidOption {
                what,
                why: format!("{m} is not in [0, 1)"),
            });
        }
    }
    if options.tolerance.is_nan() || options.tolerance < 0.0 {
        return Err(MbdError::InvalidOption {
            what: "tolerance",
            why: format!("{} is not non-negative", options.tolerance),
        });
    }
    check_kernels("coefficient", coefficient_kernels, field.bounds())?;
    check_kernels("basis", basis_kernels, field.bounds())?;
    Ok(())
}

/// A family must be non-empty and have support at the corners, face centres and centre of the
/// field's box (for hat grids and any family whose support is a union of boxes, this is where
/// coverage fails first).
pub(crate) fn check_kernels<K: SpatialKernels>(
    which: &'static str,
    kernels: &K,
    bounds: Aabb,
) -> Result<(), MbdError> {
    if kernels.is_empty() || kernels.max_support() == 0 {
        return Err(MbdError::InvalidKernels {
            which,
            why: "the family has no kernels".into(),
        });
    }
    let mut weights = KernelWeights::default();
    for i in 0..27 {
        let t = Vec3::new((i % 3) as f32, ((i / 3) % 3) as f32, (i / 9) as f32) * 0.5;
        let x = bounds.min + t * bounds.size();
        let covered = match kernels.eval(x, &mut weights) {
            Ok(()) => weights.sum() > 0.0,
            Err(CoreError::Uncovered { .. }) => false,
            Err(e) => return Err(e.into()),
        };
        if !covered {
            return Err(MbdError::KernelsDoNotCover {
                which,
                point: x.to_array(),
            });
        }
    }
    Ok(())
}

/// The paper's start `(coefficients M × L, basis N × L × D)`, flat: every basis node at the
/// field's uncentred rank-L principal subspace (so the first model is a global PCA), the
/// coefficients by [`fit_coefficients`].
pub(crate) fn initialise<C: SpatialKernels, B: SpatialKernels>(
    problem: &Problem<'_, C, B>,
) -> Result<(Vec<f32>, Vec<f32>), MbdError> {
    let field = problem.field;
    let (l, d) = (problem.rank, field.dim());
    let n = problem.basis_kernels.len();
    let global = match problem.mask {
        None => principal_subspace(field.data().view(), l)?,
        Some(mask) => {
            let rows: Vec<usize> = (0..mask.len()).filter(|&v| mask[v]).collect();
            principal_subspace(field.data().select(ndarray::Axis(0), &rows).view(), l)?
        }
    };
    let flat = global.as_slice().unwrap_or(&[]);
    let mut basis = vec![0.0f32; n * l * d];
    for node in basis.chunks_exact_mut(l * d) {
        node.copy_from_slice(flat);
    }
    let coefficients = fit_coefficients(problem, &basis)?;
    Ok((coefficients, basis))
}

/// Coefficients by ridge least squares with the basis fixed: at each coefficient kernel's centre
/// `x_m`, `c_m = argmin ‖f(x_m) − b(x_m)ᵀ c‖² + λ‖c‖²`. Kernels without a centre start at zero
/// (the first iteration then moves only the coefficients, since the basis gradient vanishes).
fn fit_coefficients<C: SpatialKernels, B: SpatialKernels>(
    problem: &Problem<'_, C, B>,
    basis: &[f32],
) -> Result<Vec<f32>, MbdError> {
    let field = problem.field;
    let (l, d) = (problem.rank, field.dim());
    let m = problem.coefficient_kernels.len();
    let lambda = (problem.lambda as f64).max(1e-12);
    let mut coefficients = vec![0.0f32; m * l];
    coefficients
        .par_chunks_mut(l)
        .enumerate()
        .try_for_each_init(
            || {
                (
                    KernelWeights::default(),
                    vec![0.0f32; d],
                    vec![0.0f32; l * d],
                    vec![0.0f64; l * l],
                    vec![0.0f64; l],
                    vec![0.0f32; l * l],
                )
            },
            |(psi, f, b, a, rhs, g32), (index, out)| -> Result<(), MbdError> {
                let Some(x) = problem.coefficient_kernels.centre(index) else {
                    return Ok(());
                };
                problem.target_at(x, f)?;
                problem.basis_kernels.eval(x, psi)?;
                b.fill(0.0);
                for (n, w) in psi.iter() {
                    let node = &basis[n as usize * l * d..(n as usize + 1) * l * d];
                    for (o, &v) in b.iter_mut().zip(node) {
                        *o += w * v;
                    }
                }
                // The normal equations as f32 products (a starting point only; the solver
                // refines it), solved in f64.
                let bm = ArrayView2::from_shape((l, d), &b[..]).map_err(shape_error)?;
                let fv = ndarray::aview1(&f[..]);
                let mut gram =
                    ArrayViewMut2::from_shape((l, l), &mut g32[..]).map_err(shape_error)?;
                general_mat_mul(1.0, &bm, &bm.t(), 0.0, &mut gram);
                for (o, v) in rhs.iter_mut().zip(bm.dot(&fv)) {
                    *o = v as f64;
                }
                for (o, &v) in a.iter_mut().zip(g32.iter()) {
                    *o = v as f64;
                }
                for i in 0..l {
                    a[i * l + i] += lambda;
                }
                if cholesky_in_place(a, l) {
                    cholesky_solve_in_place(a, rhs, l, 1);
                    for (o, &v) in out.iter_mut().zip(rhs.iter()) {
                        *o = v as f32;
                    }
                }
                Ok(())
            },
        )?;
    Ok(coefficients)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_pcg::Pcg64Mcg;

    fn records(held_out: &[f64]) -> Vec<IterationRecord> {
        held_out
            .iter()
            .map(|&h| IterationRecord {
                loss_before: 1.0,
                data_before: 1.0,
                loss_after: 0.5,
                held_out: (!h.is_nan()).then_some(h),
                step: 1.0,
                elapsed: 0.0,
            })
            .collect()
    }

    #[test]
    fn held_out_rule_needs_a_whole_calm_window() {
        let options = SolverOptions {
            tolerance: 1e-3,
            patience: 4,
            ..SolverOptions::default()
        };
        // 0.05 % per iteration over the last four: calm, but only once four iterations exist.
        let calm: Vec<f64> = (0..6).map(|k| 1.0 - 5e-4 * k as f64).collect();
        assert!(!held_out_converged(&records(&calm[..4]), &options));
        assert!(held_out_converged(&records(&calm[..5]), &options));
        // 0.5 % per iteration is progress; so is a window whose total fall exceeds the bound
        // although its last iteration was flat (the CRN loss of one iteration says nothing).
        let falling: Vec<f64> = (0..6).map(|k| 1.0 - 5e-3 * k as f64).collect();
        assert!(!held_out_converged(&records(&falling), &options));
        assert!(!held_out_converged(
            &records(&[1.0, 0.99, 0.985, 0.98, 0.98]),
            &options
        ));
        // A rise is calm; an exact fit stops at once.
        assert!(held_out_converged(
            &records(&[1.0, 1.0, 1.0, 1.0, 1.01]),
            &options
        ));
        assert!(held_out_converged(&records(&[0.0]), &options));
        assert!(!held_out_converged(&[], &options));
        // Unmeasured iterations (NaN here): the rule decides at measurements only, against the
        // latest one at least `patience` iterations back, per iteration between them.
        let nan = f64::NAN;
        let sparse = [1.0, nan, nan, nan, nan, nan, 0.999, nan];
        assert!(!held_out_converged(&records(&sparse), &options));
        assert!(held_out_converged(&records(&sparse[..7]), &options));
        let sparse = [1.0, nan, nan, nan, 0.99, nan, 0.985];
        assert!(!held_out_converged(&records(&sparse), &options));
        assert!(!held_out_converged(
            &records(&[nan, nan, nan, nan, 0.5]),
            &options
        ));
    }

    /// The lane-batched coefficient solves equal, bit for bit, one kernel at a time through
    /// `cholesky_in_place` / `cholesky_solve_in_place`, including a partial last chunk of lanes,
    /// a zero block (trace 0) and an indefinite one (failed factorisation: zero direction).
    #[test]
    fn lane_batched_block_solves_match_one_at_a_time() {
        use rand::Rng;
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        for (l, kernels) in [(3usize, 7usize), (1, 5), (8, 9)] {
            let mut hess = vec![0.0f64; kernels * l * l];
            let grad: Vec<f64> = (0..kernels * l)
                .map(|_| rng.random::<f64>() - 0.5)
                .collect();
            for (k, h) in hess.chunks_exact_mut(l * l).enumerate() {
                // G Gᵀ of a random l × l matrix: positive semi-definite.
                let g: Vec<f64> = (0..l * l).map(|_| rng.random::<f64>() - 0.5).collect();
                for i in 0..l {
                    for j in 0..l {
                        h[i * l + j] = (0..l).map(|t| g[i * l + t] * g[j * l + t]).sum();
                    }
                }
                if k == 1 {
                    h.fill(0.0);
                }
                if k == 2 && l > 1 {
                    h[1] = 10.0 * (h[0] + h[l + 1]);
                    h[l] = h[1];
                }
            }
            let mut batched = grad.clone();
            solve_single_rhs_blocks(&mut batched, &hess, l);
            for (k, (g, h)) in grad
                .chunks_exact(l)
                .zip(hess.chunks_exact(l * l))
                .enumerate()
            {
                let mut a = h.to_vec();
                let mut x = g.to_vec();
                let trace: f64 = (0..l).map(|i| a[i * l + i]).sum();
                for i in 0..l {
                    a[i * l + i] += CURVATURE_FLOOR * trace / l as f64;
                }
                if trace > 0.0 && cholesky_in_place(&mut a, l) {
                    cholesky_solve_in_place(&a, &mut x, l, 1);
                } else {
                    x.fill(0.0);
                }
                let got = &batched[k * l..(k + 1) * l];
                assert_eq!(
                    got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    x.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    "l {l}, kernel {k}"
                );
                if k == 1 || (k == 2 && l > 1) {
                    assert!(got.iter().all(|&v| v == 0.0), "l {l}, kernel {k}: {got:?}");
                }
            }
        }
    }

    #[test]
    fn iterate_average_weighs_the_first_window_equally_then_forgets() {
        let mut average = IterateAverage::new(2, &[0.0], &[0.0]);
        assert_eq!(average.update(&[4.0], &[8.0]), (&[4.0][..], &[8.0][..]));
        assert_eq!(average.update(&[2.0], &[0.0]), (&[3.0][..], &[4.0][..]));
        // From now on weight 1/2: (3 + 1) / 2.
        assert_eq!(average.update(&[1.0], &[0.0]).0, &[2.0][..]);
        let mut off = IterateAverage::new(0, &[0.0], &[0.0]);
        assert!(!off.is_active());
        assert_eq!(off.update(&[5.0], &[6.0]), (&[5.0][..], &[6.0][..]));
    }
}

//! Exact polish of an MBD (beyond the paper): alternating exact minimisation of the
//! *continuous* loss, which the stochastic solver only estimates.
//!
//! With the coefficient hats of [`crate::Mbd`] (nodes at the voxel centres, clamped outside
//! them) and the trilinear target of the field, every factor is piecewise linear along each
//! axis: the coefficients `c(x)` and the target `f(x)` between voxel centres (constant in the
//! outer half voxels), and the basis `b(x)` between its own breakpoints — basis nodes for a hat
//! grid over any box inside the field's (clamped outside it), voxel centres for the families
//! stored at the voxel centres ([`crate::WallAware`], [`crate::LabelKernels`]; see
//! [`PolishBasis`]). Splitting each axis at all those breakpoints leaves intervals on which the
//! residual `f̂ − f = c·b − f` is a polynomial of degree ≤ 2 per axis, so its square has
//! degree ≤ 4: a tensor 3-point Gauss–Legendre rule on every interval box integrates the loss
//!
//! ```text
//! E(c, B) = ∫ ‖f(x) − f̂(x)‖² dx + λ/2 ‖c‖²        (x in units of one voxel's volume)
//! ```
//!
//! exactly (up to rounding) — the loss [`crate::solve`] estimates with one jittered sample per
//! voxel, and `E_data / ∫‖f‖²` is what [`crate::evaluate`] estimates.
//!
//! [`polish`] alternates the two exact half-steps, as [`crate::solve_als`] does on the voxel
//! centres:
//! * **basis given the coefficients**: the normal equations `G vec(B) = R`, with one Gram `G` of
//!   size `N·L` shared by all D outputs (Cholesky);
//! * **coefficients given the basis**: neighbouring voxels couple through overlapping hats, so
//!   the normal equations are block-sparse (`L × L` blocks between each voxel and its 3³
//!   neighbours, the ridge on the diagonal), solved by conjugate gradients preconditioned with
//!   the diagonal blocks.
//!
//! Alternation creeps along the valley of the coupled problem, so by default [`polish`] runs
//! nonlinear conjugate gradients on the loss with the basis solved out, preconditioned by the
//! coefficient step ([`PolishAcceleration`]).
//!
//! Each step's result is rounded to the model's f32 storage and accepted only if the exact
//! loss did not increase, so the loss of the returned model never exceeds the input's. Memory:
//! the coefficient system stores each pair of neighbours' block once, `14 L²` f64 per voxel
//! (7.2 KB at L = 8: 235 MB for 32³).
//!
//! For the voxel-stored families both systems are assembled per voxel-centre cell from the
//! blended bases of its eight corners, whose rows hold a few kernels each (Sponza, 125
//! clustered kernels: 6.3 on average at radius 2, 10.1 at radius 3), so a sweep costs about
//! what it costs on the hat grid (traced Sponza 48 × 20 × 30, L = 8, radius 3: ~9 s wall on
//! two cores with the extrapolation's extra basis system; a conjugate-gradient iteration costs
//! about as much).

use std::ops::Range;
use std::time::Instant;

use ndarray::{Array2, Array3, ArrayView2, linalg::general_mat_mul};
use prt_core::{Compressor, GridField, Progress, SpatialKernels};
use prt_kernels::HatGrid;
use rayon::prelude::*;

use crate::baselines::voxel_centre_box;
use crate::subspace::{cholesky_in_place, cholesky_solve_in_place, linalg_error};
use crate::voxel_weights::VoxelWeights;
use crate::{Mbd, MbdError, MbdModel, MbdOptions, SolveReport};

/// Largest `N·L` (basis nodes × rank) for which [`polish`] assembles and factors the dense
/// normal equations of the basis step (an 8192² f64 matrix is 512 MiB).
pub const POLISH_MAX_BASIS_UNKNOWNS: usize = 8192;

/// 3-point Gauss–Legendre rule on [−1, 1]: exact for polynomials of degree ≤ 5.
const GAUSS_NODES: [f64; 3] = [-0.774_596_669_241_483_4, 0.0, 0.774_596_669_241_483_4];
const GAUSS_WEIGHTS: [f64; 3] = [5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0];
/// Basis cells whose coefficient-system contributions are held in memory before they are
/// added (in cell order, so the sums do not depend on the thread count).
const CELL_BATCH: usize = 4;
/// Voxels per chunk of the parallel matrix-vector products and dot products (fixed, so the
/// reductions do not depend on the thread count).
const NODE_CHUNK: usize = 256;
/// Growth of the extrapolation factor after a successful extrapolation, and its cap.
const EXTRAPOLATION_GROWTH: f64 = 1.5;
const MAX_EXTRAPOLATION: f64 = 16.0;
/// Points per GEMM of the basis step's Gram.
const GRAM_BATCH: usize = 2048;
/// Index of the voxel itself among its 3³ neighbours `(dx+1) + 3(dy+1) + 9(dz+1)`.
const SELF_BLOCK: usize = 13;
/// Blocks stored per voxel for data on pairs of neighbouring voxels with `X_{u,v} = X_{v,u}ᵀ`
/// (the coefficient system's blocks, the basis system's `H` and `T`): each pair is stored once,
/// by the voxel that sees the other as a forward neighbour (index above [`SELF_BLOCK`]), so a
/// voxel stores its own block at slot 0 and those towards its 13 forward neighbours after it.
const STORED_BLOCKS: usize = 14;

/// Side in voxels (x and y) of the columns [`column_order`] walks.
const COLUMN: usize = 16;

/// The voxels in columns of `COLUMN × COLUMN` voxels in x and y, each column plane by plane
/// (z, then y, then x), and where each column starts. Walking a column this way, the pair blocks
/// a voxel reads from its backward neighbours ([`pair_block`]) were read one plane before and
/// are still in cache (a plane of a column's blocks is 1.8 MB at L = 8), where a walk of the
/// whole grid in voxel order would fetch them again from memory once a plane's blocks outgrow
/// the cache (Sponza 96: 28 MB).
fn column_order([nx, ny, nz]: [usize; 3]) -> (Vec<usize>, Vec<usize>) {
    let mut order = Vec::with_capacity(nx * ny * nz);
    let mut starts = vec![0];
    for y0 in (0..ny).step_by(COLUMN) {
        for x0 in (0..nx).step_by(COLUMN) {
            for z in 0..nz {
                for y in y0..(y0 + COLUMN).min(ny) {
                    order.extend((x0..(x0 + COLUMN).min(nx)).map(|x| x + nx * (y + ny * z)));
                }
            }
            starts.push(order.len());
        }
    }
    (order, starts)
}

/// The neighbours `u` of voxel `v` in its 3³ block that lie in the grid, with their index
/// `(dx+1) + 3(dy+1) + 9(dz+1)`.
fn neighbours(v: usize, [nx, ny, nz]: [usize; 3]) -> impl Iterator<Item = (usize, usize)> {
    let at = [v % nx, v / nx % ny, v / (nx * ny)];
    (0..27).filter_map(move |nbr| {
        // Coordinates shifted by one, so that −1 is 0.
        let q = [0, 1, 2].map(|k| at[k] + [nbr % 3, nbr / 3 % 3, nbr / 9][k]);
        if (0..3).any(|k| q[k] == 0 || q[k] > [nx, ny, nz][k]) {
            return None;
        }
        Some((nbr, (q[0] - 1) + nx * ((q[1] - 1) + ny * (q[2] - 1))))
    })
}

/// The stored block of the pair of voxel `v` and its neighbour `u` (neighbour index `nbr`):
/// stored by `v` when `u` is a forward neighbour, else by `u` (then transposed as seen from
/// `v`, which makes no difference to the symmetric blocks the polish stores).
fn pair_block(v: usize, u: usize, nbr: usize) -> usize {
    if nbr >= SELF_BLOCK {
        v * STORED_BLOCKS + nbr - SELF_BLOCK
    } else {
        u * STORED_BLOCKS + SELF_BLOCK - nbr
    }
}

/// Options of [`polish`].
#[derive(Debug, Clone, PartialEq)]
pub struct PolishOptions {
    /// Sweeps (basis step, then coefficient step) or conjugate-gradient iterations, at most
    /// (default 16).
    pub sweeps: usize,
    /// Ridge weight λ on the coefficients (default 1e-8, not the solver's 1e-4). The
    /// stochastic solver needs the ridge to fix the scale ambiguity `c_l b_l = (s c_l)(b_l / s)`;
    /// the exact solves do not, and near the optimum the solver's ridge dominates the loss
    /// (synthetic 32³ × 324, L = 8: ridge 6.77 against a data term of 8e-3), so with λ = 1e-4
    /// the polish spends its steps trading coefficient scale against the basis and the relative
    /// MSE wanders (3.7–8.7e-8 over sweeps 4–16) instead of falling (3.5e-8 with 1e-8;
    /// `docs/results.md`, MBD session 6).
    pub lambda: f32,
    /// Stop when a sweep lowers the exact loss by less than this relative to the data term
    /// (default 1e-3; 0 runs all `sweeps`). The conjugate gradients judge the mean decrease of
    /// their last three iterations (so they run at least three).
    pub tolerance: f64,
    /// Relative residual at which the coefficient step's conjugate gradients stop (default
    /// 1e-8: on the synthetic 32³ field, 1e-7 … 1e-10 end at the same error to 5 digits after
    /// 4 sweeps, 1e-5 0.13 % higher; 1e-10 costs 14 % more than 1e-8).
    pub cg_tolerance: f64,
    /// Iteration cap of the conjugate gradients (default 400).
    pub max_cg_iterations: usize,
    /// How the alternating solves are sped up (default
    /// [`PolishAcceleration::ConjugateGradients`]). Alternating solves creep along the valley
    /// of the coupled c–B problem (the loss barely changes when the coefficients and the basis
    /// turn against each other smoothly in space); see [`PolishAcceleration`].
    pub acceleration: PolishAcceleration,
}

/// How [`polish`] speeds up the alternating solves ([`PolishOptions::acceleration`]).
///
/// Measured (`docs/results.md`, MBD sessions 11 and 12): on Sponza 48 (wide label kernels, 16
/// solver iterations) 24 iterations end at 3.07e-4 with conjugate gradients against 3.14e-4
/// with the extrapolation (−2.2 %, 15 % more time per iteration), and the conjugate gradients
/// stop by the default tolerance after 46 iterations at 1.085× clustered PCA (72: 47, 1.077×;
/// 96: 38, 1.042×; 37, 1.0435× since session 13); on the synthetic 32³ × 324 field (6³ hat grid, 128 solver iterations), 16
/// iterations end at 5.99e-9 against 6.27e-9 (−4.5 %, less CPU), and after a 16-iteration
/// solve they stop by their rule after 73 iterations at 4.99e-9, 28 % below blockwise PCA.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum PolishAcceleration {
    /// Plain alternation: a sweep is a basis step, then a coefficient step.
    None,
    /// After each sweep, try moving the coefficients on along the sweep's displacement
    /// `c + β (c − c_prev)`, with the basis solved exactly for them, and keep that point if its
    /// exact loss is lower. β starts at 1, grows by 1.5× (up to 16) after each success and
    /// falls back to 1 after a failure (line-search / extrapolated ALS). Judging the trial at
    /// its optimal basis rather than at the extrapolated one accepts every point the latter
    /// would, and more: on Sponza 48 with wide label kernels, 24 sweeps end 1.5 % lower
    /// (`docs/results.md`, MBD session 10).
    Extrapolation,
    /// Preconditioned nonlinear conjugate gradients (Polak–Ribière, restarted when β < 0 or
    /// the direction does not descend) on the reduced loss `g(c) = min_B E(c, B)`, whose
    /// every evaluation solves the basis exactly (variable projection). Its gradient is the
    /// coefficient step's residual at that basis, and the coefficient step itself is the
    /// gradient preconditioned by the coefficient system — the same nonlinear preconditioning
    /// of conjugate gradients by alternating least squares as De Sterck (2012, "A nonlinearly
    /// preconditioned conjugate gradient algorithm for rank-R canonical tensor
    /// approximation"). The line search starts from the step that is optimal with the basis
    /// fixed (which lowers `g`, since `g ≤ E(·, B)`), stretched by the previous iteration's
    /// ratio, and tries the vertex of the parabola through `g(0)`, `g'(0)` and that trial when it
    /// lies elsewhere: on Sponza the accepted steps are 8–10 times the fixed-basis one. An
    /// iteration costs one coefficient system and one or two basis systems, as a sweep with
    /// the extrapolation does; [`PolishStep::LineSearch`] records each trial.
    ConjugateGradients,
}

impl Default for PolishOptions {
    fn default() -> Self {
        Self {
            sweeps: 16,
            lambda: 1e-8,
            tolerance: 1e-3,
            cg_tolerance: 1e-8,
            max_cg_iterations: 400,
            acceleration: PolishAcceleration::ConjugateGradients,
        }
    }
}

/// Basis kernels whose exact continuous loss [`polish`] and [`exact_loss`] integrate (a sealed
/// trait): a [`HatGrid`] over a box inside the field's (the basis of [`crate::Mbd`]), and the
/// kernel families stored at the field's voxel centres and blended trilinearly between them,
/// [`crate::WallAware`] and [`crate::LabelKernels`]. For the latter every factor of the model is
/// trilinear between voxel centres, so the breakpoints are the voxel centres alone.
pub trait PolishBasis: SpatialKernels + sealed::Sealed {}

pub(crate) mod sealed {
    /// How a [`super::PolishBasis`] is laid out (crate-private).
    pub trait Sealed {
        /// The layout the quadrature needs.
        fn layout(&self) -> super::BasisLayout<'_>;
    }
}

/// The two layouts the quadrature integrates exactly.
pub enum BasisLayout<'a> {
    Hat(&'a HatGrid),
    Voxels(&'a VoxelWeights),
}

impl sealed::Sealed for HatGrid {
    fn layout(&self) -> BasisLayout<'_> {
        BasisLayout::Hat(self)
    }
}

impl PolishBasis for HatGrid {}

/// The exact continuous loss of a model (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ExactLoss {
    /// `∫ ‖f − f̂‖² dx` in units of one voxel's volume. It is computed as `∫‖f̂‖² − 2∫f̂·f +
    /// ∫‖f‖²` in f64, so it is exact up to rounding of order 1e-13 of `energy` (clamped at 0).
    pub data: f64,
    /// `λ/2 ‖c‖²`.
    pub ridge: f64,
    /// `∫ ‖f‖² dx`, same units.
    pub energy: f64,
}

impl ExactLoss {
    /// `data + ridge`, the loss the solvers minimise.
    pub fn loss(&self) -> f64 {
        self.data + self.ridge
    }

    /// `data / energy` (`data` for a zero field): the exact value of [`crate::evaluate`]'s
    /// relative MSE.
    pub fn relative_mse(&self) -> f64 {
        if self.energy > 0.0 {
            self.data / self.energy
        } else {
            self.data
        }
    }
}

/// Which step of a sweep or conjugate-gradient iteration a [`PolishRecord`] describes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum PolishStep {
    /// The basis solve with the coefficients fixed.
    Basis,
    /// The coefficient solve with the basis fixed (for the conjugate gradients: the end of an
    /// iteration, whose preconditioner that solve is).
    Coefficients,
    /// The extrapolation after a sweep ([`PolishAcceleration::Extrapolation`]).
    Extrapolation,
    /// A trial point of the line search of [`PolishAcceleration::ConjugateGradients`]
    /// (accepted: the best so far of its iteration).
    LineSearch,
}

/// One half-step of [`polish`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PolishRecord {
    /// Which half-step.
    pub step: PolishStep,
    /// The exact loss after it (of the model kept: the input to the step if it was rejected).
    pub loss: ExactLoss,
    /// Whether the solve lowered the exact loss and was kept.
    pub accepted: bool,
    /// Conjugate-gradient iterations (0 for the basis step).
    pub cg_iterations: usize,
    /// Seconds since the polish started.
    pub elapsed: f64,
}

/// What [`polish`] did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PolishReport {
    /// The exact loss of the input model.
    pub initial: ExactLoss,
    /// One record per half-step.
    pub history: Vec<PolishRecord>,
    /// Whether the tolerance stopped the polish before `sweeps`.
    pub converged: bool,
}

impl PolishReport {
    /// The exact loss of the returned model.
    pub fn last(&self) -> ExactLoss {
        self.history.last().map_or(self.initial, |r| r.loss)
    }
}

/// The exact continuous loss of `model` against `field` with ridge weight `lambda`.
///
/// # Errors
/// As [`polish`].
pub fn exact_loss<B: PolishBasis>(
    field: &GridField,
    model: &MbdModel<HatGrid, B>,
    lambda: f32,
) -> Result<ExactLoss, MbdError> {
    let options = PolishOptions {
        lambda,
        ..PolishOptions::default()
    };
    let quadrature = Systems::new(
        field,
        model.coefficient_kernels(),
        model.basis_kernels(),
        model.basis(),
        &options,
    )?;
    let l = model.rank();
    let c: Vec<f64> = model.coefficients().iter().map(|&v| v as f64).collect();
    let b = basis_rows(model.basis())?;
    let energy = quadrature.energy(field);
    let system = quadrature.basis_system(field, &c, l, &mut Vec::new(), &prt_core::NoProgress)?;
    Ok(ExactLoss {
        data: (system.quadratic(&b) + energy).max(0.0),
        ridge: ridge(&c, lambda),
        energy,
    })
}

/// Polishes `model` by alternating exact solves of the continuous loss (module docs), for at
/// most `options.sweeps` sweeps, and returns the polished model with the exact loss per
/// half-step. The exact loss never increases; the result is deterministic (no sampling, fixed
/// reduction order) on any thread count. Progress reports one unit per sweep; cancellation is
/// checked between basis cells and conjugate-gradient iterations.
///
/// # Errors
/// [`MbdError::InvalidKernels`] unless the coefficient kernels are those of [`crate::Mbd`] for
/// `field` (hats at the voxel centres), the basis is a hat grid of at least 2 nodes per axis
/// over a box inside the field's or a voxel-stored family on the field's own voxels and box,
/// and the field has at least 2 voxels per axis; [`MbdError::ShapeMismatch`] if the model's dimension differs
/// from the field's; [`MbdError::InvalidOption`] for a negative or non-finite λ or tolerance, a
/// non-positive `cg_tolerance`, `max_cg_iterations == 0`, or `N·L` above
/// [`POLISH_MAX_BASIS_UNKNOWNS`]; non-finite field values; cancellation.
pub fn polish<B: PolishBasis>(
    field: &GridField,
    model: MbdModel<HatGrid, B>,
    options: &PolishOptions,
    progress: &dyn Progress,
) -> Result<(MbdModel<HatGrid, B>, PolishReport), MbdError> {
    let start = Instant::now();
    let l = model.rank();
    let (coefficient_kernels, basis_kernels, coefficients, basis) = model.into_parts();
    let quadrature = Systems::new(field, &coefficient_kernels, &basis_kernels, &basis, options)?;
    let mut c: Vec<f64> = coefficients.iter().map(|&v| v as f64).collect();
    let mut b = basis_rows(&basis)?;
    let energy = quadrature.energy(field);
    let lambda = options.lambda;
    let exact = |quadratic: f64, c: &[f64]| exact_from(quadratic, c, lambda, energy);
    progress.set_len(options.sweeps as u64);
    // One buffer of 14 `L × L` blocks per voxel, passed between the coefficient system and the
    // voxel-stored basis step's neighbour blocks, so that the two are never held at once and
    // are not allocated afresh at every half-step (1.6 GB each on Sponza 96 × 40 × 59).
    let mut blocks = Vec::new();
    let mut basis_system = quadrature.basis_system(field, &c, l, &mut blocks, progress)?;
    let initial = ExactLoss {
        data: (basis_system.quadratic(&b) + energy).max(0.0),
        ridge: ridge(&c, lambda),
        energy,
    };
    let mut report = PolishReport {
        initial,
        ..PolishReport::default()
    };
    let mut loss = initial;
    if options.acceleration == PolishAcceleration::ConjugateGradients {
        let ctx = Conjugate {
            quadrature: &quadrature,
            field,
            rank: l,
            options,
            energy,
            start,
            progress,
        };
        ctx.run(&mut c, &mut b, &mut loss, basis_system, blocks, &mut report)?;
    } else {
        // The coefficients at the end of the previous sweep, and the extrapolation factor.
        let mut previous: Option<Vec<f64>> = None;
        let mut beta = 1.0;
        // Whether `b` already solves the basis system (an accepted extrapolation solved it for its
        // coefficients), so that the basis step has nothing left to do.
        let mut basis_solved = false;
        for _ in 0..options.sweeps {
            progress.check()?;
            let sweep_start = loss;
            // Basis step.
            let accepted = std::mem::take(&mut basis_solved) || {
                let after = basis_system.step(&mut b)?;
                if let Some(after) = after {
                    loss = exact(after + ridge(&c, lambda), &c);
                }
                after.is_some()
            };
            report.history.push(PolishRecord {
                step: PolishStep::Basis,
                loss,
                accepted,
                cg_iterations: 0,
                elapsed: start.elapsed().as_secs_f64(),
            });
            // Coefficient step.
            let system = quadrature.coefficient_system(
                field,
                b.as_slice().unwrap_or(&[]),
                l,
                lambda,
                std::mem::take(&mut blocks),
                progress,
            )?;
            let before = system.quadratic(&c);
            let (trial, cg_iterations) =
                system.solve(&c, system.residual(&c), options, progress)?;
            let after = system.quadratic(&trial);
            blocks = system.into_blocks();
            let accepted = after <= before;
            if accepted {
                c = trial;
                loss = exact(after, &c);
            }
            report.history.push(PolishRecord {
                step: PolishStep::Coefficients,
                loss,
                accepted,
                cg_iterations,
                elapsed: start.elapsed().as_secs_f64(),
            });
            progress.inc(1);
            progress.message(&format!("polish relative MSE {:.4e}", loss.relative_mse()));
            let decrease = sweep_start.loss() - loss.loss();
            if options.tolerance > 0.0 && decrease <= options.tolerance * sweep_start.data {
                report.converged = true;
                break;
            }
            basis_system = match previous.replace(c.clone()) {
                Some(c_prev) if options.acceleration == PolishAcceleration::Extrapolation => {
                    // Extrapolate the coefficients along this sweep's displacement and solve the
                    // basis for them; keep the point only if the exact loss falls (its basis system
                    // is the next basis step's, so a success costs nothing).
                    let c_hat: Vec<f64> = c
                        .iter()
                        .zip(&c_prev)
                        .map(|(&x, &y)| round_f32(x + beta * (x - y)))
                        .collect();
                    let system =
                        quadrature.basis_system(field, &c_hat, l, &mut blocks, progress)?;
                    let b_hat = system.solve()?;
                    let trial = exact(system.quadratic(&b_hat) + ridge(&c_hat, lambda), &c_hat);
                    let accepted = trial.loss() < loss.loss();
                    report.history.push(PolishRecord {
                        step: PolishStep::Extrapolation,
                        loss: if accepted { trial } else { loss },
                        accepted,
                        cg_iterations: 0,
                        elapsed: start.elapsed().as_secs_f64(),
                    });
                    if accepted {
                        (c, b, loss) = (c_hat, b_hat, trial);
                        basis_solved = true;
                        beta = (beta * EXTRAPOLATION_GROWTH).min(MAX_EXTRAPOLATION);
                        system
                    } else {
                        beta = 1.0;
                        quadrature.basis_system(field, &c, l, &mut blocks, progress)?
                    }
                }
                _ => quadrature.basis_system(field, &c, l, &mut blocks, progress)?,
            };
        }
    }
    let to_f32 = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
    let shape_error = |e: ndarray::ShapeError| MbdError::InvalidOption {
        what: "tensor shape",
        why: e.to_string(),
    };
    let coefficients =
        Array2::from_shape_vec(coefficients.dim(), to_f32(&c)).map_err(shape_error)?;
    let basis = Array3::from_shape_vec(basis.dim(), to_f32(b.as_slice().unwrap_or(&[])))
        .map_err(shape_error)?;
    let model = MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis)?;
    Ok((model, report))
}

/// Longest step of the conjugate-gradient line search, in multiples of the step that is optimal
/// with the basis held fixed.
const MAX_STRETCH: f64 = 32.0;
/// Iterations whose mean decrease the conjugate gradients' stopping rule judges.
const STOP_WINDOW: usize = 3;

/// Preconditioned nonlinear conjugate gradients on the reduced loss `g(c) = min_B E(c, B)`
/// ([`PolishAcceleration::ConjugateGradients`]).
struct Conjugate<'q, 'a> {
    quadrature: &'q Systems<'a>,
    field: &'q GridField,
    rank: usize,
    options: &'q PolishOptions,
    energy: f64,
    start: Instant,
    progress: &'q dyn Progress,
}

impl Conjugate<'_, '_> {
    fn exact(&self, quadratic: f64, c: &[f64]) -> ExactLoss {
        exact_from(quadratic, c, self.options.lambda, self.energy)
    }

    /// `g(c)` and the basis attaining it.
    fn reduced(
        &self,
        c: &[f64],
        scratch: &mut Vec<f64>,
    ) -> Result<(ExactLoss, Array2<f64>), MbdError> {
        let system =
            self.quadrature
                .basis_system(self.field, c, self.rank, scratch, self.progress)?;
        let b = system.solve()?;
        let loss = self.exact(system.quadratic(&b) + ridge(c, self.options.lambda), c);
        Ok((loss, b))
    }

    fn record(
        &self,
        report: &mut PolishReport,
        step: PolishStep,
        loss: ExactLoss,
        accepted: bool,
        cg_iterations: usize,
    ) {
        report.history.push(PolishRecord {
            step,
            loss,
            accepted,
            cg_iterations,
            elapsed: self.start.elapsed().as_secs_f64(),
        });
    }

    fn run(
        &self,
        c: &mut Vec<f64>,
        b: &mut Array2<f64>,
        loss: &mut ExactLoss,
        basis_system: BasisSystem,
        mut blocks: Vec<f64>,
        report: &mut PolishReport,
    ) -> Result<(), MbdError> {
        let options = self.options;
        let lambda = options.lambda;
        // The gradient needs the basis that solves the basis system.
        let after = basis_system.step(b)?;
        drop(basis_system);
        if let Some(after) = after {
            *loss = self.exact(after + ridge(c, lambda), c);
        }
        self.record(report, PolishStep::Basis, *loss, after.is_some(), 0);
        // (gradient, preconditioned gradient, direction) of the previous iteration.
        let mut previous: Option<(Vec<f64>, Vec<f64>, Vec<f64>)> = None;
        // The last accepted step in multiples of the step optimal with the basis fixed.
        let mut previous_stretch = 1.0;
        // The loss at the start of every iteration, for the stopping rule.
        let mut window: Vec<ExactLoss> = Vec::new();
        for _ in 0..options.sweeps {
            self.progress.check()?;
            let sweep_start = *loss;
            let system = self.quadrature.coefficient_system(
                self.field,
                b.as_slice().unwrap_or(&[]),
                self.rank,
                lambda,
                std::mem::take(&mut blocks),
                self.progress,
            )?;
            // Half the gradient of g: `A c − r` at the optimal basis (envelope theorem); the
            // alternating step is `−A⁻¹` of it, the preconditioned gradient.
            let residual = system.residual(c);
            let gradient: Vec<f64> = residual.iter().map(|&r| -r).collect();
            let (alternating, cg_iterations) = system.solve(c, residual, options, self.progress)?;
            let preconditioned: Vec<f64> =
                c.iter().zip(&alternating).map(|(&x, &y)| x - y).collect();
            let mut direction: Vec<f64> = preconditioned.iter().map(|&x| -x).collect();
            if let Some((g0, p0, d0)) = &previous {
                // Polak–Ribière with restarts (β ≥ 0, descent kept).
                let beta = (dot(&gradient, &preconditioned) - dot(&gradient, p0)) / dot(g0, p0);
                if beta > 0.0 && beta.is_finite() {
                    let mixed: Vec<f64> = direction
                        .iter()
                        .zip(d0)
                        .map(|(&d, &e)| d + beta * e)
                        .collect();
                    if dot(&gradient, &mixed) < 0.0 {
                        direction = mixed;
                    }
                }
            }
            let slope = dot(&gradient, &direction);
            let mut ad = vec![0.0; c.len()];
            system.apply(&direction, &mut ad);
            let curvature = dot(&direction, &ad);
            blocks = system.into_blocks();
            if !(slope < 0.0 && curvature > 0.0) {
                self.record(
                    report,
                    PolishStep::Coefficients,
                    *loss,
                    false,
                    cg_iterations,
                );
                report.converged = true;
                break;
            }
            // The step optimal with the basis fixed lowers g (g ≤ E(·, B)), but g is flatter
            // along the coupled valley (on Sponza the best step is 8–10 times longer): try the
            // previous iteration's multiple of it, then the minimum of the parabola through
            // g(0), g'(0) and that trial when it lies elsewhere; if neither lowers g, the step
            // with the basis fixed.
            let point = |alpha: f64| -> Vec<f64> {
                c.iter()
                    .zip(&direction)
                    .map(|(&x, &d)| round_f32(x + alpha * d))
                    .collect()
            };
            let fixed = -slope / curvature;
            let start_loss = *loss;
            let phi0 = start_loss.loss();
            let mut best: Option<(f64, Vec<f64>, Array2<f64>, ExactLoss)> = None;
            let try_step = |stretch: f64,
                            best: &mut Option<(f64, Vec<f64>, Array2<f64>, ExactLoss)>,
                            report: &mut PolishReport,
                            blocks: &mut Vec<f64>|
             -> Result<f64, MbdError> {
                let trial = point(fixed * stretch);
                let (trial_loss, trial_b) = self.reduced(&trial, blocks)?;
                let better = trial_loss.loss() < best.as_ref().map_or(phi0, |x| x.3.loss());
                if better {
                    *best = Some((stretch, trial, trial_b, trial_loss));
                }
                let kept = best.as_ref().map_or(start_loss, |x| x.3);
                self.record(report, PolishStep::LineSearch, kept, better, 0);
                Ok(trial_loss.loss())
            };
            let first = previous_stretch;
            let phi1 = try_step(first, &mut best, report, &mut blocks)?;
            // g(s) ≈ φ0 + 2 slope·fixed·s + κ s²; κ from the trial.
            let kappa = (phi1 - phi0 - 2.0 * slope * fixed * first) / (first * first);
            let vertex = if kappa > 0.0 {
                (-slope * fixed / kappa).min(MAX_STRETCH)
            } else {
                MAX_STRETCH
            };
            if !(0.7 * first..=1.4 * first).contains(&vertex) {
                try_step(vertex, &mut best, report, &mut blocks)?;
            }
            if best.is_none() && first != 1.0 && vertex != 1.0 {
                try_step(1.0, &mut best, report, &mut blocks)?;
            }
            let moved = best.is_some();
            if let Some((stretch, c_new, b_new, loss_new)) = best {
                (*c, *b, *loss) = (c_new, b_new, loss_new);
                previous = Some((gradient, preconditioned, direction));
                previous_stretch = stretch.max(1.0);
            } else {
                previous = None;
                previous_stretch = 1.0;
            }
            self.record(
                report,
                PolishStep::Coefficients,
                *loss,
                moved,
                cg_iterations,
            );
            self.progress.inc(1);
            self.progress
                .message(&format!("polish relative MSE {:.4e}", loss.relative_mse()));
            // The progress of one iteration varies with its line search (on Sponza 72 one
            // iteration in 24 gained 0.05 % between iterations gaining 0.25 %), so the rule
            // looks at the mean of the last few.
            window.push(sweep_start);
            let oldest = window[window.len().saturating_sub(STOP_WINDOW)];
            let mean_decrease = (oldest.loss() - loss.loss()) / STOP_WINDOW as f64;
            if !moved
                || (options.tolerance > 0.0
                    && window.len() >= STOP_WINDOW
                    && mean_decrease <= options.tolerance * oldest.data)
            {
                report.converged = true;
                break;
            }
        }
        Ok(())
    }
}

/// The basis step's dense system has `nodes · rank` unknowns: at most
/// [`POLISH_MAX_BASIS_UNKNOWNS`].
pub(crate) fn check_basis_size(nodes: usize, rank: usize) -> Result<(), MbdError> {
    if nodes.saturating_mul(rank) > POLISH_MAX_BASIS_UNKNOWNS {
        return Err(MbdError::InvalidOption {
            what: "polish basis size",
            why: format!(
                "{nodes} nodes x rank {rank} exceeds {POLISH_MAX_BASIS_UNKNOWNS} dense unknowns"
            ),
        });
    }
    Ok(())
}

/// [`PolishedMbd`]'s default stopping rule for the polish phase: a sweep that lowers the exact
/// loss by less than 3 % of the data term ends it. A sweep costs about 30 solver iterations
/// (32³ × 324, L = 8), so this is the solver's 1e-3 per iteration at equal CPU.
pub const POLISH_STALL_TOLERANCE: f64 = 3e-2;

/// MBD on hat grids fitted in two phases (beyond the paper, opt-in): the stochastic solver
/// ([`crate::solve`]) until its stopping rule fires (or its iteration cap), then exact
/// [`polish`] sweeps until a sweep gains less than `polish.tolerance`.
///
/// On smooth, noise-free fields the stochastic solver creeps long before it reaches its floor
/// (synthetic 32³ × 324, L = 8: still falling ~0.3 % per iteration at its cap of 128, 2.98e-8),
/// while the exact sweeps, which carry no sampling noise, keep descending: [`PolishedMbd::new`]
/// ends there after 128 iterations and 3 sweeps at 2.30e-8, for 1.8× the CPU of the 128
/// iterations; with the hand-off at `mbd.options.tolerance = 1e-2` the solver's rule fires at
/// 76 iterations and 4 sweeps end at 2.29e-8 (1.7× the CPU). On traced volumes, where the
/// solver's own rule fires near its floor, one sweep follows and gains 0.7–1.5 % for +40 % CPU
/// (about what running the solver as long gains), and an early hand-off is worse than
/// [`crate::Mbd`] (Cornell 1.01e-3 against 9.58e-4; measured with the basis over the field's
/// box). Figures in `docs/results.md`, MBD session 7.
#[derive(Debug, Clone, PartialEq)]
pub struct PolishedMbd {
    /// The stochastic phase: basis nodes and solver options; `options.tolerance` is the
    /// hand-off point (1e-2 hands off earlier on smooth fields, see above).
    pub mbd: Mbd,
    /// The polish phase; `tolerance` is its stopping rule and `sweeps` its cap.
    pub polish: PolishOptions,
}

impl PolishedMbd {
    /// `basis_nodes` per axis and the solver `options` (the hand-off where the solver would
    /// stop), then up to 16 sweeps stopped by [`POLISH_STALL_TOLERANCE`], with
    /// [`PolishAcceleration::Extrapolation`]: its rule judges every sweep, so a hand-off
    /// close to the optimum costs one sweep rather than the conjugate gradients' three.
    pub fn new(basis_nodes: [usize; 3], options: MbdOptions) -> Self {
        Self {
            mbd: Mbd {
                basis_nodes,
                options,
            },
            polish: PolishOptions {
                tolerance: POLISH_STALL_TOLERANCE,
                acceleration: PolishAcceleration::Extrapolation,
                ..PolishOptions::default()
            },
        }
    }

    /// Runs both phases and returns the model with both reports. Deterministic for a seed on
    /// any thread count; the progress sees the solver's iterations, then the sweeps.
    ///
    /// # Errors
    /// Those of [`crate::solve`] and [`polish`].
    pub fn fit(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<(MbdModel<HatGrid, HatGrid>, SolveReport, PolishReport), MbdError> {
        // Bad polish options fail before the stochastic phase, not after it.
        validate_options(&self.polish)?;
        check_basis_size(self.mbd.basis_nodes.iter().product(), self.mbd.options.rank)?;
        let (model, solved) = self.mbd.fit(field, progress)?;
        let (model, polished) = polish(field, model, &self.polish, progress)?;
        Ok((model, solved, polished))
    }
}

impl Compressor for PolishedMbd {
    type Model = MbdModel<HatGrid, HatGrid>;
    type Error = MbdError;

    fn compress(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<Self::Model, MbdError> {
        Ok(self.fit(field, progress)?.0)
    }
}

mod voxels;
use voxels::VoxelQuadrature;

/// `∫ ‖f(x)‖² dx` of the trilinear interpolation of `field` over its box (clamped in the outer
/// half voxels, as [`GridField::sample`]), in units of one voxel's volume, computed exactly.
/// Applied to the difference between a grid reconstruction (e.g. a [`crate::ClusterModel`]'s,
/// which is sampled trilinearly) and the field, it is that reconstruction's exact error, the
/// counterpart of [`ExactLoss::data`] (divide by the field's own value for the relative MSE).
pub fn trilinear_energy(field: &GridField) -> f64 {
    let voxels = field.dims();
    let mass = [0, 1, 2].map(|k| match voxels[k] {
        1 => vec![[0.0, 1.0, 0.0]],
        n => mass_matrix(&Axis::new(n, 2, (0.0, n as f64)), n),
    });
    trilinear_energy_with(field, mass)
}

/// `∫ φ_i φ_{i+δ}` along one axis, as `[δ = −1, 0, +1]` per voxel, from the axis' rule (exact:
/// degree 2).
fn mass_matrix(axis: &Axis, voxels: usize) -> Vec<[f64; 3]> {
    let mut m = vec![[0.0; 3]; voxels];
    for p in &axis.points {
        let (lo, hi) = (p.ci, p.ci + 1);
        let (wl, wh) = (1.0 - p.ct, p.ct);
        m[lo][1] += p.w * wl * wl;
        m[hi][1] += p.w * wh * wh;
        m[lo][2] += p.w * wl * wh;
        m[hi][0] += p.w * wl * wh;
    }
    m
}

/// `Σ_{v,v'} f_v·f_v' Π_k mass_k`, over the 27 neighbours of every voxel, in fixed chunks.
fn trilinear_energy_with(field: &GridField, mass: [Vec<[f64; 3]>; 3]) -> f64 {
    let [nx, ny, nz] = field.dims();
    let partial: Vec<f64> = (0..field.num_voxels())
        .collect::<Vec<_>>()
        .par_chunks(NODE_CHUNK)
        .map(|chunk| {
            let mut sum = 0.0;
            for &v in chunk {
                let at = [v % nx, v / nx % ny, v / (nx * ny)];
                let fv = field.voxel(v);
                for nbr in 0..27 {
                    let delta = [nbr % 3, nbr / 3 % 3, nbr / 9].map(|t| t as isize - 1);
                    let q = [0, 1, 2].map(|k| at[k] as isize + delta[k]);
                    if (0..3).any(|k| q[k] < 0 || q[k] >= [nx, ny, nz][k] as isize) {
                        continue;
                    }
                    let weight: f64 = (0..3)
                        .map(|k| mass[k][at[k]][(delta[k] + 1) as usize])
                        .product();
                    if weight == 0.0 {
                        continue;
                    }
                    let u = q[0] as usize + nx * (q[1] as usize + ny * q[2] as usize);
                    let dot: f64 = fv
                        .iter()
                        .zip(field.voxel(u))
                        .map(|(&a, &b)| a as f64 * b as f64)
                        .sum();
                    sum += weight * dot;
                }
            }
            sum
        })
        .collect();
    partial.iter().sum()
}

/// The basis tensor `N × L × D` as `N·L × D` rows in f64.
fn basis_rows(basis: &Array3<f32>) -> Result<Array2<f64>, MbdError> {
    let (n, l, d) = basis.dim();
    Array2::from_shape_vec((n * l, d), basis.iter().map(|&v| v as f64).collect()).map_err(|e| {
        MbdError::InvalidOption {
            what: "tensor shape",
            why: e.to_string(),
        }
    })
}

/// The exact loss whose coefficient quadratic `cᵀ A c − 2 rᵀ c` (the ridge included) is
/// `quadratic`.
fn exact_from(quadratic: f64, c: &[f64], lambda: f32, energy: f64) -> ExactLoss {
    let ridge = ridge(c, lambda);
    ExactLoss {
        data: (quadratic + energy - ridge).max(0.0),
        ridge,
        energy,
    }
}

/// `λ/2 ‖c‖²`.
fn ridge(c: &[f64], lambda: f32) -> f64 {
    0.5 * lambda as f64 * c.iter().map(|v| v * v).sum::<f64>()
}

/// Rounds to f32 precision (the model's storage), so that the loss computed in f64 is the loss
/// of the model returned.
fn round_f32(v: f64) -> f64 {
    v as f32 as f64
}

/// The basis domain per axis in voxels from the field's lower face, or `None` unless it lies
/// inside the field's box with a positive extent. Ends within 1e-5 voxels of a half voxel are
/// snapped to it (the voxel-centre box of [`crate::basis_box`] is computed in f32), so that
/// they coincide with the voxel-centre breakpoints.
fn basis_spans(field: &GridField, domain: prt_core::Aabb) -> Option<[(f64, f64); 3]> {
    let (bounds, size, dims) = (field.bounds(), field.voxel_size(), field.dims());
    let mut spans = [(0.0, 0.0); 3];
    for k in 0..3 {
        let to_voxels = |x: f32| {
            let u = (f64::from(x) - f64::from(bounds.min[k])) / f64::from(size[k]);
            let half = (2.0 * u).round() / 2.0;
            if (u - half).abs() < 1e-5 { half } else { u }
        };
        let (lo, hi) = (to_voxels(domain.min[k]), to_voxels(domain.max[k]));
        if !(lo >= 0.0 && hi <= dims[k] as f64 && hi > lo) {
            return None;
        }
        spans[k] = (lo, hi);
    }
    Some(spans)
}

/// One quadrature point along an axis, with the 1D kernel data there.
#[derive(Debug, Clone, Copy)]
struct AxisPoint {
    /// Weight (interval length × Gauss weight, in voxels).
    w: f64,
    /// Lower voxel (coefficient node) of the coefficient / target interpolation, and the hat
    /// weight of the upper one.
    ci: usize,
    ct: f64,
    /// Basis cell and the hat weight of its upper node.
    bi: usize,
    bt: f64,
}

/// The quadrature points of one axis, in increasing order.
struct Axis {
    points: Vec<AxisPoint>,
    /// Points of each basis cell.
    basis_cells: Vec<Range<usize>>,
}

impl Axis {
    /// `voxels ≥ 2` voxels, `nodes ≥ 2` basis nodes spanning `[lo, hi]` (in voxels from the
    /// field's lower face, `0 ≤ lo < hi ≤ voxels`; the basis is constant outside it, as a hat
    /// grid is clamped).
    fn new(voxels: usize, nodes: usize, (lo, hi): (f64, f64)) -> Axis {
        let n = voxels as f64;
        let cells = nodes - 1;
        let mut breaks: Vec<f64> = (0..voxels)
            .map(|i| i as f64 + 0.5)
            .chain((0..nodes).map(|k| lo + (hi - lo) * k as f64 / cells as f64))
            .chain([0.0, n])
            .collect();
        breaks.sort_by(f64::total_cmp);
        breaks.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
        let mut points = Vec::with_capacity(3 * breaks.len());
        for pair in breaks.windows(2) {
            let (mid, half) = (0.5 * (pair[0] + pair[1]), 0.5 * (pair[1] - pair[0]));
            for (xi, wi) in GAUSS_NODES.iter().zip(GAUSS_WEIGHTS) {
                let u = mid + half * xi;
                let uc = (u - 0.5).clamp(0.0, n - 1.0);
                let ci = (uc.floor() as usize).min(voxels - 2);
                let ub = ((u - lo) * cells as f64 / (hi - lo)).clamp(0.0, cells as f64);
                let bi = (ub.floor() as usize).min(cells - 1);
                points.push(AxisPoint {
                    w: half * wi,
                    ci,
                    ct: uc - ci as f64,
                    bi,
                    bt: ub - bi as f64,
                });
            }
        }
        let basis_cells = (0..cells)
            .map(|cell| {
                let lo = points.partition_point(|p| p.bi < cell);
                let hi = points.partition_point(|p| p.bi <= cell);
                lo..hi
            })
            .collect();
        Axis {
            points,
            basis_cells,
        }
    }

    /// The first voxel and the number of voxels the points `range` touch.
    fn voxel_span(&self, range: &Range<usize>) -> (usize, usize) {
        let lo = self.points[range.start].ci;
        let hi = self.points[range.end - 1].ci + 1;
        (lo, hi - lo + 1)
    }
}

/// The tensor quadrature of a field with the hat grids of [`crate::Mbd`].
struct Quadrature {
    axes: [Axis; 3],
    voxels: [usize; 3],
    nodes: [usize; 3],
}

/// Kernel data at one quadrature point, corners in bit order (bit 0 = x, 1 = y, 2 = z).
struct Point {
    w: f64,
    phi: [f64; 8],
    /// Voxel (coefficient node) of each corner, local to the basis cell's voxel block.
    local: [usize; 8],
    psi: [f64; 8],
}

/// The voxel block a basis cell's points touch.
struct Span {
    lo: [usize; 3],
    len: [usize; 3],
}

impl Span {
    fn count(&self) -> usize {
        self.len.iter().product()
    }

    /// Global flat voxel index of local voxel `v`.
    fn global(&self, v: usize, voxels: [usize; 3]) -> usize {
        let [ex, ey, _] = self.len;
        let (x, y, z) = (v % ex, v / ex % ey, v / (ex * ey));
        self.lo[0] + x + voxels[0] * (self.lo[1] + y + voxels[1] * (self.lo[2] + z))
    }

    /// The field's vectors of the block, `count × D` in f64.
    fn gather(&self, field: &GridField, voxels: [usize; 3]) -> Array2<f64> {
        let d = field.dim();
        let mut f = Array2::<f64>::zeros((self.count(), d));
        for (v, mut row) in f.rows_mut().into_iter().enumerate() {
            for (o, &x) in row.iter_mut().zip(field.voxel(self.global(v, voxels))) {
                *o = x as f64;
            }
        }
        f
    }
}

/// Checks the options that do not depend on the model.
pub(crate) fn validate_options(options: &PolishOptions) -> Result<(), MbdError> {
    for (what, value) in [
        ("lambda", options.lambda as f64),
        ("tolerance", options.tolerance),
    ] {
        if !(value >= 0.0 && value.is_finite()) {
            return Err(MbdError::InvalidOption {
                what,
                why: format!("{value} is not a finite non-negative number"),
            });
        }
    }
    if !(options.cg_tolerance > 0.0 && options.cg_tolerance.is_finite()) {
        return Err(MbdError::InvalidOption {
            what: "cg_tolerance",
            why: format!("{} is not a finite positive number", options.cg_tolerance),
        });
    }
    if options.max_cg_iterations == 0 {
        return Err(MbdError::InvalidOption {
            what: "max_cg_iterations",
            why: "must be at least 1".into(),
        });
    }
    Ok(())
}

/// The exact systems of a model's basis family.
enum Systems<'a> {
    Hat(Quadrature),
    Voxels(VoxelQuadrature<'a>),
}

impl<'a> Systems<'a> {
    /// Checks the field, the model's kernels and shapes and the options.
    fn new<B: PolishBasis>(
        field: &GridField,
        coefficient_kernels: &HatGrid,
        basis_kernels: &'a B,
        basis: &Array3<f32>,
        options: &PolishOptions,
    ) -> Result<Self, MbdError> {
        field.check_finite()?;
        let voxels = field.dims();
        let invalid = |which: &'static str, why: String| MbdError::InvalidKernels { which, why };
        if let Some(axis) = (0..3).find(|&k| voxels[k] < 2) {
            return Err(invalid(
                "coefficient",
                format!(
                    "the polish needs at least 2 voxels per axis (axis {axis} has {})",
                    voxels[axis]
                ),
            ));
        }
        let expected = HatGrid::new(voxels, voxel_centre_box(field))
            .map_err(|e| invalid("coefficient", e.to_string()))?;
        if *coefficient_kernels != expected {
            return Err(invalid(
                "coefficient",
                "the polish needs one hat per voxel centre of the field (as crate::Mbd)".into(),
            ));
        }
        let systems = match basis_kernels.layout() {
            BasisLayout::Hat(hats) => Systems::Hat(Quadrature::new(field, hats)?),
            BasisLayout::Voxels(weights) => {
                Systems::Voxels(VoxelQuadrature::new(field, weights, basis_kernels.len())?)
            }
        };
        let (n, l, d) = basis.dim();
        if n != basis_kernels.len() || d != field.dim() {
            return Err(MbdError::ShapeMismatch {
                what: "basis tensor",
                expected: vec![basis_kernels.len(), l, field.dim()],
                got: basis.shape().to_vec(),
            });
        }
        validate_options(options)?;
        check_basis_size(n, l)?;
        Ok(systems)
    }

    /// `∫ ‖f‖² dx` of the field's trilinear interpolation.
    fn energy(&self, field: &GridField) -> f64 {
        match self {
            Systems::Hat(q) => q.energy(field),
            Systems::Voxels(_) => trilinear_energy(field),
        }
    }

    /// The basis step's normal equations at coefficients `c`; `scratch` is working memory
    /// (any length; the voxel-stored families use it for their neighbour blocks).
    fn basis_system(
        &self,
        field: &GridField,
        c: &[f64],
        l: usize,
        scratch: &mut Vec<f64>,
        progress: &dyn Progress,
    ) -> Result<BasisSystem, MbdError> {
        match self {
            Systems::Hat(q) => q.basis_system(field, c, l, progress),
            Systems::Voxels(q) => q.basis_system(field, c, l, scratch, progress),
        }
    }

    /// The coefficient step's block-sparse normal equations at basis `b`, the ridge included,
    /// its blocks stored in `blocks` (any length; [`CoefficientSystem::into_blocks`] gives it
    /// back).
    fn coefficient_system(
        &self,
        field: &GridField,
        b: &[f64],
        l: usize,
        lambda: f32,
        mut blocks: Vec<f64>,
        progress: &dyn Progress,
    ) -> Result<CoefficientSystem, MbdError> {
        let voxels = field.dims();
        let count: usize = voxels.iter().product();
        let ll = l * l;
        zeroed(&mut blocks, count * STORED_BLOCKS * ll);
        let mut system = CoefficientSystem {
            voxels,
            columns: column_order(voxels),
            rank: l,
            blocks,
            rhs: vec![0.0; count * l],
        };
        match self {
            Systems::Hat(q) => q.add_coefficient_system(field, b, l, &mut system, progress)?,
            Systems::Voxels(q) => q.add_coefficient_system(field, b, l, &mut system, progress)?,
        }
        symmetrise(&mut system.blocks, l);
        let half_lambda = 0.5 * lambda as f64;
        for v in 0..count {
            let own = v * STORED_BLOCKS;
            let block = &mut system.blocks[own * ll..(own + 1) * ll];
            for i in 0..l {
                block[i * l + i] += half_lambda;
            }
        }
        Ok(system)
    }
}

impl Quadrature {
    /// The quadrature for a basis hat grid over a box inside the field's.
    fn new(field: &GridField, basis: &HatGrid) -> Result<Quadrature, MbdError> {
        let voxels = field.dims();
        let nodes = basis.nodes();
        let spans = basis_spans(field, basis.domain()).filter(|_| nodes.iter().all(|&n| n >= 2));
        let Some(spans) = spans else {
            return Err(MbdError::InvalidKernels {
                which: "basis",
                why: "the polish needs a hat grid of at least 2 nodes per axis over a box inside \
                      the field's"
                    .into(),
            });
        };
        Ok(Quadrature {
            axes: [0, 1, 2].map(|k| Axis::new(voxels[k], nodes[k], spans[k])),
            voxels,
            nodes,
        })
    }

    fn cells(&self) -> [usize; 3] {
        self.nodes.map(|n| n - 1)
    }

    fn num_cells(&self) -> usize {
        self.cells().iter().product()
    }

    fn cell_coords(&self, cell: usize) -> [usize; 3] {
        let [cx, cy, _] = self.cells();
        [cell % cx, cell / cx % cy, cell / (cx * cy)]
    }

    /// Flat basis node of corner `n` of basis cell `cell`.
    fn basis_node(&self, cell: [usize; 3], n: usize) -> usize {
        let [nx, ny, _] = self.nodes;
        (cell[0] + (n & 1)) + nx * ((cell[1] + (n >> 1 & 1)) + ny * (cell[2] + (n >> 2 & 1)))
    }

    /// The point ranges of basis cell `cell` and the voxel block they touch.
    fn cell_points(&self, cell: [usize; 3]) -> ([Range<usize>; 3], Span) {
        let ranges = [0, 1, 2].map(|k| self.axes[k].basis_cells[cell[k]].clone());
        let spans = [0, 1, 2].map(|k| self.axes[k].voxel_span(&ranges[k]));
        let span = Span {
            lo: spans.map(|s| s.0),
            len: spans.map(|s| s.1),
        };
        (ranges, span)
    }

    /// Calls `visit` for every point of `ranges`, with its kernel data local to `span`.
    fn for_points(&self, ranges: &[Range<usize>; 3], span: &Span, mut visit: impl FnMut(&Point)) {
        let [ex, ey, _] = span.len;
        let mut point = Point {
            w: 0.0,
            phi: [0.0; 8],
            local: [0; 8],
            psi: [0.0; 8],
        };
        for pz in &self.axes[2].points[ranges[2].clone()] {
            for py in &self.axes[1].points[ranges[1].clone()] {
                for px in &self.axes[0].points[ranges[0].clone()] {
                    let p = [px, py, pz];
                    point.w = px.w * py.w * pz.w;
                    let base = (px.ci - span.lo[0])
                        + ex * ((py.ci - span.lo[1]) + ey * (pz.ci - span.lo[2]));
                    for corner in 0..8 {
                        let bit = |k: usize| corner >> k & 1;
                        let hat = |k: usize, t: f64| if bit(k) == 1 { t } else { 1.0 - t };
                        point.phi[corner] = hat(0, p[0].ct) * hat(1, p[1].ct) * hat(2, p[2].ct);
                        point.psi[corner] = hat(0, p[0].bt) * hat(1, p[1].bt) * hat(2, p[2].bt);
                        point.local[corner] = base + bit(0) + ex * (bit(1) + ey * bit(2));
                    }
                    visit(&point);
                }
            }
        }
    }

    /// `∫ ‖f‖² dx` of the field's trilinear interpolation.
    fn energy(&self, field: &GridField) -> f64 {
        trilinear_energy_with(
            field,
            [0, 1, 2].map(|k| mass_matrix(&self.axes[k], self.voxels[k])),
        )
    }

    /// The basis step's normal equations at coefficients `c`.
    fn basis_system(
        &self,
        field: &GridField,
        c: &[f64],
        l: usize,
        progress: &dyn Progress,
    ) -> Result<BasisSystem, MbdError> {
        let d = field.dim();
        let unknowns = self.nodes.iter().product::<usize>() * l;
        let cells: Vec<Result<CellBasisSystem, MbdError>> = (0..self.num_cells())
            .into_par_iter()
            .map(|cell| {
                progress.check()?;
                let (ranges, span) = self.cell_points(self.cell_coords(cell));
                let width = 8 * l;
                let mut weights = Array2::<f64>::zeros((span.count(), width));
                let mut gram = Array2::<f64>::zeros((width, width));
                let mut z = vec![0.0; width];
                let mut cx = vec![0.0; l];
                let local_c: Vec<f64> = (0..span.count())
                    .flat_map(|v| {
                        let g = span.global(v, self.voxels);
                        c[g * l..(g + 1) * l].iter().copied()
                    })
                    .collect();
                let weights_flat = weights.as_slice_mut().unwrap_or(&mut []);
                // Rows √w z of a batch of points: the Gram is their product, in one GEMM per
                // batch (fixed batches, so the sums do not depend on the thread count).
                let mut rows = Vec::with_capacity(GRAM_BATCH * width);
                let flush = |rows: &mut Vec<f64>, gram: &mut Array2<f64>| {
                    let count = rows.len() / width;
                    if let Ok(z) = ArrayView2::from_shape((count, width), rows.as_slice()) {
                        general_mat_mul(1.0, &z.t(), &z, 1.0, gram);
                    }
                    rows.clear();
                };
                self.for_points(&ranges, &span, |p| {
                    cx.fill(0.0);
                    for k in 0..8 {
                        let row = &local_c[p.local[k] * l..(p.local[k] + 1) * l];
                        for (o, &x) in cx.iter_mut().zip(row) {
                            *o += p.phi[k] * x;
                        }
                    }
                    for n in 0..8 {
                        for (o, &x) in z[n * l..(n + 1) * l].iter_mut().zip(&cx) {
                            *o = p.psi[n] * x;
                        }
                    }
                    let root = p.w.sqrt();
                    rows.extend(z.iter().map(|&x| root * x));
                    if rows.len() == GRAM_BATCH * width {
                        flush(&mut rows, &mut gram);
                    }
                    for k in 0..8 {
                        let wk = p.w * p.phi[k];
                        if wk == 0.0 {
                            continue;
                        }
                        let row = &mut weights_flat[p.local[k] * width..(p.local[k] + 1) * width];
                        for (o, &x) in row.iter_mut().zip(&z) {
                            *o += wk * x;
                        }
                    }
                });
                flush(&mut rows, &mut gram);
                let f = span.gather(field, self.voxels);
                let mut rhs = Array2::<f64>::zeros((width, d));
                general_mat_mul(1.0, &weights.t(), &f, 0.0, &mut rhs);
                Ok((gram, rhs))
            })
            .collect();
        let mut gram = Array2::<f64>::zeros((unknowns, unknowns));
        let mut rhs = Array2::<f64>::zeros((unknowns, d));
        for (cell, part) in cells.into_iter().enumerate() {
            let (g, r) = part?;
            let coords = self.cell_coords(cell);
            let global = |j: usize| self.basis_node(coords, j / l) * l + j % l;
            for (j, row) in g.rows().into_iter().enumerate() {
                let gj = global(j);
                for (k, &x) in row.iter().enumerate() {
                    gram[[gj, global(k)]] += x;
                }
                for (o, &x) in rhs.row_mut(gj).iter_mut().zip(r.row(j)) {
                    *o += x;
                }
            }
        }
        Ok(BasisSystem { gram, rhs })
    }

    /// Adds the coefficient step's normal equations at basis `b` (without the ridge) to
    /// `system`.
    fn add_coefficient_system(
        &self,
        field: &GridField,
        b: &[f64],
        l: usize,
        system: &mut CoefficientSystem,
        progress: &dyn Progress,
    ) -> Result<(), MbdError> {
        let d = field.dim();
        let cells: Vec<usize> = (0..self.num_cells()).collect();
        for batch in cells.chunks(CELL_BATCH) {
            let parts: Vec<Result<Vec<BoxSystem>, MbdError>> = batch
                .par_iter()
                .map(|&cell| {
                    progress.check()?;
                    Ok(self.coefficient_boxes(field, b, l, d, cell))
                })
                .collect();
            for part in parts {
                for boxed in part? {
                    system.add(&boxed, self.voxels);
                }
            }
        }
        Ok(())
    }

    /// The coefficient-system contributions of basis cell `cell`, one per coefficient cell
    /// (box between 8 voxel centres) it overlaps.
    fn coefficient_boxes(
        &self,
        field: &GridField,
        b: &[f64],
        l: usize,
        d: usize,
        cell: usize,
    ) -> Vec<BoxSystem> {
        let coords = self.cell_coords(cell);
        let (ranges, span) = self.cell_points(coords);
        let width = 8 * l;
        let ll = l * l;
        // The cell's basis rows (8L × D), their Gram K and their products with the voxels.
        let mut cell_basis = Array2::<f64>::zeros((width, d));
        for n in 0..8 {
            let node = self.basis_node(coords, n);
            for li in 0..l {
                let src = &b[(node * l + li) * d..(node * l + li + 1) * d];
                cell_basis
                    .row_mut(n * l + li)
                    .iter_mut()
                    .zip(src)
                    .for_each(|(o, &x)| *o = x);
            }
        }
        let mut gram = Array2::<f64>::zeros((width, width));
        general_mat_mul(1.0, &cell_basis, &cell_basis.t(), 0.0, &mut gram);
        let f = span.gather(field, self.voxels);
        let mut projected = Array2::<f64>::zeros((span.count(), width));
        general_mat_mul(1.0, &f, &cell_basis.t(), 0.0, &mut projected);
        let projected = projected.as_slice().unwrap_or(&[]);
        // K per node pair n ≤ n' (L × L), off-diagonal pairs symmetrised: M(x) = Σ ψ_n ψ_n' K_pair.
        let pairs: Vec<(usize, usize)> = (0..8).flat_map(|n| (n..8).map(move |m| (n, m))).collect();
        let pair_blocks: Vec<f64> = pairs
            .iter()
            .flat_map(|&(n, m)| {
                let gram = &gram;
                (0..ll).map(move |e| {
                    let (i, j) = (e / l, e % l);
                    let a = gram[[n * l + i, m * l + j]];
                    if n == m {
                        a
                    } else {
                        a + gram[[m * l + i, n * l + j]]
                    }
                })
            })
            .collect();
        let corner_pairs: Vec<(usize, usize)> =
            (0..8).flat_map(|k| (k..8).map(move |m| (k, m))).collect();
        // Split each axis' points into runs of equal coefficient cell.
        let runs = |k: usize| -> Vec<Range<usize>> {
            let points = &self.axes[k].points;
            let mut out: Vec<Range<usize>> = Vec::new();
            for i in ranges[k].clone() {
                match out.last_mut() {
                    Some(r) if points[r.start].ci == points[i].ci => r.end = i + 1,
                    _ => out.push(i..i + 1),
                }
            }
            out
        };
        let (rx, ry, rz) = (runs(0), runs(1), runs(2));
        let mut boxes = Vec::with_capacity(rx.len() * ry.len() * rz.len());
        let mut m = vec![0.0; ll];
        let mut s = vec![0.0; l];
        for z in &rz {
            for y in &ry {
                for x in &rx {
                    let box_ranges = [x.clone(), y.clone(), z.clone()];
                    let mut a = vec![0.0; corner_pairs.len() * ll];
                    let mut r = vec![0.0; 8 * l];
                    self.for_points(&box_ranges, &span, |p| {
                        m.fill(0.0);
                        for (pair, &(n, n2)) in pairs.iter().enumerate() {
                            let weight = p.psi[n] * p.psi[n2];
                            if weight == 0.0 {
                                continue;
                            }
                            for (o, &k) in
                                m.iter_mut().zip(&pair_blocks[pair * ll..(pair + 1) * ll])
                            {
                                *o += weight * k;
                            }
                        }
                        s.fill(0.0);
                        for k in 0..8 {
                            let row = &projected[p.local[k] * width..(p.local[k] + 1) * width];
                            for n in 0..8 {
                                let weight = p.phi[k] * p.psi[n];
                                for (o, &h) in s.iter_mut().zip(&row[n * l..(n + 1) * l]) {
                                    *o += weight * h;
                                }
                            }
                        }
                        for (pair, &(k, k2)) in corner_pairs.iter().enumerate() {
                            let weight = p.w * p.phi[k] * p.phi[k2];
                            if weight == 0.0 {
                                continue;
                            }
                            for (o, &x) in a[pair * ll..(pair + 1) * ll].iter_mut().zip(&m) {
                                *o += weight * x;
                            }
                        }
                        for k in 0..8 {
                            let weight = p.w * p.phi[k];
                            for (o, &x) in r[k * l..(k + 1) * l].iter_mut().zip(&s) {
                                *o += weight * x;
                            }
                        }
                    });
                    let p = &self.axes;
                    boxes.push(BoxSystem {
                        lower: [
                            p[0].points[x.start].ci,
                            p[1].points[y.start].ci,
                            p[2].points[z.start].ci,
                        ],
                        a,
                        r,
                    });
                }
            }
        }
        boxes
    }
}

/// One coefficient cell's share of the coefficient system: corner pairs `k ≤ k'` (`L × L`
/// each) and per-corner right-hand sides.
struct BoxSystem {
    lower: [usize; 3],
    a: Vec<f64>,
    r: Vec<f64>,
}

/// One basis cell's share of the basis system: `8L × 8L` Gram and `8L × D` right-hand side.
type CellBasisSystem = (Array2<f64>, Array2<f64>);

/// `G vec(B) = R`: the basis step's normal equations (`N·L × N·L`, `N·L × D`).
struct BasisSystem {
    gram: Array2<f64>,
    rhs: Array2<f64>,
}

impl BasisSystem {
    /// `Σ_d b_dᵀ G b_d − 2 Σ R∘B`: the data term minus `∫‖f‖²`.
    fn quadratic(&self, b: &Array2<f64>) -> f64 {
        let mut gb = Array2::<f64>::zeros(b.dim());
        general_mat_mul(1.0, &self.gram, b, 0.0, &mut gb);
        gb.iter()
            .zip(b.iter())
            .zip(self.rhs.iter())
            .map(|((&g, &x), &r)| x * (g - 2.0 * r))
            .sum()
    }

    /// The basis step: `b` replaced by the minimiser unless that raises the quadratic (by
    /// rounding); the new quadratic if it was.
    fn step(&self, b: &mut Array2<f64>) -> Result<Option<f64>, MbdError> {
        let before = self.quadratic(b);
        let trial = self.solve()?;
        let after = self.quadratic(&trial);
        Ok((after <= before).then(|| {
            *b = trial;
            after
        }))
    }

    /// The minimiser, rounded to f32. A relative ridge (grown until the factorisation succeeds)
    /// keeps nodes without data (all their coefficients zero) solvable.
    fn solve(&self) -> Result<Array2<f64>, MbdError> {
        let n = self.gram.nrows();
        let trace: f64 = self.gram.diag().sum();
        if trace <= 0.0 {
            return Ok(Array2::zeros(self.rhs.dim()));
        }
        let mut ridge = 1e-13 * trace / n as f64;
        let solution = loop {
            match prt_linalg::cholesky_solve(self.gram.view(), self.rhs.view(), ridge) {
                Ok(x) => break x,
                Err(prt_linalg::LinalgError::NotPositiveDefinite { .. })
                    if ridge < 1e-2 * trace =>
                {
                    ridge *= 100.0
                }
                Err(e) => return Err(linalg_error("polish basis step", e)),
            }
        };
        Ok(solution.mapv(round_f32))
    }
}

/// The coefficient step's normal equations: `L × L` blocks between each voxel and its 3³
/// neighbours, each pair's stored once ([`STORED_BLOCKS`], [`pair_block`]), the ridge included.
struct CoefficientSystem {
    voxels: [usize; 3],
    /// The voxels in [`column_order`], for [`CoefficientSystem::apply`].
    columns: (Vec<usize>, Vec<usize>),
    rank: usize,
    blocks: Vec<f64>,
    rhs: Vec<f64>,
}

impl CoefficientSystem {
    /// The storage of the blocks, for reuse.
    fn into_blocks(self) -> Vec<f64> {
        self.blocks
    }

    fn add(&mut self, boxed: &BoxSystem, voxels: [usize; 3]) {
        let l = self.rank;
        add_pair_blocks(&mut self.blocks, l * l, boxed.lower, &boxed.a, voxels);
        for k in 0..8 {
            let vk = corner_voxel(boxed.lower, k, voxels);
            for (o, &x) in self.rhs[vk * l..(vk + 1) * l]
                .iter_mut()
                .zip(&boxed.r[k * l..(k + 1) * l])
            {
                *o += x;
            }
        }
    }

    /// `y = A x`, column by column ([`column_order`]; each `y_v` is summed in the same order on
    /// any thread count).
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        let l = self.rank;
        let ll = l * l;
        let (order, starts) = &self.columns;
        let columns: Vec<Vec<f64>> = starts
            .par_windows(2)
            .map(|range| {
                let voxels = &order[range[0]..range[1]];
                let mut out = vec![0.0; voxels.len() * l];
                for (yv, &v) in out.chunks_mut(l).zip(voxels) {
                    for (nbr, u) in neighbours(v, self.voxels) {
                        let stored = pair_block(v, u, nbr);
                        let block = &self.blocks[stored * ll..(stored + 1) * ll];
                        let xu = &x[u * l..(u + 1) * l];
                        // Every block is symmetric (made exactly so by `symmetrise`), so it
                        // serves both voxels of its pair, and y += A x runs along its rows:
                        // L axpys that vectorise.
                        for (row, &xj) in block.chunks(l).zip(xu) {
                            for (o, &a) in yv.iter_mut().zip(row) {
                                *o += a * xj;
                            }
                        }
                    }
                }
                out
            })
            .collect();
        for (column, range) in columns.iter().zip(starts.windows(2)) {
            for (yv, &v) in column.chunks(l).zip(&order[range[0]..range[1]]) {
                y[v * l..(v + 1) * l].copy_from_slice(yv);
            }
        }
    }

    /// `cᵀ A c − 2 rᵀ c`: the loss minus `∫‖f‖²`.
    fn quadratic(&self, c: &[f64]) -> f64 {
        let mut ac = vec![0.0; c.len()];
        self.apply(c, &mut ac);
        dot(c, &ac) - 2.0 * dot(&self.rhs, c)
    }

    /// `r − A x`.
    fn residual(&self, x: &[f64]) -> Vec<f64> {
        let mut residual = vec![0.0; x.len()];
        self.apply(x, &mut residual);
        residual
            .iter_mut()
            .zip(&self.rhs)
            .for_each(|(o, &b)| *o = b - *o);
        residual
    }

    /// Block-Jacobi preconditioned conjugate gradients from `start`, whose residual
    /// [`CoefficientSystem::residual`] is `residual`; the solution rounded to f32, and the
    /// iterations taken.
    fn solve(
        &self,
        start: &[f64],
        residual: Vec<f64>,
        options: &PolishOptions,
        progress: &dyn Progress,
    ) -> Result<(Vec<f64>, usize), MbdError> {
        let l = self.rank;
        let ll = l * l;
        let voxels = self.rhs.len() / l;
        // Factor the diagonal blocks (identity where a block is not positive definite).
        let factors: Vec<Option<Vec<f64>>> = (0..voxels)
            .into_par_iter()
            .map(|v| {
                let own = v * STORED_BLOCKS;
                let mut a = self.blocks[own * ll..(own + 1) * ll].to_vec();
                cholesky_in_place(&mut a, l).then_some(a)
            })
            .collect();
        let precondition = |r: &[f64], z: &mut [f64]| {
            z.par_chunks_mut(l)
                .zip(r.par_chunks(l))
                .zip(factors.par_iter())
                .for_each(|((z, r), f)| {
                    z.copy_from_slice(r);
                    if let Some(f) = f {
                        cholesky_solve_in_place(f, z, l, 1);
                    }
                });
        };
        let mut x = start.to_vec();
        let mut r = residual;
        let target = options.cg_tolerance * dot(&self.rhs, &self.rhs).sqrt();
        let mut z = vec![0.0; x.len()];
        precondition(&r, &mut z);
        let mut p = z.clone();
        let mut rz = dot(&r, &z);
        let mut q = vec![0.0; x.len()];
        let mut iterations = 0;
        while iterations < options.max_cg_iterations && dot(&r, &r).sqrt() > target {
            progress.check()?;
            self.apply(&p, &mut q);
            let pq = dot(&p, &q);
            if pq.is_nan() || pq <= 0.0 {
                break;
            }
            let alpha = rz / pq;
            x.iter_mut().zip(&p).for_each(|(x, &p)| *x += alpha * p);
            r.iter_mut().zip(&q).for_each(|(r, &q)| *r -= alpha * q);
            precondition(&r, &mut z);
            let rz_next = dot(&r, &z);
            let beta = rz_next / rz;
            rz = rz_next;
            p.iter_mut().zip(&z).for_each(|(p, &z)| *p = z + beta * *p);
            iterations += 1;
        }
        if x.iter().any(|v| !v.is_finite()) {
            return Err(MbdError::Diverged {
                what: "polished coefficients",
                iteration: iterations,
            });
        }
        Ok((x.into_iter().map(round_f32).collect(), iterations))
    }
}

/// Makes each `l × l` block of `blocks` exactly symmetric, `(X + Xᵀ) / 2`: blocks that are
/// symmetric in exact arithmetic (`∫ w b bᵀ`) come out of their sums asymmetric by rounding,
/// and the conjugate gradients want an exactly symmetric operator.
fn symmetrise(blocks: &mut [f64], l: usize) {
    blocks.par_chunks_mut(NODE_CHUNK * l * l).for_each(|chunk| {
        for block in chunk.chunks_mut(l * l) {
            for i in 0..l {
                for j in i + 1..l {
                    let mean = 0.5 * (block[i * l + j] + block[j * l + i]);
                    block[i * l + j] = mean;
                    block[j * l + i] = mean;
                }
            }
        }
    });
}

/// `buffer` as `len` zeros, reusing its allocation.
fn zeroed(buffer: &mut Vec<f64>, len: usize) {
    buffer.clear();
    buffer.resize(len, 0.0);
}

/// Global index of corner `k` (bit a: one step up along axis a) of the voxel-centre cell whose
/// lowest voxel is `lower`.
fn corner_voxel(lower: [usize; 3], k: usize, voxels: [usize; 3]) -> usize {
    let at = [0, 1, 2].map(|a| lower[a] + (k >> a & 1));
    at[0] + voxels[0] * (at[1] + voxels[1] * at[2])
}

/// Adds one voxel-centre cell's corner-pair blocks `a` (pairs `k ≤ k'` in order, `size`
/// values each) to per-voxel neighbour blocks `blocks` stored once per pair ([`pair_block`]).
/// The blocks are symmetric in exact arithmetic (`∫ w b bᵀ`, `∫ w c cᵀ`, or columns), so the
/// block of `(k, k')` serves as that of `(k', k)` without being transposed; [`symmetrise`]
/// removes the rounding.
fn add_pair_blocks(
    blocks: &mut [f64],
    size: usize,
    lower: [usize; 3],
    a: &[f64],
    voxels: [usize; 3],
) {
    let delta = |from: usize, to: usize| -> usize {
        (0..3)
            .map(|axis| {
                ((to >> axis & 1) as isize - (from >> axis & 1) as isize + 1) as usize
                    * [1, 3, 9][axis]
            })
            .sum()
    };
    let mut pair = 0;
    for k in 0..8 {
        let vk = corner_voxel(lower, k, voxels);
        for k2 in k..8 {
            let src = &a[pair * size..(pair + 1) * size];
            pair += 1;
            let at = pair_block(vk, corner_voxel(lower, k2, voxels), delta(k, k2)) * size;
            for (o, &x) in blocks[at..at + size].iter_mut().zip(src) {
                *o += x;
            }
        }
    }
}

/// `a·b` summed in fixed chunks (the same result on any thread count).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let partial: Vec<f64> = a
        .par_chunks(NODE_CHUNK * 8)
        .zip(b.par_chunks(NODE_CHUNK * 8))
        .map(|(a, b)| a.iter().zip(b).map(|(&x, &y)| x * y).sum::<f64>())
        .collect();
    partial.iter().sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each pair of neighbouring voxels has one stored block, the same seen from either voxel,
    /// and no two pairs share one.
    #[test]
    fn pair_blocks_are_stored_once_per_pair() {
        let voxels = [3, 4, 2];
        let count = voxels.iter().product();
        let mut owner = vec![None; count * STORED_BLOCKS];
        // Per axis a voxel has 2 or 3 neighbours in its 3-block (itself included): 7, 10 and 4
        // summed over the axes' positions.
        let pairs: usize = (0..count).map(|v| neighbours(v, voxels).count()).sum();
        assert_eq!(pairs, 7 * 10 * 4);
        for v in 0..count {
            for (nbr, u) in neighbours(v, voxels) {
                let slot = pair_block(v, u, nbr);
                assert_eq!(slot, pair_block(u, v, 26 - nbr));
                let pair = (v.min(u), v.max(u));
                assert_eq!(*owner[slot].get_or_insert(pair), pair);
            }
        }
        assert_eq!(pair_block(5, 5, SELF_BLOCK), 5 * STORED_BLOCKS);
    }

    /// Every voxel once; each column a `COLUMN × COLUMN` (or smaller, at the edges) footprint,
    /// walked plane by plane.
    #[test]
    fn column_order_walks_every_voxel_once() {
        let voxels = [37, 18, 3];
        let (order, starts) = column_order(voxels);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..37 * 18 * 3).collect::<Vec<_>>());
        assert_eq!(starts.len(), 3 * 2 + 1);
        assert_eq!(*starts.last().unwrap(), order.len());
        for range in starts.windows(2) {
            let column = &order[range[0]..range[1]];
            let z = |v: usize| v / (37 * 18);
            assert!(column.windows(2).all(|w| z(w[0]) <= z(w[1])));
            let xs: Vec<usize> = column.iter().map(|v| v % 37).collect();
            assert!(xs.iter().max().unwrap() - xs.iter().min().unwrap() < COLUMN);
        }
    }

    #[test]
    fn symmetrise_averages_each_block_with_its_transpose() {
        let mut blocks = vec![1.0, 2.0, 4.0, 3.0, 0.0, -1.0, 1.0, 5.0];
        symmetrise(&mut blocks, 2);
        assert_eq!(blocks, vec![1.0, 3.0, 3.0, 3.0, 0.0, 0.0, 0.0, 5.0]);
    }
}

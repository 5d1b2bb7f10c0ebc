//! Exact polish of an MBD (beyond the paper): minimisation of the *continuous* loss, which the
//! stochastic solver only estimates.
//!
//! With the coefficient hats of [`crate::Mbd`] (nodes at the voxel centres, clamped outside
//! them) and the trilinear target of the field, every factor is piecewise linear along each
//! axis: the coefficients `c(x)` and the target `f(x)` between voxel centres (constant in the
//! outer half voxels), and the basis `b(x)` between its own breakpoints — basis nodes for a hat
//! grid over any box inside the field's (clamped outside it), voxel centres for the families
//! stored at the voxel centres ([`crate::expert::LabelKernels`]; see [`PolishBasis`]).
//! Splitting each axis at all those breakpoints leaves intervals on which the residual
//! `f̂ − f = c·b − f` is a polynomial of degree ≤ 2 per axis, so its square has degree ≤ 4: a
//! tensor 3-point Gauss–Legendre rule on every interval box integrates the loss
//!
//! ```text
//! E(c, B) = ∫ ‖f(x) − f̂(x)‖² dx + λ/2 ‖c‖²        (x in units of one voxel's volume)
//! ```
//!
//! exactly (up to rounding) — the loss the solver estimates with one jittered sample per
//! voxel, and `E_data / ∫‖f‖²` is what [`crate::evaluate`] estimates.
//!
//! Two exact linear systems make the polish ([`systems`]; the quadrature that assembles them is
//! [`quadrature`] for hat grids and [`voxels`] for voxel-stored kernels):
//! * **basis given the coefficients**: the normal equations `G vec(B) = R`, with one Gram `G` of
//!   size `N·L` shared by all D outputs (Cholesky);
//! * **coefficients given the basis**: neighbouring voxels couple through overlapping hats, so
//!   the normal equations are block-sparse (`L × L` blocks between each voxel and its 3³
//!   neighbours, the ridge on the diagonal), solved by linear conjugate gradients
//!   preconditioned with the diagonal blocks.
//!
//! Alternating them creeps along the valley of the coupled problem, so [`polish`] runs
//! nonlinear conjugate gradients on the loss with the basis solved out, preconditioned by the
//! coefficient step ([`conjugate`]). Each step's result is rounded to the model's f32 storage
//! and accepted only if the exact loss did not increase, so the loss of the returned model
//! never exceeds the input's. Memory: the coefficient system stores each pair of neighbours'
//! block once, `14 L²` f64 per voxel (7.2 KB at L = 8: 235 MB for 32³).

use std::ops::Range;
use std::time::Instant;

use ndarray::{Array2, Array3, ArrayView2, linalg::general_mat_mul};
use prt_core::{GridField, Progress, SpatialKernels};
use prt_kernels::HatGrid;
use rayon::prelude::*;

use crate::baselines::voxel_centre_box;
use crate::subspace::{cholesky_in_place, cholesky_solve_in_place, linalg_error};
use crate::voxel_weights::VoxelWeights;
use crate::{MbdError, MbdModel};

/// Largest `N·L` (basis nodes × rank) for which [`polish`] assembles and factors the dense
/// normal equations of the basis step (an 8192² f64 matrix is 512 MiB).
pub const POLISH_MAX_BASIS_UNKNOWNS: usize = 8192;

/// Basis cells whose coefficient-system contributions are held in memory before they are
/// added (in cell order, so the sums do not depend on the thread count).
const CELL_BATCH: usize = 4;
/// Voxels per chunk of the parallel matrix-vector products and dot products (fixed, so the
/// reductions do not depend on the thread count).
const NODE_CHUNK: usize = 256;
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

/// Options of [`polish`].
#[derive(Debug, Clone, PartialEq)]
pub struct PolishOptions {
    /// Conjugate-gradient iterations on the loss, at most (default 16).
    pub iterations: usize,
    /// Ridge weight λ on the coefficients (default 1e-8, not the solver's 1e-4). The
    /// stochastic solver needs the ridge to fix the scale ambiguity `c_l b_l = (s c_l)(b_l / s)`;
    /// the exact solves do not, and near the optimum a larger ridge dominates the loss, so the
    /// polish would spend its steps trading coefficient scale against the basis.
    pub lambda: f32,
    /// Stop when the mean decrease of the exact loss over the last three iterations falls
    /// below this relative to the data term (default 1e-3; 0 runs all `iterations`).
    pub tolerance: f64,
    /// Relative residual at which the linear conjugate gradients of each coefficient solve stop
    /// (default 1e-8).
    pub cg_tolerance: f64,
    /// Iteration cap of those linear conjugate gradients (default 400).
    pub max_cg_iterations: usize,
}

impl Default for PolishOptions {
    fn default() -> Self {
        Self {
            iterations: 16,
            lambda: 1e-8,
            tolerance: 1e-3,
            cg_tolerance: 1e-8,
            max_cg_iterations: 400,
        }
    }
}

/// Basis kernels whose exact continuous loss [`polish`] and [`exact_loss`] integrate (a sealed
/// trait): a [`HatGrid`] over a box inside the field's, the kernels stored at the field's voxel
/// centres and blended trilinearly between them ([`crate::expert::LabelKernels`]; every factor
/// of the model is then trilinear between voxel centres, so the breakpoints are the voxel
/// centres alone), and [`crate::BasisKernels`], either of them.
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
    /// The end of a conjugate-gradient iteration (whose preconditioner is the coefficient
    /// solve with the basis fixed).
    Coefficients,
    /// A trial point of an iteration's line search (accepted: the best so far of its
    /// iteration).
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
    /// Whether the tolerance (or a step that could not lower the loss) stopped the polish
    /// before `iterations`.
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

/// Polishes `model` by preconditioned nonlinear conjugate gradients on its exact continuous
/// loss (module docs), for at most `options.iterations` iterations, and returns the polished
/// model with the exact loss after every step. The exact loss never increases; the result is
/// deterministic (no sampling, fixed reduction order) on any thread count. Progress reports one
/// unit per iteration; cancellation is checked between basis cells and linear
/// conjugate-gradient iterations.
///
/// # Errors
/// [`MbdError::InvalidKernels`] unless the coefficient kernels are those of [`crate::Mbd`] for
/// `field` (hats at the voxel centres), the basis is a hat grid of at least 2 nodes per axis
/// over a box inside the field's or a voxel-stored family on the field's own voxels and box,
/// and the field has at least 2 voxels per axis; [`MbdError::ShapeMismatch`] if the model's
/// dimension differs from the field's; [`MbdError::InvalidOption`] for a negative or
/// non-finite λ or tolerance, a non-positive `cg_tolerance`, `max_cg_iterations == 0`, or
/// `N·L` above [`POLISH_MAX_BASIS_UNKNOWNS`]; non-finite field values; cancellation.
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
    progress.set_len(options.iterations as u64);
    // One buffer of 14 `L × L` blocks per voxel, passed between the coefficient system and the
    // voxel-stored basis step's neighbour blocks, so that the two are never held at once and
    // are not allocated afresh at every step.
    let mut blocks = Vec::new();
    let basis_system = quadrature.basis_system(field, &c, l, &mut blocks, progress)?;
    let initial = ExactLoss {
        data: (basis_system.quadratic(&b) + energy).max(0.0),
        ridge: ridge(&c, options.lambda),
        energy,
    };
    let mut report = PolishReport {
        initial,
        ..PolishReport::default()
    };
    let mut loss = initial;
    let conjugate = Conjugate {
        quadrature: &quadrature,
        field,
        rank: l,
        options,
        energy,
        start,
        progress,
    };
    conjugate.run(&mut c, &mut b, &mut loss, basis_system, blocks, &mut report)?;
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

mod conjugate;
mod energy;
mod quadrature;
mod systems;
mod voxels;

use conjugate::Conjugate;
pub use energy::trilinear_energy;
use energy::{mass_matrix, trilinear_energy_with};
use quadrature::{Axis, Quadrature};
use systems::{
    BasisSystem, BoxSystem, CellBasisSystem, CoefficientSystem, Systems, add_pair_blocks,
    column_order, corner_voxel, neighbours, pair_block, symmetrise, zeroed,
};
use voxels::VoxelQuadrature;

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

/// `a·b` summed in fixed chunks (the same result on any thread count).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let partial: Vec<f64> = a
        .par_chunks(NODE_CHUNK * 8)
        .zip(b.par_chunks(NODE_CHUNK * 8))
        .map(|(a, b)| a.iter().zip(b).map(|(&x, &y)| x * y).sum::<f64>())
        .collect();
    partial.iter().sum()
}

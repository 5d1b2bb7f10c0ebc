//! # prt-mbd — Moving Basis Decomposition
//!
//! Moving Basis Decomposition (Silvennoinen & Sloan, "Moving Basis Decomposition for
//! Precomputed Light Transport", EGSR 2021) compresses a spatially coherent field of
//! D-dimensional vectors (a 324-D transfer volume, linear SH irradiance, ...) as a rank-L
//! expansion whose basis itself varies smoothly in space:
//!
//! ```text
//! f̂(x) = Σ_l c_l(x) b_l(x),   c_l(x) = Σ_m φ_m(x) c_{m,l},   b_l(x) = Σ_n ψ_n(x) B_{n,l}
//! ```
//!
//! with fine coefficient kernels φ (one trilinear hat per voxel) and coarse basis kernels ψ.
//! Global PCA (one basis node), blockwise PCA (box kernels) and clustered PCA are special
//! cases; with overlapping kernels the reconstruction is continuous, so there are no seams.
//!
//! ## Fit MBD to your field
//! [`Mbd`] is the one way to fit: a rank, a [`Basis`] (the paper's hat grid, or kernels
//! derived from clustered PCA's clusters), [`SolverOptions`] for the paper's stochastic
//! quasi-Newton solver, an optional exact [`PolishOptions`] polish and an optional
//! [`CoarseStart`] (fit the volume at half resolution first: for large volumes) and an optional
//! [`LossWeighting`] (each voxel's relative error counts alike: for fields whose magnitude
//! spans orders, like dim interiors beside sunlit voxels). [`Mbd::fit`]
//! returns an [`MbdFit`]: the [`MbdModel`] (a [`prt_core::FieldModel`], tensors laid out for
//! volume textures: coefficients `M × L`, basis `N × L × D`) and the solver's and polish's
//! reports.
//!
//! ```
//! use prt_core::{Aabb, NoProgress};
//! use prt_mbd::{Basis, EvalOptions, Mbd, SyntheticField, evaluate};
//!
//! let field = SyntheticField::new([8, 8, 8], 12).build(Aabb::UNIT)?; // any GridField
//! let mut mbd = Mbd::new(3, Basis::HatGrid { nodes: [3, 3, 3] });
//! mbd.solver.max_iterations = 16;
//! let fit = mbd.fit(&field, &NoProgress)?;
//! let error = evaluate(&fit.model, &field, &EvalOptions::default())?;
//! assert!(error.relative_mse < 0.1);
//! // Texture layout: 512 coefficient voxels × 3, 27 basis nodes × 3 × 12.
//! assert_eq!(fit.model.coefficients().dim(), (512, 3));
//! assert_eq!(fit.model.basis().dim(), (27, 3, 12));
//! # Ok::<(), prt_mbd::MbdError>(())
//! ```
//!
//! ## Compare
//! The baselines are [`prt_core::Compressor`]s with the same storage budget: [`GlobalPca`],
//! [`BlockPca`] (BPCA, and WBPCA with `window = 2`), [`ClusteredPca`] (Sloan et al. 2003) and
//! [`KMeansVq`]; all but global PCA return a [`PiecewisePcaModel`]. [`evaluate`] gives the
//! paper's relative MSE and per-block operator errors; two seam measures tell seams apart:
//! [`error_seams`] (how much the reconstruction's error jumps across cluster or block
//! boundaries against inside them) and [`projection_seam_ratio`] (the same jump for each
//! method's *basis* applied to a denoised reference, which separates a method's seams from the
//! field's own structure on noisy traced volumes).
//!
//! ## Going further
//! [`expert`] holds the entry points behind [`Mbd`]: the solver over any two
//! [`prt_core::SpatialKernels`], a start from a given basis, the exact polish and loss of any
//! model, MBD on an existing clustering, and the per-voxel pieces of the seam measures.
//!
//! ## Extremes
//! Rank 0 or above D, basis grids with fewer than 2 nodes on an axis, kernels that leave part of
//! the field's box uncovered and NaN/Inf in the field are typed [`MbdError`]s; an empty field
//! cannot be built ([`prt_core::GridField`] refuses it). A zero field gives zero coefficients, a
//! constant field and a field that is exactly a rank-L MBD with one global basis are reproduced to
//! rounding (tests). The ridge `λ/2‖c‖²` bounds the coefficients, since the loss never increases:
//! `λ/2‖c‖² ≤ E(initial)`.
#![deny(missing_docs)]

mod baselines;
mod centre_projection;
mod clustered;
mod coarse;
mod error;
mod eval;
mod fit;
mod loss_weights;
mod model;
mod objective;
mod polish;
mod projection;
mod solver;
mod stream;
mod subspace;
mod synthetic;
mod voxel_weights;

pub use baselines::{BlockPca, ClusteredPca, GlobalPca, KMeansVq, PiecewisePcaModel};
pub use clustered::LabelSmoothing;
pub use coarse::CoarseStart;
pub use error::MbdError;
pub use eval::{ErrorSeams, EvalOptions, Evaluation, SeamOptions, error_seams, evaluate};
pub use fit::{Basis, BasisKernels, Mbd, MbdFit};
pub use loss_weights::LossWeighting;
pub use model::MbdModel;
pub use objective::Preconditioner;
pub use polish::{PolishOptions, PolishReport};
pub use projection::{LocalBasis, projection_seam_ratio};
pub use solver::{SolveReport, SolverOptions};
pub use stream::{BASIS_SOLVE_TOLERANCE, BasisNormals, BasisSolve, ProjectScratch, StreamedMbd};
pub use synthetic::SyntheticField;

pub mod expert {
    //! The entry points behind [`Mbd`](crate::Mbd), for callers who bring their own kernels
    //! or pipeline.
    //!
    //! * [`solve`] / [`solve_from_basis`]: the stochastic solver over any coefficient and basis
    //!   [`prt_core::SpatialKernels`], from the global principal subspace or from a given basis;
    //!   [`solve_masked`] fits the valid voxels only.
    //! * [`polish`] / [`exact_loss`]: the exact continuous loss of a model with
    //!   [`Mbd`](crate::Mbd)'s coefficient hats, and its minimisation; [`trilinear_energy`]
    //!   gives the same integral for a grid reconstruction, e.g. a baseline's.
    //! * [`fit_on_clusters`]: [`Basis::Clusters`](crate::Basis::Clusters) on a clustering you
    //!   already have (e.g. the clustered-PCA baseline's).
    //! * The kernels and boxes [`Mbd`](crate::Mbd) uses, and the per-voxel pieces of the seam
    //!   measures, for drawing them.
    pub use crate::baselines::voxel_centre_box;
    pub use crate::clustered::{LabelKernels, MAX_LABEL_RADIUS};
    pub use crate::coarse::{can_halve, halved_grid};
    pub use crate::eval::{blur_valid, kernel_labels, nonzero_voxels};
    pub use crate::fit::basis_box;
    pub use crate::fit::fit_on_clusters;
    pub use crate::model::EvalScratch;
    pub use crate::polish::{
        ExactLoss, POLISH_MAX_BASIS_UNKNOWNS, PolishBasis, PolishRecord, PolishStep, exact_loss,
        polish, trilinear_energy,
    };
    pub use crate::projection::{projection_residuals, residual_seam_ratio};
    pub use crate::solver::{
        HELD_OUT_INTERVAL, IterationRecord, solve, solve_from_basis, solve_masked,
    };
}

// Internal paths used across modules.
pub(crate) use solver::solve_from_basis;

/// The README's example, compiled and run as a doc test so that it stays true.
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;

//! # prt-mbd — Moving Basis Decomposition
//!
//! Moving Basis Decomposition (Silvennoinen & Sloan, "Moving Basis Decomposition for
//! Precomputed Light Transport", 2021) compresses a spatially coherent field of D-dimensional
//! vectors (a 324-D transfer volume, linear SH irradiance, ...) as a rank-L expansion whose
//! basis itself varies smoothly in space:
//!
//! ```text
//! f̂(x) = Σ_l c_l(x) b_l(x),   c_l(x) = Σ_m φ_m(x) c_{m,l},   b_l(x) = Σ_n ψ_n(x) B_{n,l}
//! ```
//!
//! with two kernel families ([`prt_core::SpatialKernels`]): fine coefficient kernels φ (one hat
//! per voxel) and coarse basis kernels ψ (a 3³..9³ hat grid, or scattered/hybrid kernels).
//! Global PCA (one basis node), blockwise PCA (box kernels) and clustered PCA are special
//! cases; with overlapping kernels the reconstruction is continuous, so there are no seams.
//!
//! ## What is here
//! * [`MbdModel`]: the model, a [`prt_core::FieldModel`]; its tensors are laid out for volume
//!   textures (coefficients `M × L`, basis `N × L × D`).
//! * [`solve`] / [`Mbd`]: the paper's stochastic quasi-Newton solver (section 3.3): one jittered
//!   sample per voxel each iteration, Monte Carlo gradient and diagonal Hessian on common random
//!   numbers, a diagonal Newton step with backtracking, global-PCA initialisation. The work is
//!   batched per basis cell into small matrix products and run in parallel over cells with
//!   ordered f64 reductions, so a seed gives the same model on any thread count. Beyond the
//!   paper, the default [`Preconditioner::Block`] replaces the diagonal Hessian by per-kernel
//!   `L × L` blocks with the kernels' overlap lumped in: a Gershgorin bound of each block's
//!   Hessian that also captures the coupling between basis vectors, so full steps are accepted
//!   and convergence per iteration is several times faster (measured in `docs/results.md`);
//!   [`Preconditioner::Diagonal`] is the paper's. Every kernel's curvature gets a
//!   Levenberg-Marquardt floor of `1e-5` of its mean diagonal: above the field's local rank the
//!   blocks are singular, and the floor keeps f32 rounding from becoming huge basis steps.
//!   Also beyond the paper: heavy-ball momentum on the step, the returned model averaged over
//!   the last iterates (each iteration refits its own samples, so single iterates scatter), and
//!   a stopping rule on the averaged model's error on a fixed held-out sample set.
//!   [`solve_from_basis`] starts from a given basis instead (a previous fit's, or one built
//!   from a clustering) and runs the same iterations.
//! * Baselines, each a [`prt_core::Compressor`] with the same storage budget: [`GlobalPca`],
//!   [`BlockPca`] (BPCA, and WBPCA with `window = 2`), [`ClusteredPca`] (Sloan et al. 2003),
//!   [`KMeansVq`].
//! * [`evaluate`] (relative MSE on dense jittered samples, per-block operator Frobenius error) and
//!   [`seam_metric_with`] (the error's jump across cluster boundaries against the jumps inside
//!   them, optionally against a denoised reference and over a validity mask; [`seam_metric`] is
//!   the raw form), and [`projection_seam_ratio`] (module [`projection`]: the same jump of the
//!   residual of projecting a denoised field onto each voxel's basis, which tells a method's
//!   seams from the field's own structure on traced scenes; prt-cli's seam view).
//! * [`scene_adapted_basis`] (beyond the paper): Shepard basis kernels at weighted k-means
//!   centres of the valid voxels, for scenes where much of the box is inside geometry.
//! * [`wall_aware_basis`] / [`WallAware`] (beyond the paper, opt-in): the hat basis cut back
//!   at walls, each node serving only the voxels it reaches through valid voxels, blended
//!   between voxel centres (still a continuous partition of unity); module [`walls`].
//! * [`ClusteredMbd`] / [`LabelKernels`] (beyond the paper, opt-in): basis kernels from
//!   clustered PCA's clusters, smoothed over a few voxels, for scenes whose transfer changes
//!   faster than a basis cell (traced Sponza: 1.14–1.36× CPCA's error instead of the hat
//!   grid's 1.73–1.84×); module [`clustered`].
//! * [`polish`] and [`exact_loss`] (beyond the paper, opt-in): with the coefficient hats of
//!   [`Mbd`] and a hat-grid or voxel-stored basis ([`PolishBasis`]: [`WallAware`],
//!   [`LabelKernels`]) the continuous loss is a piecewise polynomial, integrated exactly by a
//!   tensor Gauss–Legendre rule; `polish` lowers it further by exact solves (basis: dense normal
//!   equations; coefficients: block-sparse conjugate gradients), alternated or, by default,
//!   driving nonlinear conjugate gradients on the loss with the basis solved out, and
//!   `exact_loss` / [`trilinear_energy`] give the exact value of [`evaluate`]'s relative MSE
//!   for MBD and for the grid-resampled baselines. [`PolishedMbd`] chains the two: the
//!   stochastic solver until its rule fires, then polish sweeps until one gains less than 3 %
//!   (for smooth fields, where the solver's last stretch creeps; MBD session 7 in
//!   `docs/results.md`).
//! * [`SyntheticField`]: smooth fields on curved manifolds in R^D, for tests and experiments.
//!
//! ## Extremes
//! Rank 0 or above D, basis grids with fewer than 2 nodes on an axis, kernels that leave part of
//! the field's box uncovered and NaN/Inf in the field are typed [`MbdError`]s; an empty field
//! cannot be built ([`prt_core::GridField`] refuses it). A zero field gives zero coefficients, a
//! constant field and a field that is exactly a rank-L MBD with one global basis are reproduced to
//! rounding (tests). The ridge `λ/2‖c‖²` bounds the coefficients, since the loss never increases:
//! `λ/2‖c‖² ≤ E(initial)`.
//!
//! ```
//! use prt_core::{Aabb, NoProgress};
//! use prt_mbd::{EvalOptions, Mbd, MbdOptions, SyntheticField, evaluate};
//!
//! let field = SyntheticField::new([8, 8, 8], 12).build(Aabb::UNIT).unwrap();
//! let mbd = Mbd { basis_nodes: [3, 3, 3], options: MbdOptions { rank: 3, max_iterations: 16, ..Default::default() } };
//! let (model, report) = mbd.fit(&field, &NoProgress).unwrap();
//! let error = evaluate(&model, &field, &EvalOptions::default()).unwrap();
//! assert!(error.relative_mse < 0.1);
//! assert!(report.history.iter().all(|r| r.loss_after <= r.loss_before));
//! // Texture layout: 512 coefficient voxels × 3, 27 basis nodes × 3 × 12.
//! assert_eq!(model.coefficients().dim(), (512, 3));
//! assert_eq!(model.basis().dim(), (27, 3, 12));
//! ```
#![deny(missing_docs)]

mod error;
mod model;
pub mod synthetic;

pub use error::MbdError;
pub use model::{EvalScratch, MbdModel};
pub use synthetic::SyntheticField;
pub mod objective;
mod solver;
mod subspace;

pub use solver::{
    HELD_OUT_INTERVAL, Init, IterationRecord, MbdOptions, Preconditioner, SolveReport, solve,
    solve_from_basis,
};
mod baselines;
pub use baselines::{BlockPca, ClusterModel, ClusteredPca, GlobalPca, KMeansVq, voxel_centre_box};
mod hat;
pub use hat::{Mbd, basis_box};
pub mod eval;
pub use eval::{
    EvalOptions, Evaluation, SeamMetric, SeamOptions, blur_valid, evaluate, kernel_labels,
    nonzero_voxels, seam_metric, seam_metric_with,
};
mod als;
pub use als::{ALS_MAX_BASIS_UNKNOWNS, solve_als};
mod adapted;
pub use adapted::{AdaptedBasisOptions, Placement, scene_adapted_basis};
pub(crate) mod polish;
pub use polish::{
    ExactLoss, POLISH_MAX_BASIS_UNKNOWNS, POLISH_STALL_TOLERANCE, PolishAcceleration, PolishBasis,
    PolishOptions, PolishRecord, PolishReport, PolishStep, PolishedMbd, exact_loss, polish,
    trilinear_energy,
};
mod voxel_weights;
pub mod walls;
pub use walls::{WallAware, WallOptions, wall_aware_basis};
pub mod clustered;
pub mod projection;
pub use clustered::{ClusterStart, ClusteredFit, ClusteredMbd, LabelKernels, LabelSmoothing};
pub use projection::{
    LocalBasis, projection_residuals, projection_seam_ratio, residual_seam_ratio,
};

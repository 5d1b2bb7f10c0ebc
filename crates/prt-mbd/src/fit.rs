//! The front door: [`Mbd`] fits a Moving Basis Decomposition to a [`GridField`].

use glam::Vec3;
use prt_core::{Aabb, Compressor, CoreError, GridField, KernelWeights, Progress, SpatialKernels};
use prt_kernels::HatGrid;

use crate::centre_projection::project_on_centres;
use crate::clustered::{LabelKernels, LabelSmoothing, align_to};
use crate::coarse::{CoarseStart, can_halve, halve};
use crate::loss_weights::{LossWeighting, unweight_coefficients, weighted_field};
use crate::polish::{self, BasisLayout, PolishBasis, PolishOptions, PolishReport};
use crate::solver::{Start, check_mask, solve_with};
use crate::subspace::principal_subspace;
use crate::{
    ClusteredPca, MbdError, MbdModel, PiecewisePcaModel, SolveReport, SolverOptions,
    solve_from_basis,
};

/// Rank-L Moving Basis Decomposition (Silvennoinen & Sloan 2021): one trilinear coefficient hat
/// per voxel centre, a moving basis on [`Mbd::basis`] kernels, fitted by the paper's stochastic
/// quasi-Newton solver and, optionally, the exact [`polish`](Mbd::polish).
///
/// `Mbd::default()` is rank 8 on a 5³ hat grid with the default solver and no polish.
#[derive(Debug, Clone, PartialEq)]
pub struct Mbd {
    /// Moving basis vectors per point, L (1..=D).
    pub rank: usize,
    /// Where the basis kernels sit.
    pub basis: Basis,
    /// The stochastic solver's options.
    pub solver: SolverOptions,
    /// Exact polish of the continuous loss after the solver (beyond the paper, opt-in; `None`:
    /// the solver's model as it stops). It pays where the solver stops far above the optimum:
    /// clustered basis kernels on scenes like Sponza, smooth noise-free fields.
    pub polish: Option<PolishOptions>,
    /// Start from a fit of the field at half (quarter, ...) resolution (beyond the paper,
    /// opt-in, [`Basis::HatGrid`] only; `None`: the paper's start, the global principal
    /// subspace). For large volumes, where each full-resolution iteration is costly.
    pub coarse_start: Option<CoarseStart>,
    /// A per-voxel weighting of the loss, undone exactly after the fit (beyond the paper,
    /// opt-in; `None`: the paper's loss, where the brightest voxels dominate).
    pub loss_weighting: Option<LossWeighting>,
    /// After the solve, re-fit each voxel's coefficients as the ridge least-squares projection
    /// of its own vector on the basis at its centre (beyond the paper, opt-in,
    /// [`Basis::HatGrid`] only; `false`: the solver's coefficients). The voxel-centre values are
    /// what renders and exports read; projected, a voxel's error there is the part of its own
    /// vector outside the local subspace, relative to its own magnitude as with the PCA
    /// baselines, rather than the stochastic solver's noise and its brighter neighbours' pull:
    /// for dim interiors and negative light in dim voxels.
    pub centre_projection: bool,
}

impl Default for Mbd {
    fn default() -> Self {
        Self::new(8, Basis::HatGrid { nodes: [5; 3] })
    }
}

/// The basis kernels of an [`Mbd`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum Basis {
    /// The paper's: trilinear hats on a grid of `nodes` per axis (at least 2) spanning the box
    /// of the voxel centres ([`crate::expert::basis_box`]).
    HatGrid {
        /// Basis nodes per axis.
        nodes: [usize; 3],
    },
    /// Beyond the paper: one kernel per cluster of clustered PCA (Sloan et al. 2003, `count`
    /// clusters at the same rank), its voxel labels smoothed over a few voxels so that the basis
    /// stays continuous. For scenes whose transfer changes faster than a basis cell (walls,
    /// columns, openings), where it comes close to clustered PCA's error without its seams; an
    /// engine then stores a label per voxel and blends more kernels per point than a hat's 8.
    Clusters {
        /// Number of clusters, i.e. basis kernels.
        count: usize,
        /// How the labels are smoothed into kernels.
        smoothing: LabelSmoothing,
    },
}

/// The basis kernels of a fitted [`Mbd`]: the [`Basis`] realised on a field.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub enum BasisKernels {
    /// [`Basis::HatGrid`].
    HatGrid(HatGrid),
    /// [`Basis::Clusters`].
    Clusters(LabelKernels),
}

/// What [`Mbd::fit`] returns.
#[derive(Debug, Clone)]
pub struct MbdFit {
    /// The fitted model.
    pub model: MbdModel<HatGrid, BasisKernels>,
    /// The stochastic solver's report.
    pub solve: SolveReport,
    /// The polish's report, when [`Mbd::polish`] asked for one.
    pub polish: Option<PolishReport>,
}

impl Mbd {
    /// Rank `rank` on `basis`, the default solver, no polish.
    pub fn new(rank: usize, basis: Basis) -> Self {
        Self {
            rank,
            basis,
            solver: SolverOptions::default(),
            polish: None,
            coarse_start: None,
            loss_weighting: None,
            centre_projection: false,
        }
    }

    /// Fits the model to `field` (the target is the field's trilinear interpolation). Progress
    /// sees the clustering (for [`Basis::Clusters`]), the solver's iterations, then the
    /// polish's. Deterministic for the solver's seed on any thread count.
    ///
    /// # Errors
    /// [`MbdError::InvalidRank`], [`MbdError::InvalidKernels`] (a hat grid with fewer than 2
    /// nodes on an axis, zero clusters), [`MbdError::InvalidOption`] (bad solver or polish
    /// options, checked before any work), non-finite field values, cancellation, and
    /// [`MbdError::Diverged`].
    pub fn fit(&self, field: &GridField, progress: &dyn Progress) -> Result<MbdFit, MbdError> {
        if let Some(weighting) = self.loss_weighting {
            let weights = weighting.weights(field, None)?;
            let unweighted = Mbd {
                loss_weighting: None,
                ..self.clone()
            };
            let fit = unweighted.fit(&weighted_field(field, &weights), progress)?;
            return unweight(fit, &weights);
        }
        match self.basis {
            Basis::HatGrid { nodes } => {
                self.check_polish(hat_basis(field, nodes)?.len())?;
                let (model, solve_report) = self.solve_hat_grid(field, None, nodes, progress)?;
                let mut fit = self.finish(field, model, solve_report, progress)?;
                if self.centre_projection {
                    fit.model = project_on_centres(field, None, fit.model, self.solver.lambda)?;
                }
                Ok(fit)
            }
            Basis::Clusters { count, .. } => {
                if count == 0 {
                    return Err(MbdError::InvalidKernels {
                        which: "basis",
                        why: "zero clusters".into(),
                    });
                }
                self.check_centre_projection()?;
                self.check_polish(count)?;
                let clusters = ClusteredPca::new(self.rank, count).compress(field, progress)?;
                fit_on_clusters(self, field, &clusters, progress)
            }
        }
    }

    /// [`Mbd::fit`] on the voxels with `valid[v]` only: invalid voxels have zero weight in the
    /// loss and their values are never read (see [`crate::expert::solve_masked`]); coefficient
    /// kernels that no valid voxel reaches stay exactly zero. For a traced volume whose invalid
    /// voxels (inside geometry) hold no data.
    ///
    /// # Errors
    /// As [`Mbd::fit`]; [`MbdError::InvalidOption`] for a basis other than
    /// [`Basis::HatGrid`] or with a polish (both fit every voxel), or a mask without a valid
    /// voxel; [`MbdError::ShapeMismatch`] for a mask of the wrong length.
    pub fn fit_masked(
        &self,
        field: &GridField,
        valid: &[bool],
        progress: &dyn Progress,
    ) -> Result<MbdFit, MbdError> {
        let Basis::HatGrid { nodes } = self.basis else {
            return Err(MbdError::InvalidOption {
                what: "basis",
                why: "a masked fit needs Basis::HatGrid".into(),
            });
        };
        if self.polish.is_some() {
            return Err(MbdError::InvalidOption {
                what: "polish",
                why: "the polish fits every voxel; a masked fit runs without it".into(),
            });
        }
        check_mask(field, valid)?;
        if let Some(weighting) = self.loss_weighting {
            let weights = weighting.weights(field, Some(valid))?;
            let unweighted = Mbd {
                loss_weighting: None,
                ..self.clone()
            };
            let fit = unweighted.fit_masked(&weighted_field(field, &weights), valid, progress)?;
            return unweight(fit, &weights);
        }
        let (mut model, solve) = self.solve_hat_grid(field, Some(valid), nodes, progress)?;
        if self.centre_projection {
            model = project_on_centres(field, Some(valid), model, self.solver.lambda)?;
        }
        Ok(MbdFit {
            model,
            solve,
            polish: None,
        })
    }

    /// The solver on a [`Basis::HatGrid`] of `nodes`, on the voxels `valid` (`None`: all),
    /// after the [`Mbd::coarse_start`] if one is set.
    fn solve_hat_grid(
        &self,
        field: &GridField,
        valid: Option<&[bool]>,
        nodes: [usize; 3],
        progress: &dyn Progress,
    ) -> Result<(MbdModel<HatGrid, BasisKernels>, SolveReport), MbdError> {
        let basis_kernels = BasisKernels::HatGrid(hat_basis(field, nodes)?);
        let coarse = match self.coarse_start {
            Some(start) if start.levels > 0 && can_halve(field.dims(), nodes) => {
                let (coarse_field, coarse_valid) = halve(field, valid)?;
                let coarser = Mbd {
                    solver: SolverOptions {
                        max_iterations: start.iterations,
                        seed: crate::objective::mix(self.solver.seed, start.levels as u64),
                        ..self.solver.clone()
                    },
                    coarse_start: Some(CoarseStart {
                        levels: start.levels - 1,
                        ..start
                    }),
                    ..self.clone()
                };
                progress.message("coarse start");
                Some(coarser.solve_hat_grid(
                    &coarse_field,
                    coarse_valid.as_deref(),
                    nodes,
                    progress,
                )?)
            }
            _ => None,
        };
        let start = match &coarse {
            Some((model, _)) => Start::Basis(model.basis()),
            None => Start::GlobalPca { rank: self.rank },
        };
        let (model, mut report) = solve_with(
            field,
            valid,
            coefficient_kernels(field)?,
            basis_kernels,
            start,
            &self.solver,
            progress,
        )?;
        if let Some((_, coarse_report)) = coarse {
            report.coarse_seconds = coarse_report.coarse_seconds + coarse_report.total_seconds();
        }
        Ok((model, report))
    }

    /// [`Mbd::centre_projection`] needs one coefficient hat per voxel and a basis to evaluate at
    /// its centre: [`Basis::HatGrid`].
    fn check_centre_projection(&self) -> Result<(), MbdError> {
        if self.centre_projection && !matches!(self.basis, Basis::HatGrid { .. }) {
            return Err(MbdError::InvalidOption {
                what: "centre_projection",
                why: "the centre projection needs Basis::HatGrid".into(),
            });
        }
        Ok(())
    }

    /// Bad polish options fail before the solve, not after it.
    pub(crate) fn check_polish(&self, basis_kernels: usize) -> Result<(), MbdError> {
        match &self.polish {
            Some(options) => {
                polish::validate_options(options)?;
                polish::check_basis_size(basis_kernels, self.rank)
            }
            None => Ok(()),
        }
    }

    /// The polish, if asked for, and the result.
    pub(crate) fn finish(
        &self,
        field: &GridField,
        model: MbdModel<HatGrid, BasisKernels>,
        solve: SolveReport,
        progress: &dyn Progress,
    ) -> Result<MbdFit, MbdError> {
        let (model, polish) = match &self.polish {
            Some(options) => {
                let (model, report) = polish::polish(field, model, options, progress)?;
                (model, Some(report))
            }
            None => (model, None),
        };
        Ok(MbdFit {
            model,
            solve,
            polish,
        })
    }
}

/// A fit to the weighted field with each voxel's coefficients divided by its weight.
fn unweight(fit: MbdFit, weights: &[f32]) -> Result<MbdFit, MbdError> {
    let (coefficient_kernels, basis_kernels, mut coefficients, basis) = fit.model.into_parts();
    unweight_coefficients(&mut coefficients, weights)?;
    Ok(MbdFit {
        model: MbdModel::new(coefficient_kernels, basis_kernels, coefficients, basis)?,
        ..fit
    })
}

impl Compressor for Mbd {
    type Model = MbdModel<HatGrid, BasisKernels>;
    type Error = MbdError;

    fn compress(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<Self::Model, MbdError> {
        Ok(self.fit(field, progress)?.model)
    }
}

/// The coefficient kernels of [`Mbd`] on `field`: one hat per voxel centre.
pub(crate) fn coefficient_kernels(field: &GridField) -> Result<HatGrid, MbdError> {
    HatGrid::new(field.dims(), crate::baselines::voxel_centre_box(field)).map_err(|e| {
        MbdError::InvalidKernels {
            which: "coefficient",
            why: e.to_string(),
        }
    })
}

/// The hat basis of [`Basis::HatGrid`] on `field`.
fn hat_basis(field: &GridField, nodes: [usize; 3]) -> Result<HatGrid, MbdError> {
    hat_basis_on(field.dims(), field.bounds(), nodes)
}

/// [`hat_basis`] of a grid of `dims` voxels filling `bounds`.
pub(crate) fn hat_basis_on(
    dims: [usize; 3],
    bounds: Aabb,
    nodes: [usize; 3],
) -> Result<HatGrid, MbdError> {
    if let Some(axis) = (0..3).find(|&k| nodes[k] < 2) {
        return Err(MbdError::InvalidKernels {
            which: "basis",
            why: format!("axis {axis} has {} nodes, need at least 2", nodes[axis]),
        });
    }
    HatGrid::new(nodes, basis_box_of(dims, bounds)).map_err(|e| MbdError::InvalidKernels {
        which: "basis",
        why: e.to_string(),
    })
}

/// The box the hat basis nodes of [`Basis::HatGrid`] span: the box of the voxel centres (on an
/// axis of one voxel, the field's box). The target and the coefficient kernels are constant in
/// the outer half voxel, so nodes on the field's faces would spend half a voxel per side where
/// nothing changes.
pub fn basis_box(field: &GridField) -> Aabb {
    basis_box_of(field.dims(), field.bounds())
}

/// [`basis_box`] of a grid of `dims` voxels filling `bounds`.
fn basis_box_of(dims: [usize; 3], bounds: Aabb) -> Aabb {
    let centres = crate::baselines::voxel_centre_box_of(dims, bounds);
    let pick = |c: Vec3, b: Vec3| {
        Vec3::new(
            if dims[0] >= 2 { c.x } else { b.x },
            if dims[1] >= 2 { c.y } else { b.y },
            if dims[2] >= 2 { c.z } else { b.z },
        )
    };
    Aabb::new(pick(centres.min, bounds.min), pick(centres.max, bounds.max))
}

impl BasisKernels {
    fn as_dyn(&self) -> &dyn SpatialKernels {
        match self {
            BasisKernels::HatGrid(k) => k,
            BasisKernels::Clusters(k) => k,
        }
    }
}

impl SpatialKernels for BasisKernels {
    fn len(&self) -> usize {
        self.as_dyn().len()
    }

    fn max_support(&self) -> usize {
        self.as_dyn().max_support()
    }

    fn domain(&self) -> Aabb {
        self.as_dyn().domain()
    }

    fn eval(&self, x: Vec3, out: &mut KernelWeights) -> Result<(), CoreError> {
        match self {
            BasisKernels::HatGrid(k) => k.eval(x, out),
            BasisKernels::Clusters(k) => k.eval(x, out),
        }
    }

    fn support_cell(&self, x: Vec3) -> Option<usize> {
        self.as_dyn().support_cell(x)
    }

    fn num_support_cells(&self) -> usize {
        self.as_dyn().num_support_cells()
    }

    fn centre(&self, i: usize) -> Option<Vec3> {
        self.as_dyn().centre(i)
    }
}

impl polish::sealed::Sealed for BasisKernels {
    fn layout(&self) -> BasisLayout<'_> {
        match self {
            BasisKernels::HatGrid(k) => polish::sealed::Sealed::layout(k),
            BasisKernels::Clusters(k) => polish::sealed::Sealed::layout(k),
        }
    }
}

impl PolishBasis for BasisKernels {}

/// MBD with [`crate::Basis::Clusters`] on the clusters of a clustered-PCA model of `field` at
/// `mbd.rank` (e.g. one already fitted as a baseline; the basis's `count` is not used).
/// Clusters without voxels are dropped (a kernel that is zero everywhere has no curvature for
/// the solver). Then the polish, if `mbd` asks for one.
///
/// # Errors
/// [`MbdError::InvalidOption`] when `mbd.basis` is not [`crate::Basis::Clusters`];
/// [`MbdError::ShapeMismatch`] when `clusters` is not of `field`'s voxels or `mbd.rank`; those
/// of [`LabelKernels::new`], [`crate::expert::solve_from_basis`] and [`crate::expert::polish`]
/// (bad polish options fail before the solve).
pub fn fit_on_clusters(
    mbd: &Mbd,
    field: &GridField,
    clusters: &PiecewisePcaModel,
    progress: &dyn Progress,
) -> Result<MbdFit, MbdError> {
    let Basis::Clusters { smoothing, .. } = mbd.basis else {
        return Err(MbdError::InvalidOption {
            what: "basis",
            why: "fitting on clusters needs Basis::Clusters".into(),
        });
    };
    let (count, rank, dim) = clusters.bases().dim();
    if clusters.labels().len() != field.num_voxels() || rank != mbd.rank || dim != field.dim() {
        return Err(MbdError::ShapeMismatch {
            what: "clusters",
            expected: vec![field.num_voxels(), mbd.rank, field.dim()],
            got: vec![clusters.labels().len(), rank, dim],
        });
    }
    mbd.check_centre_projection()?;
    mbd.check_polish(count)?;
    let mut index = vec![u32::MAX; count];
    let mut kept = Vec::new();
    let labels: Vec<u32> = clusters
        .labels()
        .iter()
        .map(|&k| {
            let k = k as usize;
            if index[k] == u32::MAX {
                index[k] = kept.len() as u32;
                kept.push(k);
            }
            index[k]
        })
        .collect();
    // CPCA puts the zero voxels inside geometry all in one cluster, which must not spread
    // into the open space beside every wall.
    let valid = crate::eval::nonzero_voxels(field);
    let kernels = LabelKernels::new(
        field.dims(),
        field.bounds(),
        &labels,
        kept.len(),
        Some(&valid),
        &smoothing,
    )?;
    let mut basis = clusters.bases().select(ndarray::Axis(0), &kept);
    let global = principal_subspace(field.data().view(), mbd.rank)?;
    align_to(&mut basis, &global)?;
    let (model, solve_report) = solve_from_basis(
        field,
        coefficient_kernels(field)?,
        BasisKernels::Clusters(kernels),
        &basis,
        &mbd.solver,
        progress,
    )?;
    mbd.finish(field, model, solve_report, progress)
}

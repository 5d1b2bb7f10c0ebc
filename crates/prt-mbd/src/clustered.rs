//! Basis kernels that follow the field's values rather than a grid: MBD on clustered PCA's
//! clusters (beyond the paper, opt-in).
//!
//! MBD's hat basis kernels sit on a regular grid, so a basis node serves whatever transfer its
//! cell holds. On scenes whose transfer changes with geometry on scales finer than a basis
//! cell (Sponza's columns, arches and open roof) clustered PCA, which groups voxels by *value*,
//! stays far ahead of MBD at the same number of basis vectors: 1.7–1.8× lower error at 5³
//! nodes (MBD sessions 7 and 8 in `docs/results.md`). Its lead comes from switching subspaces
//! from voxel to voxel: 69–81 % of Sponza's valid voxels border another cluster, and one round
//! of a majority filter on CPCA's labels (bases refitted) already costs CPCA 35–57 % of error.
//! [`ClusteredMbd`] gives MBD the same grouping while keeping the reconstruction continuous:
//!
//! 1. **Clusters.** [`crate::ClusteredPca`] (Sloan et al. 2003) with one cluster per basis
//!    kernel labels every voxel.
//! 2. **Kernels.** [`LabelKernels`]: at each voxel centre, kernel `n` weighs the share of label
//!    `n` among the voxel's neighbours within Chebyshev distance [`LabelSmoothing::radius`],
//!    each neighbour weighted `falloff^(L1 distance)`; voxels inside geometry (exactly zero,
//!    the baker's convention) do not spread their label. Between voxel centres the weights are
//!    interpolated trilinearly (clamped to the box of the voxel centres, like the field's own
//!    sampling). A convex combination of partitions of unity is one, so the family is a
//!    non-negative, continuous partition of unity, and the model is continuous.
//! 3. **Start.** Each kernel's basis starts from its cluster's subspace, rotated inside it
//!    (orthogonal Procrustes) to be as close as possible to the global principal subspace, so
//!    that neighbouring kernels' `l`-th vectors point the same way and blend without
//!    cancelling; then [`crate::solve_from_basis`] runs the stochastic solver as for any
//!    kernels.
//!
//! **Why smoothing.** MBD's coefficients are trilinear at voxel resolution, so a basis that
//! switches inside one voxel cell leaves cross terms `c_A · b_B` that the coefficients cannot
//! follow: the sharp labels (radius 0) end 21× above CPCA on Sponza. Radius 2 (the default)
//! blends over about five voxels.
//!
//! **Measured** (traced Sponza, L = 8, 125 clusters; MBD / CPCA relative MSE): 1.36× at
//! 48 × 20 × 30, 1.21× at 72 × 30 × 44, 1.14× at 96 × 40 × 59 (hat grid: 1.84×, 1.73×,
//! 1.82×); 256 iterations reach **1.09×** at 96 (radius 3: 1.07×). The exact [`crate::polish`]
//! takes these kernels and brings all three within 10 %: **1.07×** at 96 (radius 3, 8 sweeps
//! after the solver's own stop), **1.09×** at 72 (radius 3, 256 iterations, 16 sweeps),
//! **1.095×** at 48 (radius 4, 256 iterations, 32 sweeps), at 30–150× CPCA's time (MBD
//! session 9). Wider smoothing keeps that error with smoother bases: with falloff 0.75 at
//! radius 4 the solver alone ends further off (1.20× at 96, 1.44× at 48), but the polish goes
//! further, to **1.075×** at 96 (16 sweeps), **1.084×** at 72 (48 sweeps) and **1.097×** at 48
//! (64 sweeps), with the basis-projection seam ratio at CPCA's boundaries at 1.98, 2.12 and
//! 2.47 against CPCA's 5.86, 6.08 and 5.08 (falloff 0.5: 2.58 at 96, 3.17 at 48; MBD
//! session 10). [`ClusteredMbd::polish`] chains the sweeps. With the polish's conjugate
//! gradients (its default since MBD session 11) a 16-iteration solve is enough: the polish then
//! stops by its own rule at **1.085×** at 48 (46 iterations), **1.077×** at 72 (47) and
//! **1.042×** at 96 (38), with the same seams (2.59, 2.19 and 2.11; MBD sessions 11 and 12;
//! since session 13's exactly symmetric blocks, 1.0435× in 37 at 96, seams 2.09). A basis
//! that cannot jump (global PCA) reads 1.75, 1.84 and 1.71 there: above that floor CPCA's
//! seams (5.08, 6.08, 5.86) stand 4–12× higher than these.
//! On smooth fields it gains nothing
//! (Cornell: 0.79×, as the hat grid; the synthetic field: worse than the hat grid).
//!
//! **Cost.** The solve takes 1.6–2.8× the hat grid's CPU at radius 2 (4.5–9× CPCA's). An
//! engine stores one label per voxel (as for CPCA; neither [`crate::ClusterModel`] nor
//! [`crate::MbdModel`] counts labels in `stored_scalars`) and blends up to
//! [`SpatialKernels::max_support`] basis nodes at a point (28–33 on Sponza at radius 2)
//! instead of a hat's 8, or stores each voxel's few weights.

use glam::Vec3;
use ndarray::{Array2, Array3, Axis};
use prt_core::{Aabb, Compressor, CoreError, GridField, KernelWeights, Progress, SpatialKernels};
use prt_kernels::HatGrid;
use rayon::prelude::*;

use crate::subspace::principal_subspace;
use crate::voxel_weights::VoxelWeights;
use crate::{
    ClusterModel, ClusteredPca, MbdError, MbdModel, MbdOptions, PolishOptions, PolishReport,
    SolveReport, solve, solve_from_basis, voxel_centre_box,
};

/// How [`LabelKernels`] smooth the voxel labels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LabelSmoothing {
    /// Chebyshev radius in voxels of the neighbourhood whose labels a voxel centre blends
    /// (default 2: the 5³ neighbours; 0: the sharp labels).
    pub radius: usize,
    /// Weight of a neighbour at L1 distance `d` voxels: `falloff^d`, in (0, 1] (default 0.5).
    pub falloff: f32,
}

impl Default for LabelSmoothing {
    fn default() -> Self {
        Self {
            radius: 2,
            falloff: 0.5,
        }
    }
}

/// The largest [`LabelSmoothing::radius`]: a 9³ neighbourhood.
pub const MAX_LABEL_RADIUS: usize = 4;

/// Basis kernels from per-voxel labels, smoothed over a neighbourhood and interpolated between
/// voxel centres (module docs).
#[derive(Debug, Clone)]
pub struct LabelKernels {
    len: usize,
    labels: Vec<u32>,
    weights: VoxelWeights,
}

impl LabelKernels {
    /// Kernels of the labels `labels` (one per voxel of a grid of `dims` over `bounds`, x
    /// fastest), `len` kernels (every label must be below it; a kernel without voxels is zero
    /// everywhere). Voxels outside `valid` (if given; e.g. inside geometry) do not spread their
    /// label to their neighbours (they keep it themselves).
    ///
    /// # Errors
    /// [`MbdError::ShapeMismatch`] when `labels` is not one per voxel;
    /// [`MbdError::InvalidOption`] for a label ≥ `len`, a radius above [`MAX_LABEL_RADIUS`] or
    /// a falloff outside (0, 1] or more than 2^32 voxels; [`MbdError::InvalidKernels`] for an
    /// empty grid, `len` 0 or a box of zero extent.
    pub fn new(
        dims: [usize; 3],
        bounds: Aabb,
        labels: &[u32],
        len: usize,
        valid: Option<&[bool]>,
        smoothing: &LabelSmoothing,
    ) -> Result<Self, MbdError> {
        let voxels: usize = dims.iter().product();
        if voxels == 0 || len == 0 {
            return Err(MbdError::InvalidKernels {
                which: "basis",
                why: format!("{len} labels on a {dims:?} grid"),
            });
        }
        VoxelWeights::voxel_count(dims, bounds)?;
        if labels.len() != voxels {
            return Err(MbdError::ShapeMismatch {
                what: "labels",
                expected: vec![voxels],
                got: vec![labels.len()],
            });
        }
        if let Some(valid) = valid
            && valid.len() != voxels
        {
            return Err(MbdError::ShapeMismatch {
                what: "valid",
                expected: vec![voxels],
                got: vec![valid.len()],
            });
        }
        if let Some(v) = labels.iter().position(|&k| k as usize >= len) {
            return Err(MbdError::InvalidOption {
                what: "labels",
                why: format!("voxel {v} has label {}, not below {len}", labels[v]),
            });
        }
        if smoothing.radius > MAX_LABEL_RADIUS {
            return Err(MbdError::InvalidOption {
                what: "radius",
                why: format!("{} is above {MAX_LABEL_RADIUS}", smoothing.radius),
            });
        }
        if !(smoothing.falloff > 0.0 && smoothing.falloff <= 1.0) {
            return Err(MbdError::InvalidOption {
                what: "falloff",
                why: format!("{} is not in (0, 1]", smoothing.falloff),
            });
        }
        let r = smoothing.radius as i64;
        let falloff = f64::from(smoothing.falloff);
        let row = |v: usize| {
            let c = [
                v % dims[0],
                (v / dims[0]) % dims[1],
                v / (dims[0] * dims[1]),
            ]
            .map(|x| x as i64);
            let mut row: Vec<(u32, f64)> = Vec::new();
            for dz in -r..=r {
                for dy in -r..=r {
                    for dx in -r..=r {
                        let q = [c[0] + dx, c[1] + dy, c[2] + dz];
                        if (0..3).any(|k| q[k] < 0 || q[k] >= dims[k] as i64) {
                            continue;
                        }
                        let u = q[0] as usize + dims[0] * (q[1] as usize + dims[1] * q[2] as usize);
                        let own = u == v;
                        if !own && valid.is_some_and(|valid| !valid[u]) {
                            continue;
                        }
                        let w = falloff.powi((dx.abs() + dy.abs() + dz.abs()) as i32);
                        match row.iter_mut().find(|e| e.0 == labels[u]) {
                            Some(e) => e.1 += w,
                            None => row.push((labels[u], w)),
                        }
                    }
                }
            }
            let total: f64 = row.iter().map(|e| e.1).sum();
            row.sort_by_key(|e| e.0);
            row.into_iter()
                .map(|(k, w)| (k, (w / total) as f32))
                .collect::<Vec<_>>()
        };
        let rows: Vec<Vec<(u32, f32)>> = (0..voxels).into_par_iter().map(row).collect();
        Ok(Self {
            len,
            labels: labels.to_vec(),
            weights: VoxelWeights::new(dims, bounds, rows),
        })
    }

    /// The voxel labels.
    pub fn labels(&self) -> &[u32] {
        &self.labels
    }

    /// The kernel weights `(kernel, weight)` at the centre of voxel `v` (they sum to one);
    /// empty for `v` out of range.
    pub fn voxel_weights(&self, v: usize) -> impl Iterator<Item = (u32, f32)> + '_ {
        self.weights.row(v)
    }
}

impl crate::polish::sealed::Sealed for LabelKernels {
    fn layout(&self) -> crate::polish::BasisLayout<'_> {
        crate::polish::BasisLayout::Voxels(&self.weights)
    }
}

impl crate::PolishBasis for LabelKernels {}

impl SpatialKernels for LabelKernels {
    fn len(&self) -> usize {
        self.len
    }

    fn max_support(&self) -> usize {
        self.weights.max_support()
    }

    fn domain(&self) -> Aabb {
        self.weights.bounds()
    }

    /// The trilinear blend of the eight surrounding voxel centres' weights; points outside the
    /// box are clamped to it.
    fn eval(&self, x: Vec3, out: &mut KernelWeights) -> Result<(), CoreError> {
        self.weights.eval(x, out)
    }
}

/// Rotates each `L × D` block of `bases` (orthonormal rows) inside its row space to be as close
/// as possible, in the Frobenius norm, to `reference` (`L × D`): orthogonal Procrustes,
/// `R = V Uᵀ` from the SVD `B Gᵀ = U S Vᵀ`.
pub(crate) fn align_to(bases: &mut Array3<f32>, reference: &Array2<f32>) -> Result<(), MbdError> {
    let g = reference.mapv(f64::from);
    for mut block in bases.axis_iter_mut(Axis(0)) {
        let b = block.mapv(f64::from);
        let m = b.dot(&g.t());
        let svd = prt_linalg::thin_svd(m.view()).map_err(|e| MbdError::InvalidOption {
            what: "initial basis",
            why: format!("Procrustes alignment failed: {e}"),
        })?;
        let rotation = svd.vt.t().dot(&svd.u.t());
        block.assign(&rotation.dot(&b).mapv(|x| x as f32));
    }
    Ok(())
}

/// Where [`ClusteredMbd`] starts the basis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum ClusterStart {
    /// Each kernel starts from its cluster's subspace, rotated inside it to be as close as
    /// possible to the global principal subspace (the default).
    #[default]
    AlignedClusters,
    /// Every kernel starts from the global principal subspace, as [`crate::Init::GlobalPca`].
    GlobalPca,
}

/// MBD whose basis kernels are clustered PCA's clusters, smoothed ([`LabelKernels`]; module
/// docs). A [`Compressor`] with [`crate::Mbd`]'s coefficients and a basis per cluster, plus a
/// label per voxel.
#[derive(Debug, Clone, PartialEq)]
pub struct ClusteredMbd {
    /// Number of clusters, i.e. basis kernels (the paper's comparison: MBD's basis-node count).
    pub clusters: usize,
    /// How the cluster labels are smoothed into kernels.
    pub smoothing: LabelSmoothing,
    /// Where the basis starts.
    pub start: ClusterStart,
    /// The solver's options (rank, iterations, stopping rule, seed; `init` is not used).
    pub options: MbdOptions,
    /// Exact [`crate::polish`] sweeps after the solver (opt-in; default `None`: the solver's
    /// model as it stops). The solver leaves these kernels well above their optimum on
    /// scenes such as Sponza, and the wider the smoothing the further (module docs).
    pub polish: Option<PolishOptions>,
}

impl ClusteredMbd {
    /// `clusters` kernels at rank `rank`, the default smoothing, start and solver.
    pub fn new(rank: usize, clusters: usize) -> Self {
        Self {
            clusters,
            smoothing: LabelSmoothing::default(),
            start: ClusterStart::default(),
            options: MbdOptions {
                rank,
                ..MbdOptions::default()
            },
            polish: None,
        }
    }

    /// Clusters the field with [`ClusteredPca`] (`options.rank`, `clusters`), then
    /// [`ClusteredMbd::fit_clusters`].
    ///
    /// # Errors
    /// As [`ClusteredPca`] and [`ClusteredMbd::fit_clusters`].
    pub fn fit(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<ClusteredFit, MbdError> {
        self.check_polish(self.clusters)?;
        let cpca = ClusteredPca::new(self.options.rank, self.clusters).compress(field, progress)?;
        self.fit_clusters(field, &cpca, progress)
    }

    /// MBD on the clusters of a clustered-PCA model of `field` at rank `options.rank` (e.g.
    /// one already fitted as a baseline); `self.clusters` is not used. Clusters without voxels
    /// are dropped (a kernel that is zero everywhere has no curvature for the solver). Then
    /// the `polish` sweeps, if any.
    ///
    /// # Errors
    /// [`MbdError::ShapeMismatch`] when `cpca` is not of `field`'s voxels or rank; those of
    /// [`LabelKernels::new`], [`solve_from_basis`] and [`crate::polish`] (bad polish options
    /// fail before the solve).
    pub fn fit_clusters(
        &self,
        field: &GridField,
        cpca: &ClusterModel,
        progress: &dyn Progress,
    ) -> Result<ClusteredFit, MbdError> {
        let (clusters, rank, dim) = cpca.bases().dim();
        if cpca.labels().len() != field.num_voxels()
            || rank != self.options.rank
            || dim != field.dim()
        {
            return Err(MbdError::ShapeMismatch {
                what: "clusters",
                expected: vec![field.num_voxels(), self.options.rank, field.dim()],
                got: vec![cpca.labels().len(), rank, dim],
            });
        }
        self.check_polish(clusters)?;
        let mut index = vec![u32::MAX; clusters];
        let mut kept = Vec::new();
        let labels: Vec<u32> = cpca
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
        let valid = crate::nonzero_voxels(field);
        let kernels = LabelKernels::new(
            field.dims(),
            field.bounds(),
            &labels,
            kept.len(),
            Some(&valid),
            &self.smoothing,
        )?;
        let coefficient_kernels =
            HatGrid::new(field.dims(), voxel_centre_box(field)).map_err(|e| {
                MbdError::InvalidKernels {
                    which: "coefficient",
                    why: e.to_string(),
                }
            })?;
        let (model, solve_report) = match self.start {
            ClusterStart::GlobalPca => solve(
                field,
                coefficient_kernels,
                kernels,
                &MbdOptions {
                    init: crate::Init::GlobalPca,
                    ..self.options.clone()
                },
                progress,
            ),
            ClusterStart::AlignedClusters => {
                let mut basis = cpca.bases().select(Axis(0), &kept);
                let global = principal_subspace(field.data().view(), self.options.rank)?;
                align_to(&mut basis, &global)?;
                solve_from_basis(
                    field,
                    coefficient_kernels,
                    kernels,
                    &basis,
                    &self.options,
                    progress,
                )
            }
        }?;
        let (model, polish_report) = match &self.polish {
            Some(options) => {
                let (model, report) = crate::polish(field, model, options, progress)?;
                (model, Some(report))
            }
            None => (model, None),
        };
        Ok(ClusteredFit {
            model,
            solve: solve_report,
            polish: polish_report,
        })
    }

    /// Bad polish options fail before the clustering and the solve, not after them.
    fn check_polish(&self, clusters: usize) -> Result<(), MbdError> {
        match &self.polish {
            Some(polish) => {
                crate::polish::validate_options(polish)?;
                crate::polish::check_basis_size(clusters, self.options.rank)
            }
            None => Ok(()),
        }
    }
}

/// What [`ClusteredMbd::fit`] returns.
#[derive(Debug, Clone)]
pub struct ClusteredFit {
    /// The fitted model.
    pub model: MbdModel<HatGrid, LabelKernels>,
    /// The stochastic solver's report.
    pub solve: SolveReport,
    /// The polish's report, when [`ClusteredMbd::polish`] asked for one.
    pub polish: Option<PolishReport>,
}

impl Compressor for ClusteredMbd {
    type Model = MbdModel<HatGrid, LabelKernels>;
    type Error = MbdError;

    fn compress(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<Self::Model, MbdError> {
        self.fit(field, progress).map(|fit| fit.model)
    }
}

//! The PCA-family baselines of the MBD paper, each a [`Compressor`] producing a
//! [`PiecewisePcaModel`]: global PCA, blockwise PCA (BPCA), windowed blockwise PCA (WBPCA), clustered
//! PCA (CPCA, Sloan et al. 2003) and k-means vector quantisation.
//!
//! Every PCA here is *uncentred* (a truncated SVD of the cluster's rows): a rank-L cluster
//! stores exactly L basis vectors and each voxel L coefficients, the same budget as a rank-L MBD
//! whose basis grid has as many nodes as there are clusters. Reconstructions live on the voxels
//! of the input grid and are interpolated trilinearly between them, as the paper resamples
//! every method to a trilinear grid before comparing.

use glam::Vec3;
use ndarray::{Array2, Array3, ArrayView2, Axis, linalg::general_mat_mul, s};
use prt_core::{Aabb, Compressor, CoreError, FieldModel, GridField, Progress, TrilinearWeights};
use prt_linalg::{KMeansOptions, kmeans};
use rayon::prelude::*;

use crate::loss_weights::{unweight_coefficients, weighted_field};
use crate::subspace::{linalg_error, principal_subspace};
use crate::{LossWeighting, MbdError};

/// A clustered linear model on the voxels of a grid: voxel `v` belongs to cluster
/// `labels[v]` and is `coefficients[v] · bases[labels[v]]`; between voxel centres the
/// reconstruction is interpolated trilinearly.
#[derive(Debug, Clone, PartialEq)]
pub struct PiecewisePcaModel {
    name: String,
    labels: Vec<u32>,
    bases: Array3<f32>,
    coefficients: Array2<f32>,
    dims: [usize; 3],
    bounds: Aabb,
    stored_scalars: usize,
}

impl PiecewisePcaModel {
    /// A subspace model: every voxel projected onto its cluster's basis; it stores the bases
    /// and L coefficients per voxel.
    fn projected(
        name: String,
        field: &GridField,
        labels: Vec<u32>,
        bases: Array3<f32>,
    ) -> Result<Self, MbdError> {
        let coefficients = project(field, &labels, &bases);
        let stored = bases.len() + coefficients.len();
        Self::new(name, field, labels, bases, coefficients, stored)
    }

    /// The model on `field`'s grid. `stored_scalars` is what the method stores (for vector
    /// quantisation, one index per voxel rather than coefficients).
    fn new(
        name: String,
        field: &GridField,
        labels: Vec<u32>,
        bases: Array3<f32>,
        coefficients: Array2<f32>,
        stored_scalars: usize,
    ) -> Result<Self, MbdError> {
        Ok(Self {
            name,
            labels,
            bases,
            coefficients,
            dims: field.dims(),
            bounds: field.bounds(),
            stored_scalars,
        })
    }

    /// Cluster index of every voxel.
    pub fn labels(&self) -> &[u32] {
        &self.labels
    }

    /// Cluster bases, `K × L × D` (orthonormal rows for the PCA family, one centroid for VQ).
    pub fn bases(&self) -> &Array3<f32> {
        &self.bases
    }

    /// Per-voxel coefficients, `voxels × L`.
    pub fn coefficients(&self) -> &Array2<f32> {
        &self.coefficients
    }

    /// The reconstructed voxel values, computed on each call (voxels × D floats: the model
    /// itself keeps only its labels, bases and coefficients).
    pub fn reconstruct(&self) -> Result<GridField, MbdError> {
        let d = self.bases.dim().2;
        let voxels = self.labels.len();
        let mut data = Array2::<f32>::zeros((voxels, d));
        data.axis_iter_mut(Axis(0))
            .into_par_iter()
            .enumerate()
            .for_each(|(v, mut row)| {
                let basis = self.bases.index_axis(Axis(0), self.labels[v] as usize);
                row.assign(&self.coefficients.row(v).dot(&basis));
            });
        Ok(GridField::from_data(self.dims, self.bounds, data)?)
    }
}

impl FieldModel for PiecewisePcaModel {
    fn dim(&self) -> usize {
        self.bases.dim().2
    }

    /// The trilinear interpolation of the voxel reconstructions: the corners' coefficients are
    /// blended per cluster first, so a point inside one cluster costs one `L × D` product.
    fn eval(&self, x: Vec3, out: &mut [f32]) -> Result<(), CoreError> {
        if out.len() != self.dim() {
            return Err(CoreError::LengthMismatch {
                what: "sample output",
                expected: self.dim(),
                got: out.len(),
            });
        }
        let corners = TrilinearWeights::at(self.dims, self.bounds, x)?;
        let l = self.coefficients.ncols();
        let mut blended = vec![0.0f32; l];
        let mut done = [false; 8];
        let mut out = ndarray::aview_mut1(out);
        out.fill(0.0);
        for c in 0..8 {
            if done[c] {
                continue;
            }
            let label = self.labels[corners.indices[c]];
            blended.fill(0.0);
            for k in c..8 {
                let voxel = corners.indices[k];
                if !done[k] && self.labels[voxel] == label {
                    done[k] = true;
                    let w = corners.weights[k];
                    for (b, &x) in blended.iter_mut().zip(self.coefficients.row(voxel)) {
                        *b += w * x;
                    }
                }
            }
            let basis = self.bases.index_axis(Axis(0), label as usize);
            for (&w, row) in blended.iter().zip(basis.rows()) {
                out.scaled_add(w, &row);
            }
        }
        Ok(())
    }

    fn stored_scalars(&self) -> usize {
        self.stored_scalars
    }

    fn name(&self) -> String {
        self.name.clone()
    }
}

fn check_rank(rank: usize, field: &GridField) -> Result<(), MbdError> {
    if rank == 0 || rank > field.dim() {
        return Err(MbdError::InvalidRank {
            rank,
            dim: field.dim(),
        });
    }
    field.check_finite()?;
    Ok(())
}

/// Projects every voxel onto its cluster's basis: coefficients `voxels × L`.
fn project(field: &GridField, labels: &[u32], bases: &Array3<f32>) -> Array2<f32> {
    let l = bases.dim().1;
    let mut coefficients = Array2::<f32>::zeros((field.num_voxels(), l));
    coefficients
        .axis_iter_mut(Axis(0))
        .into_par_iter()
        .enumerate()
        .for_each(|(v, mut row)| {
            let basis = bases.index_axis(Axis(0), labels[v] as usize);
            row.assign(&basis.dot(&ndarray::aview1(field.voxel(v))));
        });
    coefficients
}

/// Global uncentred PCA: one basis of `rank` vectors for the whole field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GlobalPca {
    /// Number of basis vectors L.
    pub rank: usize,
}

impl Compressor for GlobalPca {
    type Model = PiecewisePcaModel;
    type Error = MbdError;

    fn compress(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<PiecewisePcaModel, MbdError> {
        check_rank(self.rank, field)?;
        progress.check()?;
        let basis = principal_subspace(field.data().view(), self.rank)?;
        let bases = basis.insert_axis(Axis(0));
        let labels = vec![0u32; field.num_voxels()];
        PiecewisePcaModel::projected(format!("PCA rank {}", self.rank), field, labels, bases)
    }
}

/// Blockwise PCA: the grid is cut into `blocks` equal boxes of voxels, each with its own rank-L
/// basis. With `window > 1` (WBPCA, the paper uses 2) each block's basis is fitted to the voxels
/// of a box `window` times as large, centred on the block, which smooths the change of basis
/// between blocks at the cost of fit inside them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlockPca {
    /// Number of basis vectors L per block.
    pub rank: usize,
    /// Blocks per axis (the paper matches MBD's basis grid: one block per basis node).
    pub blocks: [usize; 3],
    /// Fitting window relative to the block size (1 = BPCA, 2 = WBPCA).
    pub window: f32,
    /// Beyond the paper (opt-in; `None` is its loss): the subspaces minimise the weighted loss
    /// of [`LossWeighting`], as MBD's does with [`Mbd::loss_weighting`](crate::Mbd::loss_weighting).
    pub loss_weighting: Option<LossWeighting>,
}

impl BlockPca {
    /// Block index of every voxel.
    fn labels(&self, field: &GridField) -> Vec<u32> {
        let dims = field.dims();
        (0..field.num_voxels())
            .map(|v| {
                let c = field.coords(v);
                let b: Vec<usize> = (0..3).map(|k| c[k] * self.blocks[k] / dims[k]).collect();
                (b[0] + self.blocks[0] * (b[1] + self.blocks[1] * b[2])) as u32
            })
            .collect()
    }
}

impl Compressor for BlockPca {
    type Model = PiecewisePcaModel;
    type Error = MbdError;

    fn compress(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<PiecewisePcaModel, MbdError> {
        fit_weighted(field, None, self.loss_weighting, |f| self.fit(f, progress))
    }
}

impl BlockPca {
    /// The paper's BPCA of `field` (no weighting).
    fn fit(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<PiecewisePcaModel, MbdError> {
        check_rank(self.rank, field)?;
        let dims = field.dims();
        if (0..3).any(|k| self.blocks[k] == 0 || self.blocks[k] > dims[k]) {
            return Err(MbdError::InvalidOption {
                what: "blocks",
                why: format!(
                    "{:?} blocks for a {:?} grid (need 1..=voxels per axis)",
                    self.blocks, dims
                ),
            });
        }
        if !(self.window >= 1.0 && self.window.is_finite()) {
            return Err(MbdError::InvalidOption {
                what: "window",
                why: format!("{} is not >= 1", self.window),
            });
        }
        let num_blocks = self.blocks.iter().product::<usize>();
        progress.set_len(num_blocks as u64);
        let bases: Vec<Result<Array2<f32>, MbdError>> = (0..num_blocks)
            .into_par_iter()
            .map(|b| {
                progress.check()?;
                let bc = [
                    b % self.blocks[0],
                    (b / self.blocks[0]) % self.blocks[1],
                    b / (self.blocks[0] * self.blocks[1]),
                ];
                // Voxel range of the block, widened by the window around its centre.
                let mut lo = [0usize; 3];
                let mut hi = [0usize; 3];
                for k in 0..3 {
                    let a = (bc[k] * dims[k]).div_ceil(self.blocks[k]);
                    let e = ((bc[k] + 1) * dims[k]).div_ceil(self.blocks[k]);
                    let grow = ((e - a) as f32 * (self.window - 1.0) * 0.5).round() as usize;
                    lo[k] = a.saturating_sub(grow);
                    hi[k] = (e + grow).min(dims[k]);
                }
                let mut voxels = Vec::new();
                for z in lo[2]..hi[2] {
                    for y in lo[1]..hi[1] {
                        for x in lo[0]..hi[0] {
                            voxels.push(field.index(x, y, z));
                        }
                    }
                }
                let rows = field.data().select(Axis(0), &voxels);
                let basis = principal_subspace(rows.view(), self.rank)?;
                progress.inc(1);
                Ok(basis)
            })
            .collect();
        let l = self.rank;
        let d = field.dim();
        let mut stacked = Array3::<f32>::zeros((num_blocks, l, d));
        for (b, basis) in bases.into_iter().enumerate() {
            stacked.index_axis_mut(Axis(0), b).assign(&basis?);
        }
        let labels = self.labels(field);
        let name = if self.window > 1.0 { "WBPCA" } else { "BPCA" };
        PiecewisePcaModel::projected(format!("{name} rank {l}"), field, labels, stacked)
    }
}

/// Clustered PCA (Sloan, Hall, Hart & Snyder 2003), the distance-to-subspace variant: voxels
/// are assigned to the cluster whose rank-L subspace reconstructs them best, subspaces are
/// refitted to their voxels, and the two steps alternate (each never increases the total
/// squared error). Clusters start from k-means.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClusteredPca {
    /// Number of basis vectors L per cluster.
    pub rank: usize,
    /// Number of clusters (the paper matches MBD's basis-node count).
    pub clusters: usize,
    /// Assignment/refit rounds (default 8 in [`ClusteredPca::new`]).
    pub iterations: usize,
    /// Seed of the k-means start.
    pub seed: u64,
    /// Beyond the paper (opt-in; `None` is its loss): k-means start and subspaces minimise the
    /// weighted loss of [`LossWeighting`]. Assignment is unchanged (a voxel's weight scales its
    /// distance to every subspace alike).
    pub loss_weighting: Option<LossWeighting>,
}

impl ClusteredPca {
    /// Defaults: 8 rounds, seed 0, the paper's loss.
    pub fn new(rank: usize, clusters: usize) -> Self {
        Self {
            rank,
            clusters,
            iterations: 8,
            seed: 0,
            loss_weighting: None,
        }
    }
}

impl ClusteredPca {
    /// Clustered PCA with the clusters given instead of found: each cluster's rank-`rank`
    /// subspace of its voxels, every voxel projected onto its own (e.g. for labels edited after
    /// a [`ClusteredPca`] fit). `labels` holds one cluster index per voxel; an empty cluster
    /// gets the global subspace.
    ///
    /// # Errors
    /// [`MbdError::InvalidRank`], NaN/Inf in the field, [`MbdError::ShapeMismatch`] when
    /// `labels` is not one per voxel, cancellation.
    pub fn with_labels(
        field: &GridField,
        labels: Vec<u32>,
        rank: usize,
        progress: &dyn Progress,
    ) -> Result<PiecewisePcaModel, MbdError> {
        check_rank(rank, field)?;
        if labels.len() != field.num_voxels() {
            return Err(MbdError::ShapeMismatch {
                what: "labels",
                expected: vec![field.num_voxels()],
                got: vec![labels.len()],
            });
        }
        let clusters = labels.iter().map(|&k| k as usize + 1).max().unwrap_or(1);
        let bases = fit_clusters(field, &labels, clusters, rank, None, progress)?;
        PiecewisePcaModel::projected(format!("CPCA rank {rank}"), field, labels, bases)
    }
}

/// `fit` run on `field` with every voxel's vector scaled by its weight under `weighting`
/// (computed over the voxels `valid` marks), its coefficients divided back: a piecewise PCA's
/// reconstruction is linear in each voxel's vector, so the model reconstructs `field` itself
/// while its subspaces minimise the weighted loss. Without a weighting, `fit(field)`.
fn fit_weighted(
    field: &GridField,
    valid: Option<&[bool]>,
    weighting: Option<LossWeighting>,
    fit: impl FnOnce(&GridField) -> Result<PiecewisePcaModel, MbdError>,
) -> Result<PiecewisePcaModel, MbdError> {
    let Some(weighting) = weighting else {
        return fit(field);
    };
    let weights = weighting.weights(field, valid)?;
    let mut model = fit(&weighted_field(field, &weights))?;
    unweight_coefficients(&mut model.coefficients, &weights)?;
    Ok(model)
}

/// Rows per chunk of the distance-to-subspace assignment.
const ASSIGN_CHUNK: usize = 512;

/// Fits one rank-L subspace per cluster; an empty cluster keeps `previous` (or gets the global
/// subspace).
fn fit_clusters(
    field: &GridField,
    labels: &[u32],
    k: usize,
    rank: usize,
    previous: Option<&Array3<f32>>,
    progress: &dyn Progress,
) -> Result<Array3<f32>, MbdError> {
    let mut members = vec![Vec::new(); k];
    for (v, &c) in labels.iter().enumerate() {
        members[c as usize].push(v);
    }
    let fits: Vec<Result<Option<Array2<f32>>, MbdError>> = members
        .par_iter()
        .map(|voxels| {
            progress.check()?;
            if voxels.is_empty() {
                return Ok(None);
            }
            let rows = field.data().select(Axis(0), voxels);
            principal_subspace(rows.view(), rank).map(Some)
        })
        .collect();
    let mut bases = Array3::<f32>::zeros((k, rank, field.dim()));
    for (c, fit) in fits.into_iter().enumerate() {
        let basis = match (fit?, previous) {
            (Some(b), _) => b,
            (None, Some(prev)) => prev.index_axis(Axis(0), c).to_owned(),
            (None, None) => principal_subspace(field.data().view(), rank)?,
        };
        bases.index_axis_mut(Axis(0), c).assign(&basis);
    }
    Ok(bases)
}

/// Assigns every voxel to the cluster whose subspace captures the most energy `‖B_k x‖²`
/// (equivalently the smallest residual `‖x‖² − ‖B_k x‖²`), ties to the lower index.
fn assign_to_subspaces(data: ArrayView2<'_, f32>, bases: &Array3<f32>) -> Vec<u32> {
    let (k, l, d) = bases.dim();
    let all = bases
        .view()
        .into_shape_with_order((k * l, d))
        .map(|a| a.t().to_owned());
    let Ok(all) = all else {
        return vec![0; data.nrows()];
    };
    let chunks: Vec<Vec<u32>> = data
        .axis_chunks_iter(Axis(0), ASSIGN_CHUNK)
        .into_par_iter()
        .map(|rows| {
            let mut proj = Array2::<f32>::zeros((rows.nrows(), k * l));
            general_mat_mul(1.0, &rows, &all, 0.0, &mut proj);
            proj.rows()
                .into_iter()
                .map(|p| {
                    let mut best = (0u32, f32::NEG_INFINITY);
                    for c in 0..k {
                        let e: f32 = p.slice(s![c * l..(c + 1) * l]).iter().map(|v| v * v).sum();
                        if e > best.1 {
                            best = (c as u32, e);
                        }
                    }
                    best.0
                })
                .collect()
        })
        .collect();
    chunks.concat()
}

impl Compressor for ClusteredPca {
    type Model = PiecewisePcaModel;
    type Error = MbdError;

    fn compress(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<PiecewisePcaModel, MbdError> {
        fit_weighted(field, None, self.loss_weighting, |f| self.fit(f, progress))
    }
}

impl ClusteredPca {
    /// The paper's CPCA of `field` (no weighting).
    fn fit(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<PiecewisePcaModel, MbdError> {
        check_rank(self.rank, field)?;
        if self.clusters == 0 || self.clusters > field.num_voxels() {
            return Err(MbdError::InvalidOption {
                what: "clusters",
                why: format!(
                    "{} clusters for {} voxels",
                    self.clusters,
                    field.num_voxels()
                ),
            });
        }
        progress.set_len(self.iterations as u64 + 1);
        let opts = KMeansOptions {
            max_iters: 10,
            tol: 1e-4,
            seed: self.seed,
        };
        let start =
            kmeans(field.data().view(), self.clusters, &opts, progress).map_err(|e| match e {
                prt_linalg::LinalgError::Cancelled => MbdError::Core(CoreError::Cancelled),
                e => linalg_error("CPCA k-means start", e),
            })?;
        let mut labels = start.assignments;
        let mut bases = fit_clusters(field, &labels, self.clusters, self.rank, None, progress)?;
        progress.inc(1);
        for _ in 0..self.iterations {
            progress.check()?;
            let next = assign_to_subspaces(field.data().view(), &bases);
            let changed = next != labels;
            labels = next;
            bases = fit_clusters(
                field,
                &labels,
                self.clusters,
                self.rank,
                Some(&bases),
                progress,
            )?;
            progress.inc(1);
            if !changed {
                break;
            }
        }
        PiecewisePcaModel::projected(format!("CPCA rank {}", self.rank), field, labels, bases)
    }
}

impl ClusteredPca {
    /// Clustered PCA of the voxels with `valid[v]` only: the valid rows are clustered and
    /// projected, the invalid voxels' values are never read and their coefficients are zero
    /// (label 0). For a traced volume whose invalid voxels hold no data; clustering fewer rows
    /// also costs less.
    ///
    /// # Errors
    /// As [`Compressor::compress`] on the valid voxels; [`MbdError::ShapeMismatch`] for a mask
    /// of the wrong length.
    pub fn compress_masked(
        &self,
        field: &GridField,
        valid: &[bool],
        progress: &dyn Progress,
    ) -> Result<PiecewisePcaModel, MbdError> {
        fit_weighted(field, Some(valid), self.loss_weighting, |f| {
            self.fit_masked(f, valid, progress)
        })
    }

    /// [`compress_masked`](Self::compress_masked) without weighting.
    fn fit_masked(
        &self,
        field: &GridField,
        valid: &[bool],
        progress: &dyn Progress,
    ) -> Result<PiecewisePcaModel, MbdError> {
        if valid.len() != field.num_voxels() {
            return Err(MbdError::ShapeMismatch {
                what: "validity mask",
                expected: vec![field.num_voxels()],
                got: vec![valid.len()],
            });
        }
        let rows: Vec<usize> = (0..valid.len()).filter(|&v| valid[v]).collect();
        // The valid rows as a field of their own (clustering ignores where a voxel is).
        let compact = GridField::from_data(
            [rows.len().max(1), 1, 1],
            Aabb::UNIT,
            field.data().select(Axis(0), &rows),
        )?;
        let model = self.fit(&compact, progress)?;
        drop(compact);
        let mut labels = vec![0u32; field.num_voxels()];
        let mut coefficients = Array2::<f32>::zeros((field.num_voxels(), self.rank));
        for (k, &v) in rows.iter().enumerate() {
            labels[v] = model.labels[k];
            coefficients.row_mut(v).assign(&model.coefficients.row(k));
        }
        let stored = model.bases.len() + coefficients.len();
        PiecewisePcaModel::new(model.name, field, labels, model.bases, coefficients, stored)
    }
}

/// k-means vector quantisation: every voxel is replaced by the nearest of `codewords`
/// centroids and stores only its index.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KMeansVq {
    /// Number of centroids (the paper matches MBD's basis-vector count, nodes × L).
    pub codewords: usize,
    /// Lloyd iterations.
    pub iterations: usize,
    /// Seed of the k-means++ start.
    pub seed: u64,
}

impl Compressor for KMeansVq {
    type Model = PiecewisePcaModel;
    type Error = MbdError;

    fn compress(
        &self,
        field: &GridField,
        progress: &dyn Progress,
    ) -> Result<PiecewisePcaModel, MbdError> {
        field.check_finite()?;
        let opts = KMeansOptions {
            max_iters: self.iterations.max(1),
            tol: 1e-6,
            seed: self.seed,
        };
        let km =
            kmeans(field.data().view(), self.codewords, &opts, progress).map_err(|e| match e {
                prt_linalg::LinalgError::Cancelled => MbdError::Core(CoreError::Cancelled),
                e => linalg_error("k-means", e),
            })?;
        let (k, d) = km.centroids.dim();
        let bases =
            km.centroids
                .into_shape_with_order((k, 1, d))
                .map_err(|e| MbdError::InvalidOption {
                    what: "k-means centroids",
                    why: e.to_string(),
                })?;
        let coefficients = Array2::<f32>::ones((field.num_voxels(), 1));
        let stored = bases.len() + field.num_voxels();
        PiecewisePcaModel::new(
            format!("VQ k={}", self.codewords),
            field,
            km.assignments,
            bases,
            coefficients,
            stored,
        )
    }
}

/// The box spanned by the voxel centres of `field` (where a hat grid with one node per voxel
/// puts its nodes).
pub fn voxel_centre_box(field: &GridField) -> Aabb {
    voxel_centre_box_of(field.dims(), field.bounds())
}

/// [`voxel_centre_box`] of a grid of `dims` voxels filling `bounds`.
pub(crate) fn voxel_centre_box_of(dims: [usize; 3], bounds: Aabb) -> Aabb {
    let size = bounds.size() / Vec3::from_array(dims.map(|n| n as f32));
    let centre = |i: [usize; 3]| bounds.min + (Vec3::from_array(i.map(|i| i as f32)) + 0.5) * size;
    Aabb::new(centre([0; 3]), centre(dims.map(|n| n - 1)))
}

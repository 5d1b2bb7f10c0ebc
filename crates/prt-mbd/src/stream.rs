//! MBD's exact least-squares steps on a volume that arrives in pieces (tiles read one after
//! another, or parts summed on other machines), so that no step holds the whole volume.

use glam::Vec3;
use ndarray::{Array2, Array3};
use prt_core::{Aabb, KernelWeights, SpatialKernels};
use prt_kernels::HatGrid;
use rayon::prelude::*;

use crate::subspace::{cholesky_in_place, cholesky_solve_in_place};
use crate::{MbdError, MbdModel};

/// A rank-L MBD of a voxel grid with a fixed hat-grid basis, fitted one voxel at a time: each
/// voxel's coefficients are the ridge least-squares fit of its vector on the basis at its centre
/// ([`StreamedMbd::project`]), and the basis is refitted to coefficients and vectors summed
/// piece by piece ([`BasisNormals`], [`StreamedMbd::solve_basis`]): alternating least squares on
/// the voxel centres. For volumes larger than memory; start it from the basis of a fit of the
/// volume at half resolution ([`crate::CoarseStart`] explains why that is a good start).
#[derive(Debug, Clone)]
pub struct StreamedMbd {
    dims: [usize; 3],
    bounds: Aabb,
    basis_kernels: HatGrid,
    basis: Array3<f32>,
    lambda: f32,
}

impl StreamedMbd {
    /// The model of a grid of `dims` voxels filling `bounds`, with `basis` (`N × L × D`) on a
    /// hat grid of `nodes` over the box of the voxel centres ([`crate::Mbd`]'s basis kernels),
    /// and the ridge `lambda` on the coefficients.
    ///
    /// # Errors
    /// [`MbdError::InvalidKernels`] for fewer than 2 nodes on an axis or an invalid box;
    /// [`MbdError::InvalidOption`] when `basis` has not one `L × D` block per node, L = 0, or a
    /// non-finite value, or `lambda` is negative or not finite.
    pub fn new(
        dims: [usize; 3],
        bounds: Aabb,
        nodes: [usize; 3],
        basis: Array3<f32>,
        lambda: f32,
    ) -> Result<Self, MbdError> {
        let basis_kernels = crate::fit::hat_basis_on(dims, bounds, nodes)?;
        let (n, l, d) = basis.dim();
        if n != basis_kernels.len() || l == 0 || d == 0 {
            return Err(MbdError::InvalidOption {
                what: "basis",
                why: format!(
                    "shape {:?}, {} nodes need N = {}",
                    basis.dim(),
                    nodes.iter().product::<usize>(),
                    basis_kernels.len()
                ),
            });
        }
        if let Some(index) = basis.iter().position(|x| !x.is_finite()) {
            return Err(MbdError::InvalidOption {
                what: "basis",
                why: format!("non-finite value at flat index {index}"),
            });
        }
        if !(lambda >= 0.0 && lambda.is_finite()) {
            return Err(MbdError::InvalidOption {
                what: "lambda",
                why: format!("{lambda} is not a finite non-negative number"),
            });
        }
        Ok(Self {
            dims,
            bounds,
            basis_kernels,
            basis,
            lambda,
        })
    }

    /// Rank L.
    pub fn rank(&self) -> usize {
        self.basis.dim().1
    }

    /// Vector length D.
    pub fn dim(&self) -> usize {
        self.basis.dim().2
    }

    /// The basis, `N × L × D`.
    pub fn basis(&self) -> &Array3<f32> {
        &self.basis
    }

    /// The centre of voxel `voxel` (x, y, z indices).
    fn centre(&self, voxel: [usize; 3]) -> Vec3 {
        let size = self.bounds.size() / Vec3::from_array(self.dims.map(|n| n as f32));
        self.bounds.min + (Vec3::from_array(voxel.map(|i| i as f32)) + 0.5) * size
    }

    /// Writes the coefficients (L) of the voxel at `voxel` holding `f` (D) into `c`: the ridge
    /// least-squares fit `argmin ‖f − b(x)ᵀ c‖² + λ‖c‖²` at its centre `x`, in f64. Returns
    /// `‖f − b(x)ᵀ c‖²`. `scratch` is reused between calls.
    ///
    /// # Errors
    /// [`MbdError::ShapeMismatch`] for `f` or `c` of the wrong length; a voxel outside the grid.
    pub fn project(
        &self,
        voxel: [usize; 3],
        f: &[f32],
        c: &mut [f32],
        scratch: &mut ProjectScratch,
    ) -> Result<f64, MbdError> {
        let (l, d) = (self.rank(), self.dim());
        if f.len() != d || c.len() != l {
            return Err(MbdError::ShapeMismatch {
                what: "voxel vector or coefficients",
                expected: vec![d, l],
                got: vec![f.len(), c.len()],
            });
        }
        if (0..3).any(|k| voxel[k] >= self.dims[k]) {
            return Err(MbdError::ShapeMismatch {
                what: "voxel",
                expected: self.dims.to_vec(),
                got: voxel.to_vec(),
            });
        }
        let ProjectScratch { psi, b, a, rhs, .. } = scratch;
        self.basis_kernels.eval(self.centre(voxel), psi)?;
        // b(x), L × D.
        b.clear();
        b.resize(l * d, 0.0);
        let flat = self.basis.as_slice().unwrap_or(&[]);
        for (node, w) in psi.iter() {
            let block = &flat[node as usize * l * d..(node as usize + 1) * l * d];
            for (o, &v) in b.iter_mut().zip(block) {
                *o += w * v;
            }
        }
        a.clear();
        a.resize(l * l, 0.0);
        rhs.clear();
        rhs.resize(l, 0.0);
        for i in 0..l {
            let bi = &b[i * d..(i + 1) * d];
            rhs[i] = dot(bi, f);
            for j in 0..=i {
                let g = dot(bi, &b[j * d..(j + 1) * d]);
                a[i * l + j] = g;
                a[j * l + i] = g;
            }
            a[i * l + i] += f64::from(self.lambda).max(1e-12);
        }
        if cholesky_in_place(a, l) {
            cholesky_solve_in_place(a, rhs, l, 1);
        } else {
            rhs.fill(0.0);
        }
        for (o, &v) in c.iter_mut().zip(rhs.iter()) {
            *o = v as f32;
        }
        // The residual with the stored (f32) coefficients.
        let mut residual = 0.0f64;
        for (k, &fk) in f.iter().enumerate() {
            let model: f32 = (0..l).map(|i| c[i] * b[i * d + k]).sum();
            residual += f64::from(fk - model).powi(2);
        }
        Ok(residual)
    }

    /// The hat grid's nodes per axis.
    pub fn basis_grid(&self) -> [usize; 3] {
        self.basis_kernels.nodes()
    }

    /// Adds the voxel at `voxel`, holding `f` with coefficients `c`, to the basis step's normal
    /// equations.
    ///
    /// # Errors
    /// As [`StreamedMbd::project`]; `normals` of another shape, or whose nodes miss one of the
    /// voxel's.
    pub fn accumulate(
        &self,
        voxel: [usize; 3],
        f: &[f32],
        c: &[f32],
        normals: &mut BasisNormals,
        scratch: &mut ProjectScratch,
    ) -> Result<(), MbdError> {
        let (l, d) = (self.rank(), self.dim());
        let grid = self.basis_grid();
        if normals.grid != grid
            || normals.rank != l
            || normals.dim != d
            || f.len() != d
            || c.len() != l
        {
            return Err(MbdError::ShapeMismatch {
                what: "normal equations, vector or coefficients",
                expected: vec![grid[0], grid[1], grid[2], l, d, d, l],
                got: vec![
                    normals.grid[0],
                    normals.grid[1],
                    normals.grid[2],
                    normals.rank,
                    normals.dim,
                    f.len(),
                    c.len(),
                ],
            });
        }
        let ProjectScratch { psi, entries, .. } = scratch;
        self.basis_kernels.eval(self.centre(voxel), psi)?;
        // a = ψ(x) ⊗ c: entries (node in the box, its coordinates, l) = ψ_node c_l.
        entries.clear();
        for (node, w) in psi.iter() {
            let coords = node_coords(grid, node as usize);
            let local = normals
                .local(coords)
                .ok_or_else(|| MbdError::ShapeMismatch {
                    what: "normal equations' nodes",
                    expected: normals.extent.to_vec(),
                    got: coords.to_vec(),
                })?;
            for (i, &ci) in c.iter().enumerate() {
                entries.push((local, coords, i, f64::from(w) * f64::from(ci)));
            }
        }
        for &(p, pc, i, ap) in entries.iter() {
            for &(_, qc, j, aq) in entries.iter() {
                let o = neighbour_offset(pc, qc);
                normals.gram[((p * NEIGHBOURS + o) * l + i) * l + j] += ap * aq;
            }
            let row = &mut normals.rhs[(p * l + i) * d..(p * l + i + 1) * d];
            for (r, &fk) in row.iter_mut().zip(f) {
                *r += ap * f64::from(fk);
            }
        }
        Ok(())
    }

    /// Replaces the basis by the ridge least-squares fit to the sums in `normals`, which must
    /// cover every node: `(G + μ I) B = R`, μ = 1e-9 of G's mean diagonal entry, so that nodes
    /// no voxel reaches come out zero. Solved by conjugate gradients with a block-Jacobi
    /// preconditioner (one `L × L` Cholesky per node), one system per output, to
    /// [`BASIS_SOLVE_TOLERANCE`]; memory `O(nodes · (L² + L·D))`.
    ///
    /// # Errors
    /// `normals` of another shape or covering part of the grid; [`MbdError::Diverged`] for a
    /// non-finite iterate or a block that cannot be factored; [`MbdError::NotConverged`] when
    /// `10·N·L` iterations (`N·L` would be exact in exact arithmetic) do not reach the
    /// tolerance.
    pub fn solve_basis(&mut self, normals: &BasisNormals) -> Result<BasisSolve, MbdError> {
        let (n, l, d) = self.basis.dim();
        let grid = self.basis_grid();
        if normals.grid != grid
            || normals.first != [0; 3]
            || normals.extent != grid
            || normals.rank != l
            || normals.dim != d
        {
            return Err(MbdError::ShapeMismatch {
                what: "normal equations (grid, first node, extent, L, D)",
                expected: [grid, [0; 3], grid, [l, d, n]].concat(),
                got: [
                    normals.grid,
                    normals.first,
                    normals.extent,
                    [normals.rank, normals.dim, normals.nodes()],
                ]
                .concat(),
            });
        }
        let (x, report) = normals.solve()?;
        for (o, &v) in self.basis.iter_mut().zip(&x) {
            *o = v as f32;
        }
        Ok(report)
    }

    /// The model with `coefficients` (voxels × L, x fastest) and this basis.
    ///
    /// # Errors
    /// Coefficients of the wrong shape.
    pub fn into_model(
        self,
        coefficients: Array2<f32>,
    ) -> Result<MbdModel<HatGrid, HatGrid>, MbdError> {
        MbdModel::new(
            self.coefficient_kernels()?,
            self.basis_kernels,
            coefficients,
            self.basis,
        )
    }

    /// The kernels of the coefficients: a node at every voxel centre (those of the model
    /// [`StreamedMbd::into_model`] makes).
    ///
    /// # Errors
    /// A grid the hat kernels refuse.
    pub fn coefficient_kernels(&self) -> Result<HatGrid, MbdError> {
        let centres = crate::baselines::voxel_centre_box_of(self.dims, self.bounds);
        HatGrid::new(self.dims, centres).map_err(|e| MbdError::InvalidKernels {
            which: "coefficient",
            why: e.to_string(),
        })
    }

    /// The kernels of the basis.
    pub fn basis_kernels(&self) -> &HatGrid {
        &self.basis_kernels
    }

    /// Empty normal equations over every node of this model's basis: the sum the basis step
    /// solves.
    pub fn normals(&self) -> BasisNormals {
        BasisNormals::zeros(
            self.basis_grid(),
            [0; 3],
            self.basis_grid(),
            self.rank(),
            self.dim(),
        )
    }

    /// Empty normal equations over the nodes that the voxels of the box `min..max` (voxel
    /// indices, `max` exclusive) reach: a part of the volume's sum, as small as its region.
    ///
    /// # Errors
    /// [`MbdError::ShapeMismatch`] for an empty box or one outside the grid.
    pub fn normals_for_voxels(
        &self,
        min: [usize; 3],
        max: [usize; 3],
    ) -> Result<BasisNormals, MbdError> {
        if (0..3).any(|k| min[k] >= max[k] || max[k] > self.dims[k]) {
            return Err(MbdError::ShapeMismatch {
                what: "voxel box",
                expected: self.dims.to_vec(),
                got: [min, max].concat(),
            });
        }
        let grid = self.basis_grid();
        let low = self.basis_kernels.cell_of(self.centre(min))?;
        let high = self
            .basis_kernels
            .cell_of(self.centre(max.map(|m| m - 1)))?;
        // A voxel in cell c reaches nodes c and c + 1 per axis; cells are monotone in x.
        let extent = [0, 1, 2].map(|k| (high[k] + 2).min(grid[k]) - low[k]);
        Ok(BasisNormals::zeros(
            grid,
            low,
            extent,
            self.rank(),
            self.dim(),
        ))
    }
}

/// The relative residual the basis step's conjugate gradients reach for every output:
/// `‖R − (G + μI) B‖ ≤ 1e-8 ‖R‖` per column. The basis is stored in f32, and an error `e` in
/// the solution raises the basis step's loss by `eᵀ(G + μI)e`, second order in the residual.
pub const BASIS_SOLVE_TOLERANCE: f64 = 1e-8;

/// What [`StreamedMbd::solve_basis`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BasisSolve {
    /// Conjugate-gradient iterations until every output reached [`BASIS_SOLVE_TOLERANCE`].
    pub iterations: usize,
    /// The largest relative residual over the outputs at the end.
    pub relative_residual: f64,
}

/// Reused buffers of [`StreamedMbd::project`] and [`StreamedMbd::accumulate`].
#[derive(Debug, Clone, Default)]
pub struct ProjectScratch {
    psi: KernelWeights,
    b: Vec<f32>,
    a: Vec<f64>,
    rhs: Vec<f64>,
    /// (node in the normals' box, node coordinates, l, ψ_node c_l).
    entries: Vec<(usize, [usize; 3], usize, f64)>,
}

/// A hat node couples with itself and its 26 neighbours: the blocks stored per node.
const NEIGHBOURS: usize = 27;

/// The bytes of [`BasisNormals::to_bytes`]'s header: 11 little-endian u64.
const HEADER_BYTES: usize = 11 * 8;

/// The index of neighbour `q` of node `p` (each coordinate differs by at most 1) among the 27.
fn neighbour_offset(p: [usize; 3], q: [usize; 3]) -> usize {
    let step = |k: usize| q[k] + 1 - p[k];
    step(2) * 9 + step(1) * 3 + step(0)
}

/// The coordinates of node `index` (x fastest) of a grid of `grid` nodes.
fn node_coords(grid: [usize; 3], index: usize) -> [usize; 3] {
    [
        index % grid[0],
        (index / grid[0]) % grid[1],
        index / (grid[0] * grid[1]),
    ]
}

/// The normal equations of the basis step, `G = Σ a aᵀ` and `R = Σ a fᵀ` over voxels with
/// `a = ψ(x) ⊗ c`, in f64, over a box of the hat grid's nodes. A node couples only with its
/// 3 × 3 × 3 neighbours, so `G` is stored as one `L × L` block per (node, neighbour): memory
/// [`BasisNormals::bytes_for`], linear in the nodes. Sums of disjoint parts of the volume add
/// ([`BasisNormals::add`]), exactly in the order they are added; [`BasisNormals::to_bytes`] and
/// [`BasisNormals::from_bytes`] carry a part between processes.
#[derive(Debug, Clone, PartialEq)]
pub struct BasisNormals {
    /// Nodes per axis of the whole grid.
    grid: [usize; 3],
    /// The lowest node of the box, and its nodes per axis.
    first: [usize; 3],
    extent: [usize; 3],
    rank: usize,
    dim: usize,
    /// Box node (x fastest) × 27 neighbours (x fastest, offsets −1..=1) × L × L:
    /// `G[(p, i), (q, j)]`.
    gram: Vec<f64>,
    /// Box node × L × D.
    rhs: Vec<f64>,
}

impl BasisNormals {
    fn zeros(
        grid: [usize; 3],
        first: [usize; 3],
        extent: [usize; 3],
        rank: usize,
        dim: usize,
    ) -> Self {
        let n: usize = extent.iter().product();
        Self {
            grid,
            first,
            extent,
            rank,
            dim,
            gram: vec![0.0; n * NEIGHBOURS * rank * rank],
            rhs: vec![0.0; n * rank * dim],
        }
    }

    /// Bytes held by normal equations over `nodes` nodes of rank `rank` for vectors of `dim`:
    /// `8 · nodes · (27 L² + L D)` (saturating).
    pub fn bytes_for(nodes: usize, rank: usize, dim: usize) -> u64 {
        let per_node = (NEIGHBOURS as u64)
            .saturating_mul(rank as u64)
            .saturating_mul(rank as u64)
            .saturating_add((rank as u64).saturating_mul(dim as u64));
        8u64.saturating_mul(nodes as u64).saturating_mul(per_node)
    }

    /// Bytes the basis step's solve holds beside the normal equations over `nodes` nodes: the
    /// block-Jacobi factors (`8 · nodes · L²`) and five vectors of the unknowns' size
    /// (`5 · 8 · nodes · L · D`: iterate, residual, preconditioned residual, direction, product).
    pub fn solve_bytes_for(nodes: usize, rank: usize, dim: usize) -> u64 {
        let per_node = (rank as u64)
            .saturating_mul(rank as u64)
            .saturating_add(5u64.saturating_mul(rank as u64).saturating_mul(dim as u64));
        8u64.saturating_mul(nodes as u64).saturating_mul(per_node)
    }

    /// Nodes in the box.
    pub fn nodes(&self) -> usize {
        self.extent.iter().product()
    }

    /// The box of nodes: its lowest node and nodes per axis.
    pub fn node_box(&self) -> ([usize; 3], [usize; 3]) {
        (self.first, self.extent)
    }

    /// The bytes held ([`BasisNormals::bytes_for`] of its nodes).
    pub fn memory_bytes(&self) -> u64 {
        8 * (self.gram.len() + self.rhs.len()) as u64
    }

    /// The index in the box of the node at `coords`, if inside.
    fn local(&self, coords: [usize; 3]) -> Option<usize> {
        let mut index = 0;
        for k in (0..3).rev() {
            let offset = coords[k].checked_sub(self.first[k])?;
            if offset >= self.extent[k] {
                return None;
            }
            index = index * self.extent[k] + offset;
        }
        Some(index)
    }

    /// Adds the sums of another part of the volume, whose nodes lie in this box.
    ///
    /// # Errors
    /// [`MbdError::ShapeMismatch`] for sums of another grid, rank or dimension, or whose box
    /// reaches outside this one.
    pub fn add(&mut self, other: &BasisNormals) -> Result<(), MbdError> {
        let inside = (0..3).all(|k| {
            other.first[k] >= self.first[k]
                && other.first[k] + other.extent[k] <= self.first[k] + self.extent[k]
        });
        if other.grid != self.grid || other.rank != self.rank || other.dim != self.dim || !inside {
            return Err(MbdError::ShapeMismatch {
                what: "normal equations (grid, first node, extent, L, D)",
                expected: [self.grid, self.first, self.extent, [self.rank, self.dim, 0]].concat(),
                got: [
                    other.grid,
                    other.first,
                    other.extent,
                    [other.rank, other.dim, 0],
                ]
                .concat(),
            });
        }
        let (block, row) = (NEIGHBOURS * self.rank * self.rank, self.rank * self.dim);
        let [ex, ey, ez] = other.extent;
        for z in 0..ez {
            for y in 0..ey {
                for x in 0..ex {
                    let from = x + ex * (y + ey * z);
                    // Inside: checked above.
                    let to = self
                        .local([other.first[0] + x, other.first[1] + y, other.first[2] + z])
                        .unwrap_or(0);
                    for (a, b) in self.gram[to * block..(to + 1) * block]
                        .iter_mut()
                        .zip(&other.gram[from * block..(from + 1) * block])
                    {
                        *a += b;
                    }
                    for (a, b) in self.rhs[to * row..(to + 1) * row]
                        .iter_mut()
                        .zip(&other.rhs[from * row..(from + 1) * row])
                    {
                        *a += b;
                    }
                }
            }
        }
        Ok(())
    }

    /// The sums as bytes: 11 little-endian u64 (the grid, the box's first node and extent, L,
    /// D), then `G` and `R` as little-endian f64 in storage order ([`BasisNormals::from_bytes`]
    /// reads them back exactly).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(HEADER_BYTES + 8 * (self.gram.len() + self.rhs.len()));
        for v in [self.grid, self.first, self.extent]
            .concat()
            .into_iter()
            .chain([self.rank, self.dim])
        {
            out.extend_from_slice(&(v as u64).to_le_bytes());
        }
        for v in self.gram.iter().chain(&self.rhs) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    /// Reads [`BasisNormals::to_bytes`]'s bytes for a basis of `grid` nodes, rank `rank` and
    /// vectors of `dim`. Every size is checked against those before anything is allocated, so
    /// the sums take at most the whole grid's [`BasisNormals::bytes_for`].
    ///
    /// # Errors
    /// [`MbdError::MalformedNormals`] for another grid, rank or dimension, a box outside the
    /// grid, a length that is not the box's, or a non-finite sum (named by its index).
    pub fn from_bytes(
        bytes: &[u8],
        grid: [usize; 3],
        rank: usize,
        dim: usize,
    ) -> Result<Self, MbdError> {
        let malformed = |why: String| MbdError::MalformedNormals { why };
        if bytes.len() < HEADER_BYTES {
            return Err(malformed(format!(
                "{} bytes, shorter than the {HEADER_BYTES}-byte header",
                bytes.len()
            )));
        }
        let header: Vec<u64> = bytes[..HEADER_BYTES]
            .chunks_exact(8)
            .map(|b| u64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
            .collect();
        let want: Vec<u64> = grid.iter().map(|&g| g as u64).collect();
        if header[0..3] != want[..] || header[9] != rank as u64 || header[10] != dim as u64 {
            return Err(malformed(format!(
                "grid {:?}, rank {}, dimension {}; expected {grid:?}, {rank}, {dim}",
                &header[0..3],
                header[9],
                header[10]
            )));
        }
        let (first, extent) = (&header[3..6], &header[6..9]);
        if (0..3).any(|k| {
            extent[k] == 0
                || first[k]
                    .checked_add(extent[k])
                    .is_none_or(|end| end > want[k])
        }) {
            return Err(malformed(format!(
                "node box from {first:?} of {extent:?} is not inside the grid {grid:?}"
            )));
        }
        let first = [0, 1, 2].map(|k| first[k] as usize);
        let extent = [0, 1, 2].map(|k| extent[k] as usize);
        let nodes: usize = extent.iter().product();
        let expected = HEADER_BYTES as u64 + BasisNormals::bytes_for(nodes, rank, dim);
        if bytes.len() as u64 != expected {
            return Err(malformed(format!(
                "{} bytes, expected {expected} for {nodes} nodes",
                bytes.len()
            )));
        }
        let mut values = bytes[HEADER_BYTES..]
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8])));
        let gram: Vec<f64> = values
            .by_ref()
            .take(nodes * NEIGHBOURS * rank * rank)
            .collect();
        let rhs: Vec<f64> = values.collect();
        if let Some(index) = gram.iter().chain(&rhs).position(|v| !v.is_finite()) {
            return Err(malformed(format!("non-finite sum at value {index}")));
        }
        Ok(Self {
            grid,
            first,
            extent,
            rank,
            dim,
            gram,
            rhs,
        })
    }

    /// Solves `(G + μ I) X = R` over every node (see [`StreamedMbd::solve_basis`]); `X` is
    /// node × L × D.
    fn solve(&self) -> Result<(Vec<f64>, BasisSolve), MbdError> {
        let (l, d, n) = (self.rank, self.dim, self.nodes());
        let m = n * l;
        let block = NEIGHBOURS * l * l;
        let centre = neighbour_offset([1; 3], [1; 3]);
        let trace: f64 = (0..n)
            .map(|p| {
                (0..l)
                    .map(|i| self.gram[p * block + (centre * l + i) * l + i])
                    .sum::<f64>()
            })
            .sum();
        let ridge = 1e-9 * trace / m as f64 + f64::MIN_POSITIVE;
        // Block Jacobi: each node's own L × L block, factored.
        let mut factors = vec![0.0; n * l * l];
        for (p, factor) in factors.chunks_exact_mut(l * l).enumerate() {
            factor.copy_from_slice(
                &self.gram[p * block + centre * l * l..p * block + (centre + 1) * l * l],
            );
            for i in 0..l {
                factor[i * l + i] += ridge;
            }
            if !cholesky_in_place(factor, l) {
                return Err(MbdError::Diverged {
                    what: "basis normal equations' diagonal block",
                    iteration: 0,
                });
            }
        }
        let precondition = |r: &[f64], z: &mut [f64]| {
            z.copy_from_slice(r);
            z.par_chunks_mut(l * d)
                .zip(factors.par_chunks(l * l))
                .for_each(|(z, factor)| cholesky_solve_in_place(factor, z, l, d));
        };
        let b = &self.rhs;
        let b_norms = column_dots(b, b, d);
        let mut x = vec![0.0; m * d];
        let mut r = b.clone();
        let mut z = vec![0.0; m * d];
        precondition(&r, &mut z);
        let mut p = z.clone();
        let mut rz = column_dots(&r, &z, d);
        let mut q = vec![0.0; m * d];
        let relative = |r_norms: &[f64]| {
            r_norms
                .iter()
                .zip(&b_norms)
                .map(|(&r, &b)| if b > 0.0 { (r / b).sqrt() } else { 0.0 })
                .fold(0.0f64, f64::max)
        };
        let mut residual = relative(&column_dots(&r, &r, d));
        let mut iterations = 0;
        while residual > BASIS_SOLVE_TOLERANCE {
            if iterations == 10 * m {
                return Err(MbdError::NotConverged {
                    what: "basis normal equations (conjugate gradients)",
                    iterations,
                    relative_residual: residual,
                });
            }
            iterations += 1;
            self.multiply(&p, ridge, &mut q);
            let pq = column_dots(&p, &q, d);
            let alpha: Vec<f64> = rz
                .iter()
                .zip(&pq)
                .map(|(&rz, &pq)| if pq > 0.0 { rz / pq } else { 0.0 })
                .collect();
            for ((x, r), (p, q)) in x
                .chunks_exact_mut(d)
                .zip(r.chunks_exact_mut(d))
                .zip(p.chunks_exact(d).zip(q.chunks_exact(d)))
            {
                for k in 0..d {
                    x[k] += alpha[k] * p[k];
                    r[k] -= alpha[k] * q[k];
                }
            }
            residual = relative(&column_dots(&r, &r, d));
            if !residual.is_finite() {
                return Err(MbdError::Diverged {
                    what: "basis conjugate-gradient residual",
                    iteration: iterations,
                });
            }
            precondition(&r, &mut z);
            let rz_next = column_dots(&r, &z, d);
            let beta: Vec<f64> = rz_next
                .iter()
                .zip(&rz)
                .map(|(&next, &prev)| if prev > 0.0 { next / prev } else { 0.0 })
                .collect();
            for (p, z) in p.chunks_exact_mut(d).zip(z.chunks_exact(d)) {
                for k in 0..d {
                    p[k] = z[k] + beta[k] * p[k];
                }
            }
            rz = rz_next;
        }
        Ok((
            x,
            BasisSolve {
                iterations,
                relative_residual: residual,
            },
        ))
    }

    /// `out = (G + ridge I) v` over every node (the box is the whole grid), node by node in
    /// parallel: each output row is summed in a fixed order.
    fn multiply(&self, v: &[f64], ridge: f64, out: &mut [f64]) {
        let (l, d) = (self.rank, self.dim);
        let grid = self.grid;
        let block = NEIGHBOURS * l * l;
        out.par_chunks_mut(l * d).enumerate().for_each(|(p, out)| {
            let pc = node_coords(grid, p);
            for (o, row) in out.iter_mut().zip(&v[p * l * d..(p + 1) * l * d]) {
                *o = ridge * row;
            }
            for offset in 0..NEIGHBOURS {
                let step = [offset % 3, (offset / 3) % 3, offset / 9];
                let qc = [0, 1, 2].map(|k| (pc[k] + step[k]).wrapping_sub(1));
                if (0..3).any(|k| qc[k] >= grid[k]) {
                    continue;
                }
                let q = qc[0] + grid[0] * (qc[1] + grid[1] * qc[2]);
                let g = &self.gram[p * block + offset * l * l..p * block + (offset + 1) * l * l];
                for i in 0..l {
                    let out = &mut out[i * d..(i + 1) * d];
                    for j in 0..l {
                        let gij = g[i * l + j];
                        if gij == 0.0 {
                            continue;
                        }
                        let vj = &v[(q * l + j) * d..(q * l + j + 1) * d];
                        for (o, &x) in out.iter_mut().zip(vj) {
                            *o += gij * x;
                        }
                    }
                }
            }
        });
    }
}

/// `Σ_rows a[row, k] b[row, k]` per column `k` of row-major matrices with `cols` columns, in row
/// order.
fn column_dots(a: &[f64], b: &[f64], cols: usize) -> Vec<f64> {
    let mut out = vec![0.0; cols];
    for (a, b) in a.chunks_exact(cols).zip(b.chunks_exact(cols)) {
        for k in 0..cols {
            out[k] += a[k] * b[k];
        }
    }
    out
}

fn dot(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| f64::from(x) * f64::from(y))
        .sum()
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    use super::*;

    /// A model with a random basis, and a random vector and coefficients for every voxel of
    /// its grid.
    #[allow(clippy::type_complexity)]
    fn problem(
        dims: [usize; 3],
        nodes: [usize; 3],
        l: usize,
        d: usize,
        seed: u64,
    ) -> (StreamedMbd, Vec<([usize; 3], Vec<f32>, Vec<f32>)>) {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let n: usize = nodes.iter().product();
        let basis = Array3::from_shape_fn((n, l, d), |_| rng.random_range(-1.0f32..1.0));
        let bounds = Aabb::new(Vec3::ZERO, Vec3::new(1.0, 2.0, 0.5));
        let model = StreamedMbd::new(dims, bounds, nodes, basis, 0.01).unwrap();
        let mut voxels = Vec::new();
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let f = (0..d).map(|_| rng.random_range(-1.0f32..1.0)).collect();
                    let c = (0..l).map(|_| rng.random_range(-1.0f32..1.0)).collect();
                    voxels.push(([x, y, z], f, c));
                }
            }
        }
        (model, voxels)
    }

    /// The dense reference of the basis step: `G` (`N·L × N·L`) and `R` (`N·L × D`) summed
    /// voxel by voxel as `a aᵀ` and `a fᵀ`, `a = ψ(x) ⊗ c`.
    fn dense_reference(
        model: &StreamedMbd,
        voxels: &[([usize; 3], Vec<f32>, Vec<f32>)],
    ) -> (Vec<f64>, Vec<f64>) {
        let (n, l, d) = model.basis().dim();
        let m = n * l;
        let (mut gram, mut rhs) = (vec![0.0; m * m], vec![0.0; m * d]);
        let mut psi = KernelWeights::default();
        for (v, f, c) in voxels {
            model
                .basis_kernels
                .eval(model.centre(*v), &mut psi)
                .unwrap();
            let a: Vec<(usize, f64)> = psi
                .iter()
                .flat_map(|(node, w)| {
                    c.iter()
                        .enumerate()
                        .map(move |(i, &ci)| (node as usize * l + i, f64::from(w) * f64::from(ci)))
                })
                .collect();
            for &(p, ap) in &a {
                for &(q, aq) in &a {
                    gram[p * m + q] += ap * aq;
                }
                for (k, &fk) in f.iter().enumerate() {
                    rhs[p * d + k] += ap * f64::from(fk);
                }
            }
        }
        (gram, rhs)
    }

    /// The block-sparse Gram of normals over the whole grid, expanded to dense.
    fn expanded(normals: &BasisNormals) -> Vec<f64> {
        let (l, n) = (normals.rank, normals.nodes());
        let m = n * l;
        let mut dense = vec![0.0; m * m];
        for p in 0..n {
            let pc = node_coords(normals.grid, p);
            for q in 0..n {
                let qc = node_coords(normals.grid, q);
                if (0..3).any(|k| pc[k].abs_diff(qc[k]) > 1) {
                    continue;
                }
                let o = neighbour_offset(pc, qc);
                for i in 0..l {
                    for j in 0..l {
                        dense[(p * l + i) * m + q * l + j] =
                            normals.gram[((p * NEIGHBOURS + o) * l + i) * l + j];
                    }
                }
            }
        }
        dense
    }

    fn accumulated(
        model: &StreamedMbd,
        voxels: &[([usize; 3], Vec<f32>, Vec<f32>)],
        mut normals: BasisNormals,
    ) -> BasisNormals {
        let mut scratch = ProjectScratch::default();
        for (v, f, c) in voxels {
            model
                .accumulate(*v, f, c, &mut normals, &mut scratch)
                .unwrap();
        }
        normals
    }

    fn relative_difference(a: &[f64], b: &[f64]) -> f64 {
        let diff: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
        let norm: f64 = b.iter().map(|y| y * y).sum();
        (diff / norm.max(f64::MIN_POSITIVE)).sqrt()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        /// The block Gram is the dense Gram's non-zero blocks, exactly; the conjugate-gradient
        /// solve agrees with a dense Cholesky of the same ridge system to 1e-5 relative (the
        /// tolerance 1e-8 times the condition number of these well-sampled problems, at most
        /// about 1e3).
        #[test]
        fn block_normals_and_their_solve_agree_with_a_dense_reference(
            nodes in prop::array::uniform3(2usize..4),
            l in 1usize..4,
            d in 1usize..5,
            seed in any::<u64>(),
        ) {
            let dims = nodes.map(|n| 2 * n + 1);
            let (mut model, voxels) = problem(dims, nodes, l, d, seed);
            let normals = accumulated(&model, &voxels, model.normals());
            let (gram, rhs) = dense_reference(&model, &voxels);
            prop_assert!(expanded(&normals) == gram);
            prop_assert!(normals.rhs == rhs);

            let m = normals.nodes() * l;
            let trace: f64 = (0..m).map(|i| gram[i * m + i]).sum();
            let ridge = 1e-9 * trace / m as f64 + f64::MIN_POSITIVE;
            let mut a = gram.clone();
            for i in 0..m {
                a[i * m + i] += ridge;
            }
            prop_assert!(cholesky_in_place(&mut a, m));
            let mut want = rhs.clone();
            cholesky_solve_in_place(&a, &mut want, m, d);

            let report = model.solve_basis(&normals).unwrap();
            prop_assert!(report.relative_residual <= BASIS_SOLVE_TOLERANCE);
            prop_assert!(report.iterations <= 10 * m);
            let got: Vec<f64> = model.basis().iter().map(|&v| f64::from(v)).collect();
            let want32: Vec<f64> = want.iter().map(|&v| f64::from(v as f32)).collect();
            let error = relative_difference(&got, &want32);
            prop_assert!(error < 1e-5, "relative difference {error:.3e}");
        }
    }

    #[test]
    fn parts_add_into_the_whole_and_read_back_exactly() {
        let (nodes, l, d) = ([3, 4, 2], 2, 3);
        let (model, voxels) = problem([7, 9, 5], nodes, l, d, 7);
        // Two slabs of the volume, each summed over the nodes it reaches.
        let (low, high): (Vec<_>, Vec<_>) = voxels.iter().cloned().partition(|(v, ..)| v[1] < 4);
        let part_low = accumulated(
            &model,
            &low,
            model.normals_for_voxels([0; 3], [7, 4, 5]).unwrap(),
        );
        let part_high = accumulated(
            &model,
            &high,
            model.normals_for_voxels([0, 4, 0], [7, 9, 5]).unwrap(),
        );
        assert!(part_low.nodes() < 24 && part_high.nodes() < 24);
        assert_eq!(part_low.node_box(), ([0; 3], [3, 3, 2]));
        let mut total = model.normals();
        total.add(&part_low).unwrap();
        total.add(&part_high).unwrap();
        let whole = accumulated(&model, &voxels, model.normals());
        assert!(relative_difference(&total.gram, &whole.gram) < 1e-14);
        assert!(relative_difference(&total.rhs, &whole.rhs) < 1e-14);
        // The same parts in the same order: the same bits.
        let mut again = model.normals();
        again.add(&part_low).unwrap();
        again.add(&part_high).unwrap();
        assert_eq!(again, total);
        // A whole grid into a part is refused.
        let mut part = part_low.clone();
        assert!(matches!(
            part.add(&total),
            Err(MbdError::ShapeMismatch { .. })
        ));

        for normals in [&part_low, &part_high, &total] {
            let bytes = normals.to_bytes();
            assert_eq!(
                bytes.len() as u64,
                HEADER_BYTES as u64 + BasisNormals::bytes_for(normals.nodes(), l, d)
            );
            assert_eq!(
                &BasisNormals::from_bytes(&bytes, nodes, l, d).unwrap(),
                normals
            );
        }
        let bytes = part_high.to_bytes();
        let malformed = |bytes: &[u8], grid| {
            matches!(
                BasisNormals::from_bytes(bytes, grid, l, d),
                Err(MbdError::MalformedNormals { .. })
            )
        };
        assert!(malformed(&bytes, [3, 4, 3]));
        assert!(malformed(&bytes[..bytes.len() - 1], nodes));
        assert!(malformed(&bytes[..10], nodes));
        let mut nan = bytes.clone();
        nan[HEADER_BYTES + 8..HEADER_BYTES + 16].copy_from_slice(&f64::NAN.to_le_bytes());
        assert!(malformed(&nan, nodes));
        // A box past the grid's end (first node y = 3 of 4 with 3 nodes).
        let mut outside = bytes.clone();
        outside[4 * 8..5 * 8].copy_from_slice(&3u64.to_le_bytes());
        assert!(malformed(&outside, nodes));
        let mut huge = bytes.clone();
        huge[6 * 8..7 * 8].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(malformed(&huge, nodes));
    }

    #[test]
    fn memory_is_linear_in_the_nodes() {
        let (model, _) = problem([6, 6, 6], [3, 2, 2], 4, 5, 1);
        let normals = model.normals();
        assert_eq!(normals.memory_bytes(), BasisNormals::bytes_for(12, 4, 5));
        assert_eq!(BasisNormals::bytes_for(12, 4, 5), 8 * 12 * (27 * 16 + 20));
        // A node every 32 voxels of a 2000 × 2000 × 200 world, L = 8, D = 324: 0.96 GB of
        // blocks (a dense Gram would be (27 783 · 8)² · 8 B = 395 GB).
        let world = 63 * 63 * 7;
        assert_eq!(BasisNormals::bytes_for(world, 8, 324), 960_180_480);
        assert_eq!(
            BasisNormals::solve_bytes_for(world, 8, 324),
            8 * world as u64 * (64 + 5 * 8 * 324)
        );
        assert_eq!(BasisNormals::bytes_for(usize::MAX, 8, 324), u64::MAX);
    }

    #[test]
    fn the_solve_is_the_same_on_any_number_of_threads() {
        let (model, voxels) = problem([9, 7, 5], [4, 3, 2], 3, 6, 3);
        let normals = accumulated(&model, &voxels, model.normals());
        let solve = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut model = model.clone();
                let report = model.solve_basis(&normals).unwrap();
                (model.basis().clone(), report)
            })
        };
        let one = solve(1);
        assert_eq!(one, solve(3));
        assert!(one.1.iterations > 1 && one.1.relative_residual <= BASIS_SOLVE_TOLERANCE);
    }
}

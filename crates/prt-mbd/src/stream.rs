//! MBD's exact least-squares steps on a volume that arrives in pieces (tiles read one after
//! another, or parts summed on other machines), so that no step holds the whole volume.

use glam::Vec3;
use ndarray::{Array2, Array3};
use prt_core::{Aabb, KernelWeights, SpatialKernels};
use prt_kernels::HatGrid;

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

    /// Adds the voxel at `voxel`, holding `f` with coefficients `c`, to the basis step's normal
    /// equations.
    ///
    /// # Errors
    /// As [`StreamedMbd::project`]; `normals` of another shape.
    pub fn accumulate(
        &self,
        voxel: [usize; 3],
        f: &[f32],
        c: &[f32],
        normals: &mut BasisNormals,
        scratch: &mut ProjectScratch,
    ) -> Result<(), MbdError> {
        let (l, d) = (self.rank(), self.dim());
        let n = self.basis_kernels.len();
        if normals.unknowns != n * l || normals.dim != d || f.len() != d || c.len() != l {
            return Err(MbdError::ShapeMismatch {
                what: "normal equations, vector or coefficients",
                expected: vec![n * l, d, d, l],
                got: vec![normals.unknowns, normals.dim, f.len(), c.len()],
            });
        }
        let ProjectScratch { psi, entries, .. } = scratch;
        self.basis_kernels.eval(self.centre(voxel), psi)?;
        // a = ψ(x) ⊗ c: entries (node, l) = ψ_node c_l.
        entries.clear();
        for (node, w) in psi.iter() {
            for (i, &ci) in c.iter().enumerate() {
                entries.push((node as usize * l + i, f64::from(w) * f64::from(ci)));
            }
        }
        let m = normals.unknowns;
        for &(p, ap) in entries.iter() {
            for &(q, aq) in entries.iter() {
                normals.gram[p * m + q] += ap * aq;
            }
            let row = &mut normals.rhs[p * d..(p + 1) * d];
            for (r, &fk) in row.iter_mut().zip(f) {
                *r += ap * f64::from(fk);
            }
        }
        Ok(())
    }

    /// Replaces the basis by the ridge least-squares fit to the sums in `normals`
    /// (`(G + μ I) B = R`, μ = 1e-9 of G's mean diagonal entry, so that nodes no voxel reaches
    /// come out zero).
    ///
    /// # Errors
    /// `normals` of another shape; [`MbdError::Diverged`] when the system cannot be factored.
    pub fn solve_basis(&mut self, normals: &BasisNormals) -> Result<(), MbdError> {
        let (n, l, d) = self.basis.dim();
        let m = n * l;
        if normals.unknowns != m || normals.dim != d {
            return Err(MbdError::ShapeMismatch {
                what: "normal equations",
                expected: vec![m, d],
                got: vec![normals.unknowns, normals.dim],
            });
        }
        let mut a = normals.gram.clone();
        let trace: f64 = (0..m).map(|i| a[i * m + i]).sum();
        let ridge = 1e-9 * trace / m as f64 + f64::MIN_POSITIVE;
        for i in 0..m {
            a[i * m + i] += ridge;
        }
        if !cholesky_in_place(&mut a, m) {
            return Err(MbdError::Diverged {
                what: "basis normal equations",
                iteration: 0,
            });
        }
        let mut x = normals.rhs.clone();
        cholesky_solve_in_place(&a, &mut x, m, d);
        for (o, &v) in self.basis.iter_mut().zip(&x) {
            *o = v as f32;
        }
        Ok(())
    }

    /// The model with `coefficients` (voxels × L, x fastest) and this basis.
    ///
    /// # Errors
    /// Coefficients of the wrong shape.
    pub fn into_model(
        self,
        coefficients: Array2<f32>,
    ) -> Result<MbdModel<HatGrid, HatGrid>, MbdError> {
        let centres = crate::baselines::voxel_centre_box_of(self.dims, self.bounds);
        let coefficient_kernels =
            HatGrid::new(self.dims, centres).map_err(|e| MbdError::InvalidKernels {
                which: "coefficient",
                why: e.to_string(),
            })?;
        MbdModel::new(
            coefficient_kernels,
            self.basis_kernels,
            coefficients,
            self.basis,
        )
    }

    /// Empty normal equations for this model's basis.
    pub fn normals(&self) -> BasisNormals {
        let (n, l, d) = self.basis.dim();
        BasisNormals {
            unknowns: n * l,
            dim: d,
            gram: vec![0.0; n * l * n * l],
            rhs: vec![0.0; n * l * d],
        }
    }
}

/// Reused buffers of [`StreamedMbd::project`] and [`StreamedMbd::accumulate`].
#[derive(Debug, Clone, Default)]
pub struct ProjectScratch {
    psi: KernelWeights,
    b: Vec<f32>,
    a: Vec<f64>,
    rhs: Vec<f64>,
    entries: Vec<(usize, f64)>,
}

/// The normal equations of the basis step, `G = Σ a aᵀ` and `R = Σ a fᵀ` over voxels with
/// `a = ψ(x) ⊗ c`, in f64; sums of disjoint parts of the volume add ([`BasisNormals::add`]).
#[derive(Debug, Clone, PartialEq)]
pub struct BasisNormals {
    unknowns: usize,
    dim: usize,
    gram: Vec<f64>,
    rhs: Vec<f64>,
}

impl BasisNormals {
    /// Adds the sums of another part of the volume.
    ///
    /// # Errors
    /// [`MbdError::ShapeMismatch`] for sums of another shape.
    pub fn add(&mut self, other: &BasisNormals) -> Result<(), MbdError> {
        if other.unknowns != self.unknowns || other.dim != self.dim {
            return Err(MbdError::ShapeMismatch {
                what: "normal equations",
                expected: vec![self.unknowns, self.dim],
                got: vec![other.unknowns, other.dim],
            });
        }
        for (a, b) in self.gram.iter_mut().zip(&other.gram) {
            *a += b;
        }
        for (a, b) in self.rhs.iter_mut().zip(&other.rhs) {
            *a += b;
        }
        Ok(())
    }
}

fn dot(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| f64::from(x) * f64::from(y))
        .sum()
}

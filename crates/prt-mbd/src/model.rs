use glam::Vec3;
use ndarray::{Array2, Array3};
use prt_core::{CoreError, FieldModel, KernelWeights, SpatialKernels};

use crate::MbdError;

/// A rank-L Moving Basis Decomposition
/// `f̂(x) = Σ_l c_l(x) b_l(x)`, `c_l(x) = Σ_m φ_m(x) c_{m,l}`, `b_l(x) = Σ_n ψ_n(x) B_{n,l}`.
///
/// Tensor layout (what a texture writer stores):
/// * [`MbdModel::coefficients`]: `M × L` (row `m` = the L coefficients of coefficient kernel
///   `m`; for a hat grid, kernel order is the grid's node order, so this is a volume of
///   `L`-channel voxels);
/// * [`MbdModel::basis`]: `N × L × D` (basis kernel `n`, basis vector `l`, component `d`).
#[derive(Debug, Clone, PartialEq)]
pub struct MbdModel<C, B> {
    coefficient_kernels: C,
    basis_kernels: B,
    coefficients: Array2<f32>,
    basis: Array3<f32>,
}

impl<C: SpatialKernels, B: SpatialKernels> MbdModel<C, B> {
    /// A model from its kernels and tensors. Errors if the shapes disagree with the kernel
    /// counts, the rank or dimension is zero, or a value is not finite (naming its flat index).
    pub fn new(
        coefficient_kernels: C,
        basis_kernels: B,
        coefficients: Array2<f32>,
        basis: Array3<f32>,
    ) -> Result<Self, MbdError> {
        let (m, l) = coefficients.dim();
        let (n, lb, d) = basis.dim();
        if m != coefficient_kernels.len() || l == 0 {
            return Err(MbdError::ShapeMismatch {
                what: "coefficient tensor",
                expected: vec![coefficient_kernels.len(), l.max(1)],
                got: vec![m, l],
            });
        }
        if n != basis_kernels.len() || lb != l || d == 0 {
            return Err(MbdError::ShapeMismatch {
                what: "basis tensor",
                expected: vec![basis_kernels.len(), l, d.max(1)],
                got: vec![n, lb, d],
            });
        }
        let coefficients = coefficients.as_standard_layout().into_owned();
        let basis = basis.as_standard_layout().into_owned();
        if let Some(index) = coefficients.iter().position(|v| !v.is_finite()) {
            return Err(CoreError::NonFinite {
                what: "MBD coefficients",
                index,
            }
            .into());
        }
        if let Some(index) = basis.iter().position(|v| !v.is_finite()) {
            return Err(CoreError::NonFinite {
                what: "MBD basis",
                index,
            }
            .into());
        }
        Ok(Self {
            coefficient_kernels,
            basis_kernels,
            coefficients,
            basis,
        })
    }

    /// The rank L (number of moving basis vectors).
    pub fn rank(&self) -> usize {
        self.coefficients.ncols()
    }

    /// The coefficient kernels φ.
    pub fn coefficient_kernels(&self) -> &C {
        &self.coefficient_kernels
    }

    /// The basis kernels ψ.
    pub fn basis_kernels(&self) -> &B {
        &self.basis_kernels
    }

    /// Coefficients, `M × L`.
    pub fn coefficients(&self) -> &Array2<f32> {
        &self.coefficients
    }

    /// Basis vectors, `N × L × D`.
    pub fn basis(&self) -> &Array3<f32> {
        &self.basis
    }

    /// The kernels and tensors, consuming the model.
    pub fn into_parts(self) -> (C, B, Array2<f32>, Array3<f32>) {
        (
            self.coefficient_kernels,
            self.basis_kernels,
            self.coefficients,
            self.basis,
        )
    }

    /// The interpolated coefficients `c(x)` (length L) and basis `b(x)` (`L × D`, row-major) at `x`.
    pub fn eval_parts(
        &self,
        x: Vec3,
        scratch: &mut EvalScratch,
        coefficients_out: &mut [f32],
        basis_out: &mut [f32],
    ) -> Result<(), CoreError> {
        let l = self.rank();
        let d = FieldModel::dim(self);
        if coefficients_out.len() != l {
            return Err(CoreError::LengthMismatch {
                what: "coefficient output",
                expected: l,
                got: coefficients_out.len(),
            });
        }
        if basis_out.len() != l * d {
            return Err(CoreError::LengthMismatch {
                what: "basis output",
                expected: l * d,
                got: basis_out.len(),
            });
        }
        self.coefficient_kernels.eval(x, &mut scratch.phi)?;
        self.basis_kernels.eval(x, &mut scratch.psi)?;
        coefficients_out.fill(0.0);
        for (m, w) in scratch.phi.iter() {
            let row = self.coefficients.row(m as usize);
            for (o, &c) in coefficients_out.iter_mut().zip(row.iter()) {
                *o += w * c;
            }
        }
        basis_out.fill(0.0);
        let flat = self.basis.as_slice().unwrap_or(&[]);
        for (n, w) in scratch.psi.iter() {
            let node = &flat[n as usize * l * d..(n as usize + 1) * l * d];
            for (o, &b) in basis_out.iter_mut().zip(node) {
                *o += w * b;
            }
        }
        Ok(())
    }

    /// `f̂(x)` with caller-provided scratch (no allocation).
    pub fn eval_with(
        &self,
        x: Vec3,
        scratch: &mut EvalScratch,
        out: &mut [f32],
    ) -> Result<(), CoreError> {
        let d = FieldModel::dim(self);
        if out.len() != d {
            return Err(CoreError::LengthMismatch {
                what: "MBD output",
                expected: d,
                got: out.len(),
            });
        }
        let l = self.rank();
        let mut c = std::mem::take(&mut scratch.c);
        let mut b = std::mem::take(&mut scratch.b);
        c.resize(l, 0.0);
        b.resize(l * d, 0.0);
        let result = self.eval_parts(x, scratch, &mut c, &mut b);
        if result.is_ok() {
            out.fill(0.0);
            for (li, &cl) in c.iter().enumerate() {
                for (o, &bv) in out.iter_mut().zip(&b[li * d..(li + 1) * d]) {
                    *o += cl * bv;
                }
            }
        }
        scratch.c = c;
        scratch.b = b;
        result
    }
}

/// Reusable buffers for [`MbdModel::eval_with`].
#[derive(Debug, Clone, Default)]
pub struct EvalScratch {
    phi: KernelWeights,
    psi: KernelWeights,
    c: Vec<f32>,
    b: Vec<f32>,
}

impl<C: SpatialKernels, B: SpatialKernels> FieldModel for MbdModel<C, B> {
    fn dim(&self) -> usize {
        self.basis.dim().2
    }

    fn eval(&self, x: Vec3, out: &mut [f32]) -> Result<(), CoreError> {
        self.eval_with(x, &mut EvalScratch::default(), out)
    }

    fn stored_scalars(&self) -> usize {
        self.coefficients.len() + self.basis.len()
    }

    fn name(&self) -> String {
        format!("MBD rank {}", self.rank())
    }
}

//! The numerical kernels every algorithm of the crate is built on, in two interchangeable
//! implementations: faer (pure Rust, the default) and ndarray-linalg + OpenBLAS (`lapack`).
//!
//! Both take and return plain ndarray values / row-major slices so that the algorithms above
//! them are written once.

#[cfg(not(feature = "lapack"))]
mod faer_backend;
#[cfg(not(feature = "lapack"))]
pub(crate) use faer_backend::*;

#[cfg(feature = "lapack")]
mod lapack_backend;
#[cfg(feature = "lapack")]
pub(crate) use lapack_backend::*;

/// The backend's name, for benchmark tables and reports.
pub const BACKEND_NAME: &str = if cfg!(feature = "lapack") {
    "lapack (OpenBLAS)"
} else {
    "faer"
};

/// The float types the GEMM kernels run on.
pub(crate) trait Real:
    Copy + Send + Sync + 'static + faer::traits::RealField + ndarray::LinalgScalar
{
    /// Zero.
    const ZERO: Self;
    /// Widening conversion.
    fn to_f64(self) -> f64;
}
impl Real for f32 {
    const ZERO: Self = 0.0;
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
}
impl Real for f64 {
    const ZERO: Self = 0.0;
    fn to_f64(self) -> f64 {
        self
    }
}

/// `(u, s, vt)` of a thin SVD.
pub(crate) type SvdParts = (ndarray::Array2<f64>, Vec<f64>, ndarray::Array2<f64>);

/// Whether a GEMM operand is used as stored or transposed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Op {
    /// As stored.
    N,
    /// Transposed.
    T,
}

/// A row-major matrix operand of a GEMM: `rows x cols` as stored, before `op`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Operand<'a, T> {
    pub data: &'a [T],
    pub rows: usize,
    pub cols: usize,
    pub op: Op,
}

impl<'a, T> Operand<'a, T> {
    /// A stored `rows x cols` row-major matrix used as is.
    pub fn n(data: &'a [T], rows: usize, cols: usize) -> Self {
        Self {
            data,
            rows,
            cols,
            op: Op::N,
        }
    }
    /// A stored `rows x cols` row-major matrix used transposed.
    pub fn t(data: &'a [T], rows: usize, cols: usize) -> Self {
        Self {
            data,
            rows,
            cols,
            op: Op::T,
        }
    }
    /// Rows and columns after `op`.
    pub fn shape(&self) -> (usize, usize) {
        match self.op {
            Op::N => (self.rows, self.cols),
            Op::T => (self.cols, self.rows),
        }
    }
}

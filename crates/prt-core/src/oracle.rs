use std::sync::atomic::{AtomicU64, Ordering};

use ndarray::Array2;

use crate::CoreError;

/// A `rows × cols` matrix that can only be evaluated a row or a column at a time, each element
/// holding `channels` values (3 for RGB): the pixels × lights matrix of many-light rendering
/// (Hasan et al.), or a synthetic test matrix.
///
/// Element `(i, j)` occupies `channels` consecutive floats; a row is `cols * channels` floats,
/// a column `rows * channels`. Implementations count the elements they evaluate so that
/// algorithms can be compared by cost.
pub trait MatrixOracle: Sync {
    /// Number of rows (pixels).
    fn rows(&self) -> usize;

    /// Number of columns (lights).
    fn cols(&self) -> usize;

    /// Values per element (1 for scalar matrices, 3 for RGB).
    fn channels(&self) -> usize {
        1
    }

    /// Writes row `i` into `out` (`cols * channels` floats).
    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), CoreError>;

    /// Writes column `j` into `out` (`rows * channels` floats).
    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), CoreError>;

    /// Total elements evaluated so far through this oracle.
    fn elements_evaluated(&self) -> u64;
}

/// A [`MatrixOracle`] over an explicit array: the reference for tests and synthetic
/// experiments. The array is `rows × (cols * channels)`.
#[derive(Debug)]
pub struct DenseOracle {
    data: Array2<f32>,
    channels: usize,
    evaluated: AtomicU64,
}

impl DenseOracle {
    /// Wraps `data` (`rows × (cols * channels)`). Errors if `channels` is zero, does not divide
    /// the column count, or a value is non-finite.
    pub fn new(data: Array2<f32>, channels: usize) -> Result<Self, CoreError> {
        if channels == 0 {
            return Err(CoreError::Empty {
                what: "oracle channels",
            });
        }
        if !data.ncols().is_multiple_of(channels) {
            return Err(CoreError::Invalid {
                what: "oracle shape",
                why: format!(
                    "{} columns is not a multiple of {channels} channels",
                    data.ncols()
                ),
            });
        }
        if let Some(index) = data.iter().position(|v| !v.is_finite()) {
            return Err(CoreError::NonFinite {
                what: "oracle matrix",
                index,
            });
        }
        Ok(Self {
            data,
            channels,
            evaluated: AtomicU64::new(0),
        })
    }

    /// The underlying array.
    pub fn data(&self) -> &Array2<f32> {
        &self.data
    }

    /// Resets the element counter.
    pub fn reset_count(&self) {
        self.evaluated.store(0, Ordering::Relaxed);
    }
}

impl MatrixOracle for DenseOracle {
    fn rows(&self) -> usize {
        self.data.nrows()
    }

    fn cols(&self) -> usize {
        self.data.ncols() / self.channels
    }

    fn channels(&self) -> usize {
        self.channels
    }

    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), CoreError> {
        if i >= self.rows() {
            return Err(CoreError::OutOfRange {
                what: "oracle row",
                index: i,
                len: self.rows(),
            });
        }
        if out.len() != self.data.ncols() {
            return Err(CoreError::LengthMismatch {
                what: "oracle row output",
                expected: self.data.ncols(),
                got: out.len(),
            });
        }
        for (o, &x) in out.iter_mut().zip(self.data.row(i)) {
            *o = x;
        }
        self.evaluated
            .fetch_add(self.cols() as u64, Ordering::Relaxed);
        Ok(())
    }

    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        if j >= self.cols() {
            return Err(CoreError::OutOfRange {
                what: "oracle column",
                index: j,
                len: self.cols(),
            });
        }
        let c = self.channels;
        if out.len() != self.rows() * c {
            return Err(CoreError::LengthMismatch {
                what: "oracle column output",
                expected: self.rows() * c,
                got: out.len(),
            });
        }
        for (i, row) in self.data.rows().into_iter().enumerate() {
            for k in 0..c {
                out[i * c + k] = row[j * c + k];
            }
        }
        self.evaluated
            .fetch_add(self.rows() as u64, Ordering::Relaxed);
        Ok(())
    }

    fn elements_evaluated(&self) -> u64 {
        self.evaluated.load(Ordering::Relaxed)
    }
}

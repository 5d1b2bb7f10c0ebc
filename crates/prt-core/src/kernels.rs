use glam::Vec3;

use crate::{Aabb, CoreError};

/// The sparse result of evaluating a kernel family at one point: the (index, weight) pairs of
/// the kernels that are non-zero there.
///
/// Structure of arrays so that hot loops can read indices and weights separately; reused across
/// calls (`clear` keeps the allocation).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct KernelWeights {
    /// Kernel indices, each in `0..SpatialKernels::len()`.
    pub indices: Vec<u32>,
    /// Kernel values at the point, parallel to `indices`.
    pub weights: Vec<f32>,
}

impl KernelWeights {
    /// Empty, with room for `n` pairs.
    pub fn with_capacity(n: usize) -> Self {
        Self {
            indices: Vec::with_capacity(n),
            weights: Vec::with_capacity(n),
        }
    }

    /// Removes all pairs.
    pub fn clear(&mut self) {
        self.indices.clear();
        self.weights.clear();
    }

    /// Appends one pair.
    #[inline]
    pub fn push(&mut self, index: u32, weight: f32) {
        self.indices.push(index);
        self.weights.push(weight);
    }

    /// Number of pairs.
    pub fn len(&self) -> usize {
        self.indices.len()
    }

    /// Whether there are no pairs.
    pub fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }

    /// The pairs as `(index, weight)`.
    pub fn iter(&self) -> impl Iterator<Item = (u32, f32)> + '_ {
        self.indices
            .iter()
            .copied()
            .zip(self.weights.iter().copied())
    }

    /// Sum of the weights (1 for a partition of unity), accumulated in f64.
    pub fn sum(&self) -> f64 {
        self.weights.iter().map(|&w| w as f64).sum()
    }
}

/// A family of kernels `phi_0 .. phi_{n-1}` over R³, evaluated sparsely.
///
/// Moving Basis Decomposition interpolates its coefficients with one family and its basis
/// vectors with another; hat kernels on regular grids and Shepard kernels over scattered centres
/// both implement this trait (crate `prt-kernels`).
///
/// Contract:
/// * `eval(x, out)` clears `out` and writes every kernel that is non-zero at `x`, at most
///   [`SpatialKernels::max_support`] of them, with indices below [`SpatialKernels::len`];
/// * families used by MBD form a partition of unity on their [`SpatialKernels::domain`]
///   (weights non-negative, summing to one);
/// * behaviour outside the domain is the implementation's documented choice (hat grids clamp
///   to the box, Shepard kernels return [`CoreError::Uncovered`]); a non-finite `x` is
///   [`CoreError::NonFinite`].
pub trait SpatialKernels: Send + Sync {
    /// Number of kernels in the family.
    fn len(&self) -> usize;

    /// Whether the family has no kernels.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The largest number of kernels that can be non-zero at one point (8 for a trilinear hat grid).
    fn max_support(&self) -> usize;

    /// The box on which the family is defined.
    fn domain(&self) -> Aabb;

    /// Writes the non-zero kernels at `x` into `out` (cleared first).
    fn eval(&self, x: Vec3, out: &mut KernelWeights) -> Result<(), CoreError>;

    /// An identifier of the region around `x` inside which the *set* of non-zero kernels does not
    /// change (a hat grid's cell), or `None` if the family has no such structure.
    ///
    /// Solvers batch all points of one region into small dense products, since they share the
    /// same kernels.
    fn support_cell(&self, x: Vec3) -> Option<usize> {
        let _ = x;
        None
    }

    /// Number of distinct [`SpatialKernels::support_cell`] ids (0 if the family has none).
    fn num_support_cells(&self) -> usize {
        0
    }

    /// The centre (node position) of kernel `i`, where the family has one.
    fn centre(&self, i: usize) -> Option<Vec3> {
        let _ = i;
        None
    }
}

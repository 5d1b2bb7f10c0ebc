use thiserror::Error;

/// Errors raised when building a kernel family.
///
/// Evaluation goes through [`prt_core::SpatialKernels`] and reports [`prt_core::CoreError`]
/// (`NonFinite` for a NaN query point, `Uncovered` for a point no Shepard kernel reaches).
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum KernelError {
    /// An axis was given zero nodes.
    #[error("hat grid axis {axis} has no nodes (at least 1 is needed)")]
    NoNodes {
        /// The axis (0 = x, 1 = y, 2 = z).
        axis: usize,
    },
    /// An axis has fewer nodes than the family needs.
    #[error("axis {axis} has {nodes} nodes, at least {min} are needed")]
    TooFewNodes {
        /// The axis (0 = x, 1 = y, 2 = z).
        axis: usize,
        /// The node count given.
        nodes: usize,
        /// The smallest valid count.
        min: usize,
    },
    /// The domain is not a box with finite corners and `min <= max`.
    #[error("domain is not a finite box with min <= max: min {min:?}, max {max:?}")]
    InvalidDomain {
        /// The minimum corner given.
        min: [f32; 3],
        /// The maximum corner given.
        max: [f32; 3],
    },
    /// An axis with two or more nodes has zero extent, so its nodes would coincide.
    #[error("hat grid axis {axis} has {nodes} nodes but the domain has zero extent along it")]
    DegenerateAxis {
        /// The axis (0 = x, 1 = y, 2 = z).
        axis: usize,
        /// The node count given for it.
        nodes: usize,
    },
    /// The family has more kernels than a `u32` kernel index can name.
    #[error("kernel family too large: {what} exceeds the u32 index range")]
    TooManyKernels {
        /// What overflowed, in words (for example "2000000 x 2000000 x 2 nodes").
        what: String,
    },
    /// A family was built from no kernels at all.
    #[error("{what} is empty")]
    Empty {
        /// What was empty.
        what: &'static str,
    },
    /// Two slices that must have the same length did not.
    #[error("length mismatch in {what}: expected {expected}, got {got}")]
    LengthMismatch {
        /// What was being checked.
        what: &'static str,
        /// The length required.
        expected: usize,
        /// The length given.
        got: usize,
    },
    /// A centre coordinate was NaN or infinite.
    #[error("non-finite {what} at index {index}")]
    NonFinite {
        /// What held the value ("centre", "radius").
        what: &'static str,
        /// Index of the offending kernel.
        index: usize,
    },
    /// A support radius was not strictly positive.
    #[error("radius {radius} of kernel {index} is not strictly positive")]
    InvalidRadius {
        /// Index of the offending kernel.
        index: usize,
        /// The radius given.
        radius: f32,
    },
}

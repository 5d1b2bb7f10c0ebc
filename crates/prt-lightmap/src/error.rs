use thiserror::Error;

/// Errors of prt-lightmap.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum LightmapError {
    /// The scene has no triangles to put in a lightmap.
    #[error("the scene has no triangles")]
    EmptyScene,
    /// A knob was outside its valid range.
    #[error("invalid {what}: {why}")]
    Invalid {
        /// The knob.
        what: &'static str,
        /// Why it is invalid.
        why: String,
    },
    /// A value that must be finite was NaN or infinite.
    #[error("non-finite {what} at index {index}")]
    NonFinite {
        /// What held the value ("lightmap UV", "triangle position", ...).
        what: &'static str,
        /// Index of the triangle (or texel) holding it.
        index: usize,
    },
    /// The charts do not fit in the largest atlas allowed.
    #[error(
        "the charts need a {width}×{height} atlas, more than the {max}² allowed; lower the texel density"
    )]
    AtlasTooLarge {
        /// Width needed.
        width: u32,
        /// Height needed.
        height: u32,
        /// Largest side allowed.
        max: u32,
    },
    /// The bake would need more memory than its budget.
    #[error("the lightmap needs about {needed} bytes, over the budget of {budget} bytes")]
    MemoryBudget {
        /// Estimated bytes.
        needed: u64,
        /// The budget.
        budget: u64,
    },
    /// The encoder failed.
    #[error(transparent)]
    Plsq(#[from] prt_plsq::PlsqError),
    /// The basis could not be built.
    #[error(transparent)]
    Sphere(#[from] prt_sphere::SphereError),
    /// The work was cancelled through a `Progress` handle before any pass completed.
    #[error("cancelled")]
    Cancelled,
}

impl LightmapError {
    pub(crate) fn invalid(what: &'static str, why: impl Into<String>) -> Self {
        LightmapError::Invalid {
            what,
            why: why.into(),
        }
    }
}

use prt_core::CoreError;
use thiserror::Error;

/// Errors of the many-light algorithms.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum ManyLightError {
    /// The matrix has no rows (pixels), no columns (lights) or no channels.
    #[error("the matrix has no {what}")]
    EmptyMatrix {
        /// "rows (pixels)", "columns (lights)", "channels" or "frames".
        what: &'static str,
    },
    /// A sample count was zero.
    #[error("at least one {what} must be sampled")]
    ZeroSamples {
        /// "row", "column", or the LightSlice knob ("slices", "local clusters", ...).
        what: &'static str,
    },
    /// More rows or columns were requested than the matrix has (or, for LightSlice's global
    /// clusters, than its local clusters).
    #[error("{requested} {what} requested but only {available} are possible")]
    TooMany {
        /// "rows", "columns", or the LightSlice knob.
        what: &'static str,
        /// The count requested.
        requested: usize,
        /// The count available.
        available: usize,
    },
    /// The oracle returned NaN or infinity.
    #[error("non-finite matrix element ({row}, {col}), channel {channel}")]
    NonFinite {
        /// Row (pixel) of the element.
        row: usize,
        /// Column (light) of the element.
        col: usize,
        /// Channel of the element.
        channel: usize,
    },
    /// The reduced matrix would not fit in memory (`rows × channels × columns` overflows).
    #[error("reduced matrix of {rows} rows x {channels} channels x {cols} columns is too large")]
    TooLarge {
        /// Sampled rows.
        rows: usize,
        /// Channels per element.
        channels: usize,
        /// Columns of the matrix.
        cols: usize,
    },
    /// A frame of an animation has other columns or channels than the first frame.
    #[error(
        "frame {frame} has {cols} columns x {channels} channels, the first frame {expected_cols} x {expected_channels}"
    )]
    ShapeMismatch {
        /// Index of the frame.
        frame: usize,
        /// Its columns (lights).
        cols: usize,
        /// Its channels.
        channels: usize,
        /// Columns of the first frame.
        expected_cols: usize,
        /// Channels of the first frame.
        expected_channels: usize,
    },
    /// An option needs more of the oracle than the entry point called offers (LightSlice's
    /// shading guide needs the unshadowed shading of `light_slice_guided`).
    #[error("{what} needs an oracle with unshadowed shading (light_slice_guided)")]
    NeedsShading {
        /// The option.
        what: &'static str,
    },
    /// The oracle failed.
    #[error("matrix oracle: {0}")]
    Oracle(CoreError),
    /// The work was cancelled through the `Progress` handle.
    #[error("cancelled")]
    Cancelled,
}

impl From<CoreError> for ManyLightError {
    fn from(e: CoreError) -> Self {
        match e {
            CoreError::Cancelled => ManyLightError::Cancelled,
            e => ManyLightError::Oracle(e),
        }
    }
}

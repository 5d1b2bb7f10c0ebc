//! # prt-manylight — many-light rendering by matrix sampling
//!
//! With many lights (thousands of virtual point lights from a light tracer), the image is the
//! sum of the columns of a pixels × lights matrix whose elements each cost a shadow ray. The
//! matrix is only available through a [`prt_core::MatrixOracle`] (a row: one pixel against all
//! lights; a column: one light against all pixels). This crate estimates the column sum at a
//! fraction of the element evaluations:
//!
//! * [`row_column_sampling`] — Hasan, Pellacini and Bala, "Matrix Row-Column Sampling for the
//!   Many-Light Problem" (SIGGRAPH 2007): a few hundred sampled rows give a reduced matrix;
//!   lights are clustered by their reduced columns ([`cluster_columns`], cost [`cluster_cost`]);
//!   one full column per cluster, drawn proportionally to its reduced norm and weighted by the
//!   inverse probability, gives an unbiased image estimate. Lights that no sampled row sees are
//!   drawn uniformly (unbiased, [`UnseenLights::Sample`]; [`UnseenLights::Groups`] draws one
//!   per group of them) or skipped as in the paper ([`UnseenLights::Skip`]: unbiased for the
//!   seen lights, no heavy tail from unseen ones).
//! * [`tensor_clustering`] — Hašan, Velázquez-Armendáriz, Pellacini and Bala, "Tensor
//!   Clustering for Rendering Many-Light Animations" (EGSR 2008): rows sampled in every frame of
//!   an animation, rectangular clusters (lights × frame range) split in lights or in time by
//!   whichever lowers the cost more, one representative per cluster reused across its frames.
//! * [`light_slice`] — Ou and Pellacini, "LightSlice: Matrix Slice Sampling for the
//!   Many-Lights Problem" (SIGGRAPH Asia 2011): slices of pixels with similar gather-point
//!   position and normal, one sampled row per slice, a global clustering refined per slice on
//!   the rows of the nearest slices, and per-slice representatives evaluated on the slice's
//!   pixels only (through [`SliceOracle`]). [`light_slice_guided`] (beyond the paper) also
//!   draws part of each representative by the lights' unshadowed shading on probe pixels of the
//!   slice ([`ShadingGuide`]; the shading bounds every element and costs no shadow ray), which
//!   bounds the weights of lights the sampled rows barely see.
//! * [`visibility_clustering`] — shading from every light, visibility from one representative
//!   per cluster of lights, clusters minimising the L2 error of that visibility approximation
//!   (divisive or k-means; through [`VisibilityOracle`]).
//! * [`brute_force`] — the exact image, every element.
//! * [`SyntheticVplOracle`] — a procedural VPL-like matrix (coloured walls, bright primary
//!   lights, shadows, zero columns) to test and measure without a ray tracer.
//!
//! The algorithms never do I/O; they take a [`prt_core::Progress`] handle for progress and
//! cancellation. Every random choice comes from one seeded generator used in a fixed order, and
//! parallel work is split in fixed batches and reduced in order, so a seed gives the same image
//! on any number of threads.
//!
//! ```
//! use prt_core::NoProgress;
//! use prt_manylight::{RowColumnConfig, SyntheticVplOracle, brute_force, row_column_sampling};
//!
//! let oracle = SyntheticVplOracle::new(32, 32, 2000, 1);
//! let estimate = row_column_sampling(&oracle, &RowColumnConfig::new(32, 100), &NoProgress).unwrap();
//! let exact = brute_force(&oracle, &NoProgress).unwrap();
//! let total = |img: &[f32]| img.iter().map(|&v| v as f64).sum::<f64>();
//! assert!((total(&estimate.image) / total(&exact) - 1.0).abs() < 0.2);
//! // 32 rows × 2000 lights + 100 columns × 1024 pixels, instead of 1024 × 2000.
//! assert_eq!(estimate.elements, 32 * 2000 + 100 * 1024);
//! ```
#![deny(missing_docs)]

mod cluster;
mod error;
mod lightslice;
mod reduced;
mod rowcol;
mod synthetic;
mod tensor;
mod visibility;

pub use cluster::{Clustering, cluster_columns, cluster_cost, split_cluster};
pub use error::ManyLightError;
pub use lightslice::{
    GatherGeometry, LightSliceConfig, LightSliceEstimate, ShadingGuide, SliceOracle, SliceSplit,
    light_slice, light_slice_guided,
};
pub use reduced::{ReducedMatrix, stratified_rows};
pub use rowcol::{
    Representative, RowColumnConfig, RowColumnEstimate, UnseenLights, brute_force,
    row_column_sampling,
};
pub use synthetic::SyntheticVplOracle;
pub use tensor::{TensorCluster, TensorConfig, TensorEstimate, tensor_clustering};
pub use visibility::{
    VisibilityClusterMethod, VisibilityConfig, VisibilityEstimate, VisibilityOracle,
    visibility_clustering,
};

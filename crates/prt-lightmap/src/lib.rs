//! # prt-lightmap — progressive lightmaps
//!
//! Lightmaps whose texels store incident radiance in a sphere basis, baked progressively as in
//! Roughton, "Progressive Least-Squares Encoding for Linear Bases" (JCGT 9(1), 2020,
//! <http://jcgt.org/published/0009/01/02/>): each texel's path-traced radiance samples are
//! splatted, pass after pass, into per-texel progressive least-squares encoders (`prt-plsq`),
//! so a usable lightmap exists after the first pass and every later one refines it.
//!
//! * **UVs** — [`unwrap_charts`]: planar charts by normal clustering packed on shelves
//!   ([`pack_shelves`]); Rust-native, so the default build needs no C++ toolchain and gives the
//!   same atlas everywhere. [`atlas_from_uvs`]: the scene's own `TEXCOORD_1`. Both report texel
//!   density and packing efficiency ([`Atlas`]); degenerate or out-of-range UVs are warnings,
//!   overlapping ones are counted per texel ([`TexelMap::overlapping`]).
//! * **Texels** — [`TexelMap`]: the surface point of every texel a triangle touches;
//!   [`dilate_texels`] fills the padding around charts, [`Seams`] stitches texels across UV seams.
//! * **Bake** — [`bake_lightmap`] with [`LightmapConfig`] → [`LightmapBake`]: samples over the
//!   hemisphere around the texel's normal ([`Lighting`]: sky, sun, emitters, punctual lights,
//!   diffuse bounces), the paper's hemisphere rule (zero-radiance mirror samples), decorrelated
//!   per-texel Sobol' sequences, and one of the encoders of [`Encoder`] (PLSQ, non-negative PLSQ
//!   — the default, no negative light —, least squares, NNLS, naive projection) into a
//!   [`LightmapBasis`] (`sg:N`, `sh:N`, `ambient-dice`, `irradiance`). Memory is estimated
//!   before allocating ([`estimate_memory`]) and refused over a budget.
//!
//! * **Looking** — [`Lightmap::irradiance_at`] (bilinear, as a GPU filters) and
//!   [`render_view`]: the scene from a pinhole view lit by its lightmap.
//! * **Reading back** — [`LightmapManifest::parse`] and [`LightmapFolder::parse`]: the folder
//!   `prt lightmap` writes, from its bytes; [`Lightmap::coefficients_at`] filters the basis
//!   layers as [`Lightmap::irradiance_at`] does.
//!
//! The crate does no I/O; long work takes a [`prt_core::Progress`] handle (cancellation keeps
//! the last completed pass). A seed gives bit-identical lightmaps on any thread count.
//!
//! ```
//! use prt_core::NoProgress;
//! use prt_lightmap::{LightmapConfig, UnwrapConfig, bake_lightmap, unwrap_charts};
//! use prt_trace::Scene;
//!
//! let scene = Scene::cornell_box();
//! let atlas = unwrap_charts(scene.triangles(), &UnwrapConfig { texels_per_metre: 4.0, ..Default::default() })?;
//! let config = LightmapConfig { samples: 8, pass_samples: 4, ..Default::default() };
//! let bake = bake_lightmap(&scene, &atlas, &config, &NoProgress, &mut |_| {})?;
//! assert_eq!(bake.lightmap.samples_per_texel, 8);
//! // Non-negative PLSQ: no coefficient is negative.
//! assert!(bake.lightmap.coefficients.iter().flatten().all(|&c| c >= 0.0));
//! # Ok::<(), prt_lightmap::LightmapError>(())
//! ```
#![deny(missing_docs)]

mod atlas;
mod bake;
mod basis;
mod error;
mod folder;
mod pack;
mod punctual;
mod raster;
mod trace;
mod view;

pub use atlas::{Atlas, UnwrapConfig, UvSource, atlas_from_uvs, unwrap_charts};
pub use bake::{Lightmap, LightmapBake, LightmapConfig, bake_lightmap, estimate_memory};
pub use basis::{Encoder, LightmapBasis};
pub use error::LightmapError;
pub use folder::{LIGHTMAP_MANIFEST, LightmapFolder, LightmapManifest, MAX_MANIFEST_BYTES};
pub use pack::{Packing, pack_shelves};
pub use raster::{Seams, Texel, TexelMap, dilate_texels};
pub use trace::Lighting;
pub use view::render_view;

//! # prt-bake — the main job of prt as a library
//!
//! What `prt bake` does, callable from Rust: trace a scene's 324-D transfer volume, compress it
//! with Moving Basis Decomposition (and, optionally, blockwise and clustered PCA at equal basis
//! count), score every method, and write the MBD container an engine loads. The container's
//! reader gives back a model that evaluates f̂(x).
//!
//! The front door (everything a first bake needs) is at the root; the rest sits in a module per
//! concern.
//!
//! | item | what it is, when to use it |
//! |---|---|
//! | [`bake`] | the whole pipeline for a [`SceneInput`] and a [`BakeConfig`], reporting through a [`Progress`](prt_core::Progress) |
//! | [`bake_volume`] | the pipeline after the trace, on a volume traced elsewhere (tiles of a tiled bake) |
//! | [`BakeConfig`], [`Layout`], [`Quality`] | every knob (`Default` is `prt bake`'s defaults); dense or sparse-brick tracing; the named presets of [`BakeConfig::preset`] |
//! | [`SceneInput`], [`scene_hash`] | the built-in Cornell box or a glTF file, with the name the container records; the hash of a loaded scene |
//! | [`Bake`], [`Method`], [`MethodScores`] | the result: volume, MBD fit, baselines, the comparison (scores per method), seam views, stage times |
//! | [`BakeProgress`], [`Stage`] | per-stage progress handles (any `Progress` works as one) |
//! | [`BakeFolder`] | a bake folder's layout (container, kept volumes, scene mesh, reports): open one to read a bake back |
//! | [`BakeError`] | what can go wrong in a bake |
//! | [`pipeline`] | the parts of a [`Bake`] (the MBD fit, a baseline, what a sparse bake kept): when you name them in your own code |
//! | [`container`] | the MBD container an engine loads: [`write_container`](container::write_container), [`read_container`](container::read_container), its contents and errors, dense or bricked coefficients |
//! | [`folder`] | the bake folder's parts: the volume a later tool lights, whether a bake keeps its volumes, the folder's errors |
//! | [`light_basis`] | light a model's basis by a sky on the basis grid (SH9 or L1 RGB per basis vector): the pass a renderer runs when the sky changes |
//! | [`volumes`] | the traced volume and the baselines' reconstructions kept beside the container, for exports and renders that compare against them |
//! | [`memory`] | what a bake needs in memory, checked against [`BakeConfig::max_memory`] before it starts |
//! | [`seams`] | the seam view: what each method's basis does to a smooth field |
//! | [`tiles`] | tiled bakes: the plan (`prt plan`), one worker's tile (`prt bake-tile`), the merge in memory or streamed (`prt merge`), their files and errors |
//! | [`production`] | the paper's production configuration: a bake lit by a sky as linear-SH irradiance, a hybrid MBD (2D basis over the terrain, 3D coefficients), 8-bit textures at node resolution, read back |
//!
//! ```no_run
//! use prt_bake::container::read_container;
//! use prt_bake::{BakeConfig, SceneInput, bake};
//! use prt_core::{FieldModel, NoProgress, glam::Vec3};
//! use prt_texture::Limits;
//!
//! let out = std::env::temp_dir().join("cornell-mbd");
//! let config = BakeConfig { container: Some(out.clone()), ..BakeConfig::default() };
//! let baked = bake(&SceneInput::cornell_box(), &config, &NoProgress)?;
//! for row in &baked.comparison {
//!     println!("{}: relative MSE {:.3e}", row.method.name(), row.relative_mse);
//! }
//! let container = read_container(&out, &Limits::default())?;
//! let mut transfer = vec![0.0; container.model.dim()];
//! container.model.eval(Vec3::ZERO, &mut transfer)?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! The container's files and manifest are described in docs/formats.md; everything written goes
//! through prt-texture's atomic writers. This crate never prints.
#![deny(missing_docs)]

mod config;
pub mod container;
mod error;
pub mod folder;
pub mod light_basis;
mod lit;
pub mod memory;
mod methods;
pub mod pipeline;
pub mod production;
mod scene;
mod scores;
pub mod seams;
pub mod tiles;
pub mod volumes;

pub use config::{BakeConfig, Layout, Quality};
pub use error::BakeError;
pub use folder::BakeFolder;
pub use pipeline::{Bake, BakeProgress, Stage, bake, bake_volume};
pub use scene::{SceneInput, scene_hash};
pub use scores::{Method, MethodScores};

/// The README's Rust snippet, compiled as a doc test so it stays true.
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;

//! # prt-bake — the main job of prt as a library
//!
//! What `prt bake` does, callable from Rust: trace a scene's 324-D transfer volume, compress it
//! with Moving Basis Decomposition (and, optionally, blockwise and clustered PCA at equal basis
//! count), score every method, and write the MBD container an engine loads. The container's
//! reader gives back a model that evaluates f̂(x).
//!
//! | item | what it is, when to use it |
//! |---|---|
//! | [`bake`] | the whole pipeline for a [`SceneInput`] and a [`BakeConfig`], reporting through a [`Progress`](prt_core::Progress) |
//! | [`bake_volume`] | the pipeline after the trace, on a volume traced elsewhere (tiles of a tiled bake) |
//! | [`BakeConfig`] | every knob; `Default` is `prt bake`'s defaults |
//! | [`Layout`], [`BrickSummary`] | dense or sparse-brick tracing and masked fitting, and what a sparse bake kept |
//! | [`Quality`] | the named presets (draft, default, high) of [`BakeConfig::preset`] |
//! | [`SceneInput`], [`scene_hash`] | the built-in Cornell box or a glTF file, with the name the container records; the hash of a loaded scene |
//! | [`Bake`] | the result: volume, [`BakedMbd`], [`Baseline`]s, the comparison ([`MethodScores`] per [`Method`]), [`SeamView`](seams::SeamView)s, stage times |
//! | [`BakeProgress`], [`Stage`] | per-stage progress handles (any `Progress` works as one) |
//! | [`write_container`], [`read_container`], [`MbdContainer`] | write an MBD model as KTX2 volumes + JSON manifest; read it back: the model, the validity mask, the manifest |
//! | [`container`] | the container's contents, and writing it with the coefficient volume dense or in bricks of live nodes (and the rule that picks one) |
//! | [`light_basis`], [`LightBasisConfig`], [`LitBasis`], [`LitBasisTarget`] | light a model's basis by a sky on the basis grid (SH9 or L1 RGB per basis vector): the pass a renderer runs when the sky changes |
//! | [`BakeFolder`], [`FolderVolume`], [`FolderError`] | a bake folder's layout (container, kept volumes, scene mesh, reports) and the volume a later tool lights |
//! | [`KeepVolumes`], [`KeptOutcome`] | whether a bake keeps its traced volume and the baselines beside the container ([`BakeFolder::keep_volumes`]) |
//! | [`volumes`] | the traced volume and the baselines' reconstructions kept beside the container, for exports and renders that compare against them |
//! | [`memory`] | what a bake needs in memory, checked against [`BakeConfig::max_memory`] before it starts |
//! | [`seams`] | the seam view: what each method's basis does to a smooth field |
//! | [`BakeError`], [`ContainerError`] | what can go wrong |
//! | [`tiles`] | tiled bakes: the plan (`prt plan`), one worker's tile (`prt bake-tile`), the merge in memory or streamed (`prt merge`), their files and errors |
//! | [`production`] | the paper's production configuration: a bake lit by a sky as linear-SH irradiance, a hybrid MBD (2D basis over the terrain, 3D coefficients), 8-bit textures at node resolution, read back |
//!
//! ```no_run
//! use prt_bake::{BakeConfig, SceneInput, bake, read_container};
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
mod folder;
mod light_basis;
pub mod memory;
mod methods;
mod pipeline;
pub mod production;
mod scene;
mod scores;
pub mod seams;
pub mod tiles;
pub mod volumes;

pub use config::{BakeConfig, Layout, Quality, SPARSE_FROM_VOXELS, TRANSFER_DIM};
pub use container::{MbdContainer, read_container, write_container};
pub use error::{BakeError, ContainerError};
pub use folder::{BakeFolder, FolderError, FolderVolume, KeepVolumes, KeptOutcome};
pub use light_basis::{LightBasisConfig, LitBasis, LitBasisTarget, light_basis};
pub use pipeline::{
    Bake, BakeProgress, BakedMbd, Baseline, BrickSummary, Stage, bake, bake_volume,
};
pub use scene::{SceneInput, scene_hash};
pub use scores::{Method, MethodScores};

/// The README's Rust snippet, compiled as a doc test so it stays true.
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;

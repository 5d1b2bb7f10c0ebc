//! # prt-export — bakes lit by a sky, written as probe volumes engines load unchanged
//!
//! A prt bake stores light *transport* (324 values per voxel); engines load baked
//! *irradiance*. This crate takes a bake lit by a sky (a [`prt_trace::LitVolume`]; prt-bake's
//! `BakeFolder::lit_volume` lights a bake folder's volume) and writes what Bevy, three.js and
//! custom engines sample with no code of ours:
//!
//! | item | what it is, when to use it |
//! |---|---|
//! | [`dilate`], [`DilateConfig`], [`Dilated`] | fill invalid voxels from valid neighbours before export |
//! | [`remove_negative_light`], [`NonNegative`] | make every voxel's irradiance non-negative before export |
//! | [`EngineLookup`], [`Engine`] | what Bevy's or three.js's shader computes from an export, on the CPU (previews) |
//! | [`export_bevy`], [`BevyConfig`], [`BevyExport`] | Bevy's `IrradianceVolume`: ambient-cube KTX2 (RGB9E5 / RGBA16F) + placement JSON |
//! | [`export_threejs`], [`ThreejsConfig`], [`ThreejsExport`] | three.js `LightProbeGrid`: RGBA16F 3D atlas KTX2 + placement JSON |
//! | [`export_sh`], [`ShConfig`], [`ShExport`] | L1 and L2 SH volumes (KTX2 + EXR) + manifest, for custom engines and importers |
//! | [`export_lightmap`], [`LightmapEngine`], [`LightmapTexels`], [`LightmapExport`] | an irradiance lightmap (prt-lightmap's) for Bevy's `Lightmap` or three.js's `lightMap`: scene GLB with `TEXCOORD_1` + RGBA16F KTX2 + placement JSON |
//! | [`AmbientCubeFit`] | how Bevy's ambient cubes are fitted to the SH |
//! | [`layout`] | the layouts behind the exports: file names, padding, ambient cubes, three.js's SH basis and atlas, SH textures |
//! | [`sky_from_json`] | a sky from SH coefficients in JSON |
//! | [`ExportError`] | what can go wrong |
//!
//! Bevy and three.js exports are padded by [`layout::ENGINE_PADDING`] copied voxel layers so
//! that every surface of the baked box is lit with full weight in both engines. Every writer
//! writes atomically through prt-texture and also writes the bake's validity mask
//! (`validity.ktx2`, R8, 1 = valid). File layouts are documented in docs/formats.md. This
//! crate never prints; long work reports through a [`prt_core::Progress`] handle.
//!
//! ```
//! use prt_core::{Aabb, GridField, NoProgress, glam::Vec3};
//! use prt_export::{BevyConfig, DilateConfig, dilate, export_bevy};
//! use prt_sphere::Sky;
//! use prt_trace::LitVolume;
//!
//! // A 4×4×4 transfer field that passes the sky straight through (direct block = identity).
//! let bounds = Aabb::new(Vec3::ZERO, Vec3::ONE);
//! let field = GridField::from_fn([4, 4, 4], bounds, 324, |_, t| {
//!     (0..9).for_each(|i| t[i * 9 + i] = 1.0)
//! })?;
//! let valid = vec![true; 64];
//! let lit = LitVolume::from_transfer(&field, &valid, &Sky::constant([1.0; 3]), &NoProgress)?;
//! // A constant sky of radiance 1 gives irradiance π in every direction.
//! assert!((lit.irradiance(0, Vec3::Y).x - std::f32::consts::PI).abs() < 1e-4);
//! let lit = dilate(&lit, &DilateConfig::default())?.volume;
//! let out = std::env::temp_dir().join("prt-export-doc");
//! let written = export_bevy(&lit, &BevyConfig::default(), &out)?;
//! assert_eq!(written.files.len(), 3);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![deny(missing_docs)]

mod ambient;
mod bevy;
mod dilate;
mod error;
mod lightmap;
mod nonneg;
mod preview;
mod sh;
mod skyjson;
mod textures;
mod threejs;
mod write;

pub use ambient::AmbientCubeFit;
pub use bevy::{BevyConfig, BevyExport, BevyFormat, export_bevy};
pub use dilate::{DilateConfig, Dilated, dilate};
pub use error::ExportError;
pub use lightmap::{LightmapEngine, LightmapExport, LightmapTexels, export_lightmap};
pub use nonneg::{NonNegative, remove_negative_light};
pub use preview::{Engine, EngineLookup};
pub use sh::{ShConfig, ShExport, export_sh};
pub use skyjson::sky_from_json;
pub use threejs::{ThreejsConfig, ThreejsExport, export_threejs};
pub use write::WrittenFile;

/// The engines' layouts behind the exports: file names, the padding, Bevy's ambient cubes and
/// irradiance-volume texture, three.js's SH basis and atlas, the SH volumes' textures. For tests, importers and code that
/// reads an export back.
pub mod layout {
    pub use crate::ambient::{
        AmbientCubeColours, SIDES, ambient_cube, ambient_cube_blend, ambient_cube_error_bound,
    };
    pub use crate::bevy::{BEVY_PLACEMENT, BEVY_TEXTURE};
    pub use crate::lightmap::{LIGHTMAP_PLACEMENT, LIGHTMAP_SCENE, LIGHTMAP_TEXTURE};
    pub use crate::nonneg::test_directions;
    pub use crate::sh::{
        SH_EXR_FILE, SH_L1_FILES, SH_L2_FILE, SH_LAYER_NAMES, SH_MANIFEST, sh_l1, sh_l2_texture,
    };
    pub use crate::textures::{
        AMBIENT_CUBE_SIDES, AmbientCubeVolume, ShL1Layout, ShL1Volume, bevy_irradiance_volume,
        bevy_irradiance_volume_as, bevy_irradiance_volume_decode, sh_l1_volume,
        sh_l1_volume_decode,
    };
    pub use crate::threejs::{
        ATLAS_SUBVOLUMES, ENGINE_PADDING, THREEJS_PLACEMENT, THREEJS_TEXTURE, sh_to_threejs,
        threejs_atlas, threejs_atlas_probe,
    };
    pub use crate::write::VALIDITY_FILE;
}

/// The README's Rust snippet, compiled as a doc test so it stays true.
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;

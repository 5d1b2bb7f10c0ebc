//! # prt-render — the lit scene on the CPU
//!
//! Renders what a baked transfer volume looks like on the scene's surfaces: one primary ray per
//! pixel (prt-trace's [`GBuffer`](prt_trace::camera::GBuffer) through a
//! [`PinholeView`](prt_trace::camera::PinholeView)), each hit shaded as a diffuse surface lit by the
//! volume, `L = emission + albedo/π · E(n, p)`, where `E` is the irradiance of the volume's
//! incident-radiance SH at the hit point. The volume is the 324-D transfer of a bake (the traced
//! reference, an MBD container read back, or a baseline's reconstruction) lit by a sky
//! ([`prt_sphere::Sky`]) once per voxel ([`prt_trace::LitVolume`]), so a render costs one trilinear lookup per pixel.
//!
//! | item | what it is, when to use it |
//! |---|---|
//! | [`render`], [`RenderConfig`], [`Rendered`] | the image: linear RGB radiance per pixel, sky where rays miss |
//! | [`SurfaceLight`] | what lights a surface point: a [`LitVolume`](prt_trace::LitVolume) (a transfer volume or model lit by a sky) by prt's lookup, or an engine's lookup (prt-export) |
//! | [`voxels_read`] | which voxels a render reads, to limit per-voxel work to them |
//! | [`image_metrics`], [`ImageMetrics`] | a render against a reference as a person sees them: ꟻLIP and tone-mapped grey-level errors |
//! | [`ToneMap`] | exposure (fixed or [`ToneMap::auto`]), ACES filmic curve, sRGB: 8-bit display values |
//! | [`views`], [`NamedView`] | the scene's glTF cameras, then the automatic `front` and `inside` views |
//! | [`RenderError`] | what can go wrong |
//!
//! Renders are deterministic: every pixel is a pure function of the scene, view, volume and sky,
//! computed in parallel over rows, so the image is the same on any thread count. This crate
//! never prints and writes no file.
//!
//! ```
//! use prt_core::{Aabb, GridField, NoProgress, glam::Vec3};
//! use prt_render::{RenderConfig, render};
//! use prt_sphere::Sky;
//! use prt_trace::camera::PinholeView;
//! use prt_trace::{LitVolume, RayTracer, Scene, TRANSFER_DIM};
//!
//! // A volume that lets the whole sky through (direct transfer = identity) over a grey plane.
//! let scene = Scene::ground_plane(1.0, Vec3::splat(0.5));
//! let bounds = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0));
//! let transfer = GridField::from_fn([2, 2, 2], bounds, TRANSFER_DIM, |_, t| {
//!     for i in 0..9 {
//!         t[i * 9 + i] = 1.0;
//!     }
//! })?;
//! let sky = Sky::constant([1.0, 1.0, 1.0]);
//! let volume = LitVolume::from_transfer(&transfer, &[true; 8], &sky, &NoProgress)?;
//! let view = PinholeView { position: Vec3::Y, forward: Vec3::NEG_Y, up: Vec3::NEG_Z, yfov: 1.0 };
//! let config = RenderConfig { width: 16, height: 16, ..RenderConfig::default() };
//! let image = render(&scene, &RayTracer::new(scene.triangles()), &view, &volume, &sky, &config, &NoProgress)?;
//! // Irradiance π·L on the plane, so its radiance is albedo · L = 0.5.
//! let centre = image.pixels[8 * 16 + 8];
//! assert!((centre[0] - 0.5).abs() < 1e-3);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![deny(missing_docs)]

mod error;
mod metrics;
mod render;
mod tonemap;
mod views;

pub use error::RenderError;
pub use metrics::{ImageMetrics, VISIBLE_LEVELS, image_metrics};
pub use render::{RenderConfig, Rendered, SurfaceLight, render, voxels_read};
pub use tonemap::{MIDDLE_GREY, ToneMap, luminance};
pub use views::{NamedView, views};

/// The README's Rust snippet, compiled as a doc test so it stays true.
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;

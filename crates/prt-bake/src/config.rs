//! The knobs of a bake.

use std::path::PathBuf;

use prt_texture::Encoding;
use prt_trace::TRANSFER_DIM;
use serde::{Deserialize, Serialize};

use crate::BakeError;

/// Every knob of a bake; `Default` gives the defaults of `prt bake`. Serialised (a tiled bake's
/// plan records it) without the memory budget and the container folder, which belong to the
/// machine that runs it; a missing field reads as its default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct BakeConfig {
    /// Voxels along the longest axis of the scene box (the other axes in proportion, at least 2).
    pub resolution: usize,
    /// Directions traced per voxel (rounded up to a multiple of 12; of 48 with adaptive
    /// sampling or the denoiser).
    pub rays_per_voxel: usize,
    /// Hemisphere rays per surface-cache point (the one-bounce indirect part).
    pub cache_rays: usize,
    /// Per-voxel adaptive sampling ([`prt_trace::AdaptiveSampling`]): a voxel stops once the
    /// relative standard error of its transfer is at most this, `rays_per_voxel` being the cap
    /// (`None`: every voxel traces `rays_per_voxel`).
    pub adaptive_error: Option<f32>,
    /// With adaptive sampling, the directions every valid voxel traces at least.
    pub adaptive_min_rays: usize,
    /// Strength of the geometry-aware denoiser ([`prt_trace::DenoiseOptions`]; `None`: off).
    pub denoise: Option<f32>,
    /// The denoiser's neighbourhood half-width in voxels.
    pub denoise_radius: usize,
    /// Margin added around the scene bounds, in metres.
    pub margin: f32,
    /// MBD rank L: moving basis vectors per point.
    pub rank: usize,
    /// MBD basis-grid nodes per axis (at least 2; an axis with fewer voxels gets one per voxel).
    pub basis_nodes: usize,
    /// MBD iteration cap (of the coarse solves, with a coarse start).
    pub max_iterations: usize,
    /// MBD's coarse start ([`prt_mbd::Mbd::coarse_start`]): times the volume is halved and
    /// fitted before the full-resolution solve (`None`: until it has fewer than
    /// [`Layout::SPARSE_FROM_VOXELS`] voxels, so none below 64³). It trades a little error for
    /// a several-fold shorter solve.
    pub coarse_levels: Option<usize>,
    /// With a coarse start, the iteration cap of the full-resolution solve.
    pub full_iterations: usize,
    /// MBD ridge weight λ on the coefficients.
    pub lambda: f32,
    /// The per-voxel loss weighting of MBD and of the baselines alike
    /// ([`prt_mbd::Mbd::loss_weighting`]; default: relative error, exponent 1, floor 0.05, which
    /// the rendered images favour); `None`: the papers' loss. In a plan file: `[exponent, floor]` or null (absent in older plans: null).
    #[serde(default, with = "loss_weighting_serde")]
    pub loss_weighting: Option<prt_mbd::LossWeighting>,
    /// MBD's centre projection ([`prt_mbd::Mbd::centre_projection`]): each voxel's coefficients
    /// re-fitted on its own vector at its centre after the solve (default on, which the rendered
    /// images favour; the streamed merge fits every voxel this way). In a plan file: a bool
    /// (absent in older plans: false).
    #[serde(default)]
    pub centre_projection: bool,
    /// Storage encoding of the container's coefficient and basis volumes.
    pub encoding: Encoding,
    /// Whether to fit and score the blockwise and clustered PCA baselines.
    pub baselines: bool,
    /// Seed of every random choice (tracing, solver, evaluation, clustering).
    pub seed: u64,
    /// Memory budget in bytes: the bake is refused before it starts when its
    /// [`crate::memory::MemoryEstimate`] is above it (`None`: no check).
    #[serde(skip)]
    pub max_memory: Option<u64>,
    /// Folder to write the MBD container into, then score the model read back from it; `None`
    /// writes nothing.
    #[serde(skip)]
    pub container: Option<PathBuf>,
    /// Dense or sparse-brick tracing and fitting.
    pub layout: Layout,
    /// With a sparse layout, drop the bricks none of whose valid voxels sees geometry within this
    /// distance in metres (`None`: keep every brick with a valid voxel).
    pub brick_max_distance: Option<f32>,
}

/// How a bake traces, stores and fits its volume.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    /// Every voxel of the box traced and fitted (invalid voxels as zeros).
    Dense,
    /// Bricks of 4³ voxels: only bricks with a valid voxel are traced (after a probe pass) and
    /// MBD and clustered PCA fit the valid voxels only (a masked loss).
    Sparse,
    /// [`Layout::Sparse`] from [`Layout::SPARSE_FROM_VOXELS`] voxels up, else
    /// [`Layout::Dense`].
    #[default]
    Auto,
}

impl Layout {
    /// The grid size from which [`Layout::Auto`] bakes sparse bricks (64³ voxels): smaller grids
    /// (the default Cornell and Sponza bakes) take seconds either way and keep their dense
    /// figures.
    pub const SPARSE_FROM_VOXELS: usize = 1 << 18;

    /// Whether a grid of `dims` voxels is baked in sparse bricks.
    pub fn is_sparse(self, dims: [usize; 3]) -> bool {
        match self {
            Layout::Dense => false,
            Layout::Sparse => true,
            Layout::Auto => dims.iter().product::<usize>() >= Layout::SPARSE_FROM_VOXELS,
        }
    }
}

impl Default for BakeConfig {
    /// 32 voxels along the longest axis, 512 rays per voxel (528: whole rounds of the variance's
    /// four streams) without adaptive sampling, the denoiser at strength 1 over 3³ voxels, 64
    /// cache rays, no margin, rank 8
    /// on 5 basis nodes per axis, 64 iterations (a coarse start from 64³ voxels up, then 16 at
    /// full resolution), λ = 1e-4, the relative-error loss weighting, f16 storage, baselines
    /// on, seed 0,
    /// no memory budget, no container, [`Layout::Auto`] keeping every brick with a valid voxel.
    fn default() -> Self {
        BakeConfig {
            resolution: 32,
            rays_per_voxel: 512,
            cache_rays: 64,
            adaptive_error: None,
            adaptive_min_rays: 96,
            denoise: Some(1.0),
            denoise_radius: 1,
            margin: 0.0,
            rank: 8,
            basis_nodes: 5,
            max_iterations: 64,
            coarse_levels: None,
            full_iterations: 16,
            lambda: 1e-4,
            loss_weighting: Some(prt_mbd::LossWeighting::default()),
            centre_projection: true,
            encoding: Encoding::F16,
            baselines: true,
            seed: 0,
            max_memory: None,
            container: None,
            layout: Layout::Auto,
            brick_max_distance: None,
        }
    }
}

/// A named trade of bake time for accuracy, each a point of the measured curve of image error
/// against bake time (docs/results.md, "Presets and the curve of error against time"); see
/// [`BakeConfig::preset`]. A preset changes how well the volume is computed, never what is
/// stored: the grid, the rank, the basis and the encoding stay the default's (or the flags').
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Quality {
    /// The cheapest knobs whose image error stays within 10 % of the default's: for previews
    /// and iterating on a scene.
    Draft,
    /// `prt bake`'s defaults: [`BakeConfig::default`].
    #[default]
    Default,
    /// The most accurate knobs measured at up to 4× the default's time: for the bake an engine
    /// ships.
    High,
}

impl BakeConfig {
    /// The knobs of a [`Quality`]; every field not named here keeps its default.
    ///
    /// - `Draft`: 16 MBD iterations.
    /// - `Default`: [`BakeConfig::default`] exactly.
    /// - `High`: 8192 rays per voxel.
    pub fn preset(quality: Quality) -> BakeConfig {
        let default = BakeConfig::default();
        match quality {
            Quality::Draft => BakeConfig {
                max_iterations: 16,
                ..default
            },
            Quality::Default => default,
            Quality::High => BakeConfig {
                rays_per_voxel: 8192,
                ..default
            },
        }
    }

    /// Checks every knob; the error names the offending field.
    pub fn validate(&self) -> Result<(), BakeError> {
        let check = |ok: bool, field: &'static str, why: String| {
            if ok {
                Ok(())
            } else {
                Err(BakeError::InvalidConfig { field, why })
            }
        };
        check(
            self.resolution >= 2,
            "resolution",
            format!("must be at least 2 voxels (got {})", self.resolution),
        )?;
        if let Some(w) = self.loss_weighting {
            check(
                (0.0..=4.0).contains(&w.exponent) && w.floor > 0.0 && w.floor <= 1.0,
                "loss_weighting",
                format!(
                    "exponent {} must be in [0, 4] and floor {} in (0, 1]",
                    w.exponent, w.floor
                ),
            )?;
        }
        check(
            self.rays_per_voxel >= 1,
            "rays_per_voxel",
            "must be at least 1".into(),
        )?;
        check(
            self.cache_rays >= 1,
            "cache_rays",
            "must be at least 1".into(),
        )?;
        check(
            self.adaptive_error
                .is_none_or(|e| e.is_finite() && e >= 0.0),
            "adaptive_error",
            format!(
                "{:?} is not a finite non-negative error",
                self.adaptive_error
            ),
        )?;
        check(
            self.adaptive_min_rays >= 1,
            "adaptive_min_rays",
            "must be at least 1".into(),
        )?;
        check(
            self.denoise.is_none_or(|s| s.is_finite() && s > 0.0),
            "denoise",
            format!("{:?} is not a finite positive strength", self.denoise),
        )?;
        check(
            (1..=8).contains(&self.denoise_radius),
            "denoise_radius",
            format!(
                "must be between 1 and 8 voxels (got {})",
                self.denoise_radius
            ),
        )?;
        check(
            self.basis_nodes >= 2,
            "basis_nodes",
            format!("must be at least 2 (got {})", self.basis_nodes),
        )?;
        check(
            self.brick_max_distance
                .is_none_or(|d| d.is_finite() && d >= 0.0),
            "brick_max_distance",
            format!(
                "{:?} is not a finite non-negative length",
                self.brick_max_distance
            ),
        )?;
        check(
            (1..=TRANSFER_DIM).contains(&self.rank),
            "rank",
            format!(
                "must be between 1 and the transfer dimension {TRANSFER_DIM} (got {})",
                self.rank
            ),
        )?;
        check(
            self.max_iterations >= 1,
            "max_iterations",
            "must be at least 1".into(),
        )?;
        check(
            self.full_iterations >= 1,
            "full_iterations",
            "must be at least 1".into(),
        )?;
        check(
            self.lambda.is_finite() && self.lambda >= 0.0,
            "lambda",
            "must be finite and >= 0".into(),
        )?;
        check(
            self.margin.is_finite() && self.margin >= 0.0,
            "margin",
            "must be finite and >= 0".into(),
        )
    }

    /// The tracer's adaptive sampling, `None` when off.
    pub fn adaptive_sampling(&self) -> Option<prt_trace::AdaptiveSampling> {
        self.adaptive_error
            .map(|target_error| prt_trace::AdaptiveSampling {
                target_error,
                min_rays: self.adaptive_min_rays,
            })
    }

    /// The tracer's denoiser, `None` when off.
    pub fn denoise_options(&self) -> Option<prt_trace::DenoiseOptions> {
        self.denoise.map(|strength| prt_trace::DenoiseOptions {
            radius: self.denoise_radius,
            strength,
        })
    }

    /// Voxels per axis for a scene box of `size`: `resolution` along the longest side, the
    /// others in proportion (at least 2).
    pub fn grid_resolution(&self, size: [f32; 3]) -> [usize; 3] {
        let res = self.resolution;
        let longest = size.iter().copied().fold(0.0f32, f32::max);
        size.map(|s| {
            if longest > 0.0 {
                ((s / longest * res as f32).round() as usize).clamp(2, res)
            } else {
                res
            }
        })
    }

    /// The coarse levels MBD fits on a grid of `dims` voxels before the full-resolution solve:
    /// `coarse_levels`, else as many halvings as bring the grid below
    /// [`Layout::SPARSE_FROM_VOXELS`].
    pub fn coarse_levels(&self, dims: [usize; 3]) -> usize {
        self.coarse_levels.unwrap_or_else(|| {
            let mut voxels = dims.iter().product::<usize>();
            let mut levels = 0;
            while voxels >= Layout::SPARSE_FROM_VOXELS {
                voxels /= 8;
                levels += 1;
            }
            levels
        })
    }

    /// MBD basis nodes per axis on a grid of `dims` voxels: `basis_nodes`, or one per voxel on
    /// an axis with fewer voxels.
    pub fn basis_grid(&self, dims: [usize; 3]) -> [usize; 3] {
        [0, 1, 2].map(|k| self.basis_nodes.min(dims[k].max(2)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_longest_axis_gets_the_resolution_and_the_others_scale() {
        let config = BakeConfig::default();
        assert_eq!(config.grid_resolution([2.0, 1.0, 0.01]), [32, 16, 2]);
        assert_eq!(config.grid_resolution([0.0; 3]), [32; 3]);
    }

    #[test]
    fn the_default_preset_is_the_default() {
        assert_eq!(BakeConfig::preset(Quality::Default), BakeConfig::default());
        assert_eq!(Quality::default(), Quality::Default);
    }

    #[test]
    fn every_preset_is_valid_and_stores_what_the_default_stores() {
        let default = BakeConfig::default();
        for quality in [Quality::Draft, Quality::Default, Quality::High] {
            let preset = BakeConfig::preset(quality);
            assert!(preset.validate().is_ok(), "{quality:?}");
            let storage = |c: &BakeConfig| (c.resolution, c.rank, c.basis_nodes, c.encoding);
            assert_eq!(storage(&preset), storage(&default), "{quality:?}");
        }
        assert_ne!(BakeConfig::preset(Quality::Draft), default);
        assert_ne!(BakeConfig::preset(Quality::High), default);
    }

    #[test]
    fn a_bad_knob_is_named() {
        let bad = BakeConfig {
            rank: 400,
            ..BakeConfig::default()
        };
        match bad.validate() {
            Err(BakeError::InvalidConfig { field, .. }) => assert_eq!(field, "rank"),
            other => panic!("{other:?}"),
        }
        assert!(BakeConfig::default().validate().is_ok());
    }
}

/// [`BakeConfig::loss_weighting`] in JSON as `[exponent, floor]` or null (prt-mbd has no serde).
mod loss_weighting_serde {
    use prt_mbd::LossWeighting;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub fn serialize<S: Serializer>(
        value: &Option<LossWeighting>,
        serializer: S,
    ) -> Result<S::Ok, S::Error> {
        value.map(|w| [w.exponent, w.floor]).serialize(serializer)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(
        deserializer: D,
    ) -> Result<Option<LossWeighting>, D::Error> {
        Ok(Option::<[f32; 2]>::deserialize(deserializer)?
            .map(|[exponent, floor]| LossWeighting { exponent, floor }))
    }
}

//! Helpers shared by the many-light experiments: budgets and light settings, the scene set-up
//! (VPLs traced to a target count, G-buffer), the cached brute-force reference and image strips.

use std::path::{Path, PathBuf};

use crate::{cache_dir, load_scene, save_png};
use prt_core::{MatrixOracle, NoProgress};
use prt_trace::camera::{GBuffer, PinholeView};
use prt_trace::manylight::{
    DirectionalLight, SunAndUniformSky, Vpl, VplOptions, VplOracle, directional_lights, trace_vpls,
};
use prt_trace::{RayTracer, Scene};

/// A sampling budget, `rows/columns` on the command line (`300/900`): sampled rows (or slices)
/// and columns (or clusters).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Budget {
    /// Sampled rows, or LightSlice's slices.
    pub rows: usize,
    /// Sampled columns, or clusters.
    pub columns: usize,
}

impl Budget {
    /// `rows` / `columns`.
    pub const fn new(rows: usize, columns: usize) -> Self {
        Self { rows, columns }
    }
}

impl std::str::FromStr for Budget {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let (rows, columns) = text
            .split_once('/')
            .ok_or_else(|| format!("{text}: want rows/columns, e.g. 300/900"))?;
        let count = |v: &str| {
            v.trim()
                .parse::<usize>()
                .map_err(|e| format!("{text}: {e}"))
        };
        Ok(Self::new(count(rows)?, count(columns)?))
    }
}

impl std::fmt::Display for Budget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.rows, self.columns)
    }
}

/// Which lights a scene's matrix holds beside its VPLs (`--light`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Light {
    /// The sun and 1024 sky directions as directional columns after the VPL ones (none for the
    /// Cornell box, whose direct light is its emitter VPLs), every light sampled.
    #[default]
    Direct,
    /// As `direct`, but the sun's column (the first directional light) is evaluated in full
    /// (`pixels` elements, counted) and the methods sample the other lights.
    ExactSun,
    /// The VPL columns alone: a sun-and-sky scene then has no direct light.
    Indirect,
}

/// Mean and maximum of per-seed errors (0 for none).
pub fn mean_and_max(errors: &[f64]) -> (f64, f64) {
    let mean = errors.iter().sum::<f64>() / errors.len().max(1) as f64;
    (mean, errors.iter().copied().fold(0.0, f64::max))
}

/// The brute-force image of the VPL oracle with `directional` columns after the VPL ones.
pub struct Reference {
    /// The sum of every column, RGB per pixel.
    pub image: Vec<f32>,
    /// The sum of the VPL columns alone (the indirect light).
    pub vpl_image: Vec<f32>,
    /// The first directional column (the sun); zeros without directional lights.
    pub sun: Vec<f32>,
}

/// What every many-light sweep sets up: the scene, its ray tracer, about `target` VPLs and the
/// G-buffer of its default view at `width` × `width` pixels.
pub struct SweepScene {
    /// The scene.
    pub scene: Scene,
    /// Its BVH.
    pub tracer: RayTracer,
    /// About `target` VPLs: two bounces from the lights, seed 1.
    pub vpls: Vec<Vpl>,
    /// One gather point per pixel of the default view.
    pub gbuffer: GBuffer,
    /// Where the brute-force references of this scene and size are cached, a file per clamp.
    cache_stem: PathBuf,
}

impl SweepScene {
    /// The scene `name` (`cornell`, or `sponza` from ../shared; `None`, with the reason on
    /// stderr, when it cannot be used) with its tracer, VPLs and G-buffer. Panics on a setup
    /// error, as a sweep does.
    pub fn load(name: &str, width: usize, target: usize) -> Option<Self> {
        let scene = load_scene(name)
            .map_err(|e| eprintln!("skipping {name}: {e}"))
            .ok()?;
        let tracer = RayTracer::new(scene.triangles());
        let vpls = trace_about(&scene, &tracer, target);
        let view = PinholeView::for_scene(&scene).expect("non-empty scene");
        let gbuffer = GBuffer::render(&scene, &tracer, &view, width, width).expect("valid size");
        let cache_stem =
            cache_dir("manylight_cache").join(format!("{name}_{width}_{}", vpls.len()));
        Some(Self {
            scene,
            tracer,
            vpls,
            gbuffer,
            cache_stem,
        })
    }

    /// The reference of a sweep at `clamp` with `directional` columns after the VPL ones: the
    /// VPL columns' sum is read from the on-disk cache (or computed by brute force and written
    /// there: minutes at 256² × 10⁵ VPLs), the directional columns (about a thousand) are
    /// evaluated here.
    pub fn reference(&self, directional: &[DirectionalLight], clamp: f32) -> Reference {
        let file = PathBuf::from(format!("{}_{clamp}.bin", self.cache_stem.display()));
        if let Some(folder) = file.parent() {
            std::fs::create_dir_all(folder).expect("cache folder");
        }
        let vpls = &self.vpls;
        let vpl_image = self
            .oracle(clamp, &[])
            .reference_image_cached(&file, &NoProgress)
            .expect("reference image");
        let full = self.oracle(clamp, directional);
        let mut image = vpl_image.clone();
        let mut sun = vec![0.0f32; image.len()];
        let mut column = vec![0.0f32; image.len()];
        for j in vpls.len()..full.cols() {
            full.eval_col(j, &mut column).expect("directional column");
            for (r, &c) in image.iter_mut().zip(&column) {
                *r += c;
            }
            if j == vpls.len() {
                sun.copy_from_slice(&column);
            }
        }
        Reference {
            image,
            vpl_image,
            sun,
        }
    }

    /// The VPL oracle of this scene at `clamp` (shadow rays offset by 1e-4, as in every sweep)
    /// with the `directional` columns after the VPL ones. Panics on non-finite input.
    pub fn oracle<'a>(&'a self, clamp: f32, directional: &'a [DirectionalLight]) -> VplOracle<'a> {
        VplOracle::new(&self.tracer, &self.gbuffer, &self.vpls, clamp, 1e-4)
            .and_then(|o| o.with_directional(directional))
            .expect("finite input")
    }

    /// The default sun and 1024 sky directions as directional lights, the sun first.
    pub fn sun_sky(&self) -> Vec<DirectionalLight> {
        directional_lights(&self.scene, &SunAndUniformSky::default(), 1024)
            .expect("non-empty scene")
    }
}

/// About `target` VPLs (two bounces, seed 1): a pilot run of 2000 particles measures VPLs per
/// particle. Panics on a scene without lights (a sweep's setup error).
fn trace_about(scene: &Scene, tracer: &RayTracer, target: usize) -> Vec<Vpl> {
    let options = |particles| VplOptions {
        particles,
        max_bounces: 2,
        seed: 1,
        ..Default::default()
    };
    let pilot = trace_vpls(scene, tracer, &options(2000), &NoProgress).expect("lit scene");
    let per_particle = (pilot.len() as f64 / 2000.0).max(0.1);
    let particles = (target as f64 / per_particle).round().max(1.0) as usize;
    trace_vpls(scene, tracer, &options(particles), &NoProgress).expect("lit scene")
}

/// Writes `reference | panels…` side by side (square RGB images of `width`), tone-mapped with
/// one exposure (99th percentile of the reference at 0.8) and sRGB gamma; reports failure on
/// stderr instead of stopping the sweep.
pub fn write_strip(path: &Path, width: usize, reference: &[f32], panels: &[Vec<f32>]) {
    let mut sorted: Vec<f32> = reference.to_vec();
    sorted.sort_by(f32::total_cmp);
    let exposure = 0.8 / sorted[(sorted.len() * 99) / 100].max(1e-12);
    let tone = |v: f32| ((v * exposure).clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8;
    let panels: Vec<&[f32]> = std::iter::once(reference)
        .chain(panels.iter().map(Vec::as_slice))
        .collect();
    let mut out = image::RgbImage::new((panels.len() * width) as u32, width as u32);
    for (k, panel) in panels.iter().enumerate() {
        for y in 0..width {
            for x in 0..width {
                let p = 3 * (y * width + x);
                let rgb = [tone(panel[p]), tone(panel[p + 1]), tone(panel[p + 2])];
                out.put_pixel((k * width + x) as u32, y as u32, image::Rgb(rgb));
            }
        }
    }
    match save_png(&out, path) {
        Ok(()) => println!("wrote {}", path.display()),
        Err(e) => eprintln!("could not write {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budgets_parse_and_print_as_rows_slash_columns() {
        let budget: Budget = "300/900".parse().expect("valid");
        assert_eq!(budget, Budget::new(300, 900));
        assert_eq!(budget.to_string(), "300/900");
        assert!("300".parse::<Budget>().is_err());
        assert!("300/x".parse::<Budget>().is_err());
    }

    #[test]
    fn mean_and_max_of_seed_errors() {
        assert_eq!(mean_and_max(&[0.25, 0.75]), (0.5, 0.75));
        assert_eq!(mean_and_max(&[]), (0.0, 0.0));
    }
}

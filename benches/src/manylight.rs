//! Helpers shared by the many-light sweeps: the budget list, the scene set-up (VPLs traced to a
//! target count, G-buffer), the cached brute-force reference and image strips.

use std::path::{Path, PathBuf};

use prt_core::{CoreError, MatrixOracle, NoProgress};
use prt_manylight::{GatherGeometry, SliceOracle, VisibilityOracle};
use prt_trace::{
    DirectionalLight, GBuffer, LoadOptions, PinholeView, RayTracer, Scene, SunSky, Vpl, VplOptions,
    VplOracle, directional_lights, trace_vpls,
};
use rayon::prelude::*;

/// prt-trace's VPL oracle with the G-buffer's geometry, for LightSlice and visibility
/// clustering.
pub struct SceneOracle<'a> {
    /// The VPL oracle.
    pub inner: VplOracle<'a>,
    /// The G-buffer it was built on (its gather points).
    pub gbuffer: &'a GBuffer,
}

impl MatrixOracle for SceneOracle<'_> {
    fn rows(&self) -> usize {
        self.inner.rows()
    }
    fn cols(&self) -> usize {
        self.inner.cols()
    }
    fn channels(&self) -> usize {
        3
    }
    fn eval_row(&self, i: usize, out: &mut [f32]) -> Result<(), CoreError> {
        self.inner.eval_row(i, out)
    }
    fn eval_col(&self, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        self.inner.eval_col(j, out)
    }
    fn elements_evaluated(&self) -> u64 {
        self.inner.elements_evaluated()
    }
}

impl SliceOracle for SceneOracle<'_> {
    fn eval_col_rows(&self, j: usize, rows: &[usize], out: &mut [f32]) -> Result<(), CoreError> {
        out.par_chunks_mut(3)
            .zip(rows.par_iter())
            .with_min_len(64)
            .try_for_each(|(o, &i)| {
                o.copy_from_slice(&self.inner.element(i, j)?.to_array());
                Ok(())
            })
    }

    fn gather_point(&self, i: usize) -> Option<GatherGeometry> {
        let g = self.gbuffer.points.get(i).copied().flatten()?;
        Some(GatherGeometry {
            position: g.position.to_array(),
            normal: g.normal.to_array(),
        })
    }
}

impl VisibilityOracle for SceneOracle<'_> {
    fn shading(&self, i: usize, j: usize, out: &mut [f32]) -> Result<(), CoreError> {
        out.copy_from_slice(&self.inner.shading(i, j)?.to_array());
        Ok(())
    }
    fn visibility(&self, i: usize, j: usize) -> Result<f32, CoreError> {
        Ok(if self.inner.visible(i, j)? { 1.0 } else { 0.0 })
    }
}

/// The (rows, columns) budgets of the sweep, from 100/200 to 900/1800 (300/900 is the
/// paper's; 432/864 and 400/1300 sit near 50x fewer elements at 256²).
pub const BUDGETS: [(usize, usize); 6] = [
    (100, 200),
    (300, 900),
    (432, 864),
    (400, 1300),
    (600, 1200),
    (900, 1800),
];

/// A sweep's positional arguments (after the program name), each read with a default.
pub struct Args(Vec<String>);

impl Args {
    /// The arguments this process was started with.
    pub fn from_env() -> Self {
        Self(std::env::args().skip(1).collect())
    }

    /// Argument `index` as given, if it was.
    pub fn text(&self, index: usize) -> Option<&str> {
        self.0.get(index).map(String::as_str)
    }

    /// Argument `index` parsed, or `default` when it is absent or does not parse.
    pub fn parsed<T: std::str::FromStr>(&self, index: usize, default: T) -> T {
        self.text(index)
            .and_then(|a| a.parse().ok())
            .unwrap_or(default)
    }

    /// Argument `index` as one `rows/columns` budget, or `default`.
    pub fn budget(&self, index: usize, default: (usize, usize)) -> (usize, usize) {
        self.text(index)
            .and_then(|b| b.split_once('/'))
            .and_then(|(r, c)| Some((r.parse().ok()?, c.parse().ok()?)))
            .unwrap_or(default)
    }
}

/// Parses a comma-separated `rows/columns` list (`300/900,432/864`; malformed entries are
/// skipped); no list gives [`BUDGETS`].
pub fn parse_budgets(list: Option<&str>) -> Vec<(usize, usize)> {
    match list {
        Some(list) => list
            .split(',')
            .filter_map(|b| {
                let (r, c) = b.split_once('/')?;
                Some((r.parse().ok()?, c.parse().ok()?))
            })
            .collect(),
        None => BUDGETS.to_vec(),
    }
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

/// The scene of a sweep by name: `cornell` (built in) or `sponza` (`../shared/scenes/sponza`,
/// relative to the benches' `manifest` directory). `None`, with the reason on stderr, when it is
/// unknown or cannot be loaded.
fn load_scene(name: &str) -> Option<Scene> {
    match name {
        "cornell" => Some(Scene::cornell_box()),
        "sponza" => {
            let path = benches_dir().join("../../shared/scenes/sponza/Sponza.gltf");
            Scene::load_gltf(&path, &LoadOptions::default())
                .map_err(|e| eprintln!("skipping Sponza: {e}"))
                .ok()
        }
        other => {
            eprintln!("unknown scene {other} (cornell or sponza)");
            None
        }
    }
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
        let scene = load_scene(name)?;
        let tracer = RayTracer::new(scene.triangles());
        let vpls = trace_about(&scene, &tracer, target);
        let view = PinholeView::for_scene(&scene).expect("non-empty scene");
        let gbuffer = GBuffer::render(&scene, &tracer, &view, width, width).expect("valid size");
        let cache_stem = benches_dir().join(format!(
            "../target/manylight_cache/{name}_{width}_{}",
            vpls.len()
        ));
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
        directional_lights(&self.scene, &SunSky::default(), 1024).expect("non-empty scene")
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

/// The benches package's folder (the scenes and the cache are found relative to it).
fn benches_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
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
    match out.save(path) {
        Ok(()) => println!("wrote {}", path.display()),
        Err(e) => eprintln!("could not write {}: {e}", path.display()),
    }
}

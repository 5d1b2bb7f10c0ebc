//! `prt manylight`: a scene lit by thousands of point lights (VPLs traced from its sky, sun and
//! emitters, or a lights file), rendered with prt-manylight's matrix sampling methods against
//! brute force.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use prt_core::glam::{Quat, Vec3};
use prt_core::{CoreError, MatrixOracle, Progress};
use prt_manylight::{
    LightSliceConfig, RowColumnConfig, TensorConfig, VisibilityClusterMethod, VisibilityConfig,
    light_slice, row_column_sampling, tensor_clustering, visibility_clustering,
};
use prt_render::{Rendered, ToneMap, image_metrics};
use prt_trace::camera::{GBuffer, PinholeView};
use prt_trace::manylight::{
    DirectionalLight, LightsBudget, SunAndUniformSky, Vpl, VplOptions, VplOracle,
    directional_lights, read_lights_file, trace_vpls, write_lights_file,
};
use prt_trace::{LoadOptions, RayTracer, Scene};

use crate::progress::StageBar;
use crate::render::{format_of, pick_view, save_render};

/// A many-light method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// Every pixel against every light: the exact image.
    Brute,
    /// Row-column sampling (Hašan, Pellacini and Bala 2007).
    Rowcol,
    /// LightSlice (Ou and Pellacini 2011): slices of similar pixels, a clustering per slice.
    Lightslice,
    /// Visibility clustering: shading from every light, visibility from one light per cluster.
    Visibility,
    /// Tensor clustering over the frames of an animation (MRCS, Hašan et al. 2008).
    Mrcs,
}

impl MethodArg {
    /// Every method, in the order `--compare` shows them.
    const ALL: [MethodArg; 5] = [
        MethodArg::Brute,
        MethodArg::Rowcol,
        MethodArg::Lightslice,
        MethodArg::Visibility,
        MethodArg::Mrcs,
    ];

    fn name(self) -> &'static str {
        match self {
            MethodArg::Brute => "brute",
            MethodArg::Rowcol => "rowcol",
            MethodArg::Lightslice => "lightslice",
            MethodArg::Visibility => "visibility",
            MethodArg::Mrcs => "mrcs",
        }
    }
}

/// How visibility clustering groups the lights.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ClusteringArg {
    /// Divisive: the cluster of largest visibility error split along random projections.
    Divisive,
    /// The divisive clustering refined by --kmeans-iterations rounds of weighted k-means.
    Kmeans,
}

/// What moves over the frames of an animation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PathArg {
    /// The camera orbits the point it looks at, ±15° about the vertical.
    Camera,
    /// The lights move as one rig: every point light translates along the view's horizontal
    /// right axis by ±10 % of the scene's horizontal extent, and every directional light turns
    /// ±30° about the vertical.
    Light,
}

/// Options of `prt manylight`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Each pixel traces one primary ray; its colour is the sum over the lights of \
albedo/π · (the light's irradiance there) with one shadow ray per light and pixel, plus what an \
emitter seen directly emits. Traced lights: particles leave the scene's emitters (or, without \
any, a default sun and sky) and leave a VPL on the emitter and one at their first bounce; the \
direct light of the sun and sky enters as directional lights (--sky-directions). The 1/d² \
falloff is clamped at --clamp. Errors are against brute force over the lit image (emitters' own \
radiance excluded): relative L2 = sqrt(Σ (est − ref)² / Σ ref²), and ꟻLIP of the tone-mapped \
images. When brute force would evaluate more than --max-brute-elements, its time and the L2 \
error are estimated from --sample-pixels pixels (said so). PNG output is tone-mapped as by \
`prt render` (exposure, ACES filmic, sRGB); EXR holds linear radiance. Frames of an animation \
go to OUT with _NNNN before the extension."
)]
pub struct ManyLightArgs {
    /// glTF 2.0 scene; the built-in Cornell box when omitted.
    pub scene: Option<PathBuf>,
    /// About this many VPLs, traced from the scene's emitters, or its sun and sky.
    #[arg(long, default_value_t = 10_000, value_name = "N")]
    pub lights: usize,
    /// Read the lights from FILE instead of tracing them: one per line, `x y z  nx ny nz  r g b`
    /// (position, normal or 0 0 0 for an isotropic light, power in linear RGB), `#` comments.
    #[arg(long, value_name = "FILE", conflicts_with = "lights")]
    pub lights_file: Option<PathBuf>,
    /// Also write the lights used (first frame) as a lights file.
    #[arg(long, value_name = "FILE")]
    pub save_lights: Option<PathBuf>,
    /// The method that renders OUT.
    #[arg(long, value_enum, default_value_t = MethodArg::Rowcol)]
    pub method: MethodArg,
    /// Visibility clustering's clusters: divisive, or refined by k-means.
    #[arg(long, value_enum, default_value_t = ClusteringArg::Divisive)]
    pub clustering: ClusteringArg,
    /// Lloyd iterations of --clustering kmeans.
    #[arg(long, default_value_t = 4, value_name = "N")]
    pub kmeans_iterations: usize,
    /// Sampled rows (pixels) per frame; LightSlice's slices.
    #[arg(long, default_value_t = 300, value_name = "N")]
    pub rows: usize,
    /// Sampled columns (clusters) per frame; LightSlice's clusters per slice.
    #[arg(long, default_value_t = 900, value_name = "N")]
    pub columns: usize,
    /// View: the scene's glTF cameras in file order, then the automatic `front` and `inside`
    /// views of `prt render`. 0 is the first.
    #[arg(long, default_value_t = 0)]
    pub camera: usize,
    /// Width and height of the image, in pixels.
    #[arg(long, default_value_t = 256, value_name = "PIXELS")]
    pub size: usize,
    /// Frames of an animation along --path (tensor clustering shares its clusters over them;
    /// the other methods render frame by frame).
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub frames: usize,
    /// What moves over the frames.
    #[arg(long, value_enum, default_value_t = PathArg::Camera)]
    pub path: PathArg,
    /// Clamp distance of the 1/d² falloff [default: 2.5 % of the scene's bounding-box diagonal].
    #[arg(long, value_name = "DISTANCE")]
    pub clamp: Option<f32>,
    /// Directions the sky is split into (scenes lit by the default sun and sky).
    #[arg(long, default_value_t = 256, value_name = "N")]
    pub sky_directions: usize,
    /// Seed of the VPLs and of the methods' random choices.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Render every method, print a table and write OUT's stem + `_compare.png`: the methods
    /// side by side (brute, rowcol, lightslice, visibility, mrcs) over their 10× absolute
    /// differences from brute force (the middle frame).
    #[arg(long)]
    pub compare: bool,
    /// Above this many elements (pixels × lights × frames) brute force is estimated from
    /// --sample-pixels pixels instead of run (not with --method brute or --compare).
    #[arg(long, default_value_t = 2e8, value_name = "N")]
    pub max_brute_elements: f64,
    /// Pixels per frame whose full row estimates brute force's time and the error.
    #[arg(long, default_value_t = 512, value_name = "N")]
    pub sample_pixels: usize,
    /// Refuse to start when the estimated memory exceeds this many GiB.
    #[arg(long, default_value_t = 4.0, value_name = "GIB")]
    pub max_memory: f64,
    /// Exposure of the PNGs [default: `prt render`'s automatic one, from the reference].
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Output image: .png (tone-mapped sRGB) or .exr (linear radiance, f32).
    #[arg(long)]
    pub out: PathBuf,
}

/// Largest `--size`.
const MAX_SIZE: usize = 4096;
/// Largest `--frames`.
const MAX_FRAMES: usize = 1000;
/// Bytes per pixel and frame beside the lights: gather point, emission, images of the methods.
const BYTES_PER_PIXEL: u64 = 64 + 5 * 12;
/// Lights file and `--lights` at most (the oracle indexes lights with u32 in its clusters).
const MAX_LIGHTS: usize = u32::MAX as usize / 2;

/// The lights of one frame.
struct FrameLights {
    vpls: Vec<Vpl>,
    directional: Vec<DirectionalLight>,
}

/// One method's frames (RGB per pixel, lit part only), elements and wall time.
struct MethodRun {
    method: MethodArg,
    images: Vec<Vec<f32>>,
    elements: u64,
    seconds: f64,
    /// Light and time splits of tensor clustering.
    splits: Option<(usize, usize)>,
}

/// Brute force: full images, or rows of sampled pixels with the time extrapolated.
enum Reference {
    Full(MethodRun),
    Sampled {
        /// Per frame: (pixel, its RGB).
        pixels: Vec<Vec<(usize, [f32; 3])>>,
        /// The extrapolated wall time of full brute force.
        seconds: f64,
        elements: u64,
    },
}

impl Reference {
    fn seconds(&self) -> f64 {
        match self {
            Reference::Full(run) => run.seconds,
            Reference::Sampled { seconds, .. } => *seconds,
        }
    }

    fn elements(&self) -> u64 {
        match self {
            Reference::Full(run) => run.elements,
            Reference::Sampled { elements, .. } => *elements,
        }
    }

    /// Relative L2 error of `images` over every pixel, or over the sampled ones.
    fn relative_l2(&self, images: &[Vec<f32>]) -> f64 {
        let (mut diff, mut norm) = (0.0f64, 0.0f64);
        let mut add = |est: f32, exact: f32| {
            diff += (f64::from(est) - f64::from(exact)).powi(2);
            norm += f64::from(exact).powi(2);
        };
        match self {
            Reference::Full(run) => {
                for (a, b) in images.iter().zip(&run.images) {
                    a.iter().zip(b).for_each(|(&e, &r)| add(e, r));
                }
            }
            Reference::Sampled { pixels, .. } => {
                for (image, sampled) in images.iter().zip(pixels) {
                    for &(p, rgb) in sampled {
                        (0..3).for_each(|c| add(image[3 * p + c], rgb[c]));
                    }
                }
            }
        }
        (diff / norm.max(f64::MIN_POSITIVE)).sqrt()
    }
}

pub fn run(args: &ManyLightArgs) -> Result<()> {
    format_of(&args.out)?;
    check_args(args)?;
    let scene = match &args.scene {
        Some(path) => Scene::load_gltf(path, &LoadOptions::default())
            .with_context(|| format!("cannot load {}", path.display()))?,
        None => Scene::cornell_box(),
    };
    let bounds = scene.bounds().context("the scene has no triangles")?;
    let diagonal = bounds.size().length();
    let clamp = args.clamp.unwrap_or(0.025 * diagonal);
    let view = pick_view(&scene, args.camera)?;
    let tracer = RayTracer::new(scene.triangles());
    let frames = args.frames;
    let pixels = args.size * args.size;

    // Memory: per light the VPL and a reduced column of the sampled rows (every frame's, for
    // tensor clustering); per pixel the gather point and the methods' images.
    let per_light = std::mem::size_of::<Vpl>() as u64
        + 12 * args.rows as u64 * frames as u64
        + if args.path == PathArg::Light {
            std::mem::size_of::<Vpl>() as u64 * (frames as u64 - 1)
        } else {
            0
        };
    let budget = (args.max_memory * (1u64 << 30) as f64) as u64;
    let fixed = BYTES_PER_PIXEL * pixels as u64 * frames as u64;
    let lights_budget =
        LightsBudget::new(budget.saturating_sub(fixed)).with_bytes_per_light(per_light);
    if args.lights_file.is_none() {
        let need = fixed + per_light * args.lights as u64;
        if need > budget {
            bail!(
                "{} lights at {} × {} pixels × {frames} frame(s) need about {:.2} GiB, over \
                 --max-memory {} GiB",
                args.lights,
                args.size,
                args.size,
                need as f64 / (1u64 << 30) as f64,
                args.max_memory
            );
        }
    }

    let stage = StageBar::start("lights");
    let (vpls, directional, origin) = match &args.lights_file {
        Some(path) => {
            let vpls = read_lights_file(path, &lights_budget)
                .with_context(|| format!("cannot read the lights file {}", path.display()))?;
            (vpls, Vec::new(), "from the lights file")
        }
        None => {
            let vpls = trace_about(&scene, &tracer, args.lights, args.seed, &stage)?;
            let sky =
                directional_lights(&scene, &SunAndUniformSky::default(), args.sky_directions)?;
            (vpls, sky, "traced, one bounce")
        }
    };
    stage.finish();
    if let Some(path) = &args.save_lights {
        write_lights_file(path, &vpls)?;
        println!("wrote {}", path.display());
    }
    if vpls.len() > MAX_LIGHTS {
        bail!("{} lights: at most {MAX_LIGHTS} are supported", vpls.len());
    }
    let lights_count = vpls.len() + directional.len();
    if args.columns > lights_count && needs_budget(args) {
        bail!(
            "--columns {} is more than the {lights_count} lights",
            args.columns
        );
    }

    let frame_views = camera_path(&view.view, &tracer, &bounds, args.path, frames);
    let frame_lights = light_path(vpls, directional, &view.view, &bounds, args.path, frames);
    let stage = StageBar::start("G-buffer");
    stage.set_len(frames as u64);
    let gbuffers = frame_views
        .iter()
        .map(|v| {
            let g = GBuffer::render(&scene, &tracer, v, args.size, args.size);
            stage.inc(1);
            g
        })
        .collect::<Result<Vec<_>, _>>()?;
    stage.finish();
    let oracles = gbuffers
        .iter()
        .enumerate()
        .map(|(t, gbuffer)| {
            let lights = &frame_lights[t.min(frame_lights.len() - 1)];
            let inner = VplOracle::new(&tracer, gbuffer, &lights.vpls, clamp, 1e-4 * diagonal)?
                .with_directional(&lights.directional)?;
            Ok(inner)
        })
        .collect::<Result<Vec<_>, CoreError>>()?;

    println!(
        "{}: {} × {} pixels, {frames} frame(s){}, camera {} ({}), {} lights ({} VPLs {origin} \
         + {} directional), clamp {clamp:.4}, {} threads",
        args.scene
            .as_deref()
            .map_or("built-in Cornell box".into(), |p| p.display().to_string()),
        args.size,
        args.size,
        if frames > 1 {
            format!(" along a {} path", path_name(args.path))
        } else {
            String::new()
        },
        args.camera,
        view.name,
        lights_count,
        frame_lights[0].vpls.len(),
        frame_lights[0].directional.len(),
        rayon::current_num_threads(),
    );

    let methods: Vec<MethodArg> = if args.compare {
        MethodArg::ALL.to_vec()
    } else {
        vec![args.method]
    };
    let brute_elements = (pixels * lights_count * frames) as u64;
    let full_brute =
        methods.contains(&MethodArg::Brute) || brute_elements as f64 <= args.max_brute_elements;
    let reference = if full_brute {
        Reference::Full(run_method(MethodArg::Brute, &oracles, args)?)
    } else {
        sampled_brute_force(&oracles, args.sample_pixels)?
    };
    let mut runs = Vec::new();
    for &method in &methods {
        if method == MethodArg::Brute {
            continue;
        }
        runs.push(run_method(method, &oracles, args)?);
    }
    let emission: Vec<Vec<[f32; 3]>> = gbuffers.iter().map(emission_of).collect();
    let shown = |images: &[Vec<f32>]| -> Vec<Rendered> {
        images
            .iter()
            .zip(&gbuffers)
            .zip(&emission)
            .map(|((image, g), e)| rendered(image, g, e))
            .collect()
    };
    let reference_shown = match &reference {
        Reference::Full(run) => Some(shown(&run.images)),
        Reference::Sampled { .. } => None,
    };

    // Report: time, speed-up, elements and error of every method.
    let (measured, how) = match &reference {
        Reference::Full(_) => (true, "measured".to_string()),
        Reference::Sampled { pixels, .. } => (
            false,
            format!(
                "estimated from {} sampled pixels per frame",
                pixels.first().map_or(0, Vec::len)
            ),
        ),
    };
    println!(
        "brute force: {:.3} s ({how}), {:.3e} elements",
        reference.seconds(),
        reference.elements() as f64
    );
    if args.compare {
        println!(
            "\n| method | time | speed-up vs brute force ({how}) | elements | relative L2 error \
             | ꟻLIP | light / time splits |\n|---|---|---|---|---|---|---|"
        );
    }
    let tone = args.exposure.map(|exposure| ToneMap { exposure });
    let tone = tone.unwrap_or_else(|| match &reference_shown {
        Some(frames) => ToneMap::auto(&frames[frames.len() / 2]),
        None => ToneMap::auto(&shown(&runs[0].images)[runs[0].images.len() / 2]),
    });
    let mut out_images: Option<Vec<Rendered>> = None;
    let mut strip: Vec<(Rendered, Option<Rendered>)> = Vec::new();
    if let (true, Some(frames_shown)) = (args.compare, &reference_shown) {
        strip.push((frames_shown[frames_shown.len() / 2].clone(), None));
    }
    if args.method == MethodArg::Brute {
        out_images = reference_shown.clone();
    }
    for run in &runs {
        let error = reference.relative_l2(&run.images);
        let frames_shown = shown(&run.images);
        let flip = match &reference_shown {
            Some(base) => {
                let mut sum = 0.0;
                for (b, s) in base.iter().zip(&frames_shown) {
                    sum += image_metrics(b, s, &tone)?.flip;
                }
                Some(sum / base.len() as f64)
            }
            None => None,
        };
        let speedup = reference.seconds() / run.seconds.max(1e-9);
        let splits = run
            .splits
            .map_or("-".to_string(), |(l, t)| format!("{l} / {t}"));
        let flip_text = flip.map_or("- (needs full brute force)".to_string(), |f| {
            format!("{f:.4}")
        });
        if args.compare {
            println!(
                "| {} | {:.3} s | {speedup:.1}× | {:.3e} | {:.2} % | {flip_text} | {splits} |",
                run.method.name(),
                run.seconds,
                run.elements as f64,
                100.0 * error
            );
        } else {
            println!(
                "{} {}/{}: {:.3} s, speed-up {speedup:.1}× against brute force ({how}), {:.3e} \
                 elements ({:.1}× fewer); relative L2 error {:.2} %{}, ꟻLIP {flip_text}{}",
                run.method.name(),
                args.rows,
                args.columns,
                run.seconds,
                run.elements as f64,
                brute_elements as f64 / run.elements.max(1) as f64,
                100.0 * error,
                if measured {
                    ""
                } else {
                    " (on the sampled pixels)"
                },
                run.splits.map_or(String::new(), |(l, t)| format!(
                    "; {l} light and {t} time splits"
                )),
            );
        }
        if let Some(base) = &reference_shown {
            let middle = frames_shown.len() / 2;
            let difference = difference(&base[middle], &frames_shown[middle]);
            strip.push((frames_shown[middle].clone(), Some(difference)));
        }
        if run.method == args.method {
            out_images = Some(frames_shown);
        }
    }
    let out_images = out_images.context("the method of --out was not run")?;
    for (t, image) in out_images.iter().enumerate() {
        let path = frame_path(&args.out, t, frames);
        save_render(&path, image, &tone)?;
        if t == 0 || t + 1 == frames {
            println!("wrote {}", path.display());
        }
    }
    if args.compare {
        let path = sibling(&args.out, "_compare.png");
        save_strip(&path, &strip, &tone)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

fn check_args(args: &ManyLightArgs) -> Result<()> {
    if !(1..=MAX_SIZE).contains(&args.size) {
        bail!("--size {} is not in 1..={MAX_SIZE}", args.size);
    }
    if !(1..=MAX_FRAMES).contains(&args.frames) {
        bail!("--frames {} is not in 1..={MAX_FRAMES}", args.frames);
    }
    if !(1..=MAX_LIGHTS).contains(&args.lights) {
        bail!("--lights {} is not in 1..={MAX_LIGHTS}", args.lights);
    }
    if args.rows == 0 || args.columns == 0 || args.sample_pixels == 0 {
        bail!("--rows, --columns and --sample-pixels must be at least 1");
    }
    if needs_budget(args) && args.rows > args.size * args.size {
        bail!(
            "--rows {} is more than the {} pixels of a frame",
            args.rows,
            args.size * args.size
        );
    }
    if let Some(c) = args.clamp
        && !(c.is_finite() && c >= 0.0)
    {
        bail!("--clamp {c} is not a non-negative distance");
    }
    if let Some(e) = args.exposure
        && !(e.is_finite() && e > 0.0)
    {
        bail!("--exposure {e} is not a positive number");
    }
    if !(args.max_memory.is_finite() && args.max_memory > 0.0) {
        bail!(
            "--max-memory {} is not a positive number of GiB",
            args.max_memory
        );
    }
    if args.max_brute_elements.is_nan() || args.max_brute_elements < 0.0 {
        bail!("--max-brute-elements must be a non-negative number");
    }
    Ok(())
}

/// Whether a sampling method runs (rows and columns matter).
fn needs_budget(args: &ManyLightArgs) -> bool {
    args.compare || args.method != MethodArg::Brute
}

fn path_name(path: PathArg) -> &'static str {
    match path {
        PathArg::Camera => "camera",
        PathArg::Light => "light",
    }
}

/// `path` with `suffix` in place of its extension (`out.png` → `out_compare.png`).
fn sibling(path: &Path, suffix: &str) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned());
    path.with_file_name(format!("{}{suffix}", stem.unwrap_or_default()))
}

/// Frame `t`'s file: `path` itself for a single frame, else `stem_NNNN.ext`.
fn frame_path(path: &Path, t: usize, frames: usize) -> PathBuf {
    if frames == 1 {
        return path.to_owned();
    }
    let extension = path
        .extension()
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_default();
    sibling(path, &format!("_{t:04}.{extension}"))
}

/// About `target` VPLs with one bounce: a pilot run of up to 2000 particles measures VPLs per
/// particle.
fn trace_about(
    scene: &Scene,
    tracer: &RayTracer,
    target: usize,
    seed: u64,
    progress: &dyn Progress,
) -> Result<Vec<Vpl>> {
    let options = |particles| VplOptions {
        particles,
        max_bounces: 1,
        seed,
        ..Default::default()
    };
    let pilot_particles = target.clamp(1, 2000);
    let pilot = trace_vpls(scene, tracer, &options(pilot_particles), progress)?;
    if pilot.is_empty() {
        bail!("no light reaches the scene's surfaces: no VPL was traced");
    }
    let per_particle = pilot.len() as f64 / pilot_particles as f64;
    let particles = (target as f64 / per_particle).round().max(1.0) as usize;
    Ok(trace_vpls(scene, tracer, &options(particles), progress)?)
}

/// The views of `--path camera` (the same view in every frame otherwise): the eye orbits the
/// point the view's centre ray hits (the bounds' centre if it misses), ±15° about +Y.
fn camera_path(
    view: &PinholeView,
    tracer: &RayTracer,
    bounds: &prt_core::Aabb,
    path: PathArg,
    frames: usize,
) -> Vec<PinholeView> {
    if path != PathArg::Camera || frames == 1 {
        return vec![*view; frames];
    }
    let focus = tracer
        .closest_hit(view.position, view.forward, 0.0, f32::INFINITY)
        .map_or(bounds.centre(), |h| view.position + view.forward * h.t);
    (0..frames)
        .map(|t| {
            let angle = (t as f32 / (frames - 1) as f32 - 0.5) * 30f32.to_radians();
            let turn = Quat::from_rotation_y(angle);
            let position = focus + turn * (view.position - focus);
            let forward = (turn * view.forward).normalize();
            let up = (turn * view.up).normalize();
            PinholeView {
                position,
                forward,
                up,
                yfov: view.yfov,
            }
        })
        .collect()
}

/// The lights of every frame: one set for a still or a camera path; for `--path light`, the
/// rig moved in each frame (see [`PathArg::Light`]).
fn light_path(
    vpls: Vec<Vpl>,
    directional: Vec<DirectionalLight>,
    view: &PinholeView,
    bounds: &prt_core::Aabb,
    path: PathArg,
    frames: usize,
) -> Vec<FrameLights> {
    if path != PathArg::Light || frames == 1 {
        return vec![FrameLights { vpls, directional }];
    }
    let right = view.forward.cross(Vec3::Y);
    let right = Vec3::new(right.x, 0.0, right.z).normalize_or(Vec3::X);
    let size = bounds.size();
    let extent = (right.x * size.x).abs() + (right.z * size.z).abs();
    (0..frames)
        .map(|t| {
            let s = t as f32 / (frames - 1) as f32 - 0.5;
            let shift = right * (0.2 * extent * s);
            let turn = Quat::from_rotation_y(s * 60f32.to_radians());
            FrameLights {
                vpls: vpls
                    .iter()
                    .map(|v| Vpl {
                        position: v.position + shift,
                        ..*v
                    })
                    .collect(),
                directional: directional
                    .iter()
                    .map(|d| DirectionalLight {
                        direction: turn * d.direction,
                        ..*d
                    })
                    .collect(),
            }
        })
        .collect()
}

/// Runs `method` on every frame (tensor clustering on all at once).
fn run_method(
    method: MethodArg,
    oracles: &[VplOracle<'_>],
    args: &ManyLightArgs,
) -> Result<MethodRun> {
    let stage = StageBar::start(method.name());
    let start = Instant::now();
    let (rows, columns) = (args.rows, args.columns);
    let mut elements = 0u64;
    let mut splits = None;
    let images = if method == MethodArg::Mrcs {
        let frames: Vec<&dyn MatrixOracle> =
            oracles.iter().map(|o| o as &dyn MatrixOracle).collect();
        let config = TensorConfig::new(rows, columns).with_seed(args.seed);
        let e = tensor_clustering(&frames, &config, &stage)?;
        elements = e.elements;
        splits = Some((e.light_splits, e.time_splits));
        e.images
    } else {
        let mut images = Vec::with_capacity(oracles.len());
        for (t, oracle) in oracles.iter().enumerate() {
            if oracles.len() > 1 {
                stage.message(&format!("frame {}/{}", t + 1, oracles.len()));
            }
            let seed = args.seed.wrapping_mul(1000).wrapping_add(t as u64);
            let (image, e) = match method {
                MethodArg::Brute => {
                    let image = oracle.reference_image(&stage)?;
                    (image, (oracle.rows() * oracle.cols()) as u64)
                }
                MethodArg::Rowcol => {
                    let config = RowColumnConfig::new(rows, columns).with_seed(seed);
                    let e = row_column_sampling(oracle, &config, &stage)?;
                    (e.image, e.elements)
                }
                MethodArg::Lightslice => {
                    let config = LightSliceConfig::new(rows, columns).with_seed(seed);
                    let e = light_slice(oracle, &config, &stage)?;
                    (e.image, e.elements)
                }
                MethodArg::Visibility => {
                    let mut config = VisibilityConfig::new(rows, columns).with_seed(seed);
                    if args.clustering == ClusteringArg::Kmeans {
                        config = config.with_method(VisibilityClusterMethod::KMeans {
                            iterations: args.kmeans_iterations,
                        });
                    }
                    let e = visibility_clustering(oracle, &config, &stage)?;
                    (e.image, e.elements)
                }
                MethodArg::Mrcs => unreachable!("tensor clustering runs on all frames above"),
            };
            elements += e;
            images.push(image);
        }
        images
    };
    let seconds = start.elapsed().as_secs_f64();
    stage.finish();
    Ok(MethodRun {
        method,
        images,
        elements,
        seconds,
        splits,
    })
}

/// Brute force on `per_frame` pixels of every frame (spread evenly over the image), its time
/// extrapolated to every pixel.
fn sampled_brute_force(oracles: &[VplOracle<'_>], per_frame: usize) -> Result<Reference> {
    let stage = StageBar::start("brute*");
    let total: usize = oracles.iter().map(|o| per_frame.min(o.rows())).sum();
    stage.set_len(total as u64);
    let start = Instant::now();
    let mut pixels = Vec::with_capacity(oracles.len());
    let mut elements = 0u64;
    for oracle in oracles {
        let (n, m) = (oracle.rows(), oracle.cols());
        let count = per_frame.min(n);
        let mut row = vec![0.0f32; 3 * m];
        let mut sampled = Vec::with_capacity(count);
        for k in 0..count {
            stage.check()?;
            // Centres of `count` equal strata of the pixels.
            let p = (2 * k + 1) * n / (2 * count);
            oracle.eval_row(p, &mut row)?;
            let mut sum = [0.0f64; 3];
            for rgb in row.chunks_exact(3) {
                (0..3).for_each(|c| sum[c] += f64::from(rgb[c]));
            }
            sampled.push((p, sum.map(|s| s as f32)));
            stage.inc(1);
        }
        pixels.push(sampled);
        elements += (n * m) as u64;
    }
    let measured = start.elapsed().as_secs_f64();
    stage.finish();
    let rows: usize = oracles.iter().map(|o| o.rows()).sum();
    Ok(Reference::Sampled {
        pixels,
        seconds: measured * rows as f64 / total.max(1) as f64,
        elements,
    })
}

/// What each pixel shows of an emitter seen directly.
fn emission_of(gbuffer: &GBuffer) -> Vec<[f32; 3]> {
    gbuffer
        .points
        .iter()
        .map(|g| g.map_or([0.0; 3], |g| g.emission.to_array()))
        .collect()
}

/// The displayed image: the lit image plus the emitters' own radiance.
fn rendered(image: &[f32], gbuffer: &GBuffer, emission: &[[f32; 3]]) -> Rendered {
    let pixels = image
        .chunks_exact(3)
        .zip(emission)
        .map(|(rgb, e)| [rgb[0] + e[0], rgb[1] + e[1], rgb[2] + e[2]])
        .collect();
    Rendered {
        width: gbuffer.width,
        height: gbuffer.height,
        pixels,
        hit: gbuffer.points.iter().map(Option::is_some).collect(),
        unlit: 0,
    }
}

/// Ten times the absolute difference of two images.
fn difference(reference: &Rendered, test: &Rendered) -> Rendered {
    let pixels = reference
        .pixels
        .iter()
        .zip(&test.pixels)
        .map(|(a, b)| std::array::from_fn(|c| 10.0 * (a[c] - b[c]).abs()))
        .collect();
    Rendered {
        pixels,
        ..reference.clone()
    }
}

/// The methods side by side, each over its difference image (black under the reference).
fn save_strip(path: &Path, panels: &[(Rendered, Option<Rendered>)], tone: &ToneMap) -> Result<()> {
    let Some((first, _)) = panels.first() else {
        bail!("nothing to compare");
    };
    let (w, h) = (first.width, first.height);
    let mut out = image::RgbImage::new((panels.len() * w) as u32, (2 * h) as u32);
    for (k, (image, diff)) in panels.iter().enumerate() {
        for (row, panel) in [Some(image), diff.as_ref()].into_iter().enumerate() {
            let Some(panel) = panel else { continue };
            let bytes = tone.apply(panel);
            for y in 0..h {
                for x in 0..w {
                    let p = 3 * (y * w + x);
                    let rgb = [bytes[p], bytes[p + 1], bytes[p + 2]];
                    out.put_pixel((k * w + x) as u32, (row * h + y) as u32, image::Rgb(rgb));
                }
            }
        }
    }
    crate::report::save_png(path, &out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_and_compare_paths_keep_the_folder_and_extension() {
        let out = Path::new("dir/img.png");
        assert_eq!(frame_path(out, 3, 1), PathBuf::from("dir/img.png"));
        assert_eq!(frame_path(out, 3, 10), PathBuf::from("dir/img_0003.png"));
        assert_eq!(
            sibling(out, "_compare.png"),
            PathBuf::from("dir/img_compare.png")
        );
        assert!(format_of(Path::new("a.EXR")).is_ok());
        assert!(format_of(Path::new("a.jpg")).is_err());
    }

    #[test]
    fn the_camera_orbit_keeps_the_focus_in_the_centre() {
        let scene = Scene::cornell_box();
        let tracer = RayTracer::new(scene.triangles());
        let bounds = scene.bounds().expect("triangles");
        let view = PinholeView::for_scene(&scene).expect("view");
        let views = camera_path(&view, &tracer, &bounds, PathArg::Camera, 5);
        assert!((views[2].position - view.position).length() < 1e-5);
        let hit = |v: &PinholeView| {
            let h = tracer
                .closest_hit(v.position, v.forward, 0.0, f32::INFINITY)
                .expect("hits the box");
            v.position + v.forward * h.t
        };
        let focus = hit(&view);
        for v in &views {
            assert!((hit(v) - focus).length() < 1e-3);
        }
        assert_ne!(views[0].position, views[4].position);
    }
}

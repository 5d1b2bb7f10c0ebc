//! Renders a glTF scene lit by the irradiance volume that `prt export --target bevy` wrote, or
//! the scene and irradiance lightmap that `prt lightmap --engine bevy` wrote.
//!
//! ```text
//! prt bake scene.gltf --out bake
//! prt export bake --target bevy --out bake/bevy
//! cargo run --release --manifest-path examples/bevy/Cargo.toml -- bake/bevy scene.gltf
//! # no display: an image instead of a window, then exit (software Vulkan will do)
//! cargo run --release --manifest-path examples/bevy/Cargo.toml -- bake/bevy scene.gltf \
//!     --screenshot shot.png
//! # a lightmap: EXPORT_DIR holds lightmap.json, the scene is the export's lightmap_scene.glb
//! prt lightmap scene.gltf --basis irradiance --engine bevy --out lm
//! cargo run --release --manifest-path examples/bevy/Cargo.toml -- lm/bevy
//! ```
//!
//! The volume is Bevy's own `IrradianceVolume` on a `LightProbe`, placed by the transform in
//! `irradiance_volume.json`; a lightmap is Bevy's own `Lightmap` component (default `uv_rect`,
//! sampling `UV_1`, which Bevy's glTF loader fills from `TEXCOORD_1`) added to every mesh entity
//! of the scene: nothing here decodes prt data. The scene has no other light and no
//! ambient light, tone mapping is off and the camera's exposure is EV100 = −log₂ 1.2, which
//! makes Bevy's exposure factor `2^−EV100 / 1.2` exactly 1: a pixel holds the radiance Bevy
//! computes, `albedo · volume · intensity` or `albedo · lightmap texel` (`E/π`), in the sky's
//! (or the emitters') units.
//!
//! Options (after the two paths):
//!
//! * `--view EX,EY,EZ,TX,TY,TZ,FOV`: the camera at the eye `E` looking at `T` with +Y up and a
//!   vertical field of view of `FOV` degrees (a view of `prt render --camera N`: the tests
//!   pass the one prt computes); without it the camera looks at the volume's (or the lightmapped
//!   scene's) centre from near its +Z face.
//! * `--screenshot PATH`: render without a window (no winit: an offscreen `Rgba16Float` image
//!   on whatever Vulkan adapter wgpu finds, e.g. Mesa's lavapipe), save it and exit. `.pfm`
//!   writes the linear RGB values (32-bit float Portable Float Map), `.png` writes them clamped
//!   to [0, 1] and sRGB-encoded, which is what the window shows.
//! * `--size W[xH]`: the screenshot's size in pixels (default 512, square).
//! * `--frames N`: with `--screenshot`, frames to render after the assets have loaded before
//!   capturing (default 5); it also waits until no render pipeline is still compiling, then
//!   captures until two captures in a row (N frames apart) agree bit for bit, so that a frame
//!   drawn before everything was ready is never saved.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use bevy::app::ScheduleRunnerPlugin;
use bevy::asset::{AssetPlugin, RecursiveDependencyLoadState, UnapprovedPathMode};
use bevy::camera::{Exposure, RenderTarget};
use bevy::core_pipeline::tonemapping::{DebandDither, Tonemapping};
use bevy::light::{GlobalAmbientLight, IrradianceVolume, LightProbe};
use bevy::pbr::Lightmap;
use bevy::prelude::*;
use bevy::render::render_resource::{PipelineCache, TextureFormat, TextureUsages};
use bevy::render::view::screenshot::{Screenshot, ScreenshotCaptured};
use bevy::render::{Render, RenderApp, RenderSystems};
use bevy::window::ExitCondition;
use bevy::winit::WinitPlugin;
use bevy::world_serialization::WorldAsset;

/// What the program was given: asset paths (relative to the file-system root, where the asset
/// server is rooted) and the volume's placement (for a lightmap, the box around the scene).
#[derive(Resource)]
struct Inputs {
    /// The irradiance volume's or the lightmap's texture.
    texture: String,
    /// Whether `texture` is a lightmap (`lightmap.json`) rather than a volume.
    lightmap: bool,
    scene: String,
    translation: Vec3,
    scale: Vec3,
    intensity: f32,
    /// Eye, target and vertical field of view (radians) of `--view`.
    view: Option<(Vec3, Vec3, f32)>,
}

/// The command line past the two paths.
struct Options {
    view: Option<(Vec3, Vec3, f32)>,
    screenshot: Option<PathBuf>,
    size: UVec2,
    frames: u32,
}

/// Bevy's exposure factor is `2^−ev100 / 1.2`; this EV100 makes it 1.
fn unit_exposure() -> Exposure {
    Exposure {
        ev100: -1.2f32.log2(),
    }
}

fn main() -> AppExit {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (inputs, options) = match parse(&args) {
        Ok(parsed) => parsed,
        Err(e) => {
            eprintln!("error: {e}");
            eprintln!(
                "usage: prt-bevy-example EXPORT_DIR [SCENE.gltf] [--view EX,EY,EZ,TX,TY,TZ,FOV] \
                 [--screenshot OUT.pfm|OUT.png] [--size W[xH]] [--frames N]"
            );
            return AppExit::error();
        }
    };
    let assets = AssetPlugin {
        file_path: "/".into(),
        unapproved_path_mode: UnapprovedPathMode::Allow,
        ..default()
    };
    let mut app = App::new();
    match options.screenshot {
        None => {
            app.add_plugins(DefaultPlugins.set(assets))
                .add_systems(Startup, setup_window_camera);
        }
        Some(path) => {
            // No window and no winit: frames are driven by the schedule runner.
            app.add_plugins(
                DefaultPlugins
                    .set(assets)
                    .set(WindowPlugin {
                        primary_window: None,
                        exit_condition: ExitCondition::DontExit,
                        close_when_requested: false,
                        ..default()
                    })
                    .disable::<WinitPlugin>(),
            )
            .add_plugins(ScheduleRunnerPlugin::run_loop(Duration::from_millis(1)));
            let waiting = Arc::new(AtomicUsize::new(usize::MAX));
            app.sub_app_mut(RenderApp)
                .insert_resource(WaitingPipelines(waiting.clone()))
                .add_systems(
                    Render,
                    count_waiting_pipelines.in_set(RenderSystems::Cleanup),
                );
            app.insert_resource(Capture {
                path,
                size: options.size,
                frames: options.frames,
                target: Handle::default(),
                scene: Handle::default(),
                texture: Handle::default(),
                waiting: WaitingPipelines(waiting),
                state: CaptureState::Loading,
                previous: None,
                outcome: Arc::new(std::sync::Mutex::new(None)),
            })
            .add_systems(Startup, setup_image_camera.after(setup))
            .add_systems(Update, capture);
        }
    }
    app.insert_resource(GlobalAmbientLight {
        brightness: 0.0,
        ..default()
    })
    .insert_resource(inputs)
    .add_systems(Startup, setup)
    .add_systems(Update, attach_lightmap)
    .run()
}

/// Reads the command line and the placement JSON beside the texture.
fn parse(args: &[String]) -> Result<(Inputs, Options), String> {
    let Some(export) = args.first() else {
        return Err("EXPORT_DIR is required".into());
    };
    let lightmap = Path::new(export).join(LIGHTMAP_PLACEMENT).is_file();
    // A lightmap export brings its scene; an irradiance volume needs one.
    let scene = args.get(1).filter(|a| !a.starts_with("--"));
    if scene.is_none() && !lightmap {
        return Err("SCENE.gltf is required with an irradiance volume".into());
    }
    let mut options = Options {
        view: None,
        screenshot: None,
        size: UVec2::splat(512),
        frames: 5,
    };
    let mut rest = args[1 + usize::from(scene.is_some())..].iter();
    while let Some(flag) = rest.next() {
        let mut value = || {
            rest.next()
                .ok_or_else(|| format!("{flag} needs a value"))
                .cloned()
        };
        match flag.as_str() {
            "--view" => {
                let v = value()?;
                let numbers: Vec<f32> = v
                    .split(',')
                    .map(|s| s.trim().parse::<f32>())
                    .collect::<Result<_, _>>()
                    .map_err(|e| format!("--view {v}: {e}"))?;
                let [ex, ey, ez, tx, ty, tz, fov] = numbers[..] else {
                    return Err(format!("--view {v}: expected 7 numbers"));
                };
                if !(fov > 0.0 && fov < 180.0) {
                    return Err(format!("--view {v}: the field of view is not in (0, 180)"));
                }
                options.view = Some((
                    Vec3::new(ex, ey, ez),
                    Vec3::new(tx, ty, tz),
                    fov.to_radians(),
                ));
            }
            "--screenshot" => options.screenshot = Some(PathBuf::from(value()?)),
            "--size" => {
                let v = value()?;
                let parts: Vec<u32> = v
                    .split('x')
                    .map(str::parse)
                    .collect::<Result<_, _>>()
                    .map_err(|e| format!("--size {v}: {e}"))?;
                options.size = match parts[..] {
                    [s] => UVec2::splat(s),
                    [w, h] => UVec2::new(w, h),
                    _ => return Err(format!("--size {v}: expected W or WxH")),
                };
                if options.size.min_element() == 0 || options.size.max_element() > 8192 {
                    return Err(format!("--size {v}: not in 1..=8192"));
                }
            }
            "--frames" => {
                let v = value()?;
                options.frames = v.parse().map_err(|e| format!("--frames {v}: {e}"))?;
            }
            other => return Err(format!("unknown option {other}")),
        }
    }
    if let Some(path) = &options.screenshot {
        match extension(path).as_str() {
            "pfm" | "png" => {}
            _ => {
                return Err(format!(
                    "--screenshot {}: must end in .pfm or .png",
                    path.display()
                ));
            }
        }
    }
    let mut inputs = if lightmap {
        read_lightmap_inputs(Path::new(export), scene.map(Path::new))?
    } else {
        read_inputs(Path::new(export), Path::new(scene.expect("checked above")))?
    };
    inputs.view = options.view;
    Ok((inputs, options))
}

fn extension(path: &Path) -> String {
    path.extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default()
}

/// File name of the placement of `prt lightmap --engine bevy`.
const LIGHTMAP_PLACEMENT: &str = "lightmap.json";

/// A path relative to the file-system root, where the asset server is rooted.
fn root_relative(p: &Path) -> Result<String, String> {
    let absolute = p
        .canonicalize()
        .map_err(|e| format!("{}: {e}", p.display()))?;
    Ok(absolute
        .to_string_lossy()
        .trim_start_matches('/')
        .to_string())
}

fn read_json(path: &Path) -> Result<serde_json::Value, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))
}

/// `doc[group][key]` as three numbers.
fn json_vec3(doc: &serde_json::Value, group: &str, key: &str) -> Result<Vec3, String> {
    let values: Vec<f32> = doc[group][key]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|v| v.as_f64())
                .map(|v| v as f32)
                .collect()
        })
        .unwrap_or_default();
    match values[..] {
        [x, y, z] => Ok(Vec3::new(x, y, z)),
        _ => Err(format!("{group}.{key} is not three numbers")),
    }
}

/// Reads `lightmap.json`: the texture, the scene (the export's own unless `scene` is given)
/// and the scene's bounds, which place the default camera.
fn read_lightmap_inputs(export: &Path, scene: Option<&Path>) -> Result<Inputs, String> {
    let doc = read_json(&export.join(LIGHTMAP_PLACEMENT))?;
    if doc["engine"].as_str() != Some("bevy") {
        return Err(format!(
            "{}: made for {}, not Bevy (prt lightmap --engine bevy)",
            export.join(LIGHTMAP_PLACEMENT).display(),
            doc["engine"]
        ));
    }
    let texture = doc["texture"].as_str().ok_or("no texture name")?;
    let own_scene = export.join(doc["scene"].as_str().ok_or("no scene name")?);
    let (min, max) = (
        json_vec3(&doc, "bounds", "min")?,
        json_vec3(&doc, "bounds", "max")?,
    );
    Ok(Inputs {
        texture: root_relative(&export.join(texture))?,
        lightmap: true,
        scene: root_relative(scene.unwrap_or(&own_scene))?,
        translation: 0.5 * (min + max),
        scale: max - min,
        intensity: 1.0,
        view: None,
    })
}

/// Reads `irradiance_volume.json` beside the texture.
fn read_inputs(export: &Path, scene: &Path) -> Result<Inputs, String> {
    let doc = read_json(&export.join("irradiance_volume.json"))?;
    let texture = doc["texture"].as_str().ok_or("no texture name")?;
    Ok(Inputs {
        texture: root_relative(&export.join(texture))?,
        lightmap: false,
        scene: root_relative(scene)?,
        translation: json_vec3(&doc, "transform", "translation")?,
        scale: json_vec3(&doc, "transform", "scale")?,
        intensity: doc["intensity"].as_f64().ok_or("no intensity")? as f32,
        view: None,
    })
}

/// The lightmap every mesh entity of the scene gets ([`attach_lightmap`]).
#[derive(Resource)]
struct SceneLightmap(Handle<Image>);

/// The scene and the volume or lightmap; the capture keeps their handles to wait for them.
fn setup(
    mut commands: Commands,
    assets: Res<AssetServer>,
    inputs: Res<Inputs>,
    capture: Option<ResMut<Capture>>,
) {
    let scene: Handle<WorldAsset> =
        assets.load(GltfAssetLabel::Scene(0).from_asset(inputs.scene.clone()));
    let texture: Handle<Image> = assets.load(inputs.texture.clone());
    commands.spawn(WorldAssetRoot(scene.clone()));
    if inputs.lightmap {
        commands.insert_resource(SceneLightmap(texture.clone()));
    } else {
        // Bevy's light probes are the unit cube [-0.5, 0.5]³ under their transform.
        commands.spawn((
            LightProbe::default(),
            IrradianceVolume {
                voxels: texture.clone(),
                intensity: inputs.intensity,
                ..default()
            },
            Transform::from_translation(inputs.translation).with_scale(inputs.scale),
        ));
    }
    if let Some(mut capture) = capture {
        capture.scene = scene;
        capture.texture = texture;
    }
}

/// Gives every mesh entity of the spawned scene Bevy's `Lightmap` (the whole texture,
/// `uv_rect` (0, 0)..(1, 1), sampled at `UV_1`).
fn attach_lightmap(
    mut commands: Commands,
    lightmap: Option<Res<SceneLightmap>>,
    meshes: Query<Entity, (With<Mesh3d>, Without<Lightmap>)>,
) {
    let Some(lightmap) = lightmap else {
        return;
    };
    for entity in &meshes {
        commands.entity(entity).insert(Lightmap {
            image: lightmap.0.clone(),
            ..default()
        });
    }
}

/// The camera's placement and projection: `--view`, else near the volume's +Z face.
fn camera_pose(inputs: &Inputs) -> (Transform, Projection) {
    let (eye, target, fov) = inputs.view.unwrap_or((
        inputs.translation + inputs.scale * Vec3::new(0.0, 0.1, 0.45),
        inputs.translation,
        PerspectiveProjection::default().fov,
    ));
    (
        Transform::from_translation(eye).looking_at(target, Vec3::Y),
        Projection::Perspective(PerspectiveProjection { fov, ..default() }),
    )
}

/// The components every camera here has: no tone mapping, no dithering, unit exposure.
fn linear_camera() -> impl Bundle {
    (
        Camera3d::default(),
        Tonemapping::None,
        DebandDither::Disabled,
        unit_exposure(),
    )
}

fn setup_window_camera(mut commands: Commands, inputs: Res<Inputs>) {
    let (transform, projection) = camera_pose(&inputs);
    commands.spawn((linear_camera(), transform, projection));
}

/// The offscreen camera: an `Rgba16Float` image, no MSAA (edges stay one surface or the other).
fn setup_image_camera(
    mut commands: Commands,
    inputs: Res<Inputs>,
    mut images: ResMut<Assets<Image>>,
    mut capture: ResMut<Capture>,
) {
    let mut image = Image::new_target_texture(
        capture.size.x,
        capture.size.y,
        TextureFormat::Rgba16Float,
        None,
    );
    image.texture_descriptor.usage |= TextureUsages::COPY_SRC;
    let target = images.add(image);
    capture.target = target.clone();
    let (transform, projection) = camera_pose(&inputs);
    commands.spawn((
        linear_camera(),
        Camera {
            clear_color: ClearColorConfig::Custom(Color::BLACK),
            ..default()
        },
        RenderTarget::Image(target.into()),
        Msaa::Off,
        transform,
        projection,
    ));
}

/// The render world's count of pipelines still compiling (or waiting for shaders), shared with
/// the main world.
#[derive(Resource, Clone)]
struct WaitingPipelines(Arc<AtomicUsize>);

fn count_waiting_pipelines(cache: Res<PipelineCache>, waiting: Res<WaitingPipelines>) {
    waiting
        .0
        .store(cache.waiting_pipelines().count(), Ordering::Relaxed);
}

enum CaptureState {
    /// Waiting for the scene and the volume or lightmap.
    Loading,
    /// Rendering frames (the count so far) until `--frames` and no pipeline waiting.
    Settling(u32),
    /// A screenshot is on its way.
    Requested,
}

/// Linear RGB pixels, rows top to bottom.
type Pixels = Vec<[f32; 3]>;

#[derive(Resource)]
struct Capture {
    path: PathBuf,
    size: UVec2,
    frames: u32,
    target: Handle<Image>,
    scene: Handle<WorldAsset>,
    texture: Handle<Image>,
    waiting: WaitingPipelines,
    state: CaptureState,
    /// The last capture, to compare the next with.
    previous: Option<Pixels>,
    /// Set by the screenshot observer.
    outcome: Arc<std::sync::Mutex<Option<Result<Pixels, String>>>>,
}

/// How many captures may differ from their predecessor before giving up.
const MAX_CAPTURES: usize = 20;

fn capture(
    mut commands: Commands,
    assets: Res<AssetServer>,
    mut capture: ResMut<Capture>,
    mut captures: Local<usize>,
    mut exit: MessageWriter<AppExit>,
) {
    let capture = &mut *capture;
    match capture.state {
        CaptureState::Loading => {
            for id in [capture.scene.id().untyped(), capture.texture.id().untyped()] {
                if let RecursiveDependencyLoadState::Failed(e) =
                    assets.recursive_dependency_load_state(id)
                {
                    eprintln!("error: cannot load an asset: {e}");
                    exit.write(AppExit::error());
                    return;
                }
            }
            if assets.is_loaded_with_dependencies(&capture.scene)
                && assets.is_loaded_with_dependencies(&capture.texture)
            {
                capture.state = CaptureState::Settling(0);
            }
        }
        CaptureState::Settling(frames) => {
            let idle = capture.waiting.0.load(Ordering::Relaxed) == 0;
            if frames + 1 >= capture.frames && idle {
                let outcome = capture.outcome.clone();
                commands
                    .spawn(Screenshot::image(capture.target.clone()))
                    .observe(move |shot: On<ScreenshotCaptured>| {
                        *outcome.lock().expect("lock") = Some(linear_rgb(&shot.image));
                    });
                capture.state = CaptureState::Requested;
            } else {
                capture.state = CaptureState::Settling(frames + 1);
            }
        }
        CaptureState::Requested => {
            let Some(outcome) = capture.outcome.lock().expect("lock").take() else {
                return;
            };
            *captures += 1;
            let pixels = match outcome {
                Ok(pixels) => pixels,
                Err(e) => {
                    eprintln!("error: {e}");
                    exit.write(AppExit::error());
                    return;
                }
            };
            let stable = capture.previous.as_ref() == Some(&pixels);
            if !stable && *captures < MAX_CAPTURES {
                capture.previous = Some(pixels);
                capture.state = CaptureState::Settling(0);
                return;
            }
            if !stable {
                eprintln!("warning: {MAX_CAPTURES} captures in a row differed; saving the last");
            }
            match save(&capture.path, capture.size, &pixels) {
                Ok(()) => {
                    println!(
                        "wrote {} after {} captures",
                        capture.path.display(),
                        *captures
                    );
                    exit.write(AppExit::Success);
                }
                Err(e) => {
                    eprintln!("error: {}: {e}", capture.path.display());
                    exit.write(AppExit::error());
                }
            }
        }
    }
}

/// The screenshot's pixels as linear RGB.
fn linear_rgb(image: &Image) -> Result<Pixels, String> {
    let format = image.texture_descriptor.format;
    if format != TextureFormat::Rgba16Float {
        return Err(format!("the screenshot is {format:?}, not Rgba16Float"));
    }
    let data = image.data.as_ref().ok_or("the screenshot has no data")?;
    let texels = (image.width() * image.height()) as usize;
    if data.len() != 8 * texels {
        return Err(format!(
            "the screenshot holds {} bytes for {texels} texels",
            data.len()
        ));
    }
    let half = |b: &[u8]| f16_to_f32(u16::from_le_bytes([b[0], b[1]]));
    Ok(data
        .chunks_exact(8)
        .map(|t| [half(&t[0..2]), half(&t[2..4]), half(&t[4..6])])
        .collect())
}

/// IEEE 754 binary16 to f32.
fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exponent = i32::from((h >> 10) & 0x1f);
    let mantissa = f32::from(h & 0x3ff);
    sign * match exponent {
        0 => mantissa * 2f32.powi(-24),
        31 if mantissa == 0.0 => f32::INFINITY,
        31 => f32::NAN,
        e => (1.0 + mantissa / 1024.0) * 2f32.powi(e - 15),
    }
}

/// Writes `.pfm` (linear, bottom row first as the format has it) or `.png` (clamped, sRGB).
fn save(path: &Path, size: UVec2, pixels: &[[f32; 3]]) -> Result<(), String> {
    let (w, h) = (size.x as usize, size.y as usize);
    let bytes = if extension(path) == "pfm" {
        let mut out = format!("PF\n{w} {h}\n-1.0\n").into_bytes();
        for row in pixels.chunks_exact(w).rev() {
            for v in row.iter().flatten() {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out
    } else {
        let encode = |v: f32| {
            let v = v.clamp(0.0, 1.0);
            let s = if v <= 0.003_130_8 {
                12.92 * v
            } else {
                1.055 * v.powf(1.0 / 2.4) - 0.055
            };
            (s * 255.0).round() as u8
        };
        let rgb: Vec<u8> = pixels.iter().flatten().map(|&v| encode(v)).collect();
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, w as u32, h as u32);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
        writer.write_image_data(&rgb).map_err(|e| e.to_string())?;
        writer.finish().map_err(|e| e.to_string())?;
        out
    };
    std::fs::write(path, bytes).map_err(|e| e.to_string())
}

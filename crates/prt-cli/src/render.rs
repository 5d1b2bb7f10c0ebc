//! `prt render`: the lit scene of a bake folder, on the CPU, to PNG or EXR.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use prt_bake::{BakeFolder, FolderVolume, REFERENCE};
use prt_core::glam::Vec3;
use prt_core::{NoProgress, SpatialKernels};
use prt_export::{AmbientCubeFit, DilateConfig, Engine, EngineLookup};
use prt_render::{
    NamedView, RenderConfig, Rendered, SurfaceLight, ToneMap, grid_bounds, image_metrics, render,
    views,
};
use prt_sphere::Sky;
use prt_texture::Limits;
use prt_texture::exr_io::{ExrLayer, ExrSample, write_exr};
use prt_trace::{LitVolume, RayTracer, Scene, read_mesh};

use crate::progress::StageBar;
use crate::sky::SkyArgs;

/// Which volume lights the render.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// The traced transfer volume (from DIR/volumes/).
    Reference,
    /// The MBD container as written (DIR/mbd/), evaluated at the voxel centres.
    Mbd,
    /// Blockwise PCA's reconstruction (from DIR/volumes/).
    Bpca,
    /// Clustered PCA's reconstruction (from DIR/volumes/).
    Cpca,
}

impl MethodArg {
    fn key(self) -> &'static str {
        match self {
            MethodArg::Reference => REFERENCE,
            MethodArg::Mbd => BakeFolder::CONTAINER,
            MethodArg::Bpca => "bpca",
            MethodArg::Cpca => "cpca",
        }
    }
}

/// Whose probe lookup lights the render.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum LookupArg {
    /// prt's: the volume half a voxel off the surface, interpolated over valid voxels only.
    Prt,
    /// Bevy's IrradianceVolume on `prt export --target bevy`'s data: at the surface point,
    /// ambient cubes, Valve's blend.
    Bevy,
    /// three.js's LightProbeGrid on `prt export --target threejs`'s data: half a probe spacing
    /// off the surface, L2 SH irradiance clamped at 0.
    Threejs,
}

/// A lit bake as an engine samples its export.
struct EngineLight(EngineLookup);

impl SurfaceLight for EngineLight {
    fn surface_irradiance(&self, position: Vec3, normal: Vec3) -> Option<Vec3> {
        self.0.irradiance(position, normal)
    }
}

/// Options of `prt render`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Each pixel traces one primary ray through the scene mesh (BAKE_DIR/scene.mesh) \
and shows emission + albedo/π · E, where E is the diffuse irradiance of the chosen volume relit \
by the sky (incident-radiance SH9 per voxel; --lookup prt: trilinear between voxel centres over \
the valid voxels, looked up half a voxel off the surface along its normal; --lookup bevy or \
threejs: that engine's shader on the export's data); rays that miss show the sky. \
PNG output is tone-mapped: exposure, the ACES filmic curve (Narkowicz's fit), sRGB. EXR output \
holds the linear radiance. With --method other than reference, and the kept volumes present, \
the RMSE against the reference render is printed."
)]
pub struct RenderArgs {
    /// The folder `prt bake --out DIR` wrote (scene.mesh, mbd/, volumes/).
    pub bake_dir: PathBuf,
    /// View: the scene's glTF cameras in file order, then two automatic views of the scene box:
    /// `front` (looking along -Z from +Z, the box's x-y extent filling a 40° field of view) and
    /// `inside` (from inside the box near its +X or +Z end, whichever axis is longer, at 40 % of
    /// the height, looking back along that axis 10° down, 60° field of view). 0 is the first.
    #[arg(long, default_value_t = 0)]
    pub camera: usize,
    #[command(flatten)]
    pub sky: SkyArgs,
    /// Volume that lights the scene.
    #[arg(long, value_enum, default_value_t = MethodArg::Mbd)]
    pub method: MethodArg,
    /// Whose lookup reads the volume: prt's own, or what Bevy or three.js computes from
    /// `prt export`'s files for the same volume and sky (dilated with the export's default,
    /// negative light removed, padded; without the texture format's rounding).
    #[arg(long, value_enum, default_value_t = LookupArg::Prt)]
    pub lookup: LookupArg,
    /// Also score the render against the reference render of the same view, both tone-mapped
    /// with the reference's exposure: ꟻLIP and grey-level errors (needs the kept volumes).
    #[arg(long)]
    pub compare: bool,
    /// Width and height of the image, in pixels.
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Exposure (a linear factor on the radiance before tone mapping) [default: the one that
    /// maps the log-average luminance of the scene's pixels to 0.18].
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Output image: .png (tone-mapped sRGB) or .exr (linear radiance, f32).
    #[arg(long)]
    pub out: PathBuf,
}

/// Largest `--size`.
const MAX_SIZE: usize = 8192;

/// The output format of `--out`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Format {
    Png,
    Exr,
}

/// The format `path`'s extension names (`.png` or `.exr`), or why it names none.
pub(crate) fn format_of(path: &Path) -> Result<Format> {
    let extension = path
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    match extension.as_str() {
        "png" => Ok(Format::Png),
        "exr" => Ok(Format::Exr),
        _ => bail!("--out {} must end in .png or .exr", path.display()),
    }
}

/// The scene of a bake folder, from its scene mesh.
pub fn load_scene(bake_dir: &Path) -> Result<Scene> {
    let path = BakeFolder::new(bake_dir).existing_scene_mesh()?;
    read_mesh(&path, &Limits::default()).with_context(|| format!("cannot read {}", path.display()))
}

/// The volume of `method` in a bake folder, lit by `sky`.
fn load_volume(bake_dir: &Path, method: MethodArg, sky: &Sky) -> Result<LitVolume> {
    let volume = BakeFolder::new(bake_dir)
        .read_volume(method.key(), &Limits::default())
        .with_context(|| format!("--method {}", method.key()))?;
    let relit = match volume {
        FolderVolume::Mbd(container) => {
            let bounds = grid_bounds(
                container.model.coefficient_kernels().domain(),
                container.grid,
            );
            LitVolume::from_model(
                &container.model,
                container.grid,
                bounds,
                &container.valid,
                sky,
                &NoProgress,
            )
        }
        FolderVolume::Kept { field, valid, .. } => {
            LitVolume::from_transfer(&field, &valid, sky, &NoProgress)
        }
    };
    relit.with_context(|| format!("cannot relight the {} volume", method.key()))
}

/// What lights the render: the volume of `method` read by `lookup`.
fn load_light(
    bake_dir: &Path,
    method: MethodArg,
    lookup: LookupArg,
    sky: &Sky,
) -> Result<Box<dyn SurfaceLight>> {
    let engine = match lookup {
        LookupArg::Prt => return Ok(Box::new(load_volume(bake_dir, method, sky)?)),
        LookupArg::Bevy => Engine::Bevy,
        LookupArg::Threejs => Engine::Threejs,
    };
    let lit = crate::export::light_bake(bake_dir, method.key(), sky)?;
    let volume = crate::export::prepare_for_engines(&lit, &DilateConfig::default())?;
    Ok(Box::new(EngineLight(EngineLookup::new(
        &volume,
        engine,
        AmbientCubeFit::Axes,
    )?)))
}

/// The view `--camera` picks, with an error that lists them all.
fn pick_view(scene: &Scene, camera: usize) -> Result<NamedView> {
    let all = views(scene);
    all.get(camera).cloned().with_context(|| {
        let list: Vec<String> = all
            .iter()
            .enumerate()
            .map(|(i, v)| format!("{i} = {}", v.name))
            .collect();
        format!(
            "--camera {camera} does not exist; the scene has {} view(s): {}",
            all.len(),
            list.join(", ")
        )
    })
}

/// Writes a render: tone-mapped PNG or linear EXR.
pub fn save_render(path: &Path, image: &Rendered, tone: &ToneMap) -> Result<()> {
    let (w, h) = (image.width as u32, image.height as u32);
    match format_of(path)? {
        Format::Png => {
            let img = image::RgbImage::from_raw(w, h, tone.apply(image))
                .context("image buffer of the wrong size")?;
            crate::report::save_png(path, &img)
        }
        Format::Exr => {
            let layer = ExrLayer {
                name: None,
                width: w,
                height: h,
                channels: 3,
                data: image.interleaved(),
            };
            write_exr(path, &[layer], ExrSample::F32)
                .with_context(|| format!("cannot write {}", path.display()))
        }
    }
}

pub fn run(args: &RenderArgs) -> Result<()> {
    format_of(&args.out)?;
    if !(1..=MAX_SIZE).contains(&args.size) {
        bail!("--size {} is not in 1..={MAX_SIZE}", args.size);
    }
    if let Some(e) = args.exposure
        && !(e.is_finite() && e > 0.0)
    {
        bail!("--exposure {e} is not a positive number");
    }
    let sky = args.sky.sky()?;
    let scene = load_scene(&args.bake_dir)?;
    let view = pick_view(&scene, args.camera)?;
    let light = load_light(&args.bake_dir, args.method, args.lookup, &sky)?;
    let tracer = RayTracer::new(scene.triangles());
    let config = RenderConfig {
        width: args.size,
        height: args.size,
    };
    let stage = StageBar::start("render");
    let start = Instant::now();
    let image = render(&scene, &tracer, &view.view, &*light, &sky, &config, &stage)?;
    let seconds = start.elapsed().as_secs_f64();
    stage.finish();
    let tone = args
        .exposure
        .map_or_else(|| ToneMap::auto(&image), |exposure| ToneMap { exposure });
    save_render(&args.out, &image, &tone)?;
    eprintln!(
        "{} × {} pixels, camera {} ({}), {} volume, {} lookup, {:.3} s; exposure {:.4}{}",
        image.width,
        image.height,
        args.camera,
        view.name,
        args.method.key(),
        args.lookup
            .to_possible_value()
            .map(|v| v.get_name().to_string())
            .unwrap_or_default(),
        seconds,
        tone.exposure,
        if image.unlit > 0 {
            format!(
                "; {} pixels without a valid voxel nearby (emission only)",
                image.unlit
            )
        } else {
            String::new()
        }
    );
    let kept = BakeFolder::new(&args.bake_dir).has_volumes();
    if args.compare && !kept {
        bail!(
            "--compare needs the reference volume, which this bake did not keep (bake with \
             --keep-volumes always)"
        );
    }
    if args.method != MethodArg::Reference && kept {
        let reference = load_light(&args.bake_dir, MethodArg::Reference, args.lookup, &sky)?;
        let base = render(
            &scene,
            &tracer,
            &view.view,
            &*reference,
            &sky,
            &config,
            &NoProgress,
        )?;
        if let Some(rmse) = image.rmse(&base) {
            let mean = base
                .pixels
                .iter()
                .flatten()
                .map(|&v| f64::from(v))
                .sum::<f64>()
                / (3 * base.pixels.len()).max(1) as f64;
            println!(
                "RMSE against the reference render: {rmse:.4e} ({:.2} % of its mean radiance {mean:.4e})",
                100.0 * rmse / mean.max(f64::MIN_POSITIVE)
            );
        }
        if args.compare {
            let m = image_metrics(&base, &image, &ToneMap::auto(&base))?;
            println!(
                "against the reference render (its exposure, {} surface pixels): FLIP {:.4}, \
                 mean {:.2} grey levels, {:.1} % of pixels more than {:.0} levels off, darkest \
                 quartile {:.2} levels, median relative luminance error {:.1} %",
                m.pixels,
                m.flip,
                m.mean_levels,
                100.0 * m.share_off,
                prt_render::VISIBLE_LEVELS,
                m.dark_levels,
                100.0 * m.median_relative
            );
        }
    }
    println!("wrote {}", args.out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_output_format_follows_the_extension() {
        assert_eq!(format_of(Path::new("a.PNG")).expect("png"), Format::Png);
        assert_eq!(format_of(Path::new("b/c.exr")).expect("exr"), Format::Exr);
        assert!(format_of(Path::new("d.jpg")).is_err());
    }
}

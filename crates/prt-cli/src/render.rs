//! `prt render`: the lit scene of a bake folder, or of a lightmap folder (`--lightmap`), on the
//! CPU, to PNG or EXR.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use prt_bake::BakeFolder;
use prt_core::NoProgress;
use prt_core::glam::Vec3;
use prt_export::{AmbientCubeFit, DilateConfig, Engine, EngineLookup};
use prt_lightmap::{
    LIGHTMAP_MANIFEST, LightmapBasis, LightmapFolder, LightmapManifest, MAX_MANIFEST_BYTES,
};
use prt_render::{
    NamedView, RenderConfig, Rendered, SurfaceLight, ToneMap, image_metrics, render, views,
};
use prt_shaders::lightmap as lm;
use prt_sphere::Sky;
use prt_texture::Limits;
use prt_texture::exr_io::{ExrLayer, ExrSample, write_exr};
use prt_trace::mesh::read_mesh;
use prt_trace::{RayTracer, Scene};

use crate::export::VolumeArg;
use crate::progress::StageBar;
use crate::sky::SkyArgs;

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
and shows emission + albedo/π · E, where E is the diffuse irradiance of the chosen volume lit \
by the sky (incident-radiance SH9 per voxel; --lookup prt: trilinear between voxel centres over \
the valid voxels, looked up half a voxel off the surface along its normal; --lookup bevy or \
threejs: that engine's shader on the export's data); rays that miss show the sky. \
PNG output is tone-mapped: exposure, the ACES filmic curve (Narkowicz's fit), sRGB. EXR output \
holds the linear radiance. With --method other than reference, and the kept volumes present, \
the RMSE against the reference render is printed. With --lightmap DIR (a folder of `prt \
lightmap`), the scene is lit by that lightmap instead: E is the lightmap's bilinearly filtered \
texel at the hit's lightmap UV, reconstructed from an sg or sh basis's coefficients with \
prt-shaders' lightmap math (what lm_sg_diffuse / lm_sh_diffuse compute on the GPU; \
--irradiance-layer reads the stored irradiance instead, as ambient-dice and irradiance \
lightmaps always do); misses and back faces of single-sided surfaces are black, and the RMSE \
against the stored irradiance's render is printed."
)]
pub struct RenderArgs {
    /// The folder `prt bake --out DIR` wrote (scene.mesh, mbd/, volumes/).
    #[arg(required_unless_present = "lightmap")]
    pub bake_dir: Option<PathBuf>,
    /// Render a lightmap folder (`prt lightmap --out DIR`: manifest.json, lightmap.ktx2,
    /// lightmap_uvs.bin) instead of a bake folder.
    #[arg(
        long,
        value_name = "DIR",
        conflicts_with_all = ["bake_dir", "compare", "method", "lookup"]
    )]
    pub lightmap: Option<PathBuf>,
    /// With --lightmap: the scene's glTF, when the manifest's `scene` path does not reach it from
    /// here [default: the manifest's].
    #[arg(long, requires = "lightmap")]
    pub scene: Option<PathBuf>,
    /// With --lightmap: light with the stored irradiance layer, not the basis's reconstruction.
    #[arg(long, requires = "lightmap")]
    pub irradiance_layer: bool,
    /// With --lightmap of an sg or sh basis: add a GGX specular lobe of this perceptual
    /// roughness (0..=1, dielectric F0 = 0.04), reconstructed from the coefficients
    /// (lm_sg_specular / lm_sh_specular).
    #[arg(long, requires = "lightmap", value_name = "ROUGHNESS")]
    pub specular: Option<f32>,
    /// View: the scene's glTF cameras in file order, then two automatic views of the scene box:
    /// `front` (looking along -Z from +Z, the box's x-y extent filling a 40° field of view) and
    /// `inside` (from inside the box near its +X or +Z end, whichever axis is longer, at the first
    /// point 5-45 % in that is not sealed off, at 40 % of the height, looking back along that
    /// axis 10° down, 60° field of view). 0 is the first.
    #[arg(long, default_value_t = 0)]
    pub camera: usize,
    #[command(flatten)]
    pub sky: SkyArgs,
    /// Volume that lights the scene.
    #[arg(long, value_enum, default_value_t = VolumeArg::Mbd)]
    pub method: VolumeArg,
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

/// What lights the render: the volume of `method` read by `lookup`.
fn load_light(
    bake_dir: &Path,
    method: VolumeArg,
    lookup: LookupArg,
    sky: &Sky,
) -> Result<Box<dyn SurfaceLight>> {
    let lit = crate::export::light_bake(bake_dir, method, sky)?;
    let engine = match lookup {
        LookupArg::Prt => return Ok(Box::new(lit)),
        LookupArg::Bevy => Engine::Bevy,
        LookupArg::Threejs => Engine::Threejs,
    };
    let volume = crate::export::prepare_for_engines(&lit, &DilateConfig::default())?;
    Ok(Box::new(EngineLight(EngineLookup::new(
        &volume,
        engine,
        AmbientCubeFit::Axes,
    )?)))
}

/// The view `--camera` picks, with an error that lists them all.
pub(crate) fn pick_view(scene: &Scene, camera: usize) -> Result<NamedView> {
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
    if let Some(dir) = &args.lightmap {
        return run_lightmap(dir, args);
    }
    let bake_dir = args
        .bake_dir
        .as_deref()
        .context("give a bake folder or --lightmap DIR")?;
    let sky = args.sky.sky()?;
    let scene = load_scene(bake_dir)?;
    let view = pick_view(&scene, args.camera)?;
    let light = load_light(bake_dir, args.method, args.lookup, &sky)?;
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
    let kept = BakeFolder::new(bake_dir).has_volumes();
    if args.compare && !kept {
        bail!(
            "--compare needs the reference volume, which this bake did not keep (bake with \
             --keep-volumes always)"
        );
    }
    if args.method != VolumeArg::Reference && kept {
        let reference = load_light(bake_dir, VolumeArg::Reference, args.lookup, &sky)?;
        let base = render(
            &scene,
            &tracer,
            &view.view,
            &*reference,
            &sky,
            &config,
            &NoProgress,
        )?;
        print_rmse(&image, &base, "the reference render");
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

/// A file of a lightmap folder, refused before reading when over `max_bytes`.
fn read_limited(path: &Path, max_bytes: u64) -> Result<Vec<u8>> {
    let size = std::fs::metadata(path)
        .with_context(|| format!("cannot read {}", path.display()))?
        .len();
    if size > max_bytes {
        bail!(
            "{} is {size} bytes, over the limit of {max_bytes}",
            path.display()
        );
    }
    std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))
}

/// A lightmap folder read back (manifest, KTX2, UVs) with `limits`.
fn read_lightmap_folder(dir: &Path, limits: &Limits) -> Result<LightmapFolder> {
    let manifest_path = dir.join(LIGHTMAP_MANIFEST);
    let manifest = LightmapManifest::parse(&read_limited(&manifest_path, MAX_MANIFEST_BYTES)?)
        .with_context(|| format!("cannot read {}", manifest_path.display()))?;
    // The KTX2's headers and key/values come on top of its decoded bytes.
    let ktx2 = read_limited(
        &dir.join(&manifest.ktx2),
        limits.max_bytes.saturating_add(1 << 20),
    )?;
    let uvs = read_limited(&dir.join(&manifest.uvs), limits.max_bytes)?;
    LightmapFolder::parse(manifest, &ktx2, &uvs, limits)
        .with_context(|| format!("cannot read the lightmap folder {}", dir.display()))
}

/// Irradiance at a lightmap UV, and the specular lobe towards a view, as the lightmap shaders
/// reconstruct them (prt_shaders::lightmap).
enum LightmapShading<'a> {
    /// The stored irradiance layer.
    Irradiance,
    /// SG coefficients: lobe axes (tangent frame) and sharpness.
    Sg(&'a [Vec3], f32),
    /// SH coefficients (the first 9).
    Sh,
}

impl LightmapShading<'_> {
    /// `(E, specular)` at atlas position `uv` in texels, for a view direction `to_eye` in the
    /// texel's tangent frame (+Y the winding normal).
    fn shade(
        &self,
        lightmap: &prt_lightmap::Lightmap,
        uv: prt_core::glam::Vec2,
        to_eye: Vec3,
        roughness: Option<f32>,
    ) -> (Vec3, Vec3) {
        let f0 = Vec3::splat(0.04);
        match *self {
            LightmapShading::Irradiance => (lightmap.irradiance_at(uv), Vec3::ZERO),
            LightmapShading::Sg(axes, sharpness) => {
                let mut c = vec![Vec3::ZERO; axes.len()];
                lightmap.coefficients_at(uv, &mut c);
                let e = lm::sg_diffuse(axes, sharpness, &c, Vec3::Y);
                let s = roughness
                    .filter(|_| to_eye.y > 0.0)
                    .map_or(Vec3::ZERO, |r| {
                        lm::sg_specular(axes, sharpness, &c, Vec3::Y, to_eye, r, f0)
                    });
                (e, s)
            }
            LightmapShading::Sh => {
                let mut c = vec![Vec3::ZERO; lightmap.basis.len()];
                lightmap.coefficients_at(uv, &mut c);
                let mut nine = [Vec3::ZERO; lm::SH_COEFFICIENTS];
                for (o, c) in nine.iter_mut().zip(&c) {
                    *o = *c;
                }
                let e = lm::sh_diffuse(&nine, Vec3::Y);
                let s = roughness
                    .filter(|_| to_eye.y > 0.0)
                    .map_or(Vec3::ZERO, |r| {
                        lm::sh_specular(&nine, Vec3::Y, to_eye, r, f0)
                    });
                (e, s)
            }
        }
    }
}

/// `scene` from `view` lit by `folder`'s lightmap: per pixel, `emission + albedo/π · E` plus
/// the specular lobe when `roughness` is given; misses and back faces of single-sided surfaces
/// are black.
fn render_lightmapped(
    scene: &Scene,
    folder: &LightmapFolder,
    shading: &LightmapShading<'_>,
    roughness: Option<f32>,
    view: &prt_trace::camera::PinholeView,
    size: usize,
) -> Rendered {
    use rayon::prelude::*;
    let tracer = RayTracer::new(scene.triangles());
    let lightmap = &folder.lightmap;
    let pixels: Vec<Option<[f32; 3]>> = (0..size * size)
        .into_par_iter()
        .map(|i| {
            let dir = view.ray(i % size, i / size, size, size);
            let hit = tracer.closest_hit(view.position, dir, 0.0, f32::INFINITY)?;
            let t = hit.triangle as usize;
            let material = scene.material_of(t);
            if !hit.front_face && !material.double_sided {
                return Some([0.0; 3]);
            }
            let uv = folder.uvs[t];
            let b = hit.barycentrics;
            let at = uv[0] * (1.0 - b.x - b.y) + uv[1] * b.x + uv[2] * b.y;
            // The texel's frame: the triangle's winding normal, as the bake computed it.
            let tri = scene.triangles()[t];
            let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize_or_zero();
            let to_eye = lm::to_tangent(lm::tangent_frame(normal), -dir.normalize());
            let (e, specular) = shading.shade(lightmap, at, to_eye, roughness);
            let emission = if hit.front_face {
                material.emissive
            } else {
                Vec3::ZERO
            };
            let specular = if hit.front_face { specular } else { Vec3::ZERO };
            Some((emission + material.albedo / std::f32::consts::PI * e + specular).to_array())
        })
        .collect();
    Rendered {
        width: size,
        height: size,
        hit: pixels.iter().map(Option::is_some).collect(),
        pixels: pixels.into_iter().map(|p| p.unwrap_or([0.0; 3])).collect(),
        unlit: 0,
    }
}

/// `prt render --lightmap DIR`.
fn run_lightmap(dir: &Path, args: &RenderArgs) -> Result<()> {
    if let Some(r) = args.specular
        && !(0.0..=1.0).contains(&r)
    {
        bail!("--specular {r} is not a roughness in 0..=1");
    }
    let folder = read_lightmap_folder(dir, &Limits::default())?;
    let manifest = &folder.manifest;
    let scene = match (&args.scene, &manifest.scene) {
        (Some(path), _) => Scene::load_gltf(path, &prt_trace::LoadOptions::default())
            .with_context(|| format!("cannot load {}", path.display()))?,
        (None, Some(path)) => Scene::load_gltf(Path::new(path), &prt_trace::LoadOptions::default())
            .with_context(|| format!("cannot load the manifest's scene {path} (give --scene)"))?,
        (None, None) => Scene::cornell_box(),
    };
    if folder.uvs.len() != scene.triangles().len() {
        bail!(
            "the lightmap has UVs for {} triangles, the scene has {}: not its scene (give --scene)",
            folder.uvs.len(),
            scene.triangles().len()
        );
    }
    let shading = match (manifest.basis, &manifest.sg) {
        _ if args.irradiance_layer => LightmapShading::Irradiance,
        (LightmapBasis::Sg { .. }, Some((axes, sharpness))) => {
            LightmapShading::Sg(axes, *sharpness)
        }
        (LightmapBasis::Sh { .. }, _) => LightmapShading::Sh,
        _ => LightmapShading::Irradiance,
    };
    if args.specular.is_some() && matches!(shading, LightmapShading::Irradiance) {
        bail!(
            "--specular needs the coefficients of an sg or sh lightmap (this one is {}{})",
            manifest.basis.label(),
            if args.irradiance_layer {
                ", read through --irradiance-layer"
            } else {
                ""
            }
        );
    }
    let view = pick_view(&scene, args.camera)?;
    let start = Instant::now();
    let image = render_lightmapped(
        &scene,
        &folder,
        &shading,
        args.specular,
        &view.view,
        args.size,
    );
    let seconds = start.elapsed().as_secs_f64();
    let tone = args
        .exposure
        .map_or_else(|| ToneMap::auto(&image), |exposure| ToneMap { exposure });
    save_render(&args.out, &image, &tone)?;
    eprintln!(
        "{} × {} pixels, camera {} ({}), {} lightmap {}×{} ({}), {seconds:.3} s; exposure {:.4}",
        image.width,
        image.height,
        args.camera,
        view.name,
        manifest.basis.label(),
        manifest.width,
        manifest.height,
        match shading {
            LightmapShading::Irradiance => "stored irradiance",
            _ => "reconstructed from the coefficients",
        },
        tone.exposure,
    );
    if !matches!(shading, LightmapShading::Irradiance) && args.specular.is_none() {
        let base = render_lightmapped(
            &scene,
            &folder,
            &LightmapShading::Irradiance,
            None,
            &view.view,
            args.size,
        );
        print_rmse(&image, &base, "the stored irradiance's render");
    }
    println!("wrote {}", args.out.display());
    Ok(())
}

/// Prints the RMSE of `image` against `base` and its share of `base`'s mean radiance.
fn print_rmse(image: &Rendered, base: &Rendered, against: &str) {
    if let Some(rmse) = image.rmse(base) {
        let mean = base
            .pixels
            .iter()
            .flatten()
            .map(|&v| f64::from(v))
            .sum::<f64>()
            / (3 * base.pixels.len()).max(1) as f64;
        println!(
            "RMSE against {against}: {rmse:.4e} ({:.3} % of its mean radiance {mean:.4e})",
            100.0 * rmse / mean.max(f64::MIN_POSITIVE)
        );
    }
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

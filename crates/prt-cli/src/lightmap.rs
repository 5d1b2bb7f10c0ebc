//! `prt lightmap [SCENE]`: a progressive lightmap (prt-lightmap) — UVs, path-traced texels
//! encoded with (non-negative) progressive least squares, previews while it converges, EXR and
//! KTX2 output with a JSON manifest.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use prt_export::{LightmapEngine, LightmapTexels, export_lightmap};
use prt_lightmap::{
    Atlas, Encoder, Lighting, Lightmap, LightmapBasis, LightmapConfig, UnwrapConfig,
    atlas_from_uvs, bake_lightmap, estimate_memory, render_view, unwrap_charts,
};
use prt_render::{Rendered, ToneMap};
use prt_texture::exr_io::{ExrLayer, ExrSample, write_exr};
use prt_texture::{Ktx2Texture, PixelFormat, Shape, write_atomic};
use prt_trace::Scene;
use prt_trace::camera::PinholeView;
use serde_json::json;

use crate::progress::StageBar;

/// Options of `prt lightmap`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "UVs: the scene's TEXCOORD_1 when every primitive has it (unless \
--generate-uvs), else planar charts packed on shelves. Writes OUT/lightmap.exr (layer `irradiance`, then one RGB layer per basis \
function `c00`, `c01`, ...: incident radiance in each texel's tangent frame, +Y the normal), \
OUT/lightmap.ktx2 (the same as a 2D array of RGBA32F layers, alpha 1 on texels with data), \
OUT/lightmap_uvs.bin (per scene triangle, its three lightmap UVs as 6 little-endian f32, 0..1, \
origin top-left), OUT/manifest.json, OUT/atlas.png and OUT/view.png (the irradiance atlas and \
the scene lit by the lightmap, tone-mapped), OUT/view.exr (that view, linear RGB: emission + \
albedo/pi * E; its camera is the manifest's `view`), and OUT/preview/{atlas,view}_NNNNN.png \
every --preview-every samples; OUT/view_mesh.bin and OUT/view_irradiance.bin (the latest \
preview) are what `prt view OUT` shows, refreshed while the bake runs. With --engine bevy or \
--engine threejs (repeatable), also \
OUT/ENGINE/: lightmap_scene.glb (the scene with the lightmap UVs as TEXCOORD_1), lightmap.ktx2 \
(RGBA16F, E/pi for Bevy's Lightmap, E for three.js's lightMap) and lightmap.json. Ctrl-C stops \
inside a pass and writes the last completed one."
)]
pub struct LightmapArgs {
    /// glTF 2.0 scene; the built-in Cornell box when omitted.
    pub scene: Option<PathBuf>,
    /// What each texel stores: `sg:N` (N lobes over the hemisphere), `sh:N` (order N, N²
    /// functions), `ambient-dice` or `irradiance`.
    #[arg(long, default_value = "sg:9")]
    pub basis: String,
    /// `plsq-nonneg` (no negative lobes), `plsq`, `ls`, `nnls` or `naive`.
    #[arg(long, default_value = "plsq-nonneg")]
    pub encoder: String,
    /// Samples per texel.
    #[arg(long, default_value_t = 256)]
    pub samples: u32,
    /// Samples per texel per pass (the state is consistent after each).
    #[arg(long, default_value_t = 16)]
    pub pass: u32,
    /// Write a preview every K samples per texel (0: none).
    #[arg(long, default_value_t = 64, value_name = "K")]
    pub preview_every: u32,
    /// Lightmap texels per metre (the atlas size for the scene's own TEXCOORD_1 follows from
    /// it and the UV area).
    #[arg(long, default_value_t = 16.0, value_name = "DENSITY")]
    pub texels_per_metre: f32,
    /// Generate charts even when every primitive of the scene has TEXCOORD_1.
    #[arg(long)]
    pub generate_uvs: bool,
    /// Empty texels between generated charts and at the atlas edges (filled by dilation).
    #[arg(long, default_value_t = 2)]
    pub padding: u32,
    /// Diffuse bounces after the surface a texel sees.
    #[arg(long, default_value_t = 2)]
    pub bounces: u32,
    /// Sun and sky: `auto` (only for a scene without emitters or lights), `on` or `off`.
    #[arg(long, default_value = "auto", value_name = "MODE")]
    pub sun_sky: String,
    /// Refuse to bake when the estimated memory exceeds this many GiB.
    #[arg(long, default_value_t = 4.0, value_name = "GIB")]
    pub max_memory: f64,
    /// Side of the preview and final view images, pixels.
    #[arg(long, default_value_t = 256, value_name = "PIXELS")]
    pub view_size: usize,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Also write the irradiance lightmap for an engine into OUT/ENGINE: `bevy` (its
    /// `Lightmap` component) or `threejs` (`material.lightMap`, channel 1); repeatable.
    #[arg(long, value_name = "ENGINE")]
    pub engine: Vec<String>,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

pub fn run(args: &LightmapArgs) -> Result<()> {
    let basis = LightmapBasis::parse(&args.basis)?;
    let encoder = Encoder::parse(&args.encoder)?;
    if !(args.max_memory.is_finite() && args.max_memory > 0.0) {
        bail!("--max-memory must be a positive number of GiB");
    }
    let engines = args
        .engine
        .iter()
        .map(|name| match name.as_str() {
            "bevy" => Ok(LightmapEngine::Bevy),
            "threejs" => Ok(LightmapEngine::Threejs),
            other => bail!("--engine {other:?}: expected bevy or threejs"),
        })
        .collect::<Result<Vec<_>>>()?;
    if args.view_size == 0 || args.view_size > 4096 {
        bail!("--view-size must be in 1..=4096 pixels");
    }
    let scene = match &args.scene {
        Some(path) => Scene::load_gltf(path, &prt_trace::LoadOptions::default())
            .with_context(|| format!("cannot load {}", path.display()))?,
        None => Scene::cornell_box(),
    };
    for warning in scene.warnings() {
        eprintln!("warning: {warning}");
    }
    let atlas = match scene.lightmap_uvs() {
        Some(uvs) if !args.generate_uvs => {
            let side = texcoord1_side(scene.triangles(), uvs, args.texels_per_metre)?;
            atlas_from_uvs(scene.triangles(), uvs, side, side)?
        }
        _ => unwrap_charts(
            scene.triangles(),
            &UnwrapConfig {
                texels_per_metre: args.texels_per_metre,
                padding: args.padding,
                ..UnwrapConfig::default()
            },
        )?,
    };
    for warning in &atlas.warnings {
        eprintln!("warning: {warning}");
    }
    let mut lighting = Lighting::for_scene(&scene);
    match args.sun_sky.as_str() {
        "auto" => {}
        "on" => lighting.sun_sky = Some(prt_trace::manylight::SunAndUniformSky::default()),
        "off" => lighting.sun_sky = None,
        other => bail!("--sun-sky {other:?}: expected auto, on or off"),
    }
    let config = LightmapConfig {
        basis,
        encoder,
        samples: args.samples,
        pass_samples: args.pass,
        snapshot_every: args.preview_every,
        bounces: args.bounces,
        lighting: Some(lighting),
        dilation: args.padding.max(1),
        seed: args.seed,
        max_memory_bytes: Some((args.max_memory * (1u64 << 30) as f64) as u64),
        ..LightmapConfig::default()
    };
    eprintln!(
        "atlas: {}×{} texels, {} charts ({}), {:.2} texels/m, packing efficiency {:.1}%, about {:.1} MiB",
        atlas.width,
        atlas.height,
        atlas.charts,
        match atlas.source {
            prt_lightmap::UvSource::Charts => "generated",
            prt_lightmap::UvSource::Texcoord1 => "TEXCOORD_1",
        },
        atlas.texel_density,
        100.0 * atlas.packing_efficiency,
        estimate_memory(&atlas, scene.triangles().len(), &config) as f64 / f64::from(1u32 << 20),
    );
    std::fs::create_dir_all(args.out.join("preview"))
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let view = PinholeView::for_scene(&scene)?;
    crate::view::lightmap::write_mesh(&args.out, &scene, &atlas, &view)?;
    let start = Instant::now();
    let stage = StageBar::start("lightmap");
    let mut preview_error = None;
    let bake = bake_lightmap(&scene, &atlas, &config, &stage, &mut |lightmap| {
        if preview_error.is_some() || lightmap.samples_per_texel == config.samples {
            return;
        }
        let tag = format!("{:05}", lightmap.samples_per_texel);
        let dir = args.out.join("preview");
        if let Err(e) = write_pictures(&scene, &atlas, lightmap, &view, args.view_size, &dir, &tag)
            .and_then(|()| crate::view::lightmap::write_irradiance(&args.out, lightmap))
        {
            preview_error = Some(e);
        }
    })?;
    let seconds = start.elapsed().as_secs_f64();
    if bake.cancelled {
        drop(stage);
        eprintln!(
            "cancelled: writing the last completed pass ({} samples per texel)",
            bake.lightmap.samples_per_texel
        );
    } else {
        stage.finish();
    }
    if let Some(e) = preview_error {
        return Err(e.context("cannot write a preview"));
    }
    let lightmap = &bake.lightmap;
    write_pictures(
        &scene,
        &atlas,
        lightmap,
        &view,
        args.view_size,
        &args.out,
        "",
    )?;
    write_textures(&args.out, lightmap)?;
    crate::view::lightmap::write_irradiance(&args.out, lightmap)?;
    for &engine in &engines {
        let folder = args.out.join(engine.label());
        export_lightmap(
            &scene,
            &atlas.normalized_uvs(),
            &LightmapTexels {
                width: lightmap.width,
                height: lightmap.height,
                irradiance: &lightmap.irradiance,
            },
            engine,
            &folder,
        )
        .with_context(|| format!("cannot write the {} lightmap", engine.label()))?;
    }
    let uv_bytes: Vec<u8> = atlas
        .normalized_uvs()
        .iter()
        .flatten()
        .flat_map(|p| [p.x.to_le_bytes(), p.y.to_le_bytes()])
        .flatten()
        .collect();
    let uv_path = args.out.join("lightmap_uvs.bin");
    write_atomic(&uv_path, &uv_bytes)
        .with_context(|| format!("cannot write {}", uv_path.display()))?;
    let sg = match basis {
        LightmapBasis::Sg { lobes } => {
            let (axes, sharpness) = LightmapBasis::sg_lobes(lobes);
            json!({ "axes": axes.iter().map(|a| a.to_array()).collect::<Vec<_>>(), "sharpness": sharpness })
        }
        _ => serde_json::Value::Null,
    };
    let manifest = json!({
        "scene": args.scene.as_ref().map_or("built-in Cornell box".to_string(), |p| p.display().to_string()),
        "width": lightmap.width,
        "height": lightmap.height,
        "basis": basis.label(),
        "functions": basis.len(),
        "sg": sg,
        "frame": "tangent frame per texel: +Y the triangle's winding normal, X and Z glam's Vec3::any_orthonormal_pair (Duff et al. 2017) of it",
        "encoder": encoder.label(),
        "samples_per_texel": lightmap.samples_per_texel,
        "cancelled": bake.cancelled,
        "bounces": args.bounces,
        "sun_sky": lighting.sun_sky.is_some(),
        "seed": args.seed,
        "uv_source": match atlas.source {
            prt_lightmap::UvSource::Charts => "charts",
            prt_lightmap::UvSource::Texcoord1 => "TEXCOORD_1",
        },
        "charts": atlas.charts,
        "texel_density_per_metre": atlas.texel_density,
        "packing_efficiency": atlas.packing_efficiency,
        "texels": bake.texels,
        "overlapping_texels": bake.overlapping_texels,
        "seam_pairs": bake.seam_pairs,
        "estimated_bytes": bake.estimated_bytes,
        "seconds": seconds,
        "warnings": atlas.warnings,
        "view": {
            "position": view.position.to_array(),
            "forward": view.forward.to_array(),
            "up": view.up.to_array(),
            "yfov": view.yfov,
            "size": args.view_size,
        },
        "engines": engines.iter().map(|e| e.label()).collect::<Vec<_>>(),
        "files": {
            "exr": "lightmap.exr",
            "ktx2": "lightmap.ktx2",
            "uvs": "lightmap_uvs.bin",
            "atlas": "atlas.png",
            "view": "view.png",
            "view_exr": "view.exr",
        },
    });
    let manifest_path = args.out.join("manifest.json");
    write_atomic(
        &manifest_path,
        serde_json::to_string_pretty(&manifest)?.as_bytes(),
    )
    .with_context(|| format!("cannot write {}", manifest_path.display()))?;
    println!(
        "{}×{} lightmap, {} texels, {} samples per texel{} in {seconds:.1} s -> {}",
        lightmap.width,
        lightmap.height,
        bake.texels,
        lightmap.samples_per_texel,
        if bake.cancelled { " (cancelled)" } else { "" },
        args.out.display()
    );
    if bake.overlapping_texels > 0 {
        eprintln!(
            "warning: {} texels are claimed by overlapping lightmap UVs",
            bake.overlapping_texels
        );
    }
    Ok(())
}

/// The square atlas side (a multiple of 4, at most 8192) that gives the scene's own lightmap
/// UVs `density` texels per metre: `side² · UV area = surface area · density²`.
fn texcoord1_side(
    triangles: &[[glam::Vec3; 3]],
    uvs: &[[glam::Vec2; 3]],
    density: f32,
) -> Result<u32> {
    if !(density.is_finite() && density > 0.0) {
        bail!("--texels-per-metre must be > 0");
    }
    let surface: f64 = triangles
        .iter()
        .map(|t| f64::from(0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()))
        .sum();
    let uv_area: f64 = uvs
        .iter()
        .map(|t| f64::from(0.5 * (t[1] - t[0]).perp_dot(t[2] - t[0]).abs()))
        .sum();
    if !(uv_area > 0.0 && uv_area.is_finite()) {
        bail!("the scene's TEXCOORD_1 covers no area; use --generate-uvs");
    }
    let side = f64::from(density) * (surface / uv_area).sqrt();
    Ok(((side / 4.0).ceil() as u32 * 4).clamp(4, 8192))
}

/// `atlas{tag}.png` (the irradiance atlas) and `view{tag}.png` (the scene lit by the lightmap),
/// tone-mapped with one exposure from the view; for the final pictures (no tag) also the view
/// as linear `view.exr`.
fn write_pictures(
    scene: &Scene,
    atlas: &Atlas,
    lightmap: &Lightmap,
    view: &PinholeView,
    size: usize,
    dir: &Path,
    tag: &str,
) -> Result<()> {
    let pixels = render_view(scene, atlas, lightmap, view, size, size)?;
    let rendered = Rendered {
        width: size,
        height: size,
        hit: pixels.iter().map(|p| p.iter().any(|&v| v > 0.0)).collect(),
        pixels,
        unlit: 0,
    };
    let tone = ToneMap::auto(&rendered);
    save_png(&dir.join(format!("view{tag}.png")), &rendered, &tone)?;
    if tag.is_empty() {
        let exr_path = dir.join("view.exr");
        let layer = ExrLayer {
            name: None,
            width: size as u32,
            height: size as u32,
            channels: 3,
            data: rendered.pixels.iter().flatten().copied().collect(),
        };
        write_exr(&exr_path, &[layer], ExrSample::F32)
            .with_context(|| format!("cannot write {}", exr_path.display()))?;
    }
    let (w, h) = (lightmap.width as usize, lightmap.height as usize);
    let texels = Rendered {
        width: w,
        height: h,
        pixels: lightmap
            .irradiance
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect(),
        hit: lightmap.covered.clone(),
        unlit: 0,
    };
    save_png(
        &dir.join(format!("atlas{tag}.png")),
        &texels,
        &ToneMap::auto(&texels),
    )
}

fn save_png(path: &Path, image: &Rendered, tone: &ToneMap) -> Result<()> {
    let img = image::RgbImage::from_raw(image.width as u32, image.height as u32, tone.apply(image))
        .context("image buffer of the wrong size")?;
    crate::report::save_png(path, &img)
}

/// lightmap.exr (F32 layers) and lightmap.ktx2 (RGBA32F 2D array), irradiance first.
fn write_textures(out: &Path, lightmap: &Lightmap) -> Result<()> {
    let layers: Vec<(String, &Vec<f32>)> =
        std::iter::once(("irradiance".to_string(), &lightmap.irradiance))
            .chain(
                lightmap
                    .coefficients
                    .iter()
                    .enumerate()
                    .map(|(i, c)| (format!("c{i:02}"), c)),
            )
            .collect();
    let exr: Vec<ExrLayer> = layers
        .iter()
        .map(|(name, data)| ExrLayer {
            name: Some(name.clone()),
            width: lightmap.width,
            height: lightmap.height,
            channels: 3,
            data: (*data).clone(),
        })
        .collect();
    let exr_path = out.join("lightmap.exr");
    write_exr(&exr_path, &exr, ExrSample::F32)
        .with_context(|| format!("cannot write {}", exr_path.display()))?;
    // Texels with data after dilation: any texel whose irradiance or coefficients are set.
    let filled: Vec<bool> = (0..lightmap.covered.len())
        .map(|i| {
            lightmap.covered[i]
                || layers
                    .iter()
                    .any(|(_, d)| d[3 * i..3 * i + 3].iter().any(|&v| v != 0.0))
        })
        .collect();
    let mut level = Vec::with_capacity(layers.len() * filled.len() * 4);
    for (_, data) in &layers {
        for (i, rgb) in data.chunks_exact(3).enumerate() {
            level.extend_from_slice(rgb);
            level.push(if filled[i] { 1.0 } else { 0.0 });
        }
    }
    let shape = Shape::d2_array(lightmap.width, lightmap.height, layers.len() as u32);
    let texture = Ktx2Texture::from_f32(PixelFormat::R32G32B32A32Sfloat, shape, &[level])?;
    let ktx_path = out.join("lightmap.ktx2");
    texture
        .write_file(&ktx_path)
        .with_context(|| format!("cannot write {}", ktx_path.display()))
}

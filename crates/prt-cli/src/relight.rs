//! `prt relight`: all-frequency relighting of a traced scene from a fixed camera. Bakes (or
//! reuses) the per-pixel wavelet transport, turns an environment map about +Y frame by frame,
//! and renders every frame with the chosen lighting approximations (NWA, BI, PBI) and the exact
//! product; writes the frames, an animated preview, a per-frame table and the error plot.

use std::fmt::Write as _;
use std::io::Cursor;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use prt_render::{Rendered, ToneMap};
use prt_texture::{Limits, write_atomic};
use prt_trace::RayTracer;
use prt_trace::camera::PinholeView;
use prt_trace::relight::{
    Bounce, MethodRelighter, PixelTransport, PixelTransportBaker, PixelTransportOptions,
    RelightMethod, Sparsify,
};
use prt_wavelet::CubemapHaar;
use prt_wavelet::sequence::Rotation;

use crate::progress::StageBar;

/// Options of `prt relight`.
#[derive(Debug, Clone, clap::Args)]
pub struct RelightArgs {
    /// glTF 2.0 scene seen through its first camera (else a framing of its bounds); the
    /// built-in Cornell box when omitted.
    pub scene: Option<PathBuf>,
    /// The lighting: a lat-long `.hdr` / `.exr` environment map.
    #[arg(long, value_name = "MAP")]
    pub envmap: PathBuf,
    /// Turn the map by DEG degrees about +Y per frame.
    #[arg(
        long,
        default_value_t = 1.0,
        value_name = "DEG",
        allow_hyphen_values = true
    )]
    pub rotate: f32,
    /// Frames to render.
    #[arg(long, default_value_t = 60, value_name = "N")]
    pub frames: usize,
    /// The map stops turning at this frame [default: two thirds of the frames].
    #[arg(long, value_name = "FRAME")]
    pub stop: Option<usize>,
    /// Lighting terms per frame for methods given without their own (`nwa` = `nwa:K`).
    #[arg(long, default_value_t = 30, value_name = "K")]
    pub terms: usize,
    /// Lighting approximations, comma-separated: `nwa`, `bi`, `pbi` (optionally `:TERMS`, e.g.
    /// `nwa:100`) and `exact` (every coefficient). The exact product is always rendered, as the
    /// reference of the error columns.
    #[arg(
        long,
        default_value = "nwa,bi,pbi",
        value_delimiter = ',',
        value_name = "METHOD"
    )]
    pub method: Vec<String>,
    /// Image width and height in pixels.
    #[arg(long, default_value_t = 128, value_name = "PIXELS")]
    pub size: usize,
    /// Cube-map face side of the light directions (a power of two up to 256; 64 quadruples
    /// the rays and the lighting coefficients).
    #[arg(long, default_value_t = 32, value_name = "N")]
    pub cube: usize,
    /// Add one diffuse bounce (colour bleeding); the transport becomes RGB.
    #[arg(long)]
    pub bounce: bool,
    /// Gather rays per pixel for --bounce.
    #[arg(long, default_value_t = 16, value_name = "RAYS")]
    pub gathers: usize,
    /// Keep the largest wavelet coefficients of each pixel's row until they hold this fraction
    /// of its energy.
    #[arg(long, default_value_t = 0.999, value_name = "FRACTION")]
    pub energy: f32,
    /// At most this many coefficients per pixel row.
    #[arg(long, default_value_t = 1024, value_name = "TERMS")]
    pub max_terms: usize,
    /// Refuse to bake when the estimated peak memory exceeds this many GiB.
    #[arg(long, default_value_t = 4.0, value_name = "GIB")]
    pub max_memory: f64,
    /// Seed of the bounce's gather rays.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output folder: frames/METHOD_NNNN.png, preview.png (animated), frames.csv, frames.md,
    /// error.png and transport.prtpx (reused when baked with the same options and view).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

/// One method's per-frame results.
struct Track {
    relighter: MethodRelighter,
    rows: Vec<FrameRow>,
}

struct FrameRow {
    image_rmse: f64,
    relative_rmse: f64,
    lighting_l1: f64,
    terms_per_band: Vec<usize>,
    bytes: usize,
    seconds: f64,
}

pub fn run(args: &RelightArgs) -> Result<()> {
    let methods = parse_methods(&args.method, args.terms)?;
    if args.frames == 0 {
        bail!("--frames must be at least 1");
    }
    if !args.rotate.is_finite() {
        bail!("--rotate must be a finite number of degrees");
    }
    if args.size == 0 || args.size > 2048 {
        bail!("--size must be in 1..=2048 pixels");
    }
    let map = crate::sky::read_envmap(&args.envmap)?;
    let scene = match &args.scene {
        Some(path) => prt_trace::Scene::load_gltf(path, &prt_trace::LoadOptions::default())
            .with_context(|| format!("cannot load {}", path.display()))?,
        None => prt_trace::Scene::cornell_box(),
    };
    let tracer = RayTracer::new(scene.triangles());
    let view = PinholeView::for_scene(&scene)?;
    let options = PixelTransportOptions {
        width: args.size,
        height: args.size,
        cube_size: args.cube,
        sparsify: Sparsify {
            energy: args.energy,
            max_terms: args.max_terms,
        },
        bounce: args.bounce.then_some(Bounce {
            gathers: args.gathers,
        }),
        seed: args.seed,
        ..Default::default()
    };
    std::fs::create_dir_all(args.out.join("frames"))
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let transport = transport(&scene, &tracer, view, options, &args.out, args.max_memory)?;
    eprintln!(
        "transport: {} pixels × {} coefficients × {} channel(s), {} entries ({:.1} MB)",
        transport.pixels(),
        transport.cols(),
        transport.transport.len(),
        transport.nnz(),
        transport.entry_bytes() as f64 / 1e6
    );

    let stop = args.stop.unwrap_or(args.frames * 2 / 3);
    let rotation = Rotation::new(map, args.cube, args.rotate.to_radians(), stop)?;
    let mut exact = MethodRelighter::new(&transport, RelightMethod::Exact)?;
    let mut tracks = methods
        .iter()
        .filter(|m| **m != RelightMethod::Exact)
        .map(|&m| {
            Ok(Track {
                relighter: MethodRelighter::new(&transport, m)?,
                rows: Vec::new(),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let mut exact_rows = Vec::new();
    let mut haar = CubemapHaar::new(args.cube)?;
    let mut tone: Option<ToneMap> = None;
    let mut preview: Vec<Vec<u8>> = Vec::new();
    let (w, h) = (args.size, args.size);
    let stage = StageBar::start("relight");
    prt_core::Progress::set_len(&stage, args.frames as u64);
    for t in 0..args.frames {
        if prt_core::Progress::is_cancelled(&stage) {
            bail!("cancelled");
        }
        let texels = rotation.frame(t)?.into_data();
        let mut coefficients = texels.clone();
        haar.forward(&mut coefficients)?;
        let reference = exact.frame(&coefficients, &texels)?;
        let rendered = |image: &[[f32; 3]]| Rendered {
            width: w,
            height: h,
            pixels: image.to_vec(),
            hit: transport.hit.clone(),
            unlit: 0,
        };
        let exact_image = rendered(&reference.image);
        let tone = *tone.get_or_insert_with(|| ToneMap::auto(&exact_image));
        let mut strip = vec![tone.apply(&exact_image)];
        crate::render::save_render(
            &args.out.join(format!("frames/exact_{t:04}.png")),
            &exact_image,
            &tone,
        )?;
        let reference_rms = rms(&reference.image);
        exact_rows.push(FrameRow {
            image_rmse: 0.0,
            relative_rmse: 0.0,
            lighting_l1: reference.lighting_l1,
            terms_per_band: reference.terms_per_band.clone(),
            bytes: reference.bytes,
            seconds: reference.seconds,
        });
        for track in &mut tracks {
            let frame = track.relighter.frame(&coefficients, &texels)?;
            let image_rmse = rmse(&frame.image, &reference.image);
            let image = rendered(&frame.image);
            let name = track.relighter.method().name();
            crate::render::save_render(
                &args.out.join(format!("frames/{name}_{t:04}.png")),
                &image,
                &tone,
            )?;
            strip.push(tone.apply(&image));
            track.rows.push(FrameRow {
                image_rmse,
                relative_rmse: image_rmse / reference_rms.max(1e-30),
                lighting_l1: frame.lighting_l1,
                terms_per_band: frame.terms_per_band,
                bytes: frame.bytes,
                seconds: frame.seconds,
            });
        }
        preview.push(side_by_side(&strip, w, h));
        prt_core::Progress::inc(&stage, 1);
    }
    stage.finish();

    let names: Vec<String> = std::iter::once("exact".to_string())
        .chain(tracks.iter().map(|t| t.relighter.method().name()))
        .collect();
    write_apng(
        &args.out.join("preview.png"),
        &preview,
        (w * names.len()) as u32,
        h as u32,
    )?;
    let all: Vec<(String, &[FrameRow])> = std::iter::once(("exact".to_string(), &exact_rows[..]))
        .chain(
            tracks
                .iter()
                .map(|t| (t.relighter.method().name(), &t.rows[..])),
        )
        .collect();
    write_tables(&args.out, &all, stop)?;
    let plot = error_plot_png(&all[1..], stop)?;
    write_atomic(&args.out.join("error.png"), &plot)
        .with_context(|| format!("cannot write {}", args.out.join("error.png").display()))?;
    for (name, rows) in &all[1..] {
        let rotating: Vec<f64> = rows[..stop.min(rows.len())]
            .iter()
            .map(|r| r.relative_rmse)
            .collect();
        let mean = rotating.iter().sum::<f64>() / rotating.len().max(1) as f64;
        eprintln!(
            "{name:>8}: mean relative image RMSE while rotating {mean:.4}, last frame {:.4}",
            rows.last().map_or(0.0, |r| r.relative_rmse)
        );
    }
    eprintln!(
        "wrote {} frames × {} images, preview.png ({}), frames.csv, frames.md, error.png to {}",
        args.frames,
        names.len(),
        names.join(" | "),
        args.out.display()
    );
    Ok(())
}

/// `nwa`, `bi`, `pbi` with optional `:TERMS`, and `exact`.
fn parse_methods(specs: &[String], terms: usize) -> Result<Vec<RelightMethod>> {
    let mut out = Vec::new();
    for spec in specs {
        let (name, k) = match spec.split_once(':') {
            Some((name, k)) => (
                name,
                k.parse::<usize>()
                    .ok()
                    .filter(|&k| k > 0)
                    .with_context(|| {
                        format!("--method {spec}: terms must be a positive integer")
                    })?,
            ),
            None => (spec.as_str(), terms),
        };
        if k == 0 {
            bail!("--terms must be at least 1");
        }
        out.push(match name.trim().to_lowercase().as_str() {
            "nwa" => RelightMethod::Nwa(k),
            "bi" => RelightMethod::Bi(k),
            "pbi" => RelightMethod::Pbi(k),
            "exact" => RelightMethod::Exact,
            _ => bail!("--method {spec}: expected nwa, bi, pbi or exact (optionally :TERMS)"),
        });
    }
    out.dedup();
    Ok(out)
}

/// The scene key written beside the transport: a hash of the scene's triangles and materials.
const TRANSPORT_SCENE: &str = "transport.scene";

/// The transport of OUT/transport.prtpx when it was baked from this scene (its hash in
/// OUT/transport.scene) with these options and view, else a fresh bake (estimated, checked
/// against `max_memory` GiB, then written there with the scene's hash).
fn transport(
    scene: &prt_trace::Scene,
    tracer: &RayTracer,
    view: PinholeView,
    options: PixelTransportOptions,
    out: &Path,
    max_memory: f64,
) -> Result<PixelTransport> {
    let path = out.join("transport.prtpx");
    let key_path = out.join(TRANSPORT_SCENE);
    let key = prt_bake::scene_hash(scene);
    let limits = Limits {
        max_bytes: 16 << 30,
        ..Limits::default()
    };
    if path.is_file() {
        let same_scene = std::fs::read_to_string(&key_path).is_ok_and(|k| k.trim() == key);
        match PixelTransport::read(&path, &limits) {
            Ok(t) if same_scene && t.options == options && t.view == view => {
                eprintln!("reusing {}", path.display());
                return Ok(t);
            }
            Ok(_) if !same_scene => eprintln!(
                "{} was baked from another scene (or an edited one): baking again",
                path.display()
            ),
            Ok(_) => eprintln!(
                "{} was baked with other options: baking again",
                path.display()
            ),
            Err(e) => eprintln!("{e}: baking again"),
        }
    }
    let baker = PixelTransportBaker::new(scene, tracer, view, options)?;
    let estimate = baker.estimate(32);
    eprintln!(
        "estimate: {} hit pixels, ≤ {:.2e} rays, peak ≤ {:.2} GiB, transport ≤ {:.1} MB, ~{:.0} s",
        estimate.hit_pixels,
        estimate.max_rays as f64,
        estimate.peak_bytes as f64 / (1u64 << 30) as f64,
        estimate.stored_bytes as f64 / 1e6,
        estimate.seconds
    );
    let gib = estimate.peak_bytes as f64 / (1u64 << 30) as f64;
    if gib > max_memory {
        bail!(
            "the bake may need {gib:.2} GiB, more than --max-memory {max_memory}; lower --size, --cube or --max-terms"
        );
    }
    let stage = StageBar::start("transport");
    let transport = baker.bake(&stage)?;
    stage.finish();
    transport.write(&path)?;
    write_atomic(&key_path, key.as_bytes())
        .with_context(|| format!("cannot write {}", key_path.display()))?;
    Ok(transport)
}

fn rms(image: &[[f32; 3]]) -> f64 {
    let s: f64 = image.iter().flatten().map(|&v| (v as f64).powi(2)).sum();
    (s / (3 * image.len()).max(1) as f64).sqrt()
}

fn rmse(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let s: f64 = a
        .iter()
        .flatten()
        .zip(b.iter().flatten())
        .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
        .sum();
    (s / (3 * a.len()).max(1) as f64).sqrt()
}

/// RGB images of `w × h` laid out left to right.
fn side_by_side(images: &[Vec<u8>], w: usize, h: usize) -> Vec<u8> {
    let mut out = vec![0u8; images.len() * w * h * 3];
    for (i, img) in images.iter().enumerate() {
        for y in 0..h {
            let dst = (y * images.len() * w + i * w) * 3;
            out[dst..dst + 3 * w].copy_from_slice(&img[y * w * 3..(y + 1) * w * 3]);
        }
    }
    out
}

/// An animated PNG (APNG, 10 frames per second, looping), written atomically.
fn write_apng(path: &Path, frames: &[Vec<u8>], width: u32, height: u32) -> Result<()> {
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut bytes, width, height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_animated(frames.len() as u32, 0)?;
        encoder.set_frame_delay(1, 10)?;
        let mut writer = encoder.write_header()?;
        for frame in frames {
            writer.write_image_data(frame)?;
        }
        writer.finish()?;
    }
    write_atomic(path, &bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// frames.csv (one row per frame and method) and frames.md (per-method summary, then the CSV's
/// rows for the first method's frames around the stop).
fn write_tables(out: &Path, all: &[(String, &[FrameRow])], stop: usize) -> Result<()> {
    let mut csv = String::from(
        "method,frame,image_rmse,relative_image_rmse,lighting_l1,terms_per_band,transport_bytes,frame_ms\n",
    );
    for (name, rows) in all {
        for (t, r) in rows.iter().enumerate() {
            let bands: Vec<String> = r.terms_per_band.iter().map(|c| c.to_string()).collect();
            writeln!(
                csv,
                "{name},{t},{:.6e},{:.6e},{:.6e},{},{},{:.3}",
                r.image_rmse,
                r.relative_rmse,
                r.lighting_l1,
                bands.join("/"),
                r.bytes,
                r.seconds * 1e3
            )?;
        }
    }
    write_atomic(&out.join("frames.csv"), csv.as_bytes()).context("cannot write frames.csv")?;
    let mut md = format!(
        "# prt relight\n\nRelative image RMSE = RMSE against the exact frame / RMS of the exact \
         frame (linear radiance, all pixels and channels); lighting L1 = area-weighted L1 error of \
         the approximated lighting. The map rotates until frame {stop}.\n\n\
         | method | mean rel. RMSE, rotating | max rel. RMSE, rotating | rel. RMSE, last frame | \
         frames after the stop to rel. RMSE < 1e-2 | mean lighting L1 | mean frame time |\n\
         |---|---|---|---|---|---|---|\n"
    );
    for (name, rows) in all {
        let rotating = &rows[..stop.min(rows.len())];
        let mean =
            rotating.iter().map(|r| r.relative_rmse).sum::<f64>() / rotating.len().max(1) as f64;
        let max = rotating.iter().map(|r| r.relative_rmse).fold(0.0, f64::max);
        let converged = rows
            .iter()
            .enumerate()
            .skip(stop)
            .find(|(_, r)| r.relative_rmse < 1e-2)
            .map_or("—".to_string(), |(t, _)| (t - stop).to_string());
        let l1 = rows.iter().map(|r| r.lighting_l1).sum::<f64>() / rows.len().max(1) as f64;
        let ms = rows.iter().map(|r| r.seconds).sum::<f64>() * 1e3 / rows.len().max(1) as f64;
        writeln!(
            md,
            "| {name} | {mean:.4} | {max:.4} | {:.4} | {converged} | {l1:.4} | {ms:.2} ms |",
            rows.last().map_or(0.0, |r| r.relative_rmse)
        )?;
    }
    md.push_str("\nEvery frame of every method: frames.csv.\n");
    write_atomic(&out.join("frames.md"), md.as_bytes()).context("cannot write frames.md")?;
    Ok(())
}

/// Figure 6.2 of Overbeck's thesis, on images: relative image RMSE per frame for each method
/// (log scale), the stop frame marked.
fn error_plot_png(all: &[(String, &[FrameRow])], stop: usize) -> Result<Vec<u8>> {
    use plotters::prelude::*;
    crate::report::register_font()?;
    let (w, h) = (760u32, 440u32);
    let frames = all.first().map_or(1, |(_, r)| r.len()).max(2);
    let values = all
        .iter()
        .flat_map(|(_, r)| r.iter().map(|r| r.relative_rmse));
    let positive: Vec<f64> = values.filter(|&v| v > 0.0).collect();
    let hi = positive.iter().copied().fold(1e-6, f64::max) * 1.5;
    let lo = positive
        .iter()
        .copied()
        .fold(f64::MAX, f64::min)
        .min(hi / 10.0)
        .max(1e-7);
    let floor = lo;
    let mut buffer = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area();
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "Image error per frame (rotating, then stopped)",
                ("sans-serif", 20),
            )
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(80)
            .build_cartesian_2d(0..frames, (floor..hi).log_scale())
            .map_err(|e| anyhow::anyhow!("plot: {e:?}"))?;
        chart
            .configure_mesh()
            .x_desc("frame")
            .y_desc("RMSE / RMS of the exact frame")
            .label_style(("sans-serif", 14))
            .draw()
            .map_err(|e| anyhow::anyhow!("plot: {e:?}"))?;
        chart
            .draw_series(LineSeries::new(
                [(stop, floor), (stop, hi)],
                RGBColor(160, 160, 160).stroke_width(1),
            ))
            .map_err(|e| anyhow::anyhow!("plot: {e:?}"))?;
        let colours = [
            BLUE,
            RED,
            RGBColor(0, 150, 0),
            MAGENTA,
            RGBColor(230, 140, 0),
            CYAN,
            BLACK,
        ];
        for (i, (name, rows)) in all.iter().enumerate() {
            let colour = colours[i % colours.len()];
            chart
                .draw_series(LineSeries::new(
                    rows.iter()
                        .enumerate()
                        .map(|(t, r)| (t, r.relative_rmse.max(floor))),
                    colour.stroke_width(2),
                ))
                .map_err(|e| anyhow::anyhow!("plot: {e:?}"))?
                .label(name.clone())
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 18, y)], colour));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(|e| anyhow::anyhow!("plot: {e:?}"))?;
        root.present().map_err(|e| anyhow::anyhow!("plot: {e:?}"))?;
    }
    let img = image::RgbImage::from_raw(w, h, buffer).context("plot buffer of the wrong size")?;
    let mut bytes = Vec::new();
    img.write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn methods_parse_with_and_without_terms() {
        let specs: Vec<String> = ["nwa", "nwa:100", "PBI", "exact"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        assert_eq!(
            parse_methods(&specs, 30).unwrap(),
            vec![
                RelightMethod::Nwa(30),
                RelightMethod::Nwa(100),
                RelightMethod::Pbi(30),
                RelightMethod::Exact
            ]
        );
        assert!(parse_methods(&["nwa:0".to_string()], 30).is_err());
        assert!(parse_methods(&["svd".to_string()], 30).is_err());
    }

    #[test]
    fn the_transport_is_reused_only_for_the_same_scene_options_and_view() {
        let out = std::env::temp_dir().join(format!("prt-relight-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        std::fs::create_dir_all(&out).unwrap();
        let options = PixelTransportOptions {
            width: 6,
            height: 6,
            cube_size: 4,
            ..Default::default()
        };
        let bake = |scene: &prt_trace::Scene| {
            let tracer = RayTracer::new(scene.triangles());
            let view = PinholeView::for_scene(scene).unwrap();
            transport(scene, &tracer, view, options, &out, 4.0).unwrap()
        };
        let scene = prt_trace::Scene::cornell_box();
        let first = bake(&scene);
        let written = std::fs::metadata(out.join("transport.prtpx"))
            .unwrap()
            .modified()
            .unwrap();
        let again = bake(&scene);
        assert_eq!(again.view, first.view);
        let reused = std::fs::metadata(out.join("transport.prtpx"))
            .unwrap()
            .modified()
            .unwrap();
        assert_eq!(reused, written, "the same scene reuses the file");
        // The same view and options over an edited scene (one albedo changed) bake again.
        let mut edited = scene.clone();
        edited.set_uniform_albedo(prt_core::glam::Vec3::splat(0.25));
        assert_ne!(prt_bake::scene_hash(&edited), prt_bake::scene_hash(&scene));
        std::thread::sleep(std::time::Duration::from_millis(20));
        bake(&edited);
        let key = std::fs::read_to_string(out.join(TRANSPORT_SCENE)).unwrap();
        assert_eq!(key, prt_bake::scene_hash(&edited));
        let _ = std::fs::remove_dir_all(&out);
    }

    #[test]
    fn side_by_side_keeps_rows() {
        let a = vec![1u8; 2 * 2 * 3];
        let b = vec![2u8; 2 * 2 * 3];
        let s = side_by_side(&[a, b], 2, 2);
        assert_eq!(&s[..12], &[1, 1, 1, 1, 1, 1, 2, 2, 2, 2, 2, 2]);
    }
}

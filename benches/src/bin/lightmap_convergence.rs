//! Lightmap texels converging (Roughton 2020, Figure 6 on texels): the error of each encoder's
//! fit against a converged reference as samples per texel grow, for PLSQ, non-negative PLSQ,
//! least squares, NNLS and naive projection, on the same samples (same seed).
//!
//! Run: `cargo run --release -p prt-benches --bin lightmap_convergence -- [--scene cornell]
//! [--basis sg:9] [--texels-per-metre 8] [--max-samples 1024] [--reference 16384]
//! [--reference-encoder ls|nnls]
//! [--correlated] [--no-hemisphere-rule] [--plot PATH] [--csv DIR]
//! [--figure5 PATH [--figure-samples 8] [--figure-size 256]]`
//!
//! `--figure5 PATH` also writes the paper's Figure 5 on texels: the scene lit by non-negative
//! PLSQ lightmaps of `--figure-samples` samples per texel, one with every texel on the same
//! scrambled sequence (correlated) and one with a scramble per texel (decorrelated, the
//! default), beside the reference; one exposure for the three (the reference's).
//!
//! The reference is the least-squares fit (hemisphere rule on; `--reference-encoder nnls`: the
//! non-negative one) with `--reference` samples per texel and another seed: the best the basis
//! can do. Errors, over the texels with a surface
//! point: `radiance` = RMS over texels and 512 uniform hemisphere directions of the fitted minus
//! the reference radiance, relative to the reference's RMS; `irradiance` = RMS of the
//! irradiance difference relative to the reference irradiance's RMS; `negative` = fraction of
//! those directions where the fit is below zero (negative light). Time is the wall time of the
//! whole bake per sample per texel (tracing dominates; snapshots excluded).
use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Parser;
use glam::Vec3;
use prt_benches::{PlotLabels, PlotPoint, RelativeError, Table, load_scene, plot_lines, save_png};
use prt_core::{NoProgress, SphericalBasis};
use prt_lightmap::{
    Encoder, Lightmap, LightmapBasis, LightmapConfig, UnwrapConfig, bake_lightmap, render_view,
    unwrap_charts,
};
use prt_render::{Rendered, ToneMap};
use prt_sphere::{AmbientDiceSrbf, SgBasis, ShBasis};
use prt_trace::camera::PinholeView;

#[derive(Parser)]
struct Args {
    /// cornell, sponza, gas_station or town.
    #[arg(long, default_value = "cornell")]
    scene: String,
    /// sg:N, sh:N or ambient-dice.
    #[arg(long, default_value = "sg:9")]
    basis: String,
    /// Texel density of the generated charts.
    #[arg(long, default_value_t = 8.0)]
    texels_per_metre: f32,
    /// Largest sample count per texel (errors at every power of two up to it).
    #[arg(long, default_value_t = 1024)]
    max_samples: u32,
    /// Samples per texel of the reference.
    #[arg(long, default_value_t = 16384)]
    reference: u32,
    /// The reference's encoder: `ls` (the basis' best fit) or `nnls` (the best non-negative
    /// fit, the limit of the non-negative encoders).
    #[arg(long, default_value = "ls")]
    reference_encoder: String,
    /// Diffuse bounces.
    #[arg(long, default_value_t = 2)]
    bounces: u32,
    /// Every texel uses the same scrambled sequence (the paper's Figure 5, correlated).
    #[arg(long)]
    correlated: bool,
    /// Turn Roughton's hemisphere rule (zero-radiance mirror samples) off.
    #[arg(long)]
    no_hemisphere_rule: bool,
    /// Encoders, comma-separated.
    #[arg(
        long,
        default_value = "plsq,plsq-nonneg,ls,nnls,naive",
        value_delimiter = ','
    )]
    encoders: Vec<String>,
    /// Write the radiance-error plot here (PNG).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Write the table as CSV into this folder.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Write Figure 5 (correlated | decorrelated | reference views) here (PNG).
    #[arg(long)]
    figure5: Option<PathBuf>,
    /// Samples per texel of Figure 5's two lightmaps.
    #[arg(long, default_value_t = 8)]
    figure_samples: u32,
    /// Side of each of Figure 5's views, pixels.
    #[arg(long, default_value_t = 256)]
    figure_size: usize,
}

/// Figure 5: views of the scene lit by a correlated and a decorrelated lightmap of
/// `args.figure_samples` samples per texel, and by the reference, side by side.
fn figure5(
    args: &Args,
    scene: &prt_trace::Scene,
    atlas: &prt_lightmap::Atlas,
    base: &LightmapConfig,
    reference: &Lightmap,
    path: &std::path::Path,
) -> Result<(), String> {
    let view = PinholeView::for_scene(scene).map_err(|e| e.to_string())?;
    let size = args.figure_size;
    let render = |lightmap: &Lightmap| -> Result<Rendered, String> {
        let pixels =
            render_view(scene, atlas, lightmap, &view, size, size).map_err(|e| e.to_string())?;
        Ok(Rendered {
            width: size,
            height: size,
            hit: pixels.iter().map(|p| p.iter().any(|&v| v > 0.0)).collect(),
            pixels,
            unlit: 0,
        })
    };
    let mut panels = Vec::new();
    for decorrelated in [false, true] {
        let bake = bake_lightmap(
            scene,
            atlas,
            &LightmapConfig {
                encoder: Encoder::PlsqNonNegative,
                samples: args.figure_samples,
                pass_samples: args.figure_samples,
                decorrelated,
                ..*base
            },
            &NoProgress,
            &mut |_| {},
        )
        .map_err(|e| e.to_string())?;
        panels.push(render(&bake.lightmap)?);
    }
    let reference = render(reference)?;
    let tone = ToneMap::auto(&reference);
    panels.push(reference);
    let mut image = image::RgbImage::new((3 * size) as u32, size as u32);
    for (k, panel) in panels.iter().enumerate() {
        let bytes = tone.apply(panel);
        for (i, rgb) in bytes.chunks_exact(3).enumerate() {
            let (x, y) = ((k * size + i % size) as u32, (i / size) as u32);
            image.put_pixel(x, y, image::Rgb([rgb[0], rgb[1], rgb[2]]));
        }
    }
    save_png(&image, path)
}

/// The basis functions of `basis`; the irradiance basis has none to measure directions with.
fn functions(basis: LightmapBasis) -> Result<Box<dyn SphericalBasis>, String> {
    Ok(match basis {
        LightmapBasis::Sg { lobes } => {
            let (axes, sharpness) = LightmapBasis::sg_lobes(lobes);
            Box::new(SgBasis::new(axes, vec![sharpness; lobes], "sg").expect("valid lobes"))
        }
        LightmapBasis::Sh { order } => Box::new(ShBasis::new(order).expect("valid order")),
        LightmapBasis::AmbientDice => Box::new(AmbientDiceSrbf),
        LightmapBasis::Irradiance => {
            return Err(
                "--basis irradiance has no directional fit to measure; use sg:N, sh:N or \
                 ambient-dice"
                    .into(),
            );
        }
    })
}

/// 512 uniform directions over the upper hemisphere (+Y), a Fibonacci spiral.
fn hemisphere_directions() -> Vec<Vec3> {
    let n = 512;
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - (i as f32 + 0.5) / n as f32;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let phi = golden * i as f32;
            Vec3::new(r * phi.cos(), y, r * phi.sin())
        })
        .collect()
}

/// Per covered texel and direction, the fitted radiance (RGB).
fn radiance(lightmap: &Lightmap, basis: &dyn SphericalBasis, table: &[Vec<f32>]) -> Vec<Vec3> {
    let mut out = Vec::new();
    for (i, covered) in lightmap.covered.iter().enumerate() {
        if !covered {
            continue;
        }
        for b in table {
            let mut v = Vec3::ZERO;
            for (f, layer) in lightmap.coefficients.iter().enumerate().take(basis.len()) {
                v += Vec3::from_slice(&layer[3 * i..3 * i + 3]) * b[f];
            }
            out.push(v);
        }
    }
    out
}

fn irradiance(lightmap: &Lightmap) -> Vec<Vec3> {
    lightmap
        .covered
        .iter()
        .enumerate()
        .filter(|(_, c)| **c)
        .map(|(i, _)| Vec3::from_slice(&lightmap.irradiance[3 * i..3 * i + 3]))
        .collect()
}

fn relative_rms(a: &[Vec3], reference: &[Vec3]) -> f64 {
    let mut sum = RelativeError::default();
    for (x, r) in a.iter().zip(reference) {
        sum.add(&x.to_array(), &r.to_array());
    }
    sum.relative_rms()
}

fn main() -> Result<(), String> {
    let args = Args::parse();
    let scene = load_scene(&args.scene)?;
    let basis = LightmapBasis::parse(&args.basis).map_err(|e| e.to_string())?;
    let encoders: Vec<Encoder> = args
        .encoders
        .iter()
        .map(|e| Encoder::parse(e).map_err(|e| e.to_string()))
        .collect::<Result<_, _>>()?;
    let atlas = unwrap_charts(
        scene.triangles(),
        &UnwrapConfig {
            texels_per_metre: args.texels_per_metre,
            ..Default::default()
        },
    )
    .map_err(|e| e.to_string())?;
    let functions = functions(basis)?;
    let dirs = hemisphere_directions();
    let table: Vec<Vec<f32>> = dirs
        .iter()
        .map(|&d| {
            let mut b = vec![0.0; functions.len()];
            functions.eval(d, &mut b);
            b
        })
        .collect();
    let base = LightmapConfig {
        basis,
        bounces: args.bounces,
        hemisphere_rule: !args.no_hemisphere_rule,
        decorrelated: !args.correlated,
        ..LightmapConfig::default()
    };
    let started = Instant::now();
    let reference = bake_lightmap(
        &scene,
        &atlas,
        &LightmapConfig {
            encoder: Encoder::parse(&args.reference_encoder).map_err(|e| e.to_string())?,
            samples: args.reference,
            pass_samples: 256,
            seed: 0x0005_EED0_F2EF,
            hemisphere_rule: true,
            decorrelated: true,
            ..base
        },
        &NoProgress,
        &mut |_| {},
    )
    .map_err(|e| e.to_string())?;
    eprintln!(
        "{}: {}×{} atlas, {} texels; reference ({} samples) in {:.1} s",
        args.scene,
        atlas.width,
        atlas.height,
        reference.texels,
        args.reference,
        started.elapsed().as_secs_f64()
    );
    if let Some(path) = &args.figure5 {
        figure5(&args, &scene, &atlas, &base, &reference.lightmap, path)?;
    }
    let reference_radiance = radiance(&reference.lightmap, functions.as_ref(), &table);
    let reference_irradiance = irradiance(&reference.lightmap);
    let mut out = Table::new(&[
        "encoder",
        "samples",
        "radiance error",
        "irradiance error",
        "negative",
        "µs / sample / texel",
    ]);
    let mut points: Vec<PlotPoint> = Vec::new();
    for &encoder in &encoders {
        let mut rows = Vec::new();
        let mut snapshot_time = Duration::ZERO;
        let started = Instant::now();
        let bake = bake_lightmap(
            &scene,
            &atlas,
            &LightmapConfig {
                encoder,
                samples: args.max_samples,
                pass_samples: 1,
                snapshot_every: 1,
                ..base
            },
            &NoProgress,
            &mut |lightmap| {
                let n = lightmap.samples_per_texel;
                if !n.is_power_of_two() {
                    return;
                }
                let t = Instant::now();
                let fit = radiance(lightmap, functions.as_ref(), &table);
                let negative =
                    fit.iter().filter(|v| v.min_element() < 0.0).count() as f64 / fit.len() as f64;
                rows.push((
                    n,
                    relative_rms(&fit, &reference_radiance),
                    relative_rms(&irradiance(lightmap), &reference_irradiance),
                    negative,
                ));
                snapshot_time += t.elapsed();
            },
        )
        .map_err(|e| e.to_string())?;
        // Snapshots of the other sample counts (solves, dilation) are counted too; a bound.
        let per_sample = (started.elapsed() - snapshot_time).as_secs_f64() * 1e6
            / (f64::from(args.max_samples) * bake.texels as f64);
        for (n, rad, irr, neg) in rows {
            out.row(vec![
                encoder.label().into(),
                n.to_string(),
                format!("{rad:.4}"),
                format!("{irr:.4}"),
                format!("{:.2}%", 100.0 * neg),
                format!("{per_sample:.2}"),
            ]);
            points.push((encoder.label().into(), f64::from(n).log2(), rad));
        }
    }
    println!("{}", out.markdown());
    out.write_csv(
        args.csv.as_deref(),
        &format!("lightmap_convergence_{}", args.scene),
    )
    .map_err(|e| e.to_string())?;
    if let Some(path) = &args.plot {
        let title = format!(
            "{} texels, {}: radiance error vs samples per texel",
            args.scene,
            basis.label()
        );
        plot_lines(
            &points,
            &PlotLabels {
                title: &title,
                x: "samples per texel",
                y: "relative RMS error vs the converged reference",
                x_ticks: &|v| format!("{}", 2f64.powf(v).round()),
            },
            path,
        )?;
    }
    Ok(())
}

//! `prt encode ENVMAP`: fit an environment map into a sphere basis (Roughton's progressive least
//! squares, or the least-squares / NNLS / projection references) and report the radiance RMSE
//! under Probulator's definition (`prt_plsq::radiance_rmse`).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail, ensure};
use clap::ValueEnum;
use glam::Vec3;
use prt_core::SphericalBasis;
use prt_plsq::{
    EncoderConfig, LatLongFrame, ProgressiveEncoder, radiance_rmse, reference, sample_nearest,
};
use prt_sphere::{
    AmbientCube, AmbientDiceBezier, AmbientDiceSrbf, LatLongMap, SgBasis, ShBasis, sampling,
};
use serde_json::json;

/// How the coefficients are fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum EncodeMethod {
    /// Least squares over the samples (normal equations in f64).
    Ls,
    /// Non-negative least squares over the samples (Lawson-Hanson).
    Nnls,
    /// Roughton's progressive least squares (residual update, lerped denominator, Gauss-Seidel).
    Progressive,
    /// Monte Carlo projection (exact for orthonormal bases such as SH).
    Projection,
    /// Least squares of the whole map (every texel, weighted by its solid angle) through the
    /// Gram matrix; ignores `--samples` (Probulator's ambient dice fit).
    MapLs,
}

/// The frame in which sample directions and basis functions are laid over the map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Frame {
    /// prt's conventions.md lat-long mapping.
    Conventions,
    /// kayru/Probulator's mapping (conventions turned by π about +Y): reproduces its figures.
    Probulator,
}

/// Options of `prt encode`.
#[derive(Debug, clap::Args)]
pub struct EncodeArgs {
    /// Lat-long environment map (.hdr or .exr).
    pub envmap: PathBuf,
    /// Basis: `sh:N` (order N, N² functions), `sg:N` (N lobes on Probulator's spiral),
    /// `ambient-cube`, `ambient-dice` (SRBF, 12 functions) or `ambient-dice-bezier` (36).
    #[arg(long, default_value = "sg:12")]
    pub basis: String,
    /// Spherical Gaussian sharpness λ (for `sg:N`).
    #[arg(long, default_value_t = 6.0)]
    pub lambda: f32,
    /// Fitting method.
    #[arg(long, value_enum, default_value_t = EncodeMethod::Progressive)]
    pub method: EncodeMethod,
    /// Fit samples (Halton(2,3) directions, nearest texel).
    #[arg(long, default_value_t = 20000)]
    pub samples: usize,
    /// Frame of the sample directions and basis functions relative to the map.
    #[arg(long, value_enum, default_value_t = Frame::Conventions)]
    pub frame: Frame,
    /// Write the reconstruction as a tone-mapped lat-long PNG.
    #[arg(long)]
    pub png: Option<PathBuf>,
}

pub fn run(args: &EncodeArgs) -> Result<()> {
    ensure!(args.samples >= 1, "--samples must be at least 1");
    let map = crate::sky::read_envmap(&args.envmap)?;
    let (basis, clamp): (Box<dyn SphericalBasis>, bool) = parse_basis(&args.basis, args.lambda)?;
    let frame = match args.frame {
        Frame::Conventions => LatLongFrame::Conventions,
        Frame::Probulator => LatLongFrame::Probulator,
    };
    let coefficients = if args.method == EncodeMethod::MapLs {
        reference::least_squares_map(basis.as_ref(), &map, frame)?
    } else {
        let dirs = sampling::halton_sphere(args.samples);
        let values = sample_nearest(&map, &dirs, frame);
        fit(basis.as_ref(), args.method, &dirs, &values)?
    };
    let rmse = radiance_rmse(&map, basis.as_ref(), &coefficients, clamp, frame)?;
    let doc = json!({
        "envmap": args.envmap.display().to_string(),
        "basis": basis.name(),
        "method": format!("{:?}", args.method).to_lowercase(),
        "frame": format!("{:?}", args.frame).to_lowercase(),
        "samples": args.samples,
        "rmse": rmse,
        "rmse_definition": "Probulator's: sqrt(mean over texel centres, unweighted, of the per-texel MSE averaged over RGB); SH and ambient dice clamped at 0",
        "coefficients_rgb": coefficients.chunks_exact(3).map(|c| c.to_vec()).collect::<Vec<_>>(),
    });
    println!("{}", serde_json::to_string_pretty(&doc)?);
    if let Some(png) = &args.png {
        write_png(png, &map, basis.as_ref(), &coefficients, clamp, frame)?;
        eprintln!("wrote {}", png.display());
    }
    Ok(())
}

fn parse_basis(spec: &str, lambda: f32) -> Result<(Box<dyn SphericalBasis>, bool)> {
    let (kind, n) = match spec.split_once(':') {
        Some((k, n)) => (
            k,
            Some(
                n.parse::<usize>()
                    .with_context(|| format!("bad basis size in {spec:?}"))?,
            ),
        ),
        None => (spec, None),
    };
    Ok(match (kind, n) {
        ("sh", Some(order)) => (Box::new(ShBasis::new(order)?), true),
        ("sg", Some(lobes)) => (Box::new(SgBasis::spiral(lobes, lambda)?), false),
        ("ambient-cube", None) => (Box::new(AmbientCube), false),
        ("ambient-dice" | "ambient-dice-srbf", None) => (Box::new(AmbientDiceSrbf), true),
        ("ambient-dice-bezier", None) => (Box::new(AmbientDiceBezier), true),
        _ => bail!(
            "unknown basis {spec:?} (expected sh:N, sg:N, ambient-cube, ambient-dice or ambient-dice-bezier)"
        ),
    })
}

fn fit(
    basis: &dyn SphericalBasis,
    method: EncodeMethod,
    dirs: &[Vec3],
    values: &[f32],
) -> Result<Vec<f32>> {
    Ok(match method {
        EncodeMethod::Ls => reference::least_squares_samples(basis, dirs, values, 3)?,
        EncodeMethod::Nnls => reference::nnls_samples(basis, dirs, values, 3)?,
        EncodeMethod::Projection => {
            reference::naive_projection(basis, dirs, values, 3, 4.0 * std::f64::consts::PI)?
        }
        EncodeMethod::MapLs => bail!("map least squares does not use samples"),
        EncodeMethod::Progressive => {
            let mut encoder = ProgressiveEncoder::new(basis, 3, EncoderConfig::paper())?;
            for (d, v) in dirs.iter().zip(values.chunks_exact(3)) {
                encoder.add_sample(*d, v, 1.0)?;
            }
            encoder.coefficients().to_vec()
        }
    })
}

fn reconstruct(
    basis: &dyn SphericalBasis,
    coefficients: &[f32],
    dir: Vec3,
    clamp: bool,
    scratch: &mut [f32],
) -> [f32; 3] {
    basis.eval(dir, scratch);
    let mut rgb = [0.0f32; 3];
    for (i, &b) in scratch.iter().enumerate() {
        for (c, out) in rgb.iter_mut().enumerate() {
            *out += coefficients[i * 3 + c] * b;
        }
    }
    if clamp { rgb.map(|v| v.max(0.0)) } else { rgb }
}

fn write_png(
    path: &Path,
    map: &LatLongMap,
    basis: &dyn SphericalBasis,
    coefficients: &[f32],
    clamp: bool,
    frame: LatLongFrame,
) -> Result<()> {
    let mut scratch = vec![0.0f32; basis.len()];
    let (w, h) = (map.width(), map.height());
    let mean = map.data().iter().map(|&v| v as f64).sum::<f64>() / map.data().len().max(1) as f64;
    let exposure = if mean > 0.0 { (0.5 / mean) as f32 } else { 1.0 };
    let img = image::RgbImage::from_fn(w as u32, h as u32, |x, y| {
        let rgb = reconstruct(
            basis,
            coefficients,
            frame.from_conventions(map.direction(x as usize, y as usize)),
            clamp,
            &mut scratch,
        );
        image::Rgb(rgb.map(|v| {
            let t = (v * exposure).max(0.0);
            ((t / (1.0 + t)).powf(1.0 / 2.2) * 255.0).round() as u8
        }))
    });
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )?;
    prt_texture::write_atomic(path, &bytes)
        .with_context(|| format!("cannot write {}", path.display()))
}

//! What `prt bake` writes besides the bake itself: the MBD container, its read-back check, the
//! report (`report.md`, `report.json`), slice images and the loss plot.

use std::collections::BTreeMap;
use std::io::Cursor;
use std::path::Path;

use anyhow::{Context, Result, anyhow};
use glam::Vec3;
use ndarray::{Array2, Array3};
use prt_core::{GridField, resample_to_grid};
use prt_kernels::HatGrid;
use prt_mbd::{EvalOptions, MbdModel, SolveReport};
use prt_texture::container::{
    ArrayLayout, Container, GridArray, KernelDescription, LoadedContainer, MBD_BASIS,
    MBD_COEFFICIENTS,
};
use prt_texture::{Encoding, Limits, write_atomic};
use prt_trace::{BakeStats, SH9, TransferVolume, irradiance};
use serde_json::json;

use crate::bake::{BakeArgs, EncodingArg};

/// One line of the comparison table.
#[derive(Debug, Clone)]
pub struct MethodRow {
    pub name: String,
    pub relative_mse: f64,
    /// Relative Frobenius error of each 9 × 9 operator: direct, indirect R, G, B.
    pub operator_frobenius: Vec<f64>,
    pub seam_boundary: f64,
    pub seam_interior: f64,
    pub stored_scalars: usize,
    /// Bytes per voxel actually written (`None`: estimated from the stored scalars as f16).
    pub bytes_per_voxel: Option<f64>,
    pub voxels: usize,
    pub seconds: f64,
}

impl MethodRow {
    fn bytes_per_voxel(&self) -> f64 {
        self.bytes_per_voxel
            .unwrap_or(2.0 * self.stored_scalars as f64 / self.voxels.max(1) as f64)
    }

    /// Raw f32 transfer vectors (324 × 4 bytes per voxel) over the stored bytes.
    fn compression_ratio(&self) -> f64 {
        (324.0 * 4.0) / self.bytes_per_voxel()
    }

    /// Error jump across cluster boundaries over the jump inside clusters: about 1 without seams.
    fn seam_ratio(&self) -> f64 {
        if self.seam_interior > 0.0 {
            self.seam_boundary / self.seam_interior
        } else {
            0.0
        }
    }
}

/// Everything the report shows.
pub struct Report<'a> {
    pub scene: String,
    pub resolution: [usize; 3],
    pub rank: usize,
    pub basis_nodes: [usize; 3],
    pub bake: &'a BakeStats,
    pub invalid_voxels: usize,
    pub solve: &'a SolveReport,
    pub rows: Vec<MethodRow>,
    pub stage_seconds: Vec<(String, f64)>,
    pub total_seconds: f64,
}

/// The container as written.
pub struct Written {
    pub bytes_per_voxel: f64,
    pub folder: std::path::PathBuf,
    encoding: Encoding,
}

fn encoding(arg: EncodingArg) -> Encoding {
    match arg {
        EncodingArg::F32 => Encoding::F32,
        EncodingArg::F16 => Encoding::F16,
        EncodingArg::Unorm16 => Encoding::Unorm16,
        EncodingArg::Unorm8 => Encoding::Unorm8,
    }
}

fn kernel_description(kernels: &HatGrid) -> KernelDescription {
    use prt_core::SpatialKernels;
    let domain = kernels.domain();
    KernelDescription {
        kind: "hat".into(),
        nodes: kernels.nodes().map(|n| n as u32),
        domain_min: domain.min.to_array(),
        domain_max: domain.max.to_array(),
    }
}

/// Writes the MBD container (coefficient volume, basis grid, validity mask, manifest) into
/// `out_dir/mbd/`.
pub fn write_container(
    out_dir: &Path,
    model: &MbdModel<HatGrid, HatGrid>,
    coefficient_kernels: &HatGrid,
    basis_kernels: &HatGrid,
    volume: &TransferVolume,
    args: &BakeArgs,
    scene: &str,
) -> Result<Written> {
    let field = &volume.field;
    let coefficients = model.coefficients();
    let basis = model.basis();
    let (nodes, rank, dim) = basis.dim();
    let to_u32 = |d: [usize; 3]| d.map(|n| n as u32);
    let coefficient_array = GridArray::new(
        to_u32(coefficient_kernels.nodes()),
        rank,
        coefficients.iter().copied().collect(),
    )?;
    let basis_array = GridArray::new(
        to_u32(basis_kernels.nodes()),
        rank * dim,
        basis.iter().copied().collect(),
    )?;
    debug_assert_eq!(basis_array.nodes(), nodes);
    let validity = GridArray::new(
        to_u32(field.dims()),
        1,
        volume
            .valid
            .iter()
            .map(|&v| if v { 1.0 } else { 0.0 })
            .collect(),
    )?;
    let mut attributes = BTreeMap::new();
    attributes.insert("model".into(), json!("moving basis decomposition"));
    attributes.insert("scene".into(), json!(scene));
    attributes.insert("rank".into(), json!(rank));
    attributes.insert("dimension".into(), json!(dim));
    attributes.insert(
        "vector_layout".into(),
        json!("[direct 9x9 | indirect R 9x9 | G 9x9 | B 9x9], each row-major T[i*9+j], i = incident-radiance SH, j = sky SH"),
    );
    attributes.insert(
        "basis_channel_order".into(),
        json!("channel = l * dimension + d (rank-major)"),
    );
    attributes.insert("lambda".into(), json!(args.lambda));
    attributes.insert(
        "validity".into(),
        json!("1 = valid voxel, 0 = inside geometry or outside the scene"),
    );
    let mut kernels = BTreeMap::new();
    kernels.insert(
        MBD_COEFFICIENTS.to_string(),
        kernel_description(coefficient_kernels),
    );
    kernels.insert(MBD_BASIS.to_string(), kernel_description(basis_kernels));
    let enc = encoding(args.encoding);
    let container = Container {
        attributes,
        kernels,
        arrays: vec![
            (
                MBD_COEFFICIENTS.to_string(),
                coefficient_array,
                enc,
                ArrayLayout::Volume,
            ),
            (MBD_BASIS.to_string(), basis_array, enc, ArrayLayout::Rows),
            (
                "validity".to_string(),
                validity,
                Encoding::Unorm8,
                ArrayLayout::Volume,
            ),
        ],
    };
    let folder = out_dir.join("mbd");
    let bytes_per_voxel = container
        .write(&folder)?
        .bytes_per_voxel(field.num_voxels() as u64);
    Ok(Written {
        bytes_per_voxel,
        folder,
        encoding: enc,
    })
}

/// Reads the container back and evaluates the model it holds: the error an engine will see.
pub fn quantised_row(
    written: &Written,
    coefficient_kernels: &HatGrid,
    basis_kernels: &HatGrid,
    field: &GridField,
    labels: &[u32],
    eval_options: &EvalOptions,
) -> Result<MethodRow> {
    let loaded = LoadedContainer::read(&written.folder, &Limits::default())?;
    let coefficients = loaded
        .array(MBD_COEFFICIENTS)
        .ok_or_else(|| anyhow!("container lost its coefficients"))?;
    let basis = loaded
        .array(MBD_BASIS)
        .ok_or_else(|| anyhow!("container lost its basis"))?;
    let rank = coefficients.channels;
    let dim = field.dim();
    let model = MbdModel::new(
        coefficient_kernels.clone(),
        basis_kernels.clone(),
        Array2::from_shape_vec((coefficients.nodes(), rank), coefficients.data.clone())?,
        Array3::from_shape_vec((basis.nodes(), rank, dim), basis.data.clone())?,
    )?;
    let evaluation = prt_mbd::evaluate(&model, field, eval_options)?;
    let recon = resample_to_grid(&model, field.dims(), field.bounds())?;
    let seams = prt_mbd::seam_metric(field, &recon, labels)?;
    Ok(MethodRow {
        name: format!("MBD as written ({:?})", written.encoding),
        relative_mse: evaluation.relative_mse,
        operator_frobenius: evaluation.block_relative_frobenius,
        seam_boundary: seams.boundary,
        seam_interior: seams.interior,
        stored_scalars: prt_core::FieldModel::stored_scalars(&model),
        bytes_per_voxel: Some(written.bytes_per_voxel),
        voxels: field.num_voxels(),
        seconds: 0.0,
    })
}

/// The comparison table as markdown.
pub fn table_markdown(rows: &[MethodRow]) -> String {
    let mut s = String::from(
        "| method | relative MSE | operator Frobenius error (direct / R / G / B) | seam ratio (boundary / interior jump) | bytes per voxel | compression vs f32 | time |\n|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let frob = r
            .operator_frobenius
            .iter()
            .map(|e| format!("{e:.4}"))
            .collect::<Vec<_>>()
            .join(" / ");
        let bytes = if r.bytes_per_voxel.is_some() {
            format!("{:.2}", r.bytes_per_voxel())
        } else {
            format!("{:.2} (f16 est.)", r.bytes_per_voxel())
        };
        s += &format!(
            "| {} | {:.3e} | {} | {:.2} | {} | {:.1}:1 | {:.2} s |\n",
            r.name,
            r.relative_mse,
            frob,
            r.seam_ratio(),
            bytes,
            r.compression_ratio(),
            r.seconds
        );
    }
    s
}

/// The default sky of the report's images: RGB radiance `a + b·ω_y` (brighter overhead, bluish),
/// in order-3 SH.
fn default_sky() -> [[f32; SH9]; 3] {
    let four_pi = 4.0 * std::f32::consts::PI;
    let colour = [0.9f32, 1.0, 1.2];
    colour.map(|c| {
        let mut s = [0.0; SH9];
        s[0] = c * four_pi.sqrt(); // ∫ c · Y_0^0 with Y_0^0 = 1/sqrt(4π)
        s[2] = 0.6 * c * (four_pi / 3.0).sqrt(); // ∫ 0.6c·y · Y_1^0, Y_1^0 = sqrt(3/4π)·y
        s
    })
}

/// Irradiance (RGB) on an upward-facing surface at every voxel of the middle horizontal slice.
fn irradiance_slice(field: &GridField, valid: &[bool]) -> (usize, usize, Vec<Option<[f32; 3]>>) {
    let [nx, ny, nz] = field.dims();
    let y = ny / 2;
    let sky = default_sky();
    let volume = |v: usize| field.voxel(v);
    let mut pixels = Vec::with_capacity(nx * nz);
    for z in 0..nz {
        for x in 0..nx {
            let v = field.index(x, y, z);
            if !valid[v] {
                pixels.push(None);
                continue;
            }
            let t = volume(v);
            let mut rgb = [0.0f32; 3];
            for (c, out) in rgb.iter_mut().enumerate() {
                // Incident SH = (direct + indirect_c) · sky_c.
                let mut l = [0.0f32; SH9];
                for (i, li) in l.iter_mut().enumerate() {
                    for j in 0..SH9 {
                        *li += (t[i * SH9 + j] + t[81 * (c + 1) + i * SH9 + j]) * sky[c][j];
                    }
                }
                *out = irradiance(&l, Vec3::Y);
            }
            pixels.push(Some(rgb));
        }
    }
    (nx, nz, pixels)
}

const SCALE: u32 = 8;
const INVALID: [u8; 3] = [60, 60, 70];

fn magnify(w: usize, h: usize, pixel: impl Fn(usize, usize) -> [u8; 3]) -> image::RgbImage {
    let s = SCALE.max((256 / w.max(1)) as u32);
    image::RgbImage::from_fn(w as u32 * s, h as u32 * s, |px, py| {
        image::Rgb(pixel((px / s) as usize, (py / s) as usize))
    })
}

fn tonemap(v: f32, exposure: f32) -> u8 {
    let x = (v * exposure).max(0.0);
    ((x / (1.0 + x)).powf(1.0 / 2.2) * 255.0).round() as u8
}

/// Black → red → yellow → white for `t` in [0, 1].
fn heat(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    let ramp = |a: f32| ((t * 3.0 - a).clamp(0.0, 1.0) * 255.0) as u8;
    [ramp(0.0), ramp(1.0), ramp(2.0)]
}

fn save_png(path: &Path, img: &image::RgbImage) -> Result<()> {
    let mut bytes = Vec::new();
    img.write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)?;
    write_atomic(path, &bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// Writes the irradiance slices (reference and every reconstruction), their error maps and a
/// side-by-side comparison; returns the file names written.
pub fn write_images(
    out_dir: &Path,
    volume: &TransferVolume,
    reconstructions: &[(&str, GridField)],
) -> Result<Vec<String>> {
    let valid = &volume.valid;
    let (w, h, reference) = irradiance_slice(&volume.field, valid);
    let mean = {
        let vals: Vec<f32> = reference
            .iter()
            .flatten()
            .map(|p| (p[0] + p[1] + p[2]) / 3.0)
            .collect();
        vals.iter().sum::<f32>() / vals.len().max(1) as f32
    };
    let exposure = if mean > 0.0 { 1.0 / mean } else { 1.0 };
    let shade = |p: &Option<[f32; 3]>| p.map_or(INVALID, |rgb| rgb.map(|v| tonemap(v, exposure)));
    let slices: Vec<(&str, Vec<Option<[f32; 3]>>)> =
        std::iter::once(("reference", reference.clone()))
            .chain(
                reconstructions
                    .iter()
                    .map(|(name, g)| (*name, irradiance_slice(g, valid).2)),
            )
            .collect();
    let errors: Vec<Vec<Option<f32>>> = slices[1..]
        .iter()
        .map(|(_, s)| {
            s.iter()
                .zip(&reference)
                .map(|(a, b)| {
                    let (a, b) = (a.as_ref()?, b.as_ref()?);
                    Some((0..3).map(|c| (a[c] - b[c]).abs()).sum::<f32>() / 3.0)
                })
                .collect()
        })
        .collect();
    let max_error = errors
        .iter()
        .flatten()
        .flatten()
        .copied()
        .fold(0.0f32, f32::max)
        .max(1e-12);

    let mut files = Vec::new();
    for (name, s) in &slices {
        let img = magnify(w, h, |x, y| shade(&s[y * w + x]));
        let file = format!("irradiance_{name}.png");
        save_png(&out_dir.join(&file), &img)?;
        files.push(file);
    }
    for ((name, _), e) in slices[1..].iter().zip(&errors) {
        let img = magnify(w, h, |x, y| {
            e[y * w + x].map_or(INVALID, |v| heat(v / max_error))
        });
        let file = format!("error_{name}.png");
        save_png(&out_dir.join(&file), &img)?;
        files.push(file);
    }
    // Comparison: a caption band, then irradiance (reference, then each method) over error maps.
    let (tw, th) = magnify(w, h, |_, _| [0, 0, 0]).dimensions();
    let (gap, caption) = (4u32, 28u32);
    let columns = slices.len() as u32;
    let mut grid = image::RgbImage::from_pixel(
        columns * (tw + gap),
        caption + 2 * (th + gap),
        image::Rgb([255, 255, 255]),
    );
    for (i, (_, s)) in slices.iter().enumerate() {
        let img = magnify(w, h, |x, y| shade(&s[y * w + x]));
        image::imageops::replace(
            &mut grid,
            &img,
            (i as u32 * (tw + gap)) as i64,
            caption as i64,
        );
    }
    for (i, e) in errors.iter().enumerate() {
        let img = magnify(w, h, |x, y| {
            e[y * w + x].map_or(INVALID, |v| heat(v / max_error))
        });
        let x = ((i as u32 + 1) * (tw + gap)) as i64;
        image::imageops::replace(&mut grid, &img, x, (caption + th + gap) as i64);
    }
    let captions: Vec<String> = slices.iter().map(|(name, _)| name.to_uppercase()).collect();
    draw_captions(&mut grid, &captions, tw + gap)?;
    save_png(&out_dir.join("comparison.png"), &grid)?;
    files.push("comparison.png".into());
    Ok(files)
}

/// Registers the report's font with plotters once (egui's Ubuntu Light, shipped as crate data,
/// so no system font is needed).
fn register_font() -> Result<()> {
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(
            "sans-serif",
            plotters::style::FontStyle::Normal,
            epaint_default_fonts::UBUNTU_LIGHT,
        )
        .is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(anyhow!("cannot load the report font"))
    }
}

fn plot_error<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("plot: {e:?}")
}

/// Writes one caption per column at the top of `image`.
fn draw_captions(
    image: &mut image::RgbImage,
    captions: &[String],
    column_width: u32,
) -> Result<()> {
    use plotters::prelude::*;
    register_font()?;
    let (w, h) = image.dimensions();
    let root = BitMapBackend::with_buffer(image.as_mut(), (w, h)).into_drawing_area();
    for (i, text) in captions.iter().enumerate() {
        let x = (i as u32 * column_width + 6) as i32;
        root.draw(&Text::new(
            text.as_str(),
            (x, 6),
            ("sans-serif", 18).into_font().color(&BLACK),
        ))
        .map_err(plot_error)?;
    }
    root.present().map_err(plot_error)
}

/// The loss per iteration as a PNG line plot (log scale).
fn loss_plot_png(solve: &SolveReport) -> Result<Vec<u8>> {
    use plotters::prelude::*;
    register_font()?;
    let losses: Vec<(u32, f64)> = solve
        .history
        .iter()
        .enumerate()
        .map(|(i, r)| (i as u32 + 1, r.loss_after.max(1e-300)))
        .collect();
    let (w, h) = (720u32, 420u32);
    let mut buffer = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area();
        let (lo, hi) = losses
            .iter()
            .fold((f64::MAX, f64::MIN), |(lo, hi), &(_, l)| {
                (lo.min(l), hi.max(l))
            });
        let (lo, hi) = if losses.is_empty() {
            (1e-3, 1.0)
        } else {
            (lo * 0.9, hi * 1.1)
        };
        let mut chart = ChartBuilder::on(&root)
            .caption("MBD loss per iteration", ("sans-serif", 22))
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(80)
            .build_cartesian_2d(1u32..(losses.len() as u32).max(2), (lo..hi).log_scale())
            .map_err(plot_error)?;
        chart
            .configure_mesh()
            .x_desc("iteration")
            .y_desc("loss (Monte Carlo estimate)")
            .label_style(("sans-serif", 14))
            .draw()
            .map_err(plot_error)?;
        chart
            .draw_series(LineSeries::new(losses, BLUE.stroke_width(2)))
            .map_err(plot_error)?;
        root.present().map_err(plot_error)?;
    }
    let img = image::RgbImage::from_raw(w, h, buffer).ok_or_else(|| anyhow!("plot buffer size"))?;
    let mut bytes = Vec::new();
    img.write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)?;
    Ok(bytes)
}

/// Writes `report.md`, `report.json` and `loss.png`.
pub fn write_report(out_dir: &Path, report: &Report<'_>, images: &[String]) -> Result<()> {
    write_atomic(&out_dir.join("loss.png"), &loss_plot_png(report.solve)?)?;
    let [nx, ny, nz] = report.resolution;
    let bake = report.bake;
    let mut md = format!(
        "# prt bake report: {}\n\nGrid {nx} × {ny} × {nz} voxels, 324-D transfer vectors \
         (order-3 SH: direct 9×9 and one-bounce indirect 9×9 per colour). MBD rank {} on a \
         {} × {} × {} basis grid; the baselines use the same number of basis vectors (one rank-{} \
         basis per block or cluster).\n\n",
        report.scene,
        report.rank,
        report.basis_nodes[0],
        report.basis_nodes[1],
        report.basis_nodes[2],
        report.rank
    );
    md += "## Compression\n\n";
    md += &table_markdown(&report.rows);
    md += "\n*Relative MSE*: Σ‖f̂ − f‖² / Σ‖f‖² over jittered samples (f = trilinear input). \
           *Operator Frobenius error*: relative, per 9×9 operator over the volume. *Seam ratio*: \
           RMS jump of the error between neighbouring voxels across cluster (or basis-cell) \
           boundaries over the same inside clusters; about 1 means no seams, much larger means \
           visible block edges. *Bytes per voxel*: files written (MBD) or stored scalars at 2 bytes \
           (baselines). *Compression*: raw 324 × f32 per voxel over bytes per voxel.\n\n";
    md += "## Images\n\nMiddle horizontal slice, irradiance on an upward-facing surface under a sky \
           brighter overhead. Top row: reference, then each method; bottom row: absolute error \
           (black = 0, white = the largest error of any method). Grey = invalid voxels.\n\n\
           ![comparison](comparison.png)\n\n";
    md += &images
        .iter()
        .map(|f| format!("- [{f}]({f})\n"))
        .collect::<String>();
    md += "\n## Solver\n\n![loss](loss.png)\n\n";
    md += &format!(
        "{} iterations{}.\n\n## Bake\n\n{} rays ({:.1} Mrays/s), {} rays per voxel, {} surface-cache \
         points, {} invalid voxels of {}.\n\n## Stage times\n\n| stage | seconds |\n|---|---|\n",
        report.solve.history.len(),
        if report.solve.converged {
            " (converged)"
        } else {
            " (iteration cap)"
        },
        bake.rays(),
        bake.mrays_per_second(),
        bake.rays_per_voxel,
        bake.cache_points,
        report.invalid_voxels,
        bake.voxels
    );
    for (stage, s) in &report.stage_seconds {
        md += &format!("| {stage} | {s:.2} |\n");
    }
    md += &format!("| total | {:.2} |\n", report.total_seconds);
    write_atomic(&out_dir.join("report.md"), md.as_bytes())?;

    let rows: Vec<_> = report
        .rows
        .iter()
        .map(|r| {
            json!({
                "method": r.name,
                "relative_mse": r.relative_mse,
                "operator_frobenius": r.operator_frobenius,
                "seam_boundary": r.seam_boundary,
                "seam_interior": r.seam_interior,
                "seam_ratio": r.seam_ratio(),
                "bytes_per_voxel": r.bytes_per_voxel(),
                "bytes_measured": r.bytes_per_voxel.is_some(),
                "compression_ratio": r.compression_ratio(),
                "seconds": r.seconds,
            })
        })
        .collect();
    let doc = json!({
        "scene": report.scene,
        "resolution": report.resolution,
        "rank": report.rank,
        "basis_nodes": report.basis_nodes,
        "methods": rows,
        "mbd": {
            "iterations": report.solve.history.len(),
            "converged": report.solve.converged,
            "loss": report.solve.history.iter().map(|r| r.loss_after).collect::<Vec<_>>(),
        },
        "bake": {
            "rays": bake.rays(),
            "mrays_per_second": bake.mrays_per_second(),
            "invalid_voxels": report.invalid_voxels,
            "voxels": bake.voxels,
        },
        "stage_seconds": report.stage_seconds.iter().cloned().collect::<BTreeMap<_, _>>(),
        "total_seconds": report.total_seconds,
    });
    write_atomic(
        &out_dir.join("report.json"),
        serde_json::to_string_pretty(&doc)?.as_bytes(),
    )?;
    Ok(())
}

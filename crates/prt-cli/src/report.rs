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
use crate::seams::{self, LocalBasis, SeamView};

/// One line of the comparison table.
#[derive(Debug, Clone)]
pub struct MethodRow {
    pub name: String,
    pub relative_mse: f64,
    /// Relative Frobenius error of each 9 × 9 operator: direct, indirect R, G, B.
    pub operator_frobenius: Vec<f64>,
    pub seam_boundary: f64,
    pub seam_interior: f64,
    /// The seam ratio of the basis alone, on the denoised reference (see `seams`).
    pub denoised_seam_ratio: Option<f64>,
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
    /// The horizontal slice the images show.
    pub slice_y: usize,
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
        denoised_seam_ratio: None,
        stored_scalars: prt_core::FieldModel::stored_scalars(&model),
        bytes_per_voxel: Some(written.bytes_per_voxel),
        voxels: field.num_voxels(),
        seconds: 0.0,
    })
}

/// The comparison table as markdown.
pub fn table_markdown(rows: &[MethodRow]) -> String {
    let mut s = String::from(
        "| method | relative MSE | operator Frobenius error (direct / R / G / B) | seam ratio (boundary / interior jump) | seam ratio, denoised | bytes per voxel | compression vs f32 | time |\n|---|---|---|---|---|---|---|---|\n",
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
            "| {} | {:.3e} | {} | {:.2} | {} | {} | {:.1}:1 | {:.2} s |\n",
            r.name,
            r.relative_mse,
            frob,
            r.seam_ratio(),
            r.denoised_seam_ratio
                .map_or_else(|| "–".to_string(), |x| format!("**{x:.2}**")),
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

/// One compressed method as the report's images show it.
pub struct ImageMethod<'a> {
    /// File-name key ("mbd", "bpca", ...).
    pub key: &'a str,
    /// The reconstruction on the input grid.
    pub reconstruction: &'a GridField,
    /// Cluster (for MBD: basis cell) of every voxel; the seam view draws their boundaries.
    pub labels: &'a [u32],
    /// The basis the method applies at each voxel.
    pub basis: LocalBasis<'a>,
}

/// Irradiance (RGB) on an upward-facing surface under the default sky, from one 324-D transfer
/// vector.
fn irradiance_rgb<T: Copy + Into<f64>>(t: &[T], sky: &[[f32; SH9]; 3]) -> [f32; 3] {
    let mut rgb = [0.0f32; 3];
    for (c, out) in rgb.iter_mut().enumerate() {
        // Incident SH = (direct + indirect_c) · sky_c.
        let mut l = [0.0f32; SH9];
        for (i, li) in l.iter_mut().enumerate() {
            let mut sum = 0.0f64;
            for j in 0..SH9 {
                let direct: f64 = t[i * SH9 + j].into();
                let indirect: f64 = t[81 * (c + 1) + i * SH9 + j].into();
                sum += (direct + indirect) * sky[c][j] as f64;
            }
            *li = sum as f32;
        }
        *out = irradiance(&l, Vec3::Y);
    }
    rgb
}

/// Irradiance at every voxel of the horizontal slice `y` (x fastest); `None` for invalid voxels.
fn irradiance_slice(field: &GridField, valid: &[bool], y: usize) -> Vec<Option<[f32; 3]>> {
    let [nx, _, nz] = field.dims();
    let sky = default_sky();
    (0..nx * nz)
        .map(|p| {
            let v = field.index(p % nx, y, p / nx);
            valid[v].then(|| irradiance_rgb(field.voxel(v), &sky))
        })
        .collect()
}

const SCALE: u32 = 8;
const INVALID: [u8; 3] = [60, 60, 70];
const BOUNDARY: [u8; 3] = [0, 190, 255];

/// Pixels per voxel: at least [`SCALE`], and at least 256 pixels across.
fn magnification(w: usize) -> u32 {
    SCALE.max((256 / w.max(1)) as u32)
}

fn magnify(w: usize, h: usize, pixel: impl Fn(usize, usize) -> [u8; 3]) -> image::RgbImage {
    let s = magnification(w);
    image::RgbImage::from_fn(w as u32 * s, h as u32 * s, |px, py| {
        image::Rgb(pixel((px / s) as usize, (py / s) as usize))
    })
}

/// Tone-mapped display value in [0, 255] (Reinhard, then gamma 2.2).
fn tonemap(v: f32, exposure: f32) -> f32 {
    let x = (v * exposure).max(0.0);
    (x / (1.0 + x)).powf(1.0 / 2.2) * 255.0
}

/// Black → red → yellow → white for `t` in [0, 1].
fn heat(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    let ramp = |a: f32| ((t * 3.0 - a).clamp(0.0, 1.0) * 255.0) as u8;
    [ramp(0.0), ramp(1.0), ramp(2.0)]
}

/// The value below which 99 % of `values` lie (at least `floor`): the top of a heat scale that
/// a handful of outliers cannot wash out.
fn heat_scale<'a>(values: impl Iterator<Item = &'a Option<f32>>, floor: f32) -> f32 {
    let mut v: Vec<f32> = values.flatten().copied().collect();
    if v.is_empty() {
        return floor;
    }
    let k = ((v.len() - 1) as f64 * 0.99).round() as usize;
    let (_, top, _) = v.select_nth_unstable_by(k, f32::total_cmp);
    top.max(floor)
}

fn save_png(path: &Path, img: &image::RgbImage) -> Result<()> {
    let mut bytes = Vec::new();
    img.write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)?;
    write_atomic(path, &bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// What the images show, for the report text.
pub struct ImageSummary {
    /// Files written, in display order.
    pub files: Vec<String>,
    /// Row `z` of the slice along which `seam_profile.png` runs.
    pub profile_row: usize,
    /// The seam view's heat scale: jumps at or above this fraction of the field are white.
    pub jump_top: f32,
    /// The error maps' heat scale, in grey levels of the tone-mapped images.
    pub error_top: f32,
}

/// Writes the images of the horizontal slice `y`: irradiance (reference and every method), the
/// seam view of every method (`views`, in the order of `methods`), the error maps,
/// `comparison.png` (all of them in one grid) and `seam_profile.png`.
pub fn write_images(
    out_dir: &Path,
    volume: &TransferVolume,
    methods: &[ImageMethod<'_>],
    views: &[SeamView],
    y: usize,
) -> Result<ImageSummary> {
    let field = &volume.field;
    let valid = &volume.valid;
    let [w, _, h] = field.dims();
    let slice_valid: Vec<bool> = (0..w * h)
        .map(|p| valid[field.index(p % w, y, p / w)])
        .collect();

    // Irradiance, tone-mapped with the exposure that maps the reference's mean to mid-grey.
    let reference = irradiance_slice(field, valid, y);
    let mean = {
        let vals: Vec<f32> = reference
            .iter()
            .flatten()
            .map(|p| (p[0] + p[1] + p[2]) / 3.0)
            .collect();
        vals.iter().sum::<f32>() / vals.len().max(1) as f32
    };
    let exposure = if mean > 0.0 { 1.0 / mean } else { 1.0 };
    let display = |p: &Option<[f32; 3]>| p.map(|rgb| rgb.map(|v| tonemap(v, exposure)));
    let slices: Vec<(&str, Vec<Option<[f32; 3]>>)> = std::iter::once(("reference", &reference))
        .map(|(k, s)| (k, s.iter().map(display).collect()))
        .chain(methods.iter().map(|m| {
            let s = irradiance_slice(m.reconstruction, valid, y);
            (m.key, s.iter().map(display).collect())
        }))
        .collect();

    // Error maps in display units: the difference a viewer sees between the images above. (An
    // absolute radiometric error is dominated by the brightest voxels, e.g. Sponza's border
    // ring, which lies outside the walls under the open sky.)
    let errors: Vec<Vec<Option<f32>>> = slices[1..]
        .iter()
        .map(|(_, s)| {
            s.iter()
                .zip(&slices[0].1)
                .map(|(a, b)| {
                    let (a, b) = (a.as_ref()?, b.as_ref()?);
                    Some((0..3).map(|c| (a[c] - b[c]).abs()).sum::<f32>() / 3.0)
                })
                .collect()
        })
        .collect();
    let error_top = heat_scale(errors.iter().flatten(), 1.0);
    let jump_top = heat_scale(views.iter().flat_map(|v| &v.jump), 1e-6);

    let irradiance_img = |s: &[Option<[f32; 3]>]| {
        magnify(w, h, |x, z| {
            s[z * w + x].map_or(INVALID, |rgb| rgb.map(|v| v.round() as u8))
        })
    };
    let heat_img = |e: &[Option<f32>], top: f32| {
        magnify(w, h, |x, z| e[z * w + x].map_or(INVALID, |v| heat(v / top)))
    };
    let seam_imgs: Vec<image::RgbImage> =
        views.iter().map(|v| heat_img(&v.jump, jump_top)).collect();
    let error_imgs: Vec<image::RgbImage> = errors.iter().map(|e| heat_img(e, error_top)).collect();

    let mut files = Vec::new();
    let mut save = |name: String, img: &image::RgbImage| -> Result<()> {
        save_png(&out_dir.join(&name), img)?;
        files.push(name);
        Ok(())
    };

    // Comparison: captions, then irradiance (reference, then each method), the seam view and the
    // error maps; the first column of the lower rows says what they show.
    let (tw, th) = (w as u32 * magnification(w), h as u32 * magnification(w));
    let (gap, caption) = (4u32, 28u32);
    let columns = slices.len() as u32;
    let mut grid = image::RgbImage::from_pixel(
        columns * (tw + gap),
        caption + 3 * (th + gap),
        image::Rgb([255, 255, 255]),
    );
    let at = |column: u32, row: u32| {
        (
            (column * (tw + gap)) as i64,
            (caption + row * (th + gap)) as i64,
        )
    };
    for (i, (_, s)) in slices.iter().enumerate() {
        let (x, y) = at(i as u32, 0);
        image::imageops::replace(&mut grid, &irradiance_img(s), x, y);
    }
    for (row, images) in [(1, &seam_imgs), (2, &error_imgs)] {
        for (i, img) in images.iter().enumerate() {
            let (x, y) = at(i as u32 + 1, row);
            image::imageops::replace(&mut grid, img, x, y);
        }
    }
    let mut labels: Vec<(i32, i32, String, u32)> = slices
        .iter()
        .enumerate()
        .map(|(i, (key, _))| (at(i as u32, 0).0 as i32 + 6, 6, key.to_uppercase(), 18))
        .collect();
    let row_text = [
        (
            1,
            vec![
                "SEAMS: where each method's".to_string(),
                "basis jumps. Each method's".into(),
                "basis applied to the".into(),
                "denoised reference; jump of".into(),
                "what it cannot represent".into(),
                "between neighbouring voxels".into(),
                format!("(black 0, white >= {:.1} %).", 100.0 * jump_top),
                "Bright lines = seams at".into(),
                "block / cluster edges;".into(),
                "dark = seamless.".into(),
            ],
        ),
        (
            2,
            vec![
                "ERROR vs the reference,".to_string(),
                "in grey levels of the images".into(),
                format!("above (white >= {error_top:.1} of 255);"),
                "mostly the reference's".into(),
                "Monte Carlo noise.".into(),
            ],
        ),
    ];
    for (row, lines) in row_text {
        let (x, y) = at(0, row);
        for (k, line) in lines.into_iter().enumerate() {
            labels.push((x as i32 + 6, y as i32 + 4 + 20 * k as i32, line, 15));
        }
    }
    draw_text(&mut grid, &labels)?;
    save("comparison.png".into(), &grid)?;
    for (key, s) in &slices {
        save(format!("irradiance_{key}.png"), &irradiance_img(s))?;
    }
    for (m, img) in methods.iter().zip(&seam_imgs) {
        save(format!("seams_{}.png", m.key), img)?;
    }
    for (m, img) in methods.iter().zip(&error_imgs) {
        save(format!("error_{}.png", m.key), img)?;
    }

    // The profile along the row nearest the middle of the slice that is at least half valid:
    // the middle crosses the scene's interior (a row of most valid voxels can lie outside a
    // building's walls).
    let half_valid = |z: usize| 2 * (0..w).filter(|&x| slice_valid[z * w + x]).count() >= w;
    let profile_row = (0..h)
        .filter(|&z| half_valid(z))
        .min_by_key(|&z| z.abs_diff(h / 2))
        .unwrap_or(h / 2);
    let slice_labels: Vec<Vec<u32>> = methods
        .iter()
        .map(|m| {
            (0..w)
                .map(|x| m.labels[field.index(x, y, profile_row)])
                .collect()
        })
        .collect();
    let residuals: Vec<Vec<Option<f32>>> = views
        .iter()
        .map(|v| v.residual[profile_row * w..(profile_row + 1) * w].to_vec())
        .collect();
    let profile = seam_profile_png(methods, &residuals, &slice_labels, profile_row)?;
    write_atomic(&out_dir.join("seam_profile.png"), &profile)?;
    files.push("seam_profile.png".into());
    Ok(ImageSummary {
        files,
        profile_row,
        jump_top,
        error_top,
    })
}

/// One panel per method: its seam-view residual along row `z` of the slice (`residuals` and
/// `labels` hold that row), with a vertical line wherever its block or cluster changes.
fn seam_profile_png(
    methods: &[ImageMethod<'_>],
    residuals: &[Vec<Option<f32>>],
    labels: &[Vec<u32>],
    z: usize,
) -> Result<Vec<u8>> {
    use plotters::prelude::*;
    register_font()?;
    let w = residuals.first().map_or(0, Vec::len);
    let panels = methods.len().max(1);
    let (width, panel_height) = (760u32, 200u32);
    let height = panel_height * panels as u32 + 40;
    let top = residuals
        .iter()
        .flatten()
        .flatten()
        .fold(0.0f32, |a, &b| a.max(b))
        .max(1e-6) as f64
        * 100.0
        * 1.1;
    let mut buffer = vec![255u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        let root = root
            .titled(
                &format!(
                    "Seam view along slice row z = {z}: share of the denoised reference each \
                     method's basis cannot represent"
                ),
                ("sans-serif", 16),
            )
            .map_err(plot_error)?;
        let colours = [BLUE, RED, RGBColor(0, 150, 0), MAGENTA];
        for (i, (area, (m, r))) in root
            .split_evenly((panels, 1))
            .iter()
            .zip(methods.iter().zip(residuals))
            .enumerate()
        {
            let last = i + 1 == panels;
            let mut chart = ChartBuilder::on(area)
                .margin(6)
                .x_label_area_size(if last { 32 } else { 14 })
                .y_label_area_size(64)
                .build_cartesian_2d(-0.5f64..(w as f64 - 0.5), 0.0..top)
                .map_err(plot_error)?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc(if last { "voxel x" } else { "" })
                .y_desc("residual %")
                .label_style(("sans-serif", 12))
                .draw()
                .map_err(plot_error)?;
            let row = &labels[i];
            for x in 1..w {
                if row[x] != row[x - 1] {
                    let at = x as f64 - 0.5;
                    chart
                        .draw_series(LineSeries::new(
                            [(at, 0.0), (at, top)],
                            RGBColor(BOUNDARY[0], BOUNDARY[1], BOUNDARY[2]).stroke_width(1),
                        ))
                        .map_err(plot_error)?;
                }
            }
            // One line per run of valid voxels, as steps (each voxel holds its value).
            let colour = colours[i % colours.len()];
            let mut run: Vec<(f64, f64)> = Vec::new();
            let mut flush = |run: &mut Vec<(f64, f64)>| -> Result<()> {
                if !run.is_empty() {
                    chart
                        .draw_series(LineSeries::new(run.drain(..), colour.stroke_width(2)))
                        .map_err(plot_error)?;
                }
                Ok(())
            };
            for (x, value) in r.iter().enumerate() {
                match value {
                    Some(v) => {
                        let v = *v as f64 * 100.0;
                        run.push((x as f64 - 0.5, v));
                        run.push((x as f64 + 0.5, v));
                    }
                    None => flush(&mut run)?,
                }
            }
            flush(&mut run)?;
            let name = format!(
                "{}: {}",
                m.key.to_uppercase(),
                if matches!(m.basis, LocalBasis::Moving { .. }) {
                    "lines = basis cells, the basis moves smoothly across them"
                } else {
                    "lines = block / cluster edges, a separate basis on each side"
                }
            );
            area.draw(&Text::new(
                name,
                (72, 8),
                ("sans-serif", 14).into_font().color(&colour),
            ))
            .map_err(plot_error)?;
        }
        root.present().map_err(plot_error)?;
    }
    let img = image::RgbImage::from_raw(width, height, buffer)
        .ok_or_else(|| anyhow!("plot buffer size"))?;
    let mut bytes = Vec::new();
    img.write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)?;
    Ok(bytes)
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

/// Draws `(x, y, text, size)` labels in black onto `image`.
fn draw_text(image: &mut image::RgbImage, labels: &[(i32, i32, String, u32)]) -> Result<()> {
    use plotters::prelude::*;
    register_font()?;
    let (w, h) = image.dimensions();
    let root = BitMapBackend::with_buffer(image.as_mut(), (w, h)).into_drawing_area();
    for (x, y, text, size) in labels {
        root.draw(&Text::new(
            text.as_str(),
            (*x, *y),
            ("sans-serif", *size).into_font().color(&BLACK),
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
pub fn write_report(out_dir: &Path, report: &Report<'_>, images: &ImageSummary) -> Result<()> {
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
           visible block edges. Against the traced reference it is diluted by the reference's \
           Monte Carlo noise; *seam ratio, denoised* is the same ratio for each method's basis \
           applied to the denoised reference (the seam view below), where only a jump of the \
           basis can make it exceed 1. *Bytes per voxel*: files written (MBD) or stored scalars \
           at 2 bytes (baselines). *Compression*: raw 324 × f32 per voxel over bytes per \
           voxel.\n\n";
    md += &format!(
        "## Images\n\nMiddle horizontal slice (y = {slice_y}). Grey = invalid voxels.\n\n\
         - **Top row**: irradiance on an upward-facing surface under a sky brighter overhead, for \
         the reference and each method.\n\
         - **Middle row, the seam view**: each method's own basis applied to the *denoised* \
         reference (the traced volume blurred with a Gaussian of σ = {sigma} voxel over valid \
         voxels), then, per voxel, the largest jump of what the basis cannot represent to a \
         neighbour in the slice, relative to the field there (black = 0, white ≥ {jump:.1} %). \
         BPCA and CPCA fit a separate basis per block or cluster, so their residual jumps at \
         every block edge (a bright grid) and cluster edge (bright patches); MBD's basis moves \
         continuously, so its map stays dark: **no seams**. [seam_profile.png](seam_profile.png) \
         plots the residual itself along row z = {row}, with the block / cluster edges as \
         vertical lines: BPCA and CPCA step at them, MBD does not.\n\
         - **Bottom row**: error of the irradiance against the reference, in grey levels of the \
         tone-mapped images above (white ≥ {error:.1} of 255). At this ray count it is mostly \
         the reference's own Monte Carlo noise, which is why the seam view exists. It is \
         measured on the displayed values because an absolute radiometric error is dominated \
         by the brightest voxels (e.g. a ring of voxels under the open sky outside a \
         building's walls).\n\n\
         ![comparison](comparison.png)\n\n![seam profile](seam_profile.png)\n\n",
        slice_y = report.slice_y,
        sigma = seams::BLUR_SIGMA,
        jump = 100.0 * images.jump_top,
        row = images.profile_row,
        error = images.error_top,
    );
    md += &images
        .files
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
                "denoised_seam_ratio": r.denoised_seam_ratio,
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

//! The report's images of one horizontal slice: irradiance under a default sky, the seam view
//! and the error maps of every method, all of them in `comparison.png`, and the seam profile.

use std::io::Cursor;
use std::path::Path;

use anyhow::{Context, Result};
use glam::Vec3;
use prt_bake::seams::SeamView;
use prt_bake::{Bake, Method};
use prt_core::{FieldModel, GridField};
use prt_sphere::Sky;
use prt_texture::write_atomic;
use prt_trace::lit::{incident_radiance, irradiance};

use crate::report::plots::{draw_text, seam_profile_png};

/// One compressed method as the images show it.
struct ImageMethod<'a> {
    /// File-name key ("mbd", "bpca", ...).
    key: &'static str,
    /// The model.
    model: &'a dyn FieldModel,
    /// Cluster (for MBD: basis cell) of every voxel; the seam profile marks where it changes.
    labels: &'a [u32],
    /// Whether the method's basis moves continuously (MBD) or is one per block or cluster.
    moving: bool,
    /// Its seam view.
    view: &'a SeamView,
}

/// MBD, then the baselines, with their seam views.
fn image_methods(bake: &Bake) -> Vec<ImageMethod<'_>> {
    let views = bake.seam_views.iter().map(|(_, view)| view);
    std::iter::once((
        Method::Mbd.key(),
        &bake.mbd.model as &dyn FieldModel,
        bake.mbd.labels.as_slice(),
        true,
    ))
    .chain(bake.baselines.iter().map(|b| {
        (
            b.method.key(),
            &b.model as &dyn FieldModel,
            b.model.labels(),
            false,
        )
    }))
    .zip(views)
    .map(|((key, model, labels, moving), view)| ImageMethod {
        key,
        model,
        labels,
        moving,
        view,
    })
    .collect()
}

/// Irradiance (RGB) on an upward-facing surface under `sky`, from one 324-D transfer vector.
fn irradiance_rgb(t: &[f32], sky: &Sky) -> [f32; 3] {
    incident_radiance(t, sky).map(|l| irradiance(&l, Vec3::Y))
}

/// Irradiance at every voxel of `field`'s horizontal slice `y` (x fastest) from the transfer
/// vector `transfer(v, out)` gives for voxel `v`; `None` for invalid voxels.
fn irradiance_slice(
    field: &GridField,
    valid: &[bool],
    y: usize,
    mut transfer: impl FnMut(usize, &mut [f32]) -> Result<()>,
) -> Result<Vec<Option<[f32; 3]>>> {
    let [nx, _, nz] = field.dims();
    let sky = Sky::default();
    let mut t = vec![0.0f32; field.dim()];
    (0..nx * nz)
        .map(|p| {
            let v = field.index(p % nx, y, p / nx);
            if !valid[v] {
                return Ok(None);
            }
            transfer(v, &mut t)?;
            Ok(Some(irradiance_rgb(&t, &sky)))
        })
        .collect()
}

const SCALE: u32 = 8;
const INVALID: [u8; 3] = [60, 60, 70];

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
pub fn heat_scale<'a>(values: impl Iterator<Item = &'a Option<f32>>, floor: f32) -> f32 {
    let mut v: Vec<f32> = values.flatten().copied().collect();
    if v.is_empty() {
        return floor;
    }
    let k = ((v.len() - 1) as f64 * 0.99).round() as usize;
    let (_, top, _) = v.select_nth_unstable_by(k, f32::total_cmp);
    top.max(floor)
}

/// Writes `img` as a PNG, atomically.
pub fn save_png(path: &Path, img: &image::RgbImage) -> Result<()> {
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
    /// Per method (file-name key): the mean of its error map over the slice's valid voxels, in
    /// grey levels.
    pub error_means: Vec<(String, f32)>,
}

/// Writes the images of the bake's seam-view slice: irradiance (reference and every method), the
/// seam view of every method, the error maps, `comparison.png` (all of them in one grid) and
/// `seam_profile.png`.
pub fn write_images(out_dir: &Path, bake: &Bake) -> Result<ImageSummary> {
    let volume = &bake.volume;
    let methods = image_methods(bake);
    let y = bake.seam_slice;
    let field = &volume.field;
    let valid = &volume.valid;
    let [w, _, h] = field.dims();
    let slice_valid: Vec<bool> = (0..w * h)
        .map(|p| valid[field.index(p % w, y, p / w)])
        .collect();

    // Irradiance, tone-mapped with the exposure that maps the reference's mean to mid-grey.
    let reference = irradiance_slice(field, valid, y, |v, t| {
        t.copy_from_slice(field.voxel(v));
        Ok(())
    })?;
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
    let mut slices: Vec<(&str, Vec<Option<[f32; 3]>>)> =
        vec![("reference", reference.iter().map(display).collect())];
    for m in &methods {
        // A model at a voxel centre is its value on the grid.
        let s = irradiance_slice(field, valid, y, |v, t| {
            Ok(m.model.eval(field.centre_of(v), t)?)
        })?;
        slices.push((m.key, s.iter().map(display).collect()));
    }

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
    let error_means: Vec<(String, f32)> = methods
        .iter()
        .zip(&errors)
        .map(|(m, e)| {
            let valid: Vec<f32> = e.iter().flatten().copied().collect();
            let mean = valid.iter().sum::<f32>() / valid.len().max(1) as f32;
            (m.key.to_string(), mean)
        })
        .collect();
    let jump_top = heat_scale(methods.iter().flat_map(|m| &m.view.jump), 1e-6);

    let irradiance_img = |s: &[Option<[f32; 3]>]| {
        magnify(w, h, |x, z| {
            s[z * w + x].map_or(INVALID, |rgb| rgb.map(|v| v.round() as u8))
        })
    };
    let heat_img = |e: &[Option<f32>], top: f32| {
        magnify(w, h, |x, z| e[z * w + x].map_or(INVALID, |v| heat(v / top)))
    };
    let seam_imgs: Vec<image::RgbImage> = methods
        .iter()
        .map(|m| heat_img(&m.view.jump, jump_top))
        .collect();
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
    let mut error_text = vec![
        "ERROR vs the reference,".to_string(),
        "in grey levels of the images".into(),
        format!("above (white >= {error_top:.1} of 255)."),
        "Mean over the valid voxels:".into(),
    ];
    error_text.extend(
        error_means
            .iter()
            .map(|(key, mean)| format!("{} {mean:.2}", key.to_uppercase())),
    );
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
        (2, error_text),
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
    let residuals: Vec<Vec<Option<f32>>> = methods
        .iter()
        .map(|m| m.view.residual[profile_row * w..(profile_row + 1) * w].to_vec())
        .collect();
    let captions: Vec<String> = methods
        .iter()
        .map(|m| {
            format!(
                "{}: {}",
                m.key.to_uppercase(),
                if m.moving {
                    "lines = basis cells, the basis moves smoothly across them"
                } else {
                    "lines = block / cluster edges, a separate basis on each side"
                }
            )
        })
        .collect();
    let profile = seam_profile_png(&captions, &residuals, &slice_labels, profile_row)?;
    write_atomic(&out_dir.join("seam_profile.png"), &profile)?;
    files.push("seam_profile.png".into());
    Ok(ImageSummary {
        files,
        profile_row,
        jump_top,
        error_top,
        error_means,
    })
}

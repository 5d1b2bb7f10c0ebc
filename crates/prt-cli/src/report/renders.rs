//! The report's rendered views: the lit scene for the reference and every method, their
//! differences from the reference, and the rendered seam view (each method's basis applied to the
//! denoised reference), in `rendered.png`.

use std::path::Path;

use anyhow::{Context, Result};
use prt_bake::seams::BLUR_SIGMA;
use prt_bake::{Bake, BakeFolder};
use prt_core::{GridField, NoProgress};
use prt_mbd::LocalBasis;
use prt_mbd::expert::{blur_valid, projection_residuals};
use prt_render::{
    ImageMetrics, RenderConfig, Rendered, ToneMap, image_metrics, render, views, voxels_read,
};
use prt_sphere::Sky;
use prt_texture::Limits;
use prt_trace::{LitVolume, RayTracer, Scene};

use crate::report::images::{heat_scale, save_png};
use crate::report::plots::draw_text;

/// Width and height of each rendered view, in pixels.
pub const RENDER_SIZE: usize = 256;

/// What the rendered views show, for the report text.
pub struct RenderSummary {
    /// The view's name (`front`, a glTF camera's name, ...).
    pub view: String,
    /// The exposure of every image (the reference's automatic one).
    pub exposure: f32,
    /// Grey levels (of 255) of the tone-mapped images at which a difference shows in full colour.
    pub difference_top: f32,
    /// Relative change of the luminance at which the seam view shows in full colour.
    pub seam_top: f32,
    /// Each method's key and the RMSE of its render's radiance against the reference render.
    pub rmse: Vec<(String, f64)>,
    /// Every view of the scene (glTF cameras, then `front` and `inside`): each method's image
    /// error against the reference render of that view.
    pub views: Vec<ViewMetrics>,
    /// Files written, in display order.
    pub files: Vec<String>,
}

/// One view's image errors.
pub struct ViewMetrics {
    /// The view's name.
    pub view: String,
    /// Each method's key (MBD as written first, then the baselines) and its image error.
    pub methods: Vec<(String, ImageMetrics)>,
}

/// The methods ranked by their mean ꟻLIP over `views`, best first, with that mean.
pub fn rank_by_flip(views: &[ViewMetrics]) -> Vec<(String, f64)> {
    let mut ranked: Vec<(String, f64)> = views
        .first()
        .map(|v| {
            v.methods
                .iter()
                .map(|(key, _)| key.clone())
                .collect::<Vec<_>>()
        })
        .unwrap_or_default()
        .into_iter()
        .map(|key| {
            let scores: Vec<f64> = views
                .iter()
                .flat_map(|v| v.methods.iter().filter(|(k, _)| *k == key))
                .map(|(_, m)| m.flip)
                .collect();
            let mean = scores.iter().sum::<f64>() / scores.len().max(1) as f64;
            (key, mean)
        })
        .collect();
    ranked.sort_by(|a, b| a.1.total_cmp(&b.1));
    ranked
}

/// Renders the bake's scene from its first view under the default sky, lit by the traced
/// volume, by MBD as written (`folder`'s container, lit as `prt render` lights it; else the
/// fitted model) and by each baseline; writes each render, each difference from the
/// reference and `rendered.png` (all of them) into `out_dir`.
pub fn write_renders(
    out_dir: &Path,
    bake: &Bake,
    scene: &Scene,
    folder: &BakeFolder,
) -> Result<Option<RenderSummary>> {
    // Placing the automatic inside view traces rays: list the views once.
    let all_views = views(scene);
    let Some(view) = all_views.first().cloned() else {
        return Ok(None); // no triangles and no camera: nothing to look at
    };
    let sky = Sky::default();
    let field = &bake.volume.field;
    let valid = &bake.volume.valid;
    let mut volumes = vec![(
        "reference".to_string(),
        LitVolume::from_transfer(field, valid, &sky, &NoProgress)?,
    )];
    let mbd = if folder.has_container() {
        folder.lit_volume(BakeFolder::CONTAINER, &sky, &Limits::default(), &NoProgress)?
    } else {
        LitVolume::from_model(
            &bake.mbd.model,
            field.dims(),
            field.bounds(),
            valid,
            &sky,
            &NoProgress,
        )?
    };
    volumes.push(("mbd".into(), mbd));
    for b in &bake.baselines {
        volumes.push((
            b.method.key().into(),
            LitVolume::from_model(
                &b.model,
                field.dims(),
                field.bounds(),
                valid,
                &sky,
                &NoProgress,
            )?,
        ));
    }
    let tracer = RayTracer::new(scene.triangles());
    let config = RenderConfig {
        width: RENDER_SIZE,
        height: RENDER_SIZE,
    };
    // Every method's render of one view, the reference first.
    let render_all = |view: &prt_trace::camera::PinholeView| -> Result<Vec<(String, Rendered)>> {
        volumes
            .iter()
            .map(|(key, volume)| {
                let image = render(scene, &tracer, view, volume, &sky, &config, &NoProgress)?;
                Ok((key.clone(), image))
            })
            .collect()
    };
    let images = render_all(&view.view)?;
    let reference = &images[0].1;
    let tone = ToneMap::auto(reference);
    let mut view_metrics = Vec::new();
    for (index, other) in all_views.into_iter().enumerate() {
        let rendered = if index == 0 {
            images.clone()
        } else {
            render_all(&other.view)?
        };
        let base = &rendered[0].1;
        let view_tone = ToneMap::auto(base);
        let methods = rendered[1..]
            .iter()
            .map(|(key, image)| Ok((key.clone(), image_metrics(base, image, &view_tone)?)))
            .collect::<Result<_>>()?;
        view_metrics.push(ViewMetrics {
            view: other.name,
            methods,
        });
    }
    let display = |image: &Rendered| -> Vec<f32> {
        image
            .pixels
            .iter()
            .map(|p| p.iter().map(|&v| 255.0 * tone.display(v)).sum::<f32>() / 3.0)
            .collect()
    };
    let base = display(reference);
    let differences: Vec<Vec<f32>> = images[1..]
        .iter()
        .map(|(_, image)| {
            display(image)
                .iter()
                .zip(&base)
                .map(|(a, b)| a - b)
                .collect()
        })
        .collect();
    let magnitudes: Vec<Option<f32>> = differences
        .iter()
        .flatten()
        .map(|d| Some(d.abs()))
        .collect();
    let difference_top = heat_scale(magnitudes.iter(), 1.0);

    // The seam view: each method's basis applied to the denoised reference `s` (its projection
    // P s at every voxel, as prt-bake's seam stage computes it), rendered, relative to the
    // render of `s`. Only a jump of the basis makes this jump, so block and cluster edges show
    // without the reference's noise.
    let smoothed = blur_valid(field, valid, BLUR_SIGMA)?;
    // The projection costs most per voxel: only the voxels the view reads need it.
    let read = voxels_read(scene, &tracer, &view.view, field, &config)?;
    let needed: Vec<bool> = valid.iter().zip(&read).map(|(&v, &r)| v && r).collect();
    let lit = |f: &GridField| -> Result<Rendered> {
        let volume = LitVolume::from_transfer(f, valid, &sky, &NoProgress)?;
        Ok(render(
            scene,
            &tracer,
            &view.view,
            &volume,
            &sky,
            &config,
            &NoProgress,
        )?)
    };
    let luminance = |image: &Rendered| -> Vec<f32> {
        image
            .pixels
            .iter()
            .map(|&p| prt_render::luminance(p))
            .collect()
    };
    let smooth_lum = luminance(&lit(&smoothed)?);
    let floor = 0.05 * smooth_lum.iter().sum::<f32>() / smooth_lum.len().max(1) as f32;
    let mbd_basis = LocalBasis::Moving {
        kernels: bake.mbd.model.basis_kernels(),
        basis: bake.mbd.model.basis(),
    };
    let bases =
        std::iter::once(mbd_basis).chain(bake.baselines.iter().map(|b| LocalBasis::Clustered {
            labels: b.model.labels(),
            bases: b.model.bases(),
        }));
    let mut seams = Vec::new();
    for basis in bases {
        let mut projected = smoothed.clone();
        let residual = projection_residuals(&smoothed, &needed, &basis)?;
        for (x, e) in projected.data_mut().iter_mut().zip(residual.iter()) {
            *x += e;
        }
        let relative: Vec<f32> = luminance(&lit(&projected)?)
            .iter()
            .zip(&smooth_lum)
            .map(|(p, s)| (p - s) / s.max(floor))
            .collect();
        seams.push(relative);
    }
    let magnitudes: Vec<Option<f32>> = seams.iter().flatten().map(|d| Some(d.abs())).collect();
    let seam_top = heat_scale(magnitudes.iter(), 1e-4);

    let size = RENDER_SIZE as u32;
    let to_rgb = |image: &Rendered| {
        image::RgbImage::from_raw(size, size, tone.apply(image)).context("render buffer size")
    };
    let to_difference = |d: &[f32], top: f32| {
        image::RgbImage::from_fn(size, size, |x, y| {
            image::Rgb(diverging(d[(y * size + x) as usize] / top))
        })
    };
    let mut files = Vec::new();
    let (gap, caption) = (4u32, 28u32);
    let columns = images.len() as u32;
    let mut grid = image::RgbImage::from_pixel(
        columns * (size + gap),
        caption + 3 * (size + gap),
        image::Rgb([255, 255, 255]),
    );
    let at = |column: u32, row: u32| {
        (
            (column * (size + gap)) as i64,
            (caption + row * (size + gap)) as i64,
        )
    };
    let mut labels = Vec::new();
    for (i, (key, image)) in images.iter().enumerate() {
        let rgb = to_rgb(image)?;
        let (x, y) = at(i as u32, 0);
        image::imageops::replace(&mut grid, &rgb, x, y);
        labels.push((x as i32 + 6, 6, key.to_uppercase(), 18));
        let name = format!("render_{key}.png");
        save_png(&out_dir.join(&name), &rgb)?;
        files.push(name);
    }
    for (row, maps, top, prefix) in [
        (1, &differences, difference_top, "render_difference"),
        (2, &seams, seam_top, "render_seams"),
    ] {
        for (i, ((key, _), d)) in images[1..].iter().zip(maps).enumerate() {
            let img = to_difference(d, top);
            let (x, y) = at(i as u32 + 1, row);
            image::imageops::replace(&mut grid, &img, x, y);
            let name = format!("{prefix}_{key}.png");
            save_png(&out_dir.join(&name), &img)?;
            files.push(name);
        }
    }
    let row_text = [
        (
            1,
            vec![
                "DIFFERENCE from the".to_string(),
                "reference render, in grey".into(),
                "levels of the images above:".into(),
                "red = brighter, blue = darker,".into(),
                format!("full colour at ±{difference_top:.1} of 255"),
                format!("(gain {:.0}x).", 255.0 / difference_top),
                "Mean |difference| (grey".into(),
                "levels), this view:".into(),
            ],
        ),
        (
            2,
            vec![
                "SEAMS: each method's basis".to_string(),
                "applied to the denoised".into(),
                "reference, rendered, minus".into(),
                "the denoised reference's".into(),
                "render, relative to it:".into(),
                format!("full colour at ±{:.2} %.", 100.0 * seam_top),
                "Straight steps = the basis".into(),
                "jumps at block / cluster".into(),
                "edges; smooth = seamless.".into(),
            ],
        ),
    ];
    let mut row_text = row_text;
    if let Some(first) = view_metrics.first() {
        for (key, m) in &first.methods {
            row_text[0]
                .1
                .push(format!("{} {:.1}", key.to_uppercase(), m.mean_levels));
        }
    }
    for (row, lines) in row_text {
        let (x, y) = at(0, row);
        for (k, line) in lines.into_iter().enumerate() {
            labels.push((x as i32 + 6, y as i32 + 4 + 20 * k as i32, line, 15));
        }
    }
    draw_text(&mut grid, &labels)?;
    save_png(&out_dir.join("rendered.png"), &grid)?;
    files.insert(0, "rendered.png".into());
    let rmse = images[1..]
        .iter()
        .map(|(key, image)| (key.clone(), image.rmse(reference).unwrap_or(f64::NAN)))
        .collect();
    Ok(Some(RenderSummary {
        view: view.name,
        exposure: tone.exposure,
        difference_top,
        seam_top,
        rmse,
        views: view_metrics,
        files,
    }))
}

/// Black at 0, towards red for positive and blue for negative `t`, saturating at ±1.
fn diverging(t: f32) -> [u8; 3] {
    let a = (t.abs().min(1.0) * 255.0).round() as u8;
    if t >= 0.0 {
        [a, a / 4, 0]
    } else {
        [0, a / 2, a]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn metrics(flip: f64) -> ImageMetrics {
        ImageMetrics {
            flip,
            mean_levels: 0.0,
            share_off: 0.0,
            dark_levels: 0.0,
            median_relative: 0.0,
            pixels: 1,
        }
    }

    #[test]
    fn the_ranking_follows_the_mean_flip_over_views() {
        let view = |name: &str, flips: [f64; 3]| ViewMetrics {
            view: name.into(),
            methods: ["mbd", "bpca", "cpca"]
                .iter()
                .zip(flips)
                .map(|(k, f)| (k.to_string(), metrics(f)))
                .collect(),
        };
        // MBD wins one view by a little and loses the other by a lot: it ranks last.
        let views = [view("a", [0.10, 0.11, 0.12]), view("b", [0.40, 0.20, 0.10])];
        let ranked = rank_by_flip(&views);
        let keys: Vec<&str> = ranked.iter().map(|(k, _)| k.as_str()).collect();
        assert_eq!(keys, ["cpca", "bpca", "mbd"]);
        assert!((ranked[2].1 - 0.25).abs() < 1e-12);
        assert!(rank_by_flip(&[]).is_empty());
    }
}

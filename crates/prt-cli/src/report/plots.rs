//! The report's plots (loss per iteration, seam profile) and text drawn onto images, with the
//! font they use.

use std::io::Cursor;

use anyhow::{Result, anyhow};
use prt_mbd::SolveReport;

/// Colour of the block / cluster edges in the seam profile.
const BOUNDARY: [u8; 3] = [0, 190, 255];

/// One panel per method, titled `captions[i]`: its seam-view residual along row `z` of the slice
/// (`residuals` and `labels` hold that row), with a vertical line wherever its block or cluster
/// changes.
pub fn seam_profile_png(
    captions: &[String],
    residuals: &[Vec<Option<f32>>],
    labels: &[Vec<u32>],
    z: usize,
) -> Result<Vec<u8>> {
    use plotters::prelude::*;
    register_font()?;
    let w = residuals.first().map_or(0, Vec::len);
    let panels = captions.len().max(1);
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
        for (i, (area, (caption, r))) in root
            .split_evenly((panels, 1))
            .iter()
            .zip(captions.iter().zip(residuals))
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
            area.draw(&Text::new(
                caption.as_str(),
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
pub fn register_font() -> Result<()> {
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
pub fn draw_text(image: &mut image::RgbImage, labels: &[(i32, i32, String, u32)]) -> Result<()> {
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
pub fn loss_plot_png(solve: &SolveReport) -> Result<Vec<u8>> {
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

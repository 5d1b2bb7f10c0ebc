//! The report's text: `report.md` (with the comparison table) and `report.json`.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Result;
use prt_bake::seams::BLUR_SIGMA;
use prt_bake::{Bake, BakeFolder, MethodScores};
use prt_texture::write_atomic;
use serde_json::json;

use crate::report::images::ImageSummary;
use crate::report::plots::loss_plot_png;
use crate::report::renders::{RenderSummary, ViewMetrics, rank_by_flip};

/// Everything the report shows.
pub struct Report<'a> {
    /// The scene's name.
    pub scene: &'a str,
    /// The bake.
    pub bake: &'a Bake,
    /// Wall time of every stage, in order (the CLI's own stages included).
    pub stage_seconds: Vec<(String, f64)>,
    /// Wall time of the whole command.
    pub total_seconds: f64,
}

/// The comparison table as markdown.
pub fn table_markdown(rows: &[MethodScores]) -> String {
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
            format!("{:.2}", r.bytes_per_voxel_or_estimate())
        } else {
            format!("{:.2} (f16 est.)", r.bytes_per_voxel_or_estimate())
        };
        s += &format!(
            "| {} | {:.3e} | {} | {:.2} | {} | {} | {:.1}:1 | {:.2} s |\n",
            r.method.name(),
            r.relative_mse,
            frob,
            r.seam_ratio(),
            r.denoised_seam_ratio
                .map_or_else(|| "–".to_string(), |x| format!("**{x:.2}**")),
            bytes,
            r.compression_ratio(),
            r.time.as_secs_f64()
        );
    }
    s
}

/// The image metrics' section of `report.md`: what a person sees, per view and method.
pub fn image_metrics_markdown(views: &[ViewMetrics]) -> String {
    let ranked = rank_by_flip(views);
    let order: Vec<String> = ranked
        .iter()
        .map(|(key, flip)| format!("{} ({flip:.4})", key.to_uppercase()))
        .collect();
    let mut md = format!(
        "## What the eye sees\n\nEvery view rendered at {size} × {size} under the default sky \
         with each method's volume and with the traced reference, both tone-mapped with the \
         reference's exposure (ACES filmic, sRGB), and compared over the pixels that show the \
         scene: **ꟻLIP** (NVIDIA's perceptual difference, 0 = identical), the mean difference \
         in grey levels of 255, the share of pixels more than {levels:.0} levels off, the mean \
         difference over the reference's darkest quartile, and the median relative luminance \
         error. Ranked by mean ꟻLIP over the views: **{order}**.\n\n\
         | view | method | ꟻLIP | mean levels | > {levels:.0} levels | darkest quartile | median relative |\n\
         |---|---|---|---|---|---|---|\n",
        size = super::renders::RENDER_SIZE,
        levels = prt_render::VISIBLE_LEVELS,
        order = order.join(", "),
    );
    for v in views {
        for (key, m) in &v.methods {
            md += &format!(
                "| {} | {} | {:.4} | {:.2} | {:.1} % | {:.2} | {:.1} % |\n",
                v.view,
                key.to_uppercase(),
                m.flip,
                m.mean_levels,
                100.0 * m.share_off,
                m.dark_levels,
                100.0 * m.median_relative
            );
        }
    }
    md + "\n"
}

/// The rendered views' section of `report.md`.
fn renders_markdown(renders: &RenderSummary) -> String {
    let mut md = format!(
        "## Rendered views\n\nThe scene from its `{view}` view ({size} × {size} pixels, one \
         primary ray per pixel) under the default sky, each surface shaded with the diffuse \
         irradiance of a volume (incident-radiance SH, trilinear over valid voxels): the traced \
         reference, MBD as written and each baseline; one exposure ({exposure:.3}, the \
         reference's), ACES filmic curve, sRGB.\n\n\
         - **Middle row**: each render's difference from the reference render, in grey levels of \
         the images (red = brighter, blue = darker, full colour at ±{top:.1} of 255, a gain of \
         {gain:.0}×); the mean difference of each method in this view: {means}.\n\
         - **Bottom row, the seam view rendered**: each method's basis applied to the denoised \
         reference (blurred with σ = {sigma} voxel over valid voxels), rendered, minus the \
         render of the denoised reference, relative to it (full colour at ±{seam:.2} %). \
         BPCA and CPCA change basis abruptly at block and cluster edges, which shows as \
         straight steps between patches; MBD's basis moves continuously, so its map varies \
         smoothly.\n\n\
         `prt render` draws these images from the bake folder at any size.\n\n\
         ![rendered](rendered.png)\n\n\
         | method | RMSE of the render vs the reference render |\n|---|---|\n",
        view = renders.view,
        size = super::renders::RENDER_SIZE,
        exposure = renders.exposure,
        top = renders.difference_top,
        gain = 255.0 / renders.difference_top,
        sigma = BLUR_SIGMA,
        seam = 100.0 * renders.seam_top,
        means = renders
            .views
            .first()
            .map(|v| {
                v.methods
                    .iter()
                    .map(|(key, m)| format!("{} {:.2} levels", key.to_uppercase(), m.mean_levels))
                    .collect::<Vec<_>>()
                    .join(", ")
            })
            .unwrap_or_default(),
    );
    for (key, rmse) in &renders.rmse {
        md += &format!("| {} | {rmse:.4e} |\n", key.to_uppercase());
    }
    md += "\n";
    md += &renders
        .files
        .iter()
        .map(|f| format!("- [{f}]({f})\n"))
        .collect::<String>();
    md + "\n"
}

/// Writes `report.md`, `report.json` and `loss.png`.
pub fn write_report(
    out_dir: &Path,
    report: &Report<'_>,
    images: &ImageSummary,
    renders: Option<&RenderSummary>,
) -> Result<()> {
    let baked = report.bake;
    let solve = &baked.mbd.report;
    write_atomic(&out_dir.join("loss.png"), &loss_plot_png(solve)?)?;
    let [nx, ny, nz] = baked.volume.field.dims();
    let basis_nodes = baked.mbd.basis_nodes;
    let rank = baked.mbd.model.rank();
    let stats = &baked.volume.stats;
    let invalid_voxels = baked.volume.valid.iter().filter(|v| !**v).count();
    let mut md = format!(
        "# prt bake report: {}\n\nGrid {nx} × {ny} × {nz} voxels, 324-D transfer vectors \
         (order-3 SH: direct 9×9 and one-bounce indirect 9×9 per colour). MBD rank {} on a \
         {} × {} × {} basis grid; the baselines use the same number of basis vectors (one rank-{} \
         basis per block or cluster).\n\n",
        report.scene, rank, basis_nodes[0], basis_nodes[1], basis_nodes[2], rank
    );
    if let Some(renders) = renders {
        md += &image_metrics_markdown(&renders.views);
    }
    md += "## Compression\n\n";
    md += &table_markdown(&baked.comparison);
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
    if let Some(renders) = renders {
        md += &renders_markdown(renders);
    }
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
         tone-mapped images above (white ≥ {error:.1} of 255); mean over the slice's valid \
         voxels: {means}. It is measured on the displayed values because an absolute \
         radiometric error is dominated by the brightest voxels (e.g. a ring of voxels under \
         the open sky outside a building's walls).\n\n\
         ![comparison](comparison.png)\n\n![seam profile](seam_profile.png)\n\n",
        slice_y = baked.seam_slice,
        sigma = BLUR_SIGMA,
        jump = 100.0 * images.jump_top,
        row = images.profile_row,
        error = images.error_top,
        means = images
            .error_means
            .iter()
            .map(|(key, mean)| format!("{} {mean:.2}", key.to_uppercase()))
            .collect::<Vec<_>>()
            .join(", "),
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
        solve.history.len(),
        if solve.converged {
            " (converged)"
        } else {
            " (iteration cap)"
        },
        stats.rays(),
        stats.mrays_per_second(),
        stats.rays_per_voxel,
        stats.cache_points,
        invalid_voxels,
        stats.voxels
    );
    for (stage, s) in &report.stage_seconds {
        md += &format!("| {stage} | {s:.2} |\n");
    }
    md += &format!("| total | {:.2} |\n", report.total_seconds);
    write_atomic(&BakeFolder::new(out_dir).report_md(), md.as_bytes())?;

    let rows: Vec<_> = baked
        .comparison
        .iter()
        .map(|r| {
            json!({
                "method": r.method.name(),
                "relative_mse": r.relative_mse,
                "operator_frobenius": r.operator_frobenius,
                "seam_boundary": r.seam_boundary,
                "seam_interior": r.seam_interior,
                "seam_ratio": r.seam_ratio(),
                "denoised_seam_ratio": r.denoised_seam_ratio,
                "bytes_per_voxel": r.bytes_per_voxel_or_estimate(),
                "bytes_measured": r.bytes_per_voxel.is_some(),
                "compression_ratio": r.compression_ratio(),
                "seconds": r.time.as_secs_f64(),
            })
        })
        .collect();
    let doc = json!({
        "scene": report.scene,
        "resolution": [nx, ny, nz],
        "rank": rank,
        "basis_nodes": basis_nodes,
        "methods": rows,
        "mbd": {
            "iterations": solve.history.len(),
            "converged": solve.converged,
            "loss": solve.history.iter().map(|r| r.loss_after).collect::<Vec<_>>(),
        },
        "bake": {
            "rays": stats.rays(),
            "mrays_per_second": stats.mrays_per_second(),
            "cache_points": stats.cache_points,
            "cache_evaluated": stats.cache_evaluated,
            "invalid_voxels": invalid_voxels,
            "voxels": stats.voxels,
        },
        "renders": renders.map(|r| json!({
            "view": r.view,
            "size": super::renders::RENDER_SIZE,
            "exposure": r.exposure,
            "rmse_vs_reference": r.rmse.iter().cloned().collect::<BTreeMap<_, _>>(),
        })),
        "image_metrics": renders.map(|r| json!({
            "definition": "per view, each method's render against the reference render, both tone-mapped with the reference's exposure (ACES, sRGB), over the pixels that hit the scene",
            "ranking_by_flip": rank_by_flip(&r.views).into_iter().map(|(k, f)| json!({"method": k, "mean_flip": f})).collect::<Vec<_>>(),
            "views": r.views.iter().map(|v| json!({
                "view": v.view,
                "methods": v.methods.iter().map(|(k, m)| json!({
                    "method": k,
                    "flip": m.flip,
                    "mean_levels": m.mean_levels,
                    "share_over_levels": m.share_off,
                    "levels_threshold": prt_render::VISIBLE_LEVELS,
                    "darkest_quartile_levels": m.dark_levels,
                    "median_relative_luminance": m.median_relative,
                    "pixels": m.pixels,
                })).collect::<Vec<_>>(),
            })).collect::<Vec<_>>(),
        })),
        "stage_seconds": report.stage_seconds.iter().cloned().collect::<BTreeMap<_, _>>(),
        "total_seconds": report.total_seconds,
    });
    write_atomic(
        &BakeFolder::new(out_dir).report_json(),
        serde_json::to_string_pretty(&doc)?.as_bytes(),
    )?;
    Ok(())
}

//! Where a generated lightmap atlas's area goes: triangles, the rest of each chart's bounding
//! box, the gap between charts and per-chart rounding, and the packer's free space; with the share of tiny
//! charts.
//!
//! Run: `cargo run --release -p prt-benches --bin lightmap_atlas -- [--scenes cornell,sponza,gas_station]
//! [--texels-per-metre 16] [--padding 2]`
//!
//! Columns, as fractions of the atlas area: `triangles` = UV area of the triangles (the
//! packing efficiency), `chart box` = the charts' bounding boxes minus their triangles, `pad +
//! round` = the whole-texel rectangles the charts can claim, each with the gap on its right and
//! bottom, minus the bounding boxes, `free` = the atlas
//! minus the rectangles (shelf gaps, the last shelf, rounding the sides to 4). `tiny` = charts
//! that claim at most 2 × 2 texels, and their share of the rectangles' area.
use std::time::Instant;

use clap::Parser;
use glam::Vec2;
use prt_benches::{Table, load_scene};
use prt_lightmap::{UnwrapConfig, unwrap_charts};

#[derive(Parser)]
struct Args {
    /// Scenes, comma-separated: cornell, sponza, gas_station or town.
    #[arg(
        long,
        default_value = "cornell,sponza,gas_station",
        value_delimiter = ','
    )]
    scenes: Vec<String>,
    /// Texel density of the charts (`prt lightmap`'s default).
    #[arg(long, default_value_t = 16.0)]
    texels_per_metre: f32,
    /// Empty texels around each chart (`prt lightmap`'s default).
    #[arg(long, default_value_t = 2)]
    padding: u32,
}

fn main() -> Result<(), String> {
    let args = Args::parse();
    let mut table = Table::new(&[
        "scene",
        "triangles",
        "charts",
        "atlas",
        "triangles %",
        "chart box %",
        "pad + round %",
        "free %",
        "tiny charts",
        "tiny area %",
        "unwrap s",
    ]);
    for name in &args.scenes {
        let scene = load_scene(name)?;
        let config = UnwrapConfig {
            texels_per_metre: args.texels_per_metre,
            padding: args.padding,
            ..Default::default()
        };
        let start = Instant::now();
        let atlas = unwrap_charts(scene.triangles(), &config).map_err(|e| e.to_string())?;
        let seconds = start.elapsed().as_secs_f64();
        let mut boxes =
            vec![(Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)); atlas.charts];
        let mut triangle_area = 0.0f64;
        for (t, uv) in atlas.uvs.iter().enumerate() {
            triangle_area += f64::from(0.5 * (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]).abs());
            let b = &mut boxes[atlas.chart_of[t] as usize];
            for p in uv {
                b.0 = b.0.min(*p);
                b.1 = b.1.max(*p);
            }
        }
        let pad = u64::from(args.padding);
        let (mut box_area, mut rect_area, mut tiny, mut tiny_area) = (0.0f64, 0u64, 0usize, 0u64);
        for (lo, hi) in &boxes {
            let e = *hi - *lo;
            box_area += f64::from(e.x) * f64::from(e.y);
            // The packer's rectangle and the gap it carries (see `unwrap_charts`).
            let rect = [(e.x + 0.55) as u64 + 1 + pad, (e.y + 0.55) as u64 + 1 + pad];
            rect_area += rect[0] * rect[1];
            if rect[0] <= 2 + pad && rect[1] <= 2 + pad {
                tiny += 1;
                tiny_area += rect[0] * rect[1];
            }
        }
        let total = f64::from(atlas.width) * f64::from(atlas.height);
        let pct = |x: f64| format!("{:.1}", 100.0 * x / total);
        table.row(vec![
            name.clone(),
            scene.triangles().len().to_string(),
            atlas.charts.to_string(),
            format!("{}×{}", atlas.width, atlas.height),
            pct(triangle_area),
            pct(box_area - triangle_area),
            pct(rect_area as f64 - box_area),
            pct(total - rect_area as f64),
            tiny.to_string(),
            format!("{:.1}", 100.0 * tiny_area as f64 / rect_area as f64),
            format!("{seconds:.2}"),
        ]);
    }
    println!("{}", table.markdown());
    table
        .write_csv_if_requested("lightmap_atlas")
        .map_err(|e| e.to_string())
}

//! What the engines show against what prt promised: a bake's views rendered with prt's lookup
//! of the traced reference (the truth), and with each engine's lookup (Bevy's and three.js's
//! shaders on `prt export`'s data, emulated by prt-export's `EngineLookup`) of the reference and
//! of MBD as written.
//!
//! ```text
//! prt bake ../shared/scenes/sponza/Sponza.gltf --res 64 --keep-volumes always --out /tmp/sponza64
//! cargo run --release -p prt-benches --bin engine_lookup -- /tmp/sponza64 --size 256
//! ```
//!
//! Per view and (volume, lookup): the median luminance of the surface pixels relative to the
//! truth's, the share of surface pixels whose luminance is within 15 % of the truth's (plus 1 %
//! of the truth's median, so that shadows do not divide by zero), and the surface pixels the
//! lookup leaves black where the truth is lit.

use std::path::PathBuf;

use clap::Parser;
use prt_bake::container::read_container;
use prt_bake::volumes::{REFERENCE, read_volumes};
use prt_benches::Table;
use prt_core::{NoProgress, glam::Vec3};
use prt_export::{
    AmbientCubeFit, DilateConfig, Engine, EngineLookup, dilate, remove_negative_light,
};
use prt_render::{RenderConfig, Rendered, SurfaceLight, luminance, render, views};
use prt_sphere::Sky;
use prt_texture::Limits;
use prt_trace::mesh::read_mesh;
use prt_trace::{LitVolume, RayTracer};

#[derive(Debug, Parser)]
#[command(about = "Engine lookups of a bake against prt's lookup of its traced reference")]
struct Cli {
    /// Output folder of `prt bake --keep-volumes always`.
    bake: PathBuf,
    /// Image side in pixels.
    #[arg(long, default_value_t = 256)]
    size: usize,
    /// Sky: `default` or `sun` (prt's default sun and sky).
    #[arg(long, default_value = "default")]
    sky: String,
}

struct Engined(EngineLookup);

impl SurfaceLight for Engined {
    fn surface_irradiance(&self, position: Vec3, normal: Vec3) -> Option<Vec3> {
        self.0.irradiance(position, normal)
    }
}

fn engine(lit: &LitVolume, engine: Engine) -> Result<Engined, Box<dyn std::error::Error>> {
    let filled = dilate(lit, &DilateConfig::default())?.volume;
    let clean = remove_negative_light(&filled)?.volume;
    Ok(Engined(EngineLookup::new(
        &clean,
        engine,
        AmbientCubeFit::Axes,
    )?))
}

fn median(mut v: Vec<f32>) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f32::total_cmp);
    v[v.len() / 2]
}

/// `a / b`, or `-` where the truth's median is too dark to divide by (a view inside geometry).
fn ratio(a: f32, b: f32) -> String {
    if b > 1e-6 {
        format!("{:.3}", a / b)
    } else {
        "-".into()
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let cli = Cli::parse();
    let limits = Limits {
        max_bytes: 16 << 30,
        ..Limits::default()
    };
    let sky = match cli.sky.as_str() {
        "default" => Sky::default(),
        "sun" => Sky::sun_sky(&prt_sphere::SunSky::default())?,
        other => return Err(format!("--sky {other}: default or sun").into()),
    };
    let scene = read_mesh(&cli.bake.join("scene.mesh"), &limits)?;
    let kept = read_volumes(&cli.bake.join("volumes"), &limits)?;
    let reference = kept.get(REFERENCE).ok_or("no kept reference volume")?;
    let container = read_container(&cli.bake.join("mbd"), &limits)?;
    let truth = LitVolume::from_transfer(reference, &kept.valid, &sky, &NoProgress)?;
    let lit_mbd = container.light(&sky, &NoProgress)?;
    let lights: Vec<(&str, &str, Box<dyn SurfaceLight>)> = vec![
        ("reference", "bevy", Box::new(engine(&truth, Engine::Bevy)?)),
        (
            "reference",
            "threejs",
            Box::new(engine(&truth, Engine::Threejs)?),
        ),
        ("mbd", "prt", Box::new(lit_mbd.clone())),
        ("mbd", "bevy", Box::new(engine(&lit_mbd, Engine::Bevy)?)),
        (
            "mbd",
            "threejs",
            Box::new(engine(&lit_mbd, Engine::Threejs)?),
        ),
    ];
    let tracer = RayTracer::new(scene.triangles());
    let config = RenderConfig {
        width: cli.size,
        height: cli.size,
    };
    let mut table = Table::new(&[
        "view",
        "volume",
        "lookup",
        "median luminance / truth's",
        "pixels within 15 %",
        "black where lit",
    ]);
    for view in views(&scene) {
        let base = render(
            &scene,
            &tracer,
            &view.view,
            &truth,
            &sky,
            &config,
            &NoProgress,
        )?;
        let surface = |image: &Rendered| -> Vec<f32> {
            image
                .pixels
                .iter()
                .zip(&base.hit)
                .filter(|&(_, &hit)| hit)
                .map(|(&p, _)| luminance(p))
                .collect()
        };
        let want = surface(&base);
        let floor = 0.01 * median(want.clone());
        for (volume, lookup, light) in &lights {
            let image = render(
                &scene,
                &tracer,
                &view.view,
                &**light,
                &sky,
                &config,
                &NoProgress,
            )?;
            let got = surface(&image);
            let within = got
                .iter()
                .zip(&want)
                .filter(|&(&g, &w)| (g - w).abs() <= 0.15 * w + floor)
                .count();
            let black = got
                .iter()
                .zip(&want)
                .filter(|&(&g, &w)| g <= 0.0 && w > floor)
                .count();
            table.row(vec![
                view.name.clone(),
                (*volume).into(),
                (*lookup).into(),
                ratio(median(got.clone()), median(want.clone())),
                format!("{:.1} %", 100.0 * within as f64 / want.len().max(1) as f64),
                format!("{}", black),
            ]);
        }
    }
    println!("{}", table.markdown());
    table.write_csv_if_requested("engine_lookup")?;
    Ok(())
}

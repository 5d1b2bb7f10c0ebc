//! Relighting traced scenes from a fixed camera with per-pixel wavelet transport: NWA, BI and
//! PBI measured on images (relative RMSE against the exact product) under rotating maps, the
//! engine's frame time against its memory-bandwidth bound, and transport size against image
//! error over the sparsification knob.
//!
//! `cargo run -p prt-benches --bin pixel_relight --config 'profile.dev.opt-level=3' -- --help`
//! (the transport of each scene and size is cached in target/pixel_transport/).

use std::path::PathBuf;
use std::time::Instant;

use clap::Parser;
use prt_benches::{
    Table, cache_dir, cpu_seconds, large_file_limits, load_average, load_envmap, load_scene,
    relative_rms,
};
use prt_core::NoProgress;
use prt_trace::RayTracer;
use prt_trace::camera::PinholeView;
use prt_trace::relight::{
    Bounce, MethodRelighter, PixelTransport, PixelTransportBaker, PixelTransportOptions,
    RelightMethod, Sparsify,
};
use prt_wavelet::CubemapHaar;
use prt_wavelet::sequence::Rotation;

#[derive(Debug, Parser)]
#[command(about = "NWA / BI / PBI on relit images, engine speed, transport size vs error")]
struct Cli {
    /// Scenes (cornell, sponza, town, gas_station).
    #[arg(long, value_delimiter = ',', default_value = "cornell,sponza")]
    scenes: Vec<String>,
    /// Maps from ../shared/envmaps.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "probulator_uffizi,probulator_grace,probulator_pisa"
    )]
    maps: Vec<String>,
    /// Image side in pixels for the method comparison.
    #[arg(long, default_value_t = 128)]
    size: usize,
    /// Cube face side.
    #[arg(long, default_value_t = 32)]
    cube: usize,
    /// Frames (rotating until --stop, then static).
    #[arg(long, default_value_t = 60)]
    frames: usize,
    /// Stop frame.
    #[arg(long, default_value_t = 40)]
    stop: usize,
    /// Degrees per frame.
    #[arg(long, default_value_t = 1.0)]
    rotate: f32,
    /// Energy kept per row.
    #[arg(long, default_value_t = 0.999)]
    energy: f32,
    /// Largest terms per row.
    #[arg(long, default_value_t = 1024)]
    max_terms: usize,
    /// Gather rays per pixel of one diffuse bounce (0: direct light only).
    #[arg(long, default_value_t = 0)]
    bounce: usize,
    /// Engine speed at these image sides (Cornell box, first map) instead of the comparison.
    #[arg(long, value_delimiter = ',')]
    speed: Vec<usize>,
    /// Transport size against image error over these sparsifications, `ENERGY` or
    /// `ENERGY:MAX_TERMS` (no cap when omitted), on the first scene and map, instead of the
    /// comparison.
    #[arg(long, value_delimiter = ',')]
    curve: Vec<String>,
    /// With --curve: also plot bytes against error into this PNG.
    #[arg(long)]
    plot: Option<PathBuf>,
}

fn options(cli: &Cli, size: usize, energy: f32, max_terms: usize) -> PixelTransportOptions {
    PixelTransportOptions {
        width: size,
        height: size,
        cube_size: cli.cube,
        sparsify: Sparsify { energy, max_terms },
        bounce: (cli.bounce > 0).then_some(Bounce {
            gathers: cli.bounce,
        }),
        ..Default::default()
    }
}

/// Wall and CPU seconds of a bake.
struct BakeTime {
    wall: f64,
    cpu: f64,
}

/// The scene's transport, from target/pixel_transport/ when baked before with these options.
fn transport(scene_name: &str, options: PixelTransportOptions) -> PixelTransport {
    timed_transport(scene_name, options).0
}

/// [`transport`] and its bake time (`None` when read from the cache).
fn timed_transport(
    scene_name: &str,
    options: PixelTransportOptions,
) -> (PixelTransport, Option<BakeTime>) {
    let dir = cache_dir("pixel_transport");
    std::fs::create_dir_all(&dir).expect("cache dir");
    let gathers = options.bounce.map_or(0, |b| b.gathers);
    let path: PathBuf = dir.join(format!(
        "{scene_name}_{}_{}_{}_{}_b{gathers}.prtpx",
        options.width, options.cube_size, options.sparsify.energy, options.sparsify.max_terms
    ));
    let limits = large_file_limits();
    let scene = load_scene(scene_name).unwrap_or_else(|e| panic!("{e}"));
    let view = PinholeView::for_scene(&scene).expect("view");
    if let Ok(t) = PixelTransport::read(&path, &limits)
        && t.options == options
        && t.view == view
    {
        return (t, None);
    }
    let tracer = RayTracer::new(scene.triangles());
    let baker = PixelTransportBaker::new(&scene, &tracer, view, options).expect("baker");
    let estimate = baker.estimate(64);
    eprintln!(
        "{scene_name} {}²: {} hit pixels, ≤ {:.2e} rays, peak ≤ {:.2} GB, ~{:.0} s estimated",
        options.width,
        estimate.hit_pixels,
        estimate.max_rays as f64,
        estimate.peak_bytes as f64 / 1e9,
        estimate.seconds
    );
    let (start, cpu) = (Instant::now(), cpu_seconds());
    let t = baker.bake(&NoProgress).expect("bake");
    let time = BakeTime {
        wall: start.elapsed().as_secs_f64(),
        cpu: cpu_seconds() - cpu,
    };
    eprintln!(
        "  baked in {:.1} s wall, {:.1} s CPU (load {}), {} entries ({:.1} MB)",
        time.wall,
        time.cpu,
        load_average(),
        t.nnz(),
        t.entry_bytes() as f64 / 1e6
    );
    t.write(&path).expect("write the transport");
    (t, Some(time))
}

/// Relative image RMSE per frame of every method, and mean frame times.
struct Run {
    errors: Vec<Vec<f64>>,
    seconds: Vec<f64>,
}

fn run(cli: &Cli, t: &PixelTransport, map: &str, methods: &[RelightMethod]) -> Run {
    let latlong = load_envmap(map).unwrap_or_else(|e| panic!("{e}"));
    let rotation = Rotation::new(latlong, cli.cube, cli.rotate.to_radians(), cli.stop).unwrap();
    let mut haar = CubemapHaar::new(cli.cube).unwrap();
    let mut exact = MethodRelighter::new(t, RelightMethod::Exact).unwrap();
    let mut relighters: Vec<MethodRelighter> = methods
        .iter()
        .map(|&m| MethodRelighter::new(t, m).unwrap())
        .collect();
    let mut errors = vec![Vec::new(); methods.len()];
    let mut seconds = vec![0.0; methods.len()];
    for f in 0..cli.frames {
        let texels = rotation.frame(f).unwrap().into_data();
        let mut coefficients = texels.clone();
        haar.forward(&mut coefficients).unwrap();
        let reference = exact.frame(&coefficients, &texels).unwrap();
        for (m, r) in relighters.iter_mut().enumerate() {
            let frame = r.frame(&coefficients, &texels).unwrap();
            errors[m].push(relative_rms(
                frame.image.as_flattened(),
                reference.image.as_flattened(),
            ));
            seconds[m] += frame.seconds / cli.frames as f64;
        }
    }
    Run { errors, seconds }
}

fn compare(cli: &Cli) {
    let methods = [
        RelightMethod::Nwa(30),
        RelightMethod::Nwa(60),
        RelightMethod::Nwa(100),
        RelightMethod::Bi(30),
        RelightMethod::Pbi(30),
    ];
    let mut table = Table::new(&[
        "scene",
        "map",
        "method",
        "mean rel. RMSE, frames 10..stop",
        "max, 10..stop",
        "last frame",
        "frames after stop to < 1e-2",
        "frame time",
    ]);
    let mut claims = Table::new(&[
        "scene",
        "map",
        "PBI30 ≤ NWA60, frames 10..stop",
        "mean PBI30 / mean NWA60",
        "mean PBI30 / mean NWA100",
        "PBI30 frames after stop to < 1e-2",
    ]);
    let rotating = 10..cli.stop.min(cli.frames);
    for scene in &cli.scenes {
        let t = transport(scene, options(cli, cli.size, cli.energy, cli.max_terms));
        for map in &cli.maps {
            let (start, cpu) = (Instant::now(), cpu_seconds());
            let r = run(cli, &t, map, &methods);
            eprintln!(
                "{scene} {map}: {:.1} s wall, {:.1} s CPU, load {}",
                start.elapsed().as_secs_f64(),
                cpu_seconds() - cpu,
                load_average()
            );
            let mean = |e: &[f64]| e[rotating.clone()].iter().sum::<f64>() / rotating.len() as f64;
            let converged = |e: &[f64]| {
                e.iter()
                    .enumerate()
                    .skip(cli.stop)
                    .find(|(_, v)| **v < 1e-2)
                    .map_or("never".to_string(), |(f, _)| (f - cli.stop).to_string())
            };
            for (m, method) in methods.iter().enumerate() {
                let e = &r.errors[m];
                table.row(vec![
                    scene.clone(),
                    map.clone(),
                    method.name(),
                    format!("{:.4}", mean(e)),
                    format!(
                        "{:.4}",
                        e[rotating.clone()].iter().fold(0.0f64, |a, &b| a.max(b))
                    ),
                    format!("{:.4}", e[e.len() - 1]),
                    converged(e),
                    format!("{:.2} ms", r.seconds[m] * 1e3),
                ]);
            }
            let (nwa60, nwa100, pbi) = (&r.errors[1], &r.errors[2], &r.errors[4]);
            let below = rotating.clone().filter(|&f| pbi[f] <= nwa60[f]).count();
            claims.row(vec![
                scene.clone(),
                map.clone(),
                format!("{below} of {}", rotating.len()),
                format!("{:.2}", mean(pbi) / mean(nwa60)),
                format!("{:.2}", mean(pbi) / mean(nwa100)),
                converged(pbi),
            ]);
        }
    }
    println!(
        "Relative image RMSE against the exact product ({}² pixels, {}² faces, {}°/frame until frame {}, {} frames)\n",
        cli.size, cli.cube, cli.rotate, cli.stop, cli.frames
    );
    println!("{}", table.markdown());
    println!("{}", claims.markdown());
    table.write_csv_if_requested("pixel_relight").ok();
}

fn speed(cli: &Cli) {
    let bandwidth = prt_benches::read_bandwidth();
    let threads = rayon::current_num_threads();
    let mut table = Table::new(&[
        "pixels",
        "method",
        "frame time (wall)",
        "CPU per frame",
        "bytes touched per frame",
        "bandwidth bound",
        "wall / bound",
        "load",
    ]);
    let map = &cli.maps[0];
    for &size in &cli.speed {
        let t = transport("cornell", options(cli, size, cli.energy, cli.max_terms));
        let latlong = load_envmap(map).unwrap_or_else(|e| panic!("{e}"));
        let rotation =
            Rotation::new(latlong, cli.cube, cli.rotate.to_radians(), cli.frames).unwrap();
        let frames: Vec<(Vec<f32>, Vec<f32>)> = (0..cli.frames.min(30))
            .map(|f| {
                let texels = rotation.frame(f).unwrap().into_data();
                let mut c = texels.clone();
                CubemapHaar::new(cli.cube).unwrap().forward(&mut c).unwrap();
                (c, texels)
            })
            .collect();
        for method in [
            RelightMethod::Nwa(30),
            RelightMethod::Bi(30),
            RelightMethod::Pbi(30),
        ] {
            let mut r = MethodRelighter::new(&t, method).unwrap();
            let (mut wall, mut touched) = (0.0, 0usize);
            let cpu = cpu_seconds();
            for (c, texels) in &frames {
                let frame = r.frame(c, texels).unwrap();
                wall += frame.seconds;
                // Columns read, plus each replaced band's partial image read and cleared and
                // the total read and written (pixels padded to four floats).
                touched += frame.bytes + frame.replaced_bands * t.pixels() * 16 * 3;
            }
            // The CPU time includes the image copies of `frame`; an upper bound.
            let cpu = (cpu_seconds() - cpu) / frames.len() as f64;
            let n = frames.len() as f64;
            let bound = touched as f64 / n / bandwidth;
            table.row(vec![
                format!("{size}²"),
                method.name(),
                format!("{:.2} ms", wall / n * 1e3),
                format!("≤ {:.2} ms", cpu * 1e3),
                format!("{:.1} MB", touched as f64 / n / 1e6),
                format!("{:.2} ms", bound * 1e3),
                format!("{:.1}", wall / n / bound),
                load_average(),
            ]);
        }
    }
    println!(
        "Engine frame time, Cornell box, {} rayon thread(s); read bandwidth here {:.1} GB/s (one thread)\n",
        threads,
        bandwidth / 1e9
    );
    println!("{}", table.markdown());
}

/// A `--curve` point: `ENERGY` or `ENERGY:MAX_TERMS`.
fn curve_point(text: &str, full_terms: usize) -> (f32, usize) {
    let (energy, cap) = text.split_once(':').unwrap_or((text, ""));
    let energy = energy
        .parse()
        .unwrap_or_else(|_| panic!("--curve: bad energy {text}"));
    let cap = if cap.is_empty() {
        full_terms
    } else {
        cap.parse()
            .unwrap_or_else(|_| panic!("--curve: bad term cap {text}"))
    };
    (energy, cap)
}

fn curve(cli: &Cli) {
    let scene = &cli.scenes[0];
    let full_terms = 6 * cli.cube * cli.cube;
    let baked = |(t, time): (PixelTransport, Option<BakeTime>)| {
        let time = time.map_or("cached".to_string(), |b| {
            format!("{:.0} s ({:.0} s CPU)", b.wall, b.cpu)
        });
        (t, time)
    };
    let (full, full_time) = baked(timed_transport(
        scene,
        options(cli, cli.size, 1.0, full_terms),
    ));
    let mut table = Table::new(&[
        "energy kept",
        "max terms",
        "entries per hit pixel",
        "transport bytes",
        "mean rel. image RMSE vs the untruncated transport",
        "bake wall (CPU)",
    ]);
    let latlong = load_envmap(&cli.maps[0]).unwrap_or_else(|e| panic!("{e}"));
    let rotation = Rotation::new(latlong, cli.cube, 5f32.to_radians(), 100).unwrap();
    let frames: Vec<(Vec<f32>, Vec<f32>)> = (0..8)
        .map(|f| {
            let texels = rotation.frame(f * 9).unwrap().into_data();
            let mut c = texels.clone();
            CubemapHaar::new(cli.cube).unwrap().forward(&mut c).unwrap();
            (c, texels)
        })
        .collect();
    let images = |t: &PixelTransport| -> Vec<Vec<[f32; 3]>> {
        frames
            .iter()
            .map(|(c, texels)| {
                let mut e = MethodRelighter::new(t, RelightMethod::Exact).unwrap();
                e.frame(c, texels).unwrap().image
            })
            .collect()
    };
    let per_hit_pixel =
        |t: &PixelTransport| t.nnz() as f64 / t.hit.iter().filter(|h| **h).count().max(1) as f64;
    let reference = images(&full);
    table.row(vec![
        "1 (all)".into(),
        format!("{full_terms}"),
        format!("{:.0}", per_hit_pixel(&full)),
        format!("{:.1} MB", full.entry_bytes() as f64 / 1e6),
        "reference".into(),
        full_time,
    ]);
    drop(full);
    let mut points: Vec<(String, f64, f64)> = Vec::new();
    for text in &cli.curve {
        let (energy, cap) = curve_point(text, full_terms);
        let (t, time) = baked(timed_transport(scene, options(cli, cli.size, energy, cap)));
        let err: f64 = images(&t)
            .iter()
            .zip(&reference)
            .map(|(a, b)| relative_rms(a.as_flattened(), b.as_flattened()))
            .sum::<f64>()
            / frames.len() as f64;
        table.row(vec![
            format!("{energy}"),
            format!("{cap}"),
            format!("{:.1}", per_hit_pixel(&t)),
            format!("{:.2} MB", t.entry_bytes() as f64 / 1e6),
            format!("{err:.2e}"),
            time,
        ]);
        let series = if cap == full_terms {
            "no cap".to_string()
        } else {
            format!("at most {cap} terms")
        };
        points.push((series, t.entry_bytes() as f64, err));
    }
    let bounce = if cli.bounce > 0 {
        format!(", one bounce ({} gathers)", cli.bounce)
    } else {
        ", direct light".to_string()
    };
    println!(
        "Transport size against image error, {scene} {}²{bounce}, {}² faces, map {} at 8 angles\n",
        cli.size, cli.cube, cli.maps[0]
    );
    println!("{}", table.markdown());
    if let Some(path) = &cli.plot {
        plot_curve(&points, &format!("{scene}, {}²{bounce}", cli.size), path);
    }
}

/// Image error against transport bytes, log-log, one line per term cap.
fn plot_curve(points: &[(String, f64, f64)], title: &str, path: &std::path::Path) {
    let points: Vec<prt_benches::PlotPoint> = points
        .iter()
        .map(|(series, bytes, error)| (series.clone(), bytes.log10(), *error))
        .collect();
    let labels = prt_benches::PlotLabels {
        title,
        x: "transport bytes (log scale)",
        y: "relative image RMSE",
        x_ticks: &|v| format!("{:.1e}", 10f64.powf(v)),
    };
    prt_benches::plot_lines(&points, &labels, path).expect("plot");
    eprintln!("wrote {}", path.display());
}

fn main() {
    let cli = Cli::parse();
    if !cli.speed.is_empty() {
        speed(&cli);
    } else if !cli.curve.is_empty() {
        curve(&cli);
    } else {
        compare(&cli);
    }
}

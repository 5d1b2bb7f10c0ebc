//! BRDF editing on an image (Ben-Artzi, Overbeck and Ramamoorthi 2006; Overbeck's thesis §3.2
//! and §4): per-pixel transport against a 256-bin half-angle curve under a fixed view and a
//! fixed environment map, projected onto Daubechies-4 and sparsified; a scripted edit sequence
//! is shown with the exact curve, BI and NWA at a fixed number of terms per frame, and the
//! image error per frame against the exact image of the edited curve tells whether "BI at 30
//! terms per frame is exact within 9 frames" holds on images.
//!
//! `cargo run --release -p prt-benches --bin wavelet_brdf_image -- --help`

use std::path::PathBuf;
use std::time::Instant;

use glam::Vec3;
use prt_benches::{Table, load_envmap, load_scene, save_png};
use prt_core::NoProgress;
use prt_render::{Rendered, ToneMap, luminance, views};
use prt_trace::RayTracer;
use prt_trace::camera::{GBuffer, PinholeView};
use prt_trace::relight::{
    CubeRays, HalfAngleOptions, HalfAngleTransport, trace_half_angle_transport,
};
use prt_wavelet::brdf::{
    CurveEditor, CurveRelighter, CurveTransport, beckmann_curve, brush_stroke,
};
use prt_wavelet::{Cubemap, Daubechies4, Policy};

const BINS: usize = 256;
/// Specular weight folded into every curve (the edited curve is `KS · D(θ_h)` plus strokes).
const KS: f32 = 0.3;
/// A frame is converged when its image is this close (relative L2) to the exact image.
const EXACT: f64 = 1e-6;
/// Gain of the error panels of the example strips.
const DIFF_GAIN: f32 = 30.0;

#[derive(Debug, clap::Parser)]
#[command(
    about = "BRDF editing on an image: per-frame image error of BI and NWA against the exact edit"
)]
struct Cli {
    /// Scenes: cornell (built in) and/or sponza (../shared/scenes/sponza, its `inside` view).
    #[arg(long, value_delimiter = ',', default_value = "cornell,sponza")]
    scenes: Vec<String>,
    /// Environment map in ../shared/envmaps (file stem).
    #[arg(long, default_value = "probulator_grace")]
    envmap: String,
    /// Image side in pixels.
    #[arg(long, default_value_t = 128)]
    size: usize,
    /// Cube-map face side of the lighting (texels).
    #[arg(long, default_value_t = 32)]
    cube: usize,
    /// Shadow rays per cube texel along each edge (samples² per texel).
    #[arg(long, default_value_t = 2)]
    samples: usize,
    /// Daubechies-4 coefficients kept per pixel (a list: the edit script runs once per value).
    #[arg(long, value_delimiter = ',', default_value = "64,256")]
    keep: Vec<usize>,
    /// Frames held after each edit.
    #[arg(long, default_value_t = 12)]
    hold: usize,
    /// Print the per-frame table of every frame.
    #[arg(long)]
    frames: bool,
    /// Folder for the example strips, one PNG per scene at the first kept count: before | after
    /// (exact) | BI-30 and NWA-30 on the first frame after the roughness jump, each with its
    /// error against the exact image (× 30).
    #[arg(long)]
    png: Option<PathBuf>,
}

/// One frame of the script: the curve shown and what happened.
struct Frame {
    curve: Vec<f32>,
    event: String,
    /// Index of the edit this frame belongs to; `held` = frames since that edit's last frame.
    edit: usize,
    held: usize,
}

fn curve(roughness: f32) -> Vec<f32> {
    let mut c = beckmann_curve(roughness, BINS).expect("valid roughness");
    c.iter_mut().for_each(|v| *v *= KS);
    c
}

/// Three edits, each followed by `hold` frames: a roughness slider dragged from 0.3 to 0.1 over
/// 8 frames, three brush strokes raising a haze around θ_h = 20°, a roughness jump to 0.5.
fn script(hold: usize) -> (Vec<f32>, Vec<Frame>, Vec<&'static str>) {
    let start = curve(0.3);
    let mut frames = Vec::new();
    let names = vec![
        "roughness 0.3 -> 0.1, dragged over 8 frames",
        "3 brush strokes around θ_h = 20° (one per frame)",
        "roughness jump to 0.5 (one frame)",
    ];
    let push_hold = |frames: &mut Vec<Frame>, c: &[f32], edit: usize| {
        for h in 1..=hold {
            frames.push(Frame {
                curve: c.to_vec(),
                event: String::new(),
                edit,
                held: h,
            });
        }
    };
    for f in 1..=8 {
        frames.push(Frame {
            curve: curve(0.3 - 0.2 * f as f32 / 8.0),
            event: format!("drag {f}/8"),
            edit: 0,
            held: 0,
        });
    }
    let mut c = curve(0.1);
    push_hold(&mut frames, &c, 0);
    for (k, centre) in [48.0f32, 57.0, 66.0].into_iter().enumerate() {
        brush_stroke(&mut c, centre, 14.0, 0.4 * KS);
        frames.push(Frame {
            curve: c.clone(),
            event: format!("stroke {}/3", k + 1),
            edit: 1,
            held: 0,
        });
    }
    push_hold(&mut frames, &c, 1);
    let c = curve(0.5);
    frames.push(Frame {
        curve: c.clone(),
        event: "jump".into(),
        edit: 2,
        held: 0,
    });
    push_hold(&mut frames, &c, 2);
    (start, frames, names)
}

fn d4(curve: &[f32]) -> Vec<f32> {
    let mut c = curve.to_vec();
    Daubechies4::new(BINS)
        .expect("power of two")
        .forward(&mut c)
        .expect("length");
    c
}

/// Relative L2 distance of `a` from `b`.
fn relative(a: &[f32], b: &[f32]) -> f64 {
    let (num, den) = a.iter().zip(b).fold((0.0, 0.0), |(n, d), (&x, &y)| {
        (n + (x as f64 - y as f64).powi(2), d + (y as f64).powi(2))
    });
    (num / den.max(1e-300)).sqrt()
}

fn add(a: &[f32], b: &[f32]) -> Vec<f32> {
    a.iter().zip(b).map(|(x, y)| x + y).collect()
}

/// A method under test: an editor and its image engine.
struct Method {
    name: String,
    editor: CurveEditor,
    engine: CurveRelighter,
}

impl Method {
    fn new(
        name: &str,
        terms: usize,
        policy: Policy,
        transport: &CurveTransport,
        start: &[f32],
    ) -> Self {
        let mut m = Self {
            name: name.into(),
            editor: CurveEditor::with_policy(BINS, terms, policy).expect("editor"),
            engine: CurveRelighter::new(transport.clone()),
        };
        // Settled on the starting curve before the script begins.
        for _ in 0..=BINS.div_ceil(terms) {
            m.step(start);
        }
        m
    }

    /// One frame; returns the wall time of the editor step plus the image update (µs) and
    /// the transport entries read.
    fn step(&mut self, target: &[f32]) -> (f64, usize) {
        let t = Instant::now();
        self.editor.step(target).expect("finite curve");
        let read = self
            .engine
            .apply(self.editor.update())
            .expect("update fits");
        (t.elapsed().as_secs_f64() * 1e6, read)
    }
}

/// A linear RGB image (pixel-major floats) as a [`Rendered`] for tone mapping.
fn rendered(image: &[f32], size: usize, hit: &[bool]) -> Rendered {
    Rendered {
        width: size,
        height: size,
        pixels: image.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect(),
        hit: hit.to_vec(),
        unlit: 0,
    }
}

fn main() {
    let cli = <Cli as clap::Parser>::parse();
    let map = load_envmap(&cli.envmap).unwrap_or_else(|e| panic!("{e}"));
    let samples = Cubemap::default_samples(map.width(), cli.cube);
    let lighting = Cubemap::from_lat_long(&map, cli.cube, 0.0, samples)
        .expect("valid cube size")
        .into_data();
    let rays = CubeRays::new(cli.cube, cli.samples).expect("valid cube rays");
    let (start, frames, edit_names) = script(cli.hold);
    println!(
        "# BRDF editing on an image: {}² pixels, {} under {} on a 6×{}² cube ({}² rays per texel), \
         {BINS} bins, Daubechies-4, {} coefficients kept per pixel, curve = {KS} × Beckmann\n",
        cli.size,
        cli.scenes.join(" and "),
        cli.envmap,
        cli.cube,
        cli.samples,
        cli.keep
            .iter()
            .map(usize::to_string)
            .collect::<Vec<_>>()
            .join(" and ")
    );
    for name in &cli.scenes {
        let scene = match load_scene(name) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("skipping {name}: {e}");
                continue;
            }
        };
        let tracer = RayTracer::new(scene.triangles());
        let bounds = scene.bounds().expect("non-empty scene");
        // The Cornell box through its open side (prt render's `front`); Sponza down its atrium,
        // whose open roof is the only way the distant light gets in (prt render's `inside` view
        // looks down a covered gallery, which no sky light reaches).
        let view = if name == "sponza" {
            let eye = Vec3::new(12.0, 8.0, -0.5);
            let forward = (Vec3::new(-10.0, 4.0, -0.5) - eye).normalize();
            let right = forward.cross(Vec3::Y).normalize();
            PinholeView {
                position: eye,
                forward,
                up: right.cross(forward),
                yfov: 60f32.to_radians(),
            }
        } else {
            views(&scene)
                .into_iter()
                .find(|v| v.name == "front")
                .expect("automatic views of a non-empty scene")
                .view
        };
        let gbuffer = GBuffer::render(&scene, &tracer, &view, cli.size, cli.size).expect("size");
        let options = HalfAngleOptions {
            bins: BINS,
            offset: 1e-4 * bounds.size().length(),
        };
        // Estimate from every 64th pixel before tracing them all.
        let pilot = GBuffer {
            width: gbuffer.points.len().div_ceil(64),
            height: 1,
            points: gbuffer.points.iter().step_by(64).copied().collect(),
        };
        let t = Instant::now();
        trace_half_angle_transport(
            &tracer,
            &pilot,
            view.position,
            &rays,
            &lighting,
            &options,
            &NoProgress,
        )
        .expect("pilot");
        let estimate =
            t.elapsed().as_secs_f64() * gbuffer.points.len() as f64 / pilot.points.len() as f64;
        println!(
            "## {name}\n\ntrace estimate {estimate:.0} s ({:.0} M shadow rays at most), dense transport {:.1} MB",
            (gbuffer.points.len() * rays.texels() * cli.samples * cli.samples) as f64 * 1e-6,
            HalfAngleTransport::bytes(gbuffer.points.len(), BINS) as f64 * 1e-6
        );
        let t = Instant::now();
        let traced = trace_half_angle_transport(
            &tracer,
            &gbuffer,
            view.position,
            &rays,
            &lighting,
            &options,
            &NoProgress,
        )
        .expect("trace");
        let lit = traced
            .diffuse
            .chunks_exact(3)
            .filter(|d| d.iter().any(|&v| v > 0.0))
            .count();
        println!(
            "traced in {:.1} s; {lit} of {} pixels receive light\n",
            t.elapsed().as_secs_f64(),
            traced.pixels
        );

        sparsification_table(&traced, &start, &frames.last().expect("frames").curve);

        for (k, &keep) in cli.keep.iter().enumerate() {
            let t = Instant::now();
            let transport = CurveTransport::new(&traced.glossy, BINS, keep).expect("transport");
            let project = t.elapsed().as_secs_f64();
            println!(
                "### {keep} coefficients kept per pixel\n\nDaubechies-4 projection and sparsification: {project:.2} s, {} entries, {:.1} MB\n",
                transport.nnz(),
                transport.bytes() as f64 * 1e-6
            );
            let mut methods = vec![
                Method::new("exact", BINS, Policy::Incremental, &transport, &start),
                Method::new("BI-30", 30, Policy::Incremental, &transport, &start),
                Method::new("NWA-30", 30, Policy::NonIncremental, &transport, &start),
                Method::new("NWA-60", 60, Policy::NonIncremental, &transport, &start),
                Method::new("BI-10", 10, Policy::Incremental, &transport, &start),
            ];
            let before = add(
                &traced.diffuse,
                &transport.image(&d4(&start)).expect("image"),
            );
            let mut errors = vec![vec![0.0f64; frames.len()]; methods.len()];
            let mut times = vec![vec![0.0f64; frames.len()]; methods.len()];
            let mut reads = vec![vec![0usize; frames.len()]; methods.len()];
            let mut residual_at_stop = vec![0usize; edit_names.len()];
            let mut strip: Vec<Vec<f32>> = vec![before];
            for (f, frame) in frames.iter().enumerate() {
                let target = d4(&frame.curve);
                let exact = add(&traced.diffuse, &transport.image(&target).expect("image"));
                if frame.held == 1 {
                    // The BI-30 residual when this edit's last frame was shown.
                    residual_at_stop[frame.edit] = methods[1]
                        .editor
                        .coefficients()
                        .iter()
                        .zip(&target)
                        .filter(|(a, b)| a != b)
                        .count();
                }
                for (m, method) in methods.iter_mut().enumerate() {
                    let (us, read) = method.step(&frame.curve);
                    let shown = add(&traced.diffuse, &method.engine.image());
                    errors[m][f] = relative(&shown, &exact);
                    times[m][f] = us;
                    reads[m][f] = read;
                    if frame.edit == 2 && frame.held == 1 && (m == 1 || m == 2) {
                        let error = shown
                            .iter()
                            .zip(&exact)
                            .map(|(a, b)| DIFF_GAIN * (a - b).abs());
                        strip.push(shown.clone());
                        strip.push(error.collect());
                    }
                }
                if frame.edit == 2 && frame.held == 1 {
                    strip.insert(1, exact);
                }
            }
            if cli.frames {
                per_frame_table(&frames, &methods, &errors, &times);
            }
            convergence_table(&frames, &methods, &errors, &edit_names, &residual_at_stop);
            cost_table(&methods, &times, &reads, &transport);
            if let (Some(folder), 0) = (&cli.png, k) {
                std::fs::create_dir_all(folder).expect("png folder");
                let hit: Vec<bool> = gbuffer.points.iter().map(Option::is_some).collect();
                // The key of `prt render`, but no brighter than the 99th luminance percentile at
                // 0.8: Sponza's sunlit atrium floor would otherwise saturate its highlight.
                let after = rendered(&strip[1], cli.size, &hit);
                let mut lum: Vec<f32> = after.pixels.iter().map(|&p| luminance(p)).collect();
                lum.sort_by(f32::total_cmp);
                let p99 = lum[lum.len() * 99 / 100].max(1e-6);
                let tone = ToneMap {
                    exposure: ToneMap::auto(&after).exposure.min(0.8 / p99),
                };
                let (w, h) = (cli.size, cli.size);
                let mut pixels = vec![0u8; strip.len() * w * h * 3];
                for (k, img) in strip.iter().enumerate() {
                    let srgb = tone.apply(&rendered(img, cli.size, &hit));
                    for y in 0..h {
                        let dst = (y * strip.len() * w + k * w) * 3;
                        pixels[dst..dst + 3 * w].copy_from_slice(&srgb[y * w * 3..(y + 1) * w * 3]);
                    }
                }
                let image = image::RgbImage::from_raw((strip.len() * w) as u32, h as u32, pixels)
                    .expect("buffer size");
                let path = folder.join(format!("brdf_edit_{name}.png"));
                save_png(&image, &path).unwrap_or_else(|e| panic!("{e}"));
                println!(
                    "wrote {} (before | after, exact | BI-30, first frame after the jump | its error × {DIFF_GAIN} | NWA-30 | its error × {DIFF_GAIN})\n",
                    path.display()
                );
            }
        }
    }
}

/// Image error of the sparsified transport against the dense one, per kept count.
fn sparsification_table(traced: &HalfAngleTransport, start: &[f32], edited: &[f32]) {
    let dense_start = traced.image(start).expect("image");
    let dense_edited = traced.image(edited).expect("image");
    let row_norms: Vec<f64> = traced
        .glossy
        .chunks_exact(BINS)
        .map(|r| r.iter().map(|&t| (t as f64).powi(2)).sum::<f64>().sqrt())
        .collect();
    let mut table = Table::new(&[
        "kept per pixel",
        "entries",
        "MB",
        "rel. error, start curve",
        "rel. error, last curve",
        "max error / Parseval bound (where above round-off)",
    ]);
    for keep in [8usize, 16, 32, 64, 128, BINS] {
        let transport = CurveTransport::new(&traced.glossy, BINS, keep).expect("transport");
        let mut worst = 0.0f64;
        let mut errs = Vec::new();
        for (curve, dense) in [(start, &dense_start), (edited, &dense_edited)] {
            let norm = curve
                .iter()
                .map(|&f| (f as f64).powi(2))
                .sum::<f64>()
                .sqrt();
            let sparse = add(
                &traced.diffuse,
                &transport.image(&d4(curve)).expect("image"),
            );
            for (i, (s, d)) in sparse.iter().zip(dense.iter()).enumerate() {
                let bound = (transport.dropped_energy()[i / 3][i % 3] as f64).sqrt() * norm;
                // Where the bound is below the f32 round-off of the transforms it says nothing.
                if bound > 1e-5 * row_norms[i] * norm {
                    worst = worst.max((*s as f64 - *d as f64).abs() / bound);
                }
            }
            errs.push(relative(&sparse, dense));
        }
        table.row(vec![
            keep.to_string(),
            transport.nnz().to_string(),
            format!("{:.1}", transport.bytes() as f64 * 1e-6),
            format!("{:.2e}", errs[0]),
            format!("{:.2e}", errs[1]),
            format!("{worst:.3}"),
        ]);
    }
    println!(
        "### Sparsification (relative L2 image error against the dense transport; diffuse + glossy)\n\n{}",
        table.markdown()
    );
}

fn per_frame_table(frames: &[Frame], methods: &[Method], errors: &[Vec<f64>], times: &[Vec<f64>]) {
    let mut header = vec!["frame".to_string(), "event".to_string()];
    header.extend(methods.iter().map(|m| format!("{} rel. error", m.name)));
    header.extend(methods.iter().map(|m| format!("{} µs", m.name)));
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    let mut table = Table::new(&header);
    for (f, frame) in frames.iter().enumerate() {
        let event = if frame.held > 0 {
            format!("hold {}", frame.held)
        } else {
            frame.event.clone()
        };
        let mut row = vec![(f + 1).to_string(), event];
        row.extend(errors.iter().map(|e| format!("{:.2e}", e[f])));
        row.extend(times.iter().map(|t| format!("{:.0}", t[f])));
        table.row(row);
    }
    println!(
        "### Per frame (image error relative to the exact image of the edited curve)\n\n{}",
        table.markdown()
    );
}

fn convergence_table(
    frames: &[Frame],
    methods: &[Method],
    errors: &[Vec<f64>],
    names: &[&str],
    residual: &[usize],
) {
    let mut table = Table::new(&[
        "edit",
        "BI-30 residual non-zeros at the stop",
        "⌈nnz / 30⌉",
        "method",
        "frames to exact (rel. ≤ 1e-6)",
        "frames to rel. ≤ 1e-3",
        "error, held frames 1 / 3 / 6 / 9",
    ]);
    for (e, name) in names.iter().enumerate() {
        let held: Vec<usize> = (0..frames.len())
            .filter(|&f| frames[f].edit == e && frames[f].held > 0)
            .collect();
        for (m, method) in methods.iter().enumerate() {
            if m == 0 {
                continue;
            }
            let first = |tol: f64| {
                held.iter()
                    .position(|&f| errors[m][f] <= tol)
                    .map_or(format!("> {}", held.len()), |p| (p + 1).to_string())
            };
            let at = |h: usize| {
                held.get(h - 1)
                    .map_or("-".into(), |&f| format!("{:.1e}", errors[m][f]))
            };
            table.row(vec![
                name.to_string(),
                residual[e].to_string(),
                residual[e].div_ceil(30).to_string(),
                method.name.clone(),
                first(EXACT),
                first(1e-3),
                format!("{} / {} / {} / {}", at(1), at(3), at(6), at(9)),
            ]);
        }
    }
    println!(
        "### Convergence after each edit stops (held frames counted from the first frame after the edit's last)\n\n{}",
        table.markdown()
    );
}

fn cost_table(
    methods: &[Method],
    times: &[Vec<f64>],
    reads: &[Vec<usize>],
    transport: &CurveTransport,
) {
    let mut table = Table::new(&[
        "method",
        "median frame µs",
        "max frame µs",
        "mean entries read",
        "full image entries",
    ]);
    for (m, method) in methods.iter().enumerate() {
        let mut t = times[m].clone();
        t.sort_by(f64::total_cmp);
        let mean = reads[m].iter().sum::<usize>() as f64 / reads[m].len() as f64;
        table.row(vec![
            method.name.clone(),
            format!("{:.0}", t[t.len() / 2]),
            format!("{:.0}", t[t.len() - 1]),
            format!("{mean:.0}"),
            transport.nnz().to_string(),
        ]);
    }
    println!(
        "### Cost per frame (editor step + image update, wall clock on a shared machine)\n\n{}",
        table.markdown()
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use prt_trace::Scene;

    /// The traced chain at a tiny size: the Daubechies-4 exact path is the direct sum over bins,
    /// and BI-30 shows the exact image within `⌈nnz / 30⌉` frames of the last edit.
    #[test]
    fn traced_cornell_box_follows_the_laws() {
        let scene = Scene::cornell_box();
        let tracer = RayTracer::new(scene.triangles());
        let view = PinholeView::for_scene(&scene).unwrap();
        let gbuffer = GBuffer::render(&scene, &tracer, &view, 8, 8).unwrap();
        let rays = CubeRays::new(4, 1).unwrap();
        let lighting: Vec<f32> = (0..3 * rays.texels())
            .map(|i| 0.2 + (i % 7) as f32)
            .collect();
        let options = HalfAngleOptions {
            bins: BINS,
            offset: 1e-3,
        };
        let traced = trace_half_angle_transport(
            &tracer,
            &gbuffer,
            view.position,
            &rays,
            &lighting,
            &options,
            &NoProgress,
        )
        .unwrap();
        let transport = CurveTransport::new(&traced.glossy, BINS, BINS).unwrap();
        let start = curve(0.3);
        let mut edited = curve(0.1);
        brush_stroke(&mut edited, 40.0, 10.0, 0.5);
        for f in [&start, &edited] {
            let direct = traced.image(f).unwrap();
            let wavelet = add(&traced.diffuse, &transport.image(&d4(f)).unwrap());
            assert!(
                relative(&wavelet, &direct) < 1e-6,
                "{}",
                relative(&wavelet, &direct)
            );
        }
        let mut bi = Method::new("BI-30", 30, Policy::Incremental, &transport, &start);
        bi.step(&edited);
        let target = d4(&edited);
        let nonzeros = bi
            .editor
            .coefficients()
            .iter()
            .zip(&target)
            .filter(|(a, b)| a != b)
            .count();
        for _ in 0..nonzeros.div_ceil(30) {
            bi.step(&edited);
        }
        let exact = transport.image(&target).unwrap();
        assert!(relative(&bi.engine.image(), &exact) < 1e-6);
    }
}

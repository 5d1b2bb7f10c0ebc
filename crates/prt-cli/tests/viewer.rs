//! The viewer in a real headless browser: `prt view` serves a small Cornell bake, Debian's
//! chromium (WebGL2 on SwiftShader) screenshots fixed frames of it, and `prt render` renders the
//! same frames on the CPU. They must agree (PSNR within about 6 dB of what is measured, i.e. at
//! most about four times the measured squared error, on the 8-bit images), and turning the sky
//! must move the browser's image the way it moves the CPU's. A bake whose grid is 10 voxels
//! wide (rows of one-byte texels not a multiple of 4 bytes) must draw too, and a load error
//! must show on the page. A lightmap folder (`prt lightmap --out`) shows the lightmapped box,
//! and the page picks up a new lightmap when the bake writes one.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

mod common;
use common::{chromium, run, scratch};

/// Image side in pixels.
const SIZE: u32 = 256;

fn prt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_prt"))
}

/// A small Cornell bake (the default 32³ one takes minutes in a debug build) with `res` voxels
/// along each axis, its volumes kept.
fn bake_cornell(res: u32, out: &Path) {
    run(prt()
        .args(["bake", "--res", &res.to_string(), "--rays", "96"])
        .args(["--cache-rays", "32", "--rank", "4", "--basis-nodes", "3"])
        .args(["--iterations", "24", "--keep-volumes", "always", "--out"])
        .arg(out));
}

/// `prt view` on a free port, stopped when dropped.
struct Server {
    child: Child,
    url: String,
}

impl Server {
    fn start(bake: &Path, envmap: &Path) -> Server {
        Self::start_with_lines(bake, &[envmap]).0
    }

    /// The server, with `--envmap` for each of `envmaps`, and the lines it prints after its URL.
    fn start_with_lines(bake: &Path, envmaps: &[&Path]) -> (Server, mpsc::Receiver<String>) {
        let mut command = prt();
        command.args(["view", bake.to_str().expect("utf-8"), "--port", "0"]);
        for envmap in envmaps {
            command.arg("--envmap").arg(envmap);
        }
        let mut child = command
            .stdout(Stdio::piped())
            .spawn()
            .expect("prt view starts");
        let mut stdout = BufReader::new(child.stdout.take().expect("stdout"));
        let mut line = String::new();
        stdout
            .read_line(&mut line)
            .expect("prt view prints its URL");
        let url = line
            .split_whitespace()
            .find(|w| w.starts_with("http://127.0.0.1:"))
            .unwrap_or_else(|| panic!("no URL in {line:?}"))
            .to_string();
        let (send, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in stdout.lines().map_while(Result::ok) {
                if send.send(line).is_err() {
                    break;
                }
            }
        });
        (Server { child, url }, lines)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Headless chromium with WebGL2 on SwiftShader, a fresh profile, no GPU.
fn browser(profile: &Path, size: u32) -> Command {
    let mut c = Command::new(chromium());
    c.args([
        "--headless",
        "--no-sandbox",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--hide-scrollbars",
        "--force-device-scale-factor=1",
        "--virtual-time-budget=600000",
        &format!("--window-size={size},{size}"),
    ])
    .arg(format!("--user-data-dir={}", profile.display()))
    // Chromium's own temporary folders go into the test's scratch folder too.
    .env("TMPDIR", profile);
    std::fs::create_dir_all(profile).expect("browser profile");
    c
}

/// Screenshots the viewer at `query` (after checking, in the DOM, that the frame got drawn).
fn screenshot(server: &Server, query: &str, out: &Path) -> image::RgbImage {
    let url = format!("{}?{query}&size={SIZE}", server.url);
    let profile = out.with_extension("profile");
    let dom = run(browser(&profile, SIZE).arg("--dump-dom").arg(&url));
    assert!(
        dom.contains("<title>ready</title>"),
        "the page did not get ready for {url}:\n{}",
        dom.lines()
            .filter(|l| l.contains("id=\"error\"") || l.contains("<title>"))
            .collect::<Vec<_>>()
            .join("\n")
    );
    run(browser(&profile, SIZE)
        .arg(format!("--screenshot={}", out.display()))
        .arg(&url));
    image::open(out).expect("screenshot").to_rgb8()
}

/// `prt render` of the same frame.
fn render(bake: &Path, args: &[&str], out: &Path) -> image::RgbImage {
    run(prt()
        .args([
            "render",
            bake.to_str().expect("utf-8"),
            "--size",
            &SIZE.to_string(),
        ])
        .args(args)
        .arg("--out")
        .arg(out));
    image::open(out).expect("render").to_rgb8()
}

fn psnr(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let mse = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| (f64::from(x) - f64::from(y)).powi(2))
        .sum::<f64>()
        / a.as_raw().len() as f64;
    10.0 * (255.0f64.powi(2) / mse.max(1e-12)).log10()
}

/// Per-value differences `b - a`.
fn change(a: &image::RgbImage, b: &image::RgbImage) -> Vec<f64> {
    a.as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| f64::from(y) - f64::from(x))
        .collect()
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (ma, mb) = (mean(a), mean(b));
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        ab += (x - ma) * (y - mb);
        aa += (x - ma).powi(2);
        bb += (y - mb).powi(2);
    }
    ab / (aa * bb).sqrt().max(1e-12)
}

/// A copy of `bake` (scene mesh and MBD container) whose container has its coefficient volume
/// in the bricks layout.
fn write_in_bricks(bake: &Path, out: &Path) {
    std::fs::create_dir_all(out).expect("folder");
    std::fs::copy(bake.join("scene.mesh"), out.join("scene.mesh")).expect("copy the mesh");
    let dense =
        prt_bake::container::read_container(&bake.join("mbd"), &prt_texture::Limits::default())
            .expect("read the bake");
    let contents = prt_bake::container::ContainerContents {
        model: &dense.model,
        grid: dense.grid,
        valid: &dense.valid,
        scene: dense.attribute_str("scene").unwrap_or("cornell"),
        lambda: 1e-4,
        encoding: dense.encoding,
    };
    let config = prt_bake::container::LayoutConfig {
        layout: prt_bake::container::CoefficientLayout::Bricks,
        ..prt_bake::container::LayoutConfig::default()
    };
    let report = prt_bake::container::write_container_with(&out.join("mbd"), &contents, &config)
        .expect("write in bricks");
    assert!(report.manifest.arrays[0].bricks.is_some());
}

/// A lat-long sky that is not symmetric about +Y: a warm lobe low towards +X over a dim blue
/// dome, so that turning it about +Y lights the box anew through its open side.
fn write_lobe_sky(path: &Path) {
    let (w, h) = (64usize, 32usize);
    let mut data = Vec::with_capacity(3 * w * h);
    for row in 0..h {
        for col in 0..w {
            let theta = std::f32::consts::PI * (row as f32 + 0.5) / h as f32;
            let phi = 2.0 * std::f32::consts::PI * (col as f32 + 0.5) / w as f32;
            let d = [
                theta.sin() * phi.cos(),
                theta.cos(),
                theta.sin() * phi.sin(),
            ];
            let lobe = 6.0 * (d[0] * 0.8 + d[1] * 0.2).max(0.0).powi(4);
            data.extend_from_slice(&[0.2 + lobe, 0.25 + 0.7 * lobe, 0.35 + 0.3 * lobe]);
        }
    }
    let image = prt_texture::hdr::RgbImage {
        width: w as u32,
        height: h as u32,
        data,
    };
    std::fs::write(path, prt_texture::hdr::encode_hdr(&image).expect("encode")).expect("write");
}

#[test]
#[cfg_attr(
    prt_skip_chromium,
    ignore = "needs chromium, absent at build time (PRT_REQUIRE_CHROMIUM=1 requires it)"
)]
fn the_viewer_draws_what_prt_render_renders_and_lights_like_it() {
    let dir = scratch("cornell");
    let bake = dir.join("bake");
    bake_cornell(16, &bake);
    let sky = dir.join("lobe.hdr");
    write_lobe_sky(&sky);
    let sky_arg = sky.to_str().expect("utf-8");
    let server = Server::start(&bake, &sky);

    // (query, render flags, name, least PSNR): the default sky with MBD, the lobe sky with the
    // reference volume, and MBD under the lobe sky at two rotations. Measured (SwiftShader,
    // chromium 156): 47.1, 46.1, 46.4 and 50.9 dB; each bound is about 6 dB below (four times
    // the squared error).
    let cases: [(&str, Vec<&str>, &str, f64); 4] = [
        (
            "camera=0&rotate=0&method=mbd",
            vec!["--camera", "0", "--rotate", "0", "--method", "mbd"],
            "mbd",
            41.0,
        ),
        (
            "camera=0&rotate=0&method=reference&sky=1",
            vec![
                "--camera",
                "0",
                "--rotate",
                "0",
                "--method",
                "reference",
                "--sky",
                sky_arg,
            ],
            "reference-lobe",
            40.0,
        ),
        (
            "camera=0&rotate=0&method=mbd&sky=1&exposure=1",
            vec![
                "--camera",
                "0",
                "--rotate",
                "0",
                "--method",
                "mbd",
                "--sky",
                sky_arg,
                "--exposure",
                "1",
            ],
            "mbd-lobe-0",
            40.0,
        ),
        (
            "camera=0&rotate=120&method=mbd&sky=1&exposure=1",
            vec![
                "--camera",
                "0",
                "--rotate",
                "120",
                "--method",
                "mbd",
                "--sky",
                sky_arg,
                "--exposure",
                "1",
            ],
            "mbd-lobe-120",
            45.0,
        ),
    ];
    let mut pairs = Vec::new();
    for (query, flags, name, min_db) in &cases {
        let shot = screenshot(&server, query, &dir.join(format!("{name}-view.png")));
        let cpu = render(&bake, flags, &dir.join(format!("{name}-render.png")));
        let db = psnr(&shot, &cpu);
        eprintln!("{name}: PSNR {db:.2} dB between the viewer and prt render");
        assert!(
            db >= *min_db,
            "{name}: PSNR {db:.2} dB < {min_db} dB (images in {})",
            dir.display()
        );
        pairs.push((shot, cpu));
    }
    // The same bake with its coefficient volume in bricks (4 cells: 4 × 4 × 4 bricks on this
    // grid, so most pixels sit near a brick border): the viewer reads it through the
    // indirection and must draw what it drew from the dense volume.
    let bricked = dir.join("bake-bricks");
    write_in_bricks(&bake, &bricked);
    drop(server);
    let server = Server::start(&bricked, &sky);
    let (query, _, name, min_db) = &cases[0];
    let shot = screenshot(&server, query, &dir.join(format!("{name}-bricks-view.png")));
    let (dense_shot, cpu) = &pairs[0];
    let (db_cpu, db_dense) = (psnr(&shot, cpu), psnr(&shot, dense_shot));
    eprintln!(
        "{name} in bricks: PSNR {db_cpu:.2} dB against prt render, {db_dense:.2} dB against the dense volume's view"
    );
    // Measured 47.1 dB against prt render (as from the dense volume) and 92.0 dB against the
    // dense volume's view (a few values 1 apart).
    assert!(
        db_cpu >= *min_db,
        "bricks: PSNR {db_cpu:.2} dB < {min_db} dB"
    );
    assert!(
        db_dense >= 85.0,
        "bricks against dense: PSNR {db_dense:.2} dB < 85 dB"
    );

    // Turning the sky by 120° changes the image a lot, and the same way in both.
    let (view_0, cpu_0) = &pairs[2];
    let (view_120, cpu_120) = &pairs[3];
    let moved_view = change(view_0, view_120);
    let moved_cpu = change(cpu_0, cpu_120);
    let rms = (moved_cpu.iter().map(|d| d * d).sum::<f64>() / moved_cpu.len() as f64).sqrt();
    let r = correlation(&moved_view, &moved_cpu);
    eprintln!("turning the sky by 120°: RMS change {rms:.1} (8-bit), correlation {r:.4}");
    assert!(
        rms > 10.0,
        "turning the sky barely changed the CPU render (RMS {rms:.2})"
    );
    // Measured: RMS 49.0, correlation 0.9997 (1 − r about 3e-4).
    assert!(
        r > 0.999,
        "the viewer's change correlates {r:.4} with the CPU's"
    );
}

#[test]
#[cfg_attr(
    prt_skip_chromium,
    ignore = "needs chromium, absent at build time (PRT_REQUIRE_CHROMIUM=1 requires it)"
)]
fn a_grid_not_a_multiple_of_4_wide_draws_and_load_errors_show_on_the_page() {
    let dir = scratch("odd");
    let bake = dir.join("bake");
    // 10 voxels along x: the one-byte validity rows (10 bytes) are not a multiple of WebGL's
    // default 4-byte unpack alignment, which once left the canvas black.
    bake_cornell(10, &bake);
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(bake.join("mbd/manifest.json")).expect("manifest"))
            .expect("json");
    let validity = manifest["arrays"]
        .as_array()
        .and_then(|a| a.iter().find(|e| e["name"] == "validity"))
        .expect("a validity array");
    assert_eq!(validity["dims"][0], 10, "{validity}");
    assert_eq!(validity["single_channel"], true, "{validity}");
    let sky = dir.join("lobe.hdr");
    write_lobe_sky(&sky);
    let server = Server::start(&bake, &sky);
    let shot = screenshot(
        &server,
        "camera=0&rotate=0&method=mbd",
        &dir.join("view.png"),
    );
    let cpu = render(
        &bake,
        &["--camera", "0", "--rotate", "0", "--method", "mbd"],
        &dir.join("render.png"),
    );
    let mean =
        shot.as_raw().iter().map(|&v| f64::from(v)).sum::<f64>() / shot.as_raw().len() as f64;
    let db = psnr(&shot, &cpu);
    eprintln!(
        "10-voxel grid: mean {mean:.1} (8-bit), PSNR {db:.2} dB between the viewer and prt render"
    );
    assert!(
        mean > 40.0,
        "the viewer drew black (mean {mean:.1}; images in {})",
        dir.display()
    );
    // Measured: 46.4 dB (mean 136).
    assert!(
        db >= 40.0,
        "PSNR {db:.2} dB < 40 dB (images in {})",
        dir.display()
    );

    // A file that cannot be loaded: the page says so, in its error box and title.
    std::fs::remove_file(bake.join("mbd/validity.ktx2")).expect("remove");
    let url = format!("{}?camera=0&size={SIZE}", server.url);
    let dom = run(browser(&dir.join("error.profile"), SIZE)
        .arg("--dump-dom")
        .arg(&url));
    assert!(dom.contains("<title>error</title>"), "{dom}");
    assert!(
        dom.contains(
            "<div id=\"error\">prt view: cannot load bake/mbd/validity.ktx2: HTTP 404</div>"
        ),
        "{dom}"
    );
    drop(server);
}

/// Mean 8-bit RGB over the rows 30..70 % of the column band `from..from + 10 %` (as the lightmap
/// page measures its own frame).
fn band_mean(image: &image::RgbImage, from: f64) -> [f64; 3] {
    let (w, h) = (f64::from(image.width()), f64::from(image.height()));
    let mut sum = [0.0; 3];
    let mut n = 0.0;
    for y in (0.3 * h) as u32..(0.7 * h) as u32 {
        for x in (from * w) as u32..((from + 0.1) * w) as u32 {
            let p = image.get_pixel(x, y);
            for c in 0..3 {
                sum[c] += f64::from(p[c]);
            }
            n += 1.0;
        }
    }
    sum.map(|s| s / n)
}

#[test]
#[cfg_attr(
    prt_skip_chromium,
    ignore = "needs chromium, absent at build time (PRT_REQUIRE_CHROMIUM=1 requires it)"
)]
fn the_viewer_shows_a_lightmap_and_picks_up_a_new_one() {
    let dir = scratch("lightmap");
    let out = dir.join("lightmap");
    // The built-in Cornell box, small and quick.
    run(prt()
        .args(["lightmap", "--samples", "16", "--pass", "8"])
        .args(["--preview-every", "8", "--texels-per-metre", "6"])
        .args(["--view-size", "16", "--out"])
        .arg(&out));
    let (server, mut lines) = Server::start_with_lines(&out, &[]);
    let shot = screenshot(&server, "poll=50", &dir.join("lightmap-view.png"));
    let (left, right) = (band_mean(&shot, 0.03), band_mean(&shot, 0.87));
    eprintln!("lightmap view: left wall {left:.0?}, right wall {right:.0?} (8-bit RGB)");
    // The box is lit, its left wall red and its right wall green (measured: [106, 23, 16] and
    // [91, 142, 68]).
    let mean =
        shot.as_raw().iter().map(|&v| f64::from(v)).sum::<f64>() / shot.as_raw().len() as f64;
    assert!(
        mean > 30.0,
        "the page drew black (mean {mean:.1}; {})",
        dir.display()
    );
    assert!(
        left[0] > left[1] + 30.0 && left[0] > left[2] + 30.0,
        "the left wall is not red: {left:?}"
    );
    assert!(
        right[1] > right[0] + 30.0 && right[1] > right[2] + 30.0,
        "the right wall is not green: {right:?}"
    );

    // The page keeps polling until it shows a lightmap of 1000 samples per texel; once it shows
    // the bake's (16), a quarter as bright a one of "1000" samples replaces the file, as the
    // bake does (write, then rename).
    while lines.try_recv().is_ok() {}
    let url = format!("{}?size={SIZE}&poll=50&until=1000", server.url);
    let browser_run = browser(&dir.join("refresh.profile"), SIZE)
        .arg("--dump-dom")
        .arg(&url)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("chromium starts");
    let shown = |lines: &mut mpsc::Receiver<String>, samples: u32| loop {
        let line = lines
            .recv_timeout(Duration::from_secs(300))
            .expect("the page reports what it shows");
        if line == format!("lightmap: the page shows {samples} samples per texel") {
            break;
        }
    };
    shown(&mut lines, 16);
    let path = out.join("view_irradiance.bin");
    let mut bytes = std::fs::read(&path).expect("irradiance");
    bytes[16..20].copy_from_slice(&1000u32.to_le_bytes());
    for v in bytes[20..].chunks_exact_mut(4) {
        let e = f32::from_le_bytes(v.try_into().expect("4 bytes")) * 0.25;
        v.copy_from_slice(&e.to_le_bytes());
    }
    let partial = out.join("view_irradiance.bin.partial");
    std::fs::write(&partial, &bytes).expect("write");
    std::fs::rename(&partial, &path).expect("rename");
    shown(&mut lines, 1000);
    let dom = browser_run.wait_with_output().expect("chromium ends");
    let dom = String::from_utf8_lossy(&dom.stdout);
    assert!(dom.contains("<title>ready</title>"), "{dom}");
    let attribute = |name: &str| -> [f64; 3] {
        let key = format!("data-{name}=\"");
        let start = dom
            .find(&key)
            .unwrap_or_else(|| panic!("no {key} in {dom}"))
            + key.len();
        let values: Vec<f64> = dom[start..dom[start..].find('"').expect("end") + start]
            .split(',')
            .map(|v| v.parse().expect("a number"))
            .collect();
        [values[0], values[1], values[2]]
    };
    assert!(dom.contains("data-samples=\"1000\""), "{dom}");
    let (left_after, right_after) = (attribute("left"), attribute("right"));
    eprintln!("after the refresh: left wall {left_after:.0?}, right wall {right_after:.0?}");
    // The page's exposure stays that of the first lightmap, so a quarter of the light shows
    // darker. Measured: left wall red 106 -> 46, right wall green 142 -> 79.
    assert!(
        left_after[0] < 0.85 * left[0] && right_after[1] < 0.85 * right[1],
        "the page did not show the new lightmap: left {left:?} -> {left_after:?}, right {right:?} -> {right_after:?}"
    );
    drop(server);
}

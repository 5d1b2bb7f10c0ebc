//! prt's three.js export in three.js itself (issue 36): a small Cornell bake is exported with
//! `--target threejs` and `--target sh` under the same sky; the test serves examples/threejs
//! (its pinned `three`, the README's loader module `load-prt-probe-grid.js`, the pages in
//! `check/`) and the export over HTTP on 127.0.0.1, and headless Chromium renders with
//! three.js's own grids, `LightProbeGridWebGL` (WebGL 2 on SwiftShader) and `LightProbeGrid`
//! (WebGPU on SwiftShader's Vulkan), into float render targets (no tone mapping, no other
//! light):
//!
//! * white Lambert test surfaces at 104 known points and normals: inside the grid; on the bake
//!   box's faces with inward (the walls that rendered black), tilted and outward normals; at and
//!   near its corners; on its edges. Each must show `E/π`, `E` computed here from the SH export
//!   (`sh.exr`, f32, not padded) with this file's own code: trilinear between voxel centres at
//!   three.js's sample point `p + n ⊙ spacing/2` (clamped to the outermost voxel centres, which
//!   the padding repeats), then the L2 irradiance convolution (Ramamoorthi–Hanrahan), within
//!   the error of the atlas's f16 coefficients (`Σ_k |w_k(n)| |t_k| 2⁻¹⁰` in three.js's basis)
//!   plus a small floor;
//! * the baked scene from `prt render`'s camera, against `prt render --lookup threejs`'s linear
//!   EXR, and against `--lookup prt` (mean relative error over the pixels three.js drew).
//!
//! Measured (Debian chromium 156, SwiftShader; both renderers agree to 5e-7): test points within
//! 8.2e-5 of `E/π` (largest 0.52), at most 0.32 of the f16 bound; whole scene 4.3e-4 against
//! `--lookup threejs`, 0.0125 against `--lookup prt`. The test takes ~6 s (two pages ~2 s each).
//!
//! The lightmap test: `prt lightmap --engine threejs` bakes a small irradiance lightmap of the
//! Cornell box of ../shared; `check/lightmap.html` (WebGL 2) and `check/lightmap-webgpu.html`
//! (WebGPU) load it with the README's `load-prt-lightmap.js` (GLTFLoader, KTX2Loader, `lightMap`
//! on channel 1) and render it with no other light; each must show `prt lightmap`'s own
//! `view.exr` (mean and per-material relative errors below; both renderers measured alike) and
//! keep the red and green walls' colours. A lightmap loaded upside down (`flipY`) gives a mean
//! relative error of 0.38 and per-material medians up to 67 %. ~6 s.
//!
//! Ignored when chromium was absent at build time (`PRT_REQUIRE_CHROMIUM=1` makes it run and
//! fail instead); returns with a message when examples/threejs/node_modules is missing (run
//! `npm ci` there), which fails under `PRT_REQUIRE_CHROMIUM=1`. `PRT_THREEJS_SHOTS=DIR` saves
//! the tone-mapped whole-scene renders (three.js's WebGL 2 one and `prt render --lookup
//! threejs`, one exposure) as PNGs (docs/examples/engines/).
//!
//! WebGPU: Debian's headless Chromium offers `navigator.gpu` but no adapter by default; with
//! `--enable-unsafe-webgpu --enable-features=Vulkan --use-vulkan=swiftshader` it gets
//! SwiftShader's Vulkan adapter (a fallback adapter), which the WebGPU page uses.

use std::collections::HashMap;
use std::f64::consts::PI;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Component, Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

mod common;
use common::{chromium, run, scratch};

use serde_json::{Value, json};

/// The sky of both exports and of `prt render`.
const SKY: &str = "sun:40,120";
/// Side of the whole-scene render, pixels.
const SIZE: usize = 256;
/// `prt render --camera` (and the three.js camera): the Cornell box's `front` view.
const CAMERA: usize = 0;
/// Per stored atlas coefficient: relative error of f16 (round to nearest is 2⁻¹¹; 2⁻¹⁰ leaves
/// room for the GPU's filtering arithmetic).
const F16_RELATIVE: f64 = 1.0 / 1024.0;
/// Absolute floor of the per-point tolerance, as a fraction of the largest expected radiance
/// (for values near 0, and for a GPU that filters with fewer bits; SwiftShader stays within the
/// f16 bound alone: at most 0.32 of it, measured).
const FLOOR: f64 = 1e-4;
/// Largest mean relative error of the whole-scene render against `prt render --lookup threejs`
/// (measured: 4e-4, on SwiftShader in WebGL 2 and WebGPU alike).
const MAX_SCENE_ERROR: f64 = 2e-3;
/// Largest mean relative error of the whole-scene render against `prt render --lookup prt`
/// (prt's own lookup: no dilation or negative-light removal, interpolation over valid voxels
/// only), measured: 0.0125.
const MAX_LOOKUP_DIFFERENCE: f64 = 0.05;
/// How long a page may take.
const PAGE_TIMEOUT: Duration = Duration::from_secs(180);

fn prt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_prt"))
}

fn example_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/threejs")
}

fn json_file(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("read JSON")).expect("parse JSON")
}

fn vec3(v: &Value) -> [f64; 3] {
    std::array::from_fn(|k| v[k].as_f64().expect("number"))
}

// ---------------------------------------------------------------------------------------------
// A bounded HTTP server for the page: GET serves files under its roots, POST /result/NAME hands
// the body to the test.

struct Server {
    address: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    results: mpsc::Receiver<(String, Vec<u8>)>,
}

impl Server {
    /// Serves `roots` (URL prefix, folder; the longest matching prefix wins).
    fn start(roots: Vec<(&'static str, PathBuf)>) -> Server {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind 127.0.0.1");
        let address = listener.local_addr().expect("address");
        listener.set_nonblocking(true).expect("non-blocking");
        let stop = Arc::new(AtomicBool::new(false));
        let (send, results) = mpsc::channel();
        let roots = Arc::new(roots);
        let flag = Arc::clone(&stop);
        let thread = std::thread::spawn(move || {
            while !flag.load(Ordering::Relaxed) {
                match listener.accept() {
                    Ok((stream, _)) => {
                        let (roots, send) = (Arc::clone(&roots), send.clone());
                        std::thread::spawn(move || {
                            let _ = serve(stream, &roots, &send);
                        });
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                        std::thread::sleep(Duration::from_millis(5));
                    }
                    Err(_) => break,
                }
            }
        });
        Server {
            address,
            stop,
            thread: Some(thread),
            results,
        }
    }

    fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.address)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

fn content_type(path: &Path) -> &'static str {
    match path.extension().and_then(|e| e.to_str()) {
        Some("html") => "text/html; charset=utf-8",
        Some("js" | "mjs") => "text/javascript; charset=utf-8",
        Some("json") => "application/json",
        Some("wasm") => "application/wasm",
        Some("ktx2") => "image/ktx2",
        _ => "application/octet-stream",
    }
}

/// One request per connection (`Connection: close`).
fn serve(
    stream: TcpStream,
    roots: &[(&'static str, PathBuf)],
    results: &mpsc::Sender<(String, Vec<u8>)>,
) -> std::io::Result<()> {
    stream.set_nonblocking(false)?;
    stream.set_read_timeout(Some(Duration::from_secs(30)))?;
    let mut reader = BufReader::new(stream.try_clone()?);
    let mut line = String::new();
    reader.read_line(&mut line)?;
    let mut words = line.split_whitespace();
    let (method, target) = (
        words.next().unwrap_or("").to_string(),
        words.next().unwrap_or("/").to_string(),
    );
    let mut length = 0usize;
    loop {
        let mut header = String::new();
        if reader.read_line(&mut header)? == 0 || header.trim().is_empty() {
            break;
        }
        if let Some((name, value)) = header.split_once(':')
            && name.trim().eq_ignore_ascii_case("content-length")
        {
            length = value.trim().parse().unwrap_or(0);
        }
    }
    let mut body = vec![0u8; length];
    reader.read_exact(&mut body)?;
    let path = target.split(['?', '#']).next().unwrap_or("/");
    let mut stream = stream;
    let respond = |stream: &mut TcpStream, status: &str, kind: &str, body: &[u8]| {
        let head = format!(
            "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
            body.len()
        );
        stream.write_all(head.as_bytes())?;
        stream.write_all(body)?;
        stream.flush()
    };
    if method == "POST" {
        if let Some(name) = path.strip_prefix("/result/") {
            let _ = results.send((name.to_string(), body));
            return respond(&mut stream, "204 No Content", "text/plain", b"");
        }
        return respond(&mut stream, "404 Not Found", "text/plain", b"not found");
    }
    let file = roots
        .iter()
        .filter(|(prefix, _)| path.starts_with(prefix))
        .max_by_key(|(prefix, _)| prefix.len())
        .map(|(prefix, root)| root.join(&path[prefix.len()..]))
        .filter(|file| {
            Path::new(&path)
                .components()
                .all(|c| !matches!(c, Component::ParentDir))
                && file.is_file()
        });
    match file.and_then(|f| std::fs::read(&f).ok().map(|bytes| (f, bytes))) {
        Some((f, bytes)) => respond(&mut stream, "200 OK", content_type(&f), &bytes),
        None => respond(&mut stream, "404 Not Found", "text/plain", b"not found"),
    }
}

// ---------------------------------------------------------------------------------------------
// Headless Chromium, in its own process group so that the whole browser stops at the end.

struct Browser {
    child: Child,
}

impl Browser {
    fn open(url: &str, profile: &Path, webgpu: bool, log: &Path) -> Browser {
        let mut command = Command::new(chromium());
        command.args([
            "--headless",
            "--no-sandbox",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--no-first-run",
            "--window-size=64,64",
        ]);
        if webgpu {
            command.args([
                "--enable-unsafe-webgpu",
                "--enable-features=Vulkan",
                "--use-vulkan=swiftshader",
            ]);
        }
        let log = std::fs::File::create(log).expect("browser log");
        std::fs::create_dir_all(profile).expect("browser profile");
        command
            .arg(format!("--user-data-dir={}", profile.display()))
            // Chromium's own temporary folders go into the test's scratch folder too.
            .env("TMPDIR", profile)
            .arg(url)
            .stdin(Stdio::null())
            .stdout(log.try_clone().expect("log"))
            .stderr(log);
        #[cfg(unix)]
        std::os::unix::process::CommandExt::process_group(&mut command, 0);
        let child = command.spawn().expect("chromium starts");
        Browser { child }
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        // The browser and the processes it started (GPU, renderer, zygote) share its group.
        #[cfg(unix)]
        let _ = Command::new("kill")
            .args(["-KILL", "--", &format!("-{}", self.child.id())])
            .status();
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// What a page posted: `points` (none from lightmap.html) and `scene` as RGBA f32.
struct PageResult {
    points: Vec<[f64; 4]>,
    scene: Vec<[f64; 4]>,
    seconds: f64,
    /// The renderer, backend and device, as the page describes them.
    device: String,
}

fn rgba(bytes: &[u8]) -> Vec<[f64; 4]> {
    bytes
        .chunks_exact(16)
        .map(|t| {
            std::array::from_fn(|c| {
                f64::from(f32::from_le_bytes(t[4 * c..4 * c + 4].try_into().unwrap()))
            })
        })
        .collect()
}

fn run_page(server: &Server, page: &str, webgpu: bool, dir: &Path) -> PageResult {
    while server.results.try_recv().is_ok() {}
    let url = server.url(&format!("/check/{page}?case=/out/case.json"));
    let log = dir.join(format!("{page}.log"));
    let start = Instant::now();
    let browser = Browser::open(&url, &dir.join(format!("{page}.profile")), webgpu, &log);
    let mut got: HashMap<String, Vec<u8>> = HashMap::new();
    let outcome = loop {
        let left = PAGE_TIMEOUT.saturating_sub(start.elapsed());
        match server.results.recv_timeout(left) {
            Ok((name, body)) if name == "done" || name == "error" => break Some((name, body)),
            Ok((name, body)) => {
                got.insert(name, body);
            }
            Err(_) => break None,
        }
    };
    drop(browser);
    let seconds = start.elapsed().as_secs_f64();
    let browser_log = || {
        std::fs::read_to_string(&log)
            .unwrap_or_default()
            .lines()
            .filter(|l| !l.contains("dbus") && !l.contains("Fontconfig"))
            .take(40)
            .collect::<Vec<_>>()
            .join("\n")
    };
    let device = match outcome {
        Some((name, body)) if name == "done" => String::from_utf8_lossy(&body).into_owned(),
        Some((_, message)) => panic!(
            "{page} failed in the browser: {}\nbrowser log:\n{}",
            String::from_utf8_lossy(&message),
            browser_log()
        ),
        None => panic!(
            "{page} posted no result in {PAGE_TIMEOUT:?} ({url})\nbrowser log:\n{}",
            browser_log()
        ),
    };
    PageResult {
        points: got.get("points").map(|b| rgba(b)).unwrap_or_default(),
        scene: rgba(&got["scene"]),
        seconds,
        device,
    }
}

// ---------------------------------------------------------------------------------------------
// The expected value, from the SH export (prt's basis, incident radiance, f32 EXR).

/// prt's real SH of order 3 at unit `n` (the polynomials `sh.json` lists).
fn prt_sh(n: [f64; 3]) -> [f64; 9] {
    let [x, y, z] = n;
    [
        0.282_094_791_773_878_1,
        -0.488_602_511_902_919_9 * x,
        0.488_602_511_902_919_9 * y,
        -0.488_602_511_902_919_9 * z,
        1.092_548_430_592_079_2 * x * z,
        -1.092_548_430_592_079_2 * x * y,
        0.315_391_565_252_520_05 * (3.0 * y * y - 1.0),
        -1.092_548_430_592_079_2 * y * z,
        0.546_274_215_296_039_6 * (z * z - x * x),
    ]
}

/// Clamped-cosine convolution per band (Ramamoorthi & Hanrahan): π, 2π/3, π/4.
fn band_factor(j: usize) -> f64 {
    match j {
        0 => PI,
        1..=3 => 2.0 * PI / 3.0,
        _ => PI / 4.0,
    }
}

/// Weights three.js's shader gives its 9 coefficients (basis `1, y, z, x, xy, yz, 3z²−1, xz,
/// x²−y²`) for irradiance at unit `n` (lightprobes_pars_fragment).
fn threejs_weights(n: [f64; 3]) -> [f64; 9] {
    let [x, y, z] = n;
    [
        0.886_227,
        2.0 * 0.511_664 * y,
        2.0 * 0.511_664 * z,
        2.0 * 0.511_664 * x,
        2.0 * 0.429_043 * x * y,
        2.0 * 0.429_043 * y * z,
        0.743_125 * z * z - 0.247_708,
        2.0 * 0.429_043 * x * z,
        0.429_043 * (x * x - y * y),
    ]
}

/// prt's coefficients in three.js's basis (docs/formats.md, "To the common (Sloan) order").
fn to_threejs(c: &[f64; 9]) -> [f64; 9] {
    let h = 3f64.sqrt() / 2.0;
    [
        c[0],
        c[2],
        -c[3],
        -c[1],
        -c[5],
        -c[7],
        -0.5 * c[6] + h * c[8],
        c[4],
        -h * c[6] - 0.5 * c[8],
    ]
}

/// The SH export's grid and its radiance coefficients per voxel (`[channel][coefficient]`).
struct ShVolume {
    dims: [usize; 3],
    min: [f64; 3],
    max: [f64; 3],
    edge: [f64; 3],
    coefficients: Vec<[[f64; 9]; 3]>,
}

impl ShVolume {
    fn read(folder: &Path) -> ShVolume {
        let manifest = json_file(&folder.join("sh.json"));
        let grid = &manifest["grid"];
        let dims: [usize; 3] =
            std::array::from_fn(|k| grid["resolution"][k].as_u64().expect("resolution") as usize);
        let (min, max) = (vec3(&grid["bounds_min"]), vec3(&grid["bounds_max"]));
        let edge = std::array::from_fn(|k| (max[k] - min[k]) / dims[k] as f64);
        let names = manifest["exr"]["layers"].as_array().expect("layers");
        let layers = prt_texture::exr_io::read_exr(
            &folder.join(manifest["exr"]["file"].as_str().expect("file")),
            &prt_texture::Limits::default(),
        )
        .expect("read sh.exr");
        let [nx, ny, nz] = dims;
        let mut coefficients = vec![[[0.0; 9]; 3]; nx * ny * nz];
        for (j, name) in names.iter().enumerate() {
            let layer = layers
                .iter()
                .find(|l| l.name.as_deref() == name.as_str())
                .unwrap_or_else(|| panic!("sh.exr has no layer {name}"));
            assert_eq!((layer.width as usize, layer.height as usize), (nx, ny * nz));
            for (v, c) in coefficients.iter_mut().enumerate() {
                // Voxel (x, y, z) at row y + ny z from the top, column x.
                for (channel, c) in c.iter_mut().enumerate() {
                    c[j] = f64::from(layer.data[layer.channels * v + channel]);
                }
            }
        }
        ShVolume {
            dims,
            min,
            max,
            edge,
            coefficients,
        }
    }

    /// Trilinear weights between voxel centres at `s`, clamped to the outermost centres.
    fn trilinear(&self, s: [f64; 3]) -> Vec<(usize, f64)> {
        let mut axis = [[(0usize, 0.0f64); 2]; 3];
        for k in 0..3 {
            let n = self.dims[k];
            let f = ((s[k] - self.min[k]) / self.edge[k] - 0.5).clamp(0.0, (n - 1) as f64);
            let i = (f.floor() as usize).min(n.saturating_sub(2));
            let t = f - i as f64;
            axis[k] = [(i, 1.0 - t), ((i + 1).min(n - 1), t)];
        }
        let mut out = Vec::with_capacity(8);
        for &(z, wz) in &axis[2] {
            for &(y, wy) in &axis[1] {
                for &(x, wx) in &axis[0] {
                    out.push((x + self.dims[0] * (y + self.dims[1] * z), wx * wy * wz));
                }
            }
        }
        out
    }

    /// White Lambertian exit radiance (E/π, clamped at 0 as three.js does) at `p` with unit
    /// normal `n` as three.js's grid evaluates it, and its tolerance per channel.
    fn expected(&self, p: [f64; 3], n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        let s: [f64; 3] = std::array::from_fn(|k| p[k] + n[k] * 0.5 * self.edge[k]);
        let weights = self.trilinear(s);
        let y = prt_sh(n);
        let w3 = threejs_weights(n);
        let mut value = [0.0; 3];
        let mut tolerance = [0.0; 3];
        for c in 0..3 {
            let mut coefficient = [0.0; 9];
            let mut magnitude = [0.0; 9];
            for &(v, w) in &weights {
                let t = to_threejs(&self.coefficients[v][c]);
                for j in 0..9 {
                    coefficient[j] += w * self.coefficients[v][c][j];
                    magnitude[j] += w * t[j].abs();
                }
            }
            let e: f64 = (0..9).map(|j| band_factor(j) * coefficient[j] * y[j]).sum();
            value[c] = e.max(0.0) / PI;
            tolerance[c] = (0..9)
                .map(|j| w3[j].abs() * magnitude[j] * F16_RELATIVE)
                .sum::<f64>()
                / PI;
        }
        (value, tolerance)
    }
}

// ---------------------------------------------------------------------------------------------
// Test points and the scene.

/// A deterministic generator in [0, 1).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let l = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    v.map(|x| x / l)
}

/// (label, position, unit normal).
fn test_points(sh: &ShVolume) -> Vec<(String, [f64; 3], [f64; 3])> {
    let (min, max) = (sh.min, sh.max);
    let mut rng = Lcg(36);
    let at =
        |u: [f64; 3]| -> [f64; 3] { std::array::from_fn(|k| min[k] + u[k] * (max[k] - min[k])) };
    let mut points = Vec::new();
    // On every face of the bake box: inward normals (what rendered black before issue 36),
    // tilted inward normals, and an outward one.
    for axis in 0..3 {
        for side in [0.0, 1.0] {
            let inward = if side == 0.0 { 1.0 } else { -1.0 };
            for k in 0..6 {
                let mut u = [0.0; 3];
                for (j, u) in u.iter_mut().enumerate() {
                    *u = if j == axis {
                        side
                    } else {
                        0.03 + 0.94 * rng.next()
                    };
                }
                let mut n = [0.0; 3];
                n[axis] = inward;
                let label = match k {
                    0..=3 => "face, inward normal",
                    4 => {
                        n[(axis + 1) % 3] = 0.6 * (2.0 * rng.next() - 1.0);
                        n[(axis + 2) % 3] = 0.6 * (2.0 * rng.next() - 1.0);
                        "face, tilted inward normal"
                    }
                    _ => {
                        n[axis] = -inward;
                        "face, outward normal"
                    }
                };
                points.push((
                    format!("{label} (axis {axis}, side {side})"),
                    at(u),
                    normalize(n),
                ));
            }
        }
    }
    // The corners (on them and a tenth of a voxel in) with normals along the inward diagonal and
    // along one axis; the midpoints of the twelve edges.
    for corner in 0..8u32 {
        let u: [f64; 3] = std::array::from_fn(|k| f64::from((corner >> k) & 1));
        let inward: [f64; 3] = u.map(|u| 1.0 - 2.0 * u);
        points.push((
            format!("corner {corner}, diagonal normal"),
            at(u),
            normalize(inward),
        ));
        let p: [f64; 3] = std::array::from_fn(|k| at(u)[k] + inward[k] * 0.1 * sh.edge[k]);
        let mut n = [0.0; 3];
        n[corner as usize % 3] = inward[corner as usize % 3];
        points.push((format!("near corner {corner}, axis normal"), p, n));
    }
    for axis in 0..3 {
        for corner in 0..4u32 {
            let mut u = [0.5; 3];
            u[(axis + 1) % 3] = f64::from(corner & 1);
            u[(axis + 2) % 3] = f64::from(corner >> 1);
            let n = normalize(u.map(|u| if u == 0.5 { 0.0 } else { 1.0 - 2.0 * u }));
            points.push((format!("edge along axis {axis}, #{corner}"), at(u), n));
        }
    }
    // Inside, with random normals.
    for k in 0..40 {
        let u = [rng.next(), rng.next(), rng.next()];
        let n = loop {
            let v: [f64; 3] = std::array::from_fn(|_| 2.0 * rng.next() - 1.0);
            let l = v.iter().map(|x| x * x).sum::<f64>();
            if l > 0.01 && l <= 1.0 {
                break normalize(v);
            }
        };
        points.push((format!("inside #{k}"), at(u), n));
    }
    points
}

/// The bake's scene mesh as JSON for check.js: per material, flat triangles.
fn scene_json(scene: &prt_trace::Scene) -> Value {
    let materials: Vec<Value> = scene
        .materials()
        .iter()
        .enumerate()
        .map(|(m, material)| {
            let mut positions = Vec::new();
            let mut normals = Vec::new();
            for (t, tri) in scene.triangles().iter().enumerate() {
                if scene.material_ids()[t] as usize != m {
                    continue;
                }
                let normal = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
                for v in tri {
                    positions.extend(v.to_array());
                    normals.extend(normal.to_array());
                }
            }
            json!({
                "name": material.name,
                "albedo": material.albedo.to_array(),
                "emission": material.emissive.to_array(),
                "double_sided": material.double_sided,
                "positions": positions,
                "normals": normals,
            })
        })
        .collect();
    json!({ "materials": materials })
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Compares a page's test points with the expected values; returns (max, median) of the error
/// over the tolerance.
fn check_points(
    renderer: &str,
    got: &[[f64; 4]],
    points: &[(String, [f64; 3], [f64; 3])],
    expected: &[([f64; 3], [f64; 3])],
    floor: f64,
) {
    assert_eq!(
        got.len(),
        points.len(),
        "{renderer}: one pixel per test point"
    );
    let mut ratios = Vec::new();
    let mut f16_ratios = Vec::new();
    let mut absolute = Vec::new();
    let mut relative = Vec::new();
    let mut failures = Vec::new();
    for ((g, (label, p, n)), (want, tolerance)) in got.iter().zip(points).zip(expected) {
        assert!(
            g[3] > 0.99,
            "{renderer}: {label} at {p:?} was not drawn (alpha {})",
            g[3]
        );
        for c in 0..3 {
            let error = (g[c] - want[c]).abs();
            let bound = tolerance[c] + floor;
            ratios.push(error / bound);
            f16_ratios.push(error / tolerance[c]);
            relative.push(error / want[c].max(floor));
            absolute.push(error);
            if error > bound {
                failures.push(format!(
                    "{label}: p {p:.3?}, n {n:.3?}, channel {c}: three.js {:.6}, expected {:.6} (error {error:.2e} > {bound:.2e})",
                    g[c], want[c]
                ));
            }
        }
    }
    ratios.sort_by(f64::total_cmp);
    f16_ratios.sort_by(f64::total_cmp);
    absolute.sort_by(f64::total_cmp);
    relative.sort_by(f64::total_cmp);
    let last = |v: &[f64]| v[v.len() - 1];
    eprintln!(
        "{renderer}: {} test points × 3 channels, |three.js − expected|: max {:.2e}, median \
         {:.2e} (radiance; largest expected {:.3}); relative max {:.2e}, median {:.2e}; over \
         the f16 bound: max {:.3}, median {:.3}; over the tolerance (bound + floor {floor:.1e}): \
         max {:.3}",
        points.len(),
        last(&absolute),
        percentile(&absolute, 0.5),
        floor / FLOOR,
        last(&relative),
        percentile(&relative, 0.5),
        last(&f16_ratios),
        percentile(&f16_ratios, 0.5),
        last(&ratios),
    );
    assert!(
        failures.is_empty(),
        "{renderer}: {} of {} values outside the tolerance:\n{}",
        failures.len(),
        3 * points.len(),
        failures.join("\n")
    );
}

/// Rows from the top, as `prt render` writes them.
fn top_down(renderer: &str, pixels: &[[f64; 4]], size: usize) -> Vec<[f64; 4]> {
    assert_eq!(pixels.len(), size * size, "{renderer}: scene pixels");
    if renderer == "webgl" {
        // readPixels returns the bottom row first.
        pixels.chunks_exact(size).rev().flatten().copied().collect()
    } else {
        pixels.to_vec()
    }
}

/// Mean relative error Σ|a − b| / Σ|b| over the pixels three.js drew, and the fraction drawn.
fn scene_error(three: &[[f64; 4]], cpu: &[[f64; 3]]) -> (f64, f64) {
    let (mut diff, mut sum, mut drawn) = (0.0, 0.0, 0usize);
    for (a, b) in three.iter().zip(cpu) {
        if a[3] < 0.5 {
            continue;
        }
        drawn += 1;
        for c in 0..3 {
            diff += (a[c] - b[c]).abs();
            sum += b[c].abs();
        }
    }
    (diff / sum.max(1e-30), drawn as f64 / three.len() as f64)
}

fn save_png(path: &Path, pixels: Vec<[f32; 3]>, hit: &[bool], tone: &prt_render::ToneMap) {
    let image = prt_render::Rendered {
        width: SIZE,
        height: SIZE,
        pixels,
        hit: hit.to_vec(),
        unlit: 0,
    };
    let rgb =
        image::RgbImage::from_raw(SIZE as u32, SIZE as u32, tone.apply(&image)).expect("image");
    rgb.save(path).expect("save PNG");
}

/// The README shows the loader modules the test pages import, verbatim.
#[test]
fn the_readme_shows_the_tested_loader_verbatim() {
    let example = example_dir();
    let readme = std::fs::read_to_string(example.join("README.md")).expect("README");
    for (module, pages) in [
        (
            "load-prt-probe-grid.js",
            &["check/webgl.html", "check/webgpu.html"][..],
        ),
        ("load-prt-lightmap.js", &["check/lightmap.html"][..]),
    ] {
        let loader = std::fs::read_to_string(example.join(module)).expect("loader");
        assert!(
            readme.contains(&format!("```js\n{loader}```")),
            "examples/threejs/README.md must show {module} verbatim in a ```js block"
        );
        for page in pages {
            let html = std::fs::read_to_string(example.join(page)).expect("page");
            assert!(
                html.contains(&format!("'../{module}'")),
                "{page} must use the loader module {module}"
            );
        }
    }
}

#[test]
// One attribute for both needs: two `ignore`s on one test are a duplicate-attribute warning.
#[cfg_attr(
    any(prt_skip_chromium, prt_skip_threejs),
    ignore = "needs chromium and examples/threejs/node_modules (`npm ci` there), one absent at \
              build time (PRT_REQUIRE_CHROMIUM=1 requires them)"
)]
fn threejs_lights_the_export_as_the_sh_volume_and_prt_render_do() {
    let example = example_dir();
    assert!(
        example.join("node_modules/three/package.json").is_file(),
        "examples/threejs/node_modules/three is missing: run `npm ci` in examples/threejs \
         (.ci/extra does) before this test"
    );
    let dir = scratch("cornell");
    let bake = dir.join("bake");
    let started = Instant::now();
    run(prt()
        .arg("bake")
        .args(common::TINY_BAKE)
        .arg("--out")
        .arg(&bake));
    let out = dir.join("out");
    for target in ["threejs", "sh"] {
        run(prt()
            .arg("export")
            .arg(&bake)
            .args(["--target", target, "--sky", SKY, "--out"])
            .arg(out.join(target)));
    }
    let baked = started.elapsed().as_secs_f64();

    // The placement three.js gets: one cell per probe around the baked box padded by a voxel.
    let sh = ShVolume::read(&out.join("sh"));
    let placement = json_file(&out.join("threejs/light_probe_grid.json"));
    let resolution: [usize; 3] =
        std::array::from_fn(|k| placement["resolution"][k].as_u64().expect("resolution") as usize);
    assert_eq!(
        resolution,
        sh.dims.map(|n| n + 2),
        "light_probe_grid.json: resolution {resolution:?} is not the baked grid {:?} padded by one voxel per side (three.js ≥ 0.187 puts probes at cell centres)",
        sh.dims
    );
    let (centre, size) = (vec3(&placement["position"]), vec3(&placement["size"]));
    for k in 0..3 {
        let want_size = sh.max[k] - sh.min[k] + 2.0 * sh.edge[k];
        let want_centre = 0.5 * (sh.min[k] + sh.max[k]);
        assert!(
            (size[k] - want_size).abs() < 1e-4 * want_size
                && (centre[k] - want_centre).abs() < 1e-4 * want_size,
            "light_probe_grid.json: position {centre:?} size {size:?}, expected the bake box \
             {:?}..{:?} grown by a voxel {:?}",
            sh.min,
            sh.max,
            sh.edge
        );
    }

    // Test points and the scene, for the page.
    let points = test_points(&sh);
    let expected: Vec<_> = points.iter().map(|(_, p, n)| sh.expected(*p, *n)).collect();
    let brightest = expected.iter().flat_map(|(v, _)| *v).fold(0.0f64, f64::max);
    assert!(brightest > 0.0, "the exported volume is black");
    let floor = FLOOR * brightest;
    let scene =
        prt_trace::mesh::read_mesh(&bake.join("scene.mesh"), &prt_texture::Limits::default())
            .expect("read scene.mesh");
    let view = prt_render::views(&scene)[CAMERA].view;
    std::fs::write(
        out.join("scene.json"),
        serde_json::to_vec(&scene_json(&scene)).expect("JSON"),
    )
    .expect("write scene.json");
    let case = json!({
        "gi": "/out/threejs",
        "points": points.iter().map(|(_, p, n)| json!({ "p": p, "n": n })).collect::<Vec<_>>(),
        "scene": {
            "mesh": "/out/scene.json",
            "size": SIZE,
            "camera": {
                "position": view.position.to_array(),
                "forward": view.forward.to_array(),
                "up": view.up.to_array(),
                "yfov": view.yfov,
                "near": 0.05,
                "far": 100.0,
            },
        },
    });
    std::fs::write(
        out.join("case.json"),
        serde_json::to_vec(&case).expect("JSON"),
    )
    .expect("write case.json");

    // `prt render` of the same view: with three.js's lookup on the export's data (what three.js
    // must draw) and with prt's own (how far an engine's lookup is from it).
    let help = run(prt().args(["render", "--help"]));
    assert!(
        help.contains("--lookup") && help.contains("threejs"),
        "prt render has no --lookup threejs"
    );
    let render = |lookup: &str| -> Vec<[f64; 3]> {
        let exr = dir.join(format!("prt-render-{lookup}.exr"));
        run(prt()
            .arg("render")
            .arg(&bake)
            .args([
                "--sky",
                SKY,
                "--camera",
                &CAMERA.to_string(),
                "--lookup",
                lookup,
            ])
            .args(["--size", &SIZE.to_string(), "--out"])
            .arg(&exr));
        let layer = prt_texture::exr_io::read_exr(&exr, &prt_texture::Limits::default())
            .expect("read the render")
            .remove(0);
        assert_eq!((layer.width as usize, layer.height as usize), (SIZE, SIZE));
        layer
            .data
            .chunks_exact(layer.channels)
            .map(|p| std::array::from_fn(|c| f64::from(p[c])))
            .collect()
    };
    let cpu = render("threejs");
    let cpu_prt = render("prt");

    let server = Server::start(vec![("/", example.clone()), ("/out/", out.clone())]);
    let mut scene_errors = Vec::new();
    for (renderer, page, webgpu) in [
        ("webgl", "webgl.html", false),
        ("webgpu", "webgpu.html", true),
    ] {
        let result = run_page(&server, page, webgpu, &dir);
        eprintln!(
            "{renderer}: {} drew the page in {:.1} s; first point {:?}",
            result.device, result.seconds, result.points[0]
        );
        check_points(renderer, &result.points, &points, &expected, floor);
        let three = top_down(renderer, &result.scene, SIZE);
        let (error, drawn) = scene_error(&three, &cpu);
        let (error_prt, _) = scene_error(&three, &cpu_prt);
        eprintln!(
            "{renderer}: whole scene over the {:.1} % of pixels three.js drew: mean relative error \
             {error:.2e} against prt render --lookup threejs, {error_prt:.4} against --lookup prt",
            100.0 * drawn
        );
        scene_errors.push((renderer, error, error_prt, drawn, three));
    }
    drop(server);
    let (webgl, webgpu) = (&scene_errors[0].4, &scene_errors[1].4);
    let apart = webgl
        .iter()
        .zip(webgpu)
        .filter(|(a, b)| a[3] > 0.5 && b[3] > 0.5)
        .map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs()).fold(0.0, f64::max))
        .fold(0.0, f64::max);
    eprintln!("WebGL 2 and WebGPU whole-scene renders differ by at most {apart:.2e}");

    save_shots(
        &scene_errors[0].4,
        &cpu,
        ["threejs-cornell.png", "prt-render-cornell.png"],
    );
    for (renderer, error, error_prt, drawn, _) in &scene_errors {
        assert!(
            *drawn > 0.5,
            "{renderer}: three.js drew only {:.1} % of the image",
            100.0 * drawn
        );
        assert!(
            *error <= MAX_SCENE_ERROR,
            "{renderer}: whole scene {error:.4} mean relative error against prt render --lookup threejs > {MAX_SCENE_ERROR} (files in {})",
            dir.display()
        );
        assert!(
            *error_prt <= MAX_LOOKUP_DIFFERENCE,
            "{renderer}: whole scene {error_prt:.4} mean relative error against prt render --lookup prt > {MAX_LOOKUP_DIFFERENCE}"
        );
    }
    eprintln!(
        "bake and exports {baked:.1} s, whole test {:.1} s",
        started.elapsed().as_secs_f64()
    );
}

/// Largest mean relative error of three.js's lightmapped Cornell box against `prt lightmap`'s
/// own view of it (`view.exr`: prt-lightmap's `render_view`, bilinear in f32), over the pixels
/// three.js drew; measured on SwiftShader: 1.31e-3 (64 samples per texel).
const MAX_LIGHTMAP_ERROR: f64 = 2e-3;
/// Largest per-material median of the per-pixel relative error (luminance) on pixels inside one
/// material; measured 0.06–0.37 %. SwiftShader's filtering is less exact than f32 bilinear: the
/// error follows the lightmap's texel-to-texel contrast (at 1024 samples per texel, smoother,
/// the medians are 0.02–0.09 %, p90 ≤ 0.41 %).
const MAX_LIGHTMAP_MEDIAN: f64 = 6e-3;
/// Largest per-material 90th percentile of it; measured 0.21–1.72 %.
const MAX_LIGHTMAP_P90: f64 = 2.5e-2;

/// The material each pixel of `view` shows (prt's ray), or `None` for a miss.
fn materials_seen(
    scene: &prt_trace::Scene,
    view: &prt_trace::camera::PinholeView,
    size: usize,
) -> Vec<Option<String>> {
    let tracer = prt_trace::RayTracer::new(scene.triangles());
    (0..size * size)
        .map(|i| {
            let dir = view.ray(i % size, i / size, size, size);
            tracer
                .closest_hit(view.position, dir, 0.0, f32::INFINITY)
                .map(|hit| scene.material_of(hit.triangle as usize).name.clone())
        })
        .collect()
}

/// three.js's lightMap (channel 1) on `prt lightmap --engine threejs`'s GLB: a small irradiance
/// lightmap of the Cornell box of ../shared, rendered by WebGL 2 on SwiftShader into a float
/// target with no other light and no tone mapping, must show what `prt lightmap`'s `view.exr`
/// shows from the same camera (`emission + albedo/π · E`), and the red and green walls must keep
/// their colours (a lightmap read at the wrong UVs mixes them).
#[test]
// One attribute for the three needs: two `ignore`s on one test are a duplicate-attribute warning.
#[cfg_attr(
    any(prt_skip_chromium, prt_skip_threejs, prt_skip_shared),
    ignore = "needs chromium, examples/threejs/node_modules (`npm ci` there) and ../shared/scenes, \
              one absent at build time (PRT_REQUIRE_CHROMIUM=1 and PRT_REQUIRE_SHARED=1 require them)"
)]
fn threejs_lightmap_shows_what_prt_lightmap_shows() {
    let example = example_dir();
    assert!(
        example.join("node_modules/three/package.json").is_file(),
        "examples/threejs/node_modules/three is missing: run `npm ci` in examples/threejs"
    );
    let gltf = common::shared_cornell();
    let dir = scratch("lightmap");
    let out = dir.join("out");
    let started = Instant::now();
    run(prt()
        .arg("lightmap")
        .arg(&gltf)
        .args(["--basis", "irradiance", "--samples", "64", "--pass", "64"])
        .args(["--preview-every", "0", "--texels-per-metre", "16"])
        .args([
            "--view-size",
            &SIZE.to_string(),
            "--engine",
            "threejs",
            "--out",
        ])
        .arg(&out));
    let manifest = json_file(&out.join("manifest.json"));
    let camera = &manifest["view"];
    let as_vec3 = |v: &Value| glam::Vec3::from_array(vec3(v).map(|x| x as f32));
    let view = prt_trace::camera::PinholeView {
        position: as_vec3(&camera["position"]),
        forward: as_vec3(&camera["forward"]),
        up: as_vec3(&camera["up"]),
        yfov: camera["yfov"].as_f64().expect("yfov") as f32,
    };
    let case = json!({
        "lightmap": "/out/threejs",
        "size": SIZE,
        "camera": {
            "position": view.position.to_array(),
            "forward": view.forward.to_array(),
            "up": view.up.to_array(),
            "yfov": view.yfov,
            "near": 0.05,
            "far": 100.0,
        },
    });
    std::fs::write(
        out.join("case.json"),
        serde_json::to_vec(&case).expect("JSON"),
    )
    .expect("write case.json");
    let layer =
        prt_texture::exr_io::read_exr(&out.join("view.exr"), &prt_texture::Limits::default())
            .expect("read view.exr")
            .remove(0);
    assert_eq!((layer.width as usize, layer.height as usize), (SIZE, SIZE));
    let cpu: Vec<[f64; 3]> = layer
        .data
        .chunks_exact(layer.channels)
        .map(|p| std::array::from_fn(|c| f64::from(p[c])))
        .collect();

    let scene = prt_trace::Scene::load_gltf(&gltf, &prt_trace::LoadOptions::default())
        .expect("load the Cornell box");
    let seen = materials_seen(&scene, &view, SIZE);
    let server = Server::start(vec![("/", example.clone()), ("/out/", out.clone())]);
    let mut failures = Vec::new();
    for (renderer, page, webgpu) in [
        ("webgl", "lightmap.html", false),
        ("webgpu", "lightmap-webgpu.html", true),
    ] {
        let result = run_page(&server, page, webgpu, &dir);
        let three = top_down(renderer, &result.scene, SIZE);
        eprintln!(
            "{renderer} lightmap: {} drew the page in {:.1} s",
            result.device, result.seconds
        );
        failures.extend(
            judge_lightmap(&three, &cpu, &seen)
                .into_iter()
                .map(|f| format!("{renderer}: {f}")),
        );
        if renderer == "webgl" {
            save_shots(
                &three,
                &cpu,
                [
                    "threejs-lightmap-cornell.png",
                    "prt-lightmap-view-cornell.png",
                ],
            );
        }
    }
    drop(server);
    assert!(
        failures.is_empty(),
        "{} (files in {})",
        failures.join("; "),
        dir.display()
    );
    eprintln!("whole test {:.1} s", started.elapsed().as_secs_f64());
}

/// three.js's lightmapped render (rows from the top, RGBA) against prt's `view.exr`: the mean
/// relative error over the pixels three.js drew, per material the median and 90th percentile of
/// the relative error inside the material and the mean colour, the walls' colours. Failures.
fn judge_lightmap(three: &[[f64; 4]], cpu: &[[f64; 3]], seen: &[Option<String>]) -> Vec<String> {
    let (error, drawn) = scene_error(three, cpu);
    eprintln!(
        "  over the {:.1} % of pixels three.js drew, mean relative error {error:.2e} against \
         prt lightmap's view.exr",
        100.0 * drawn
    );
    // Per material: the mean colour three.js and prt show.
    let mut means: HashMap<String, ([f64; 3], [f64; 3], usize)> = HashMap::new();
    for (i, name) in seen.iter().enumerate() {
        if let (Some(name), true) = (name, three[i][3] > 0.5) {
            let entry = means.entry(name.clone()).or_default();
            for c in 0..3 {
                entry.0[c] += three[i][c];
                entry.1[c] += cpu[i][c];
            }
            entry.2 += 1;
        }
    }
    // Per material, the relative error of each pixel whose 8 neighbours show the same material
    // (rasterisation and prt's rays may disagree on edges).
    let luma = |c: &[f64]| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
    let mut errors: HashMap<String, Vec<f64>> = HashMap::new();
    for y in 1..SIZE - 1 {
        for x in 1..SIZE - 1 {
            let i = y * SIZE + x;
            let Some(name) = &seen[i] else { continue };
            let same = (0..9).all(|k| {
                let j = (y + k / 3 - 1) * SIZE + x + k % 3 - 1;
                seen[j].as_ref() == Some(name) && three[j][3] > 0.5
            });
            if same {
                let (a, b) = (luma(&three[i][..3]), luma(&cpu[i]));
                errors
                    .entry(name.clone())
                    .or_default()
                    .push((a - b).abs() / b.max(1e-12));
            }
        }
    }
    let mut names: Vec<_> = means.keys().cloned().collect();
    names.sort();
    let mut failures = Vec::new();
    for name in &names {
        let (three_sum, cpu_sum, n) = means[name];
        let (a, b) = (
            three_sum.map(|v| v / n as f64),
            cpu_sum.map(|v| v / n as f64),
        );
        let mut relative = errors.remove(name).unwrap_or_default();
        relative.sort_by(f64::total_cmp);
        let (median, p90) = if relative.is_empty() {
            (0.0, 0.0)
        } else {
            (percentile(&relative, 0.5), percentile(&relative, 0.9))
        };
        eprintln!(
            "{name:>10}: {n:5} px, mean three.js {a:.4?} / prt {b:.4?}; {} interior px, \
             relative error median {:.3} % p90 {:.3} %",
            relative.len(),
            100.0 * median,
            100.0 * p90
        );
        if relative.len() >= 40 && (median > MAX_LIGHTMAP_MEDIAN || p90 > MAX_LIGHTMAP_P90) {
            failures.push(format!(
                "{name}: relative error median {:.3} % p90 {:.3} % (at most {:.2} % / {:.2} %)",
                100.0 * median,
                100.0 * p90,
                100.0 * MAX_LIGHTMAP_MEDIAN,
                100.0 * MAX_LIGHTMAP_P90
            ));
        }
        if luma(&a) < 0.9 * luma(&b) {
            failures.push(format!("{name}: three.js {a:.4?} darker than prt {b:.4?}"));
        }
    }
    for (wall, channel, other) in [("leftWall", 0, 1), ("rightWall", 1, 0)] {
        let (sum, _, _) = means
            .get(wall)
            .unwrap_or_else(|| panic!("no {wall} in view"));
        if sum[channel] <= 2.0 * sum[other] || sum[channel].is_nan() {
            failures.push(format!("{wall}: three.js's mean {sum:?} lost its colour"));
        }
    }
    if drawn <= 0.5 {
        failures.push(format!(
            "three.js drew only {:.1} % of the image",
            100.0 * drawn
        ));
    }
    if error > MAX_LIGHTMAP_ERROR {
        failures.push(format!(
            "mean relative error {error:.2e} against prt lightmap's view > {MAX_LIGHTMAP_ERROR}"
        ));
    }
    failures
}

/// With `PRT_THREEJS_SHOTS=DIR`: three.js's render and prt's, one exposure, as `names`.
fn save_shots(three: &[[f64; 4]], cpu: &[[f64; 3]], names: [&str; 2]) {
    let Some(shots) = std::env::var_os("PRT_THREEJS_SHOTS") else {
        return;
    };
    let shots = PathBuf::from(shots);
    std::fs::create_dir_all(&shots).expect("shots folder");
    let hit: Vec<bool> = three.iter().map(|p| p[3] > 0.5).collect();
    let cpu32: Vec<[f32; 3]> = cpu.iter().map(|p| p.map(|v| v as f32)).collect();
    let tone = prt_render::ToneMap::auto(&prt_render::Rendered {
        width: SIZE,
        height: SIZE,
        pixels: cpu32.clone(),
        hit: hit.clone(),
        unlit: 0,
    });
    save_png(
        &shots.join(names[0]),
        three
            .iter()
            .map(|p| [p[0] as f32, p[1] as f32, p[2] as f32])
            .collect(),
        &hit,
        &tone,
    );
    save_png(&shots.join(names[1]), cpu32, &hit, &tone);
    eprintln!(
        "saved the renders in {} (exposure {:.4})",
        shots.display(),
        tone.exposure
    );
}

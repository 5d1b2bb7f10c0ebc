//! `prt view`: serves a bake folder and the WebGL2 viewer page on 127.0.0.1.
//!
//! A minimal HTTP/1.1 server on std::net (GET and HEAD, one request per connection): the page
//! and its script come from `viewer/` (compiled in), the GLSL from prt-shaders, the skies and
//! views as JSON, and `/bake/...` from the bake folder, refusing any path that could leave it.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use prt_render::{read_mesh, views};
use prt_sphere::Sky;
use prt_texture::Limits;
use serde_json::json;

use crate::sky::parse_sky;

/// The viewer page and its script, compiled into the binary (no build step, no network).
const INDEX_HTML: &str = include_str!("../viewer/index.html");
const VIEWER_JS: &str = include_str!("../viewer/viewer.js");

/// The scene mesh `prt bake` writes into its output folder (`prt render` reads the same file).
const SCENE_MESH: &str = "scene.mesh";
/// Largest request head we read; browsers send well under 2 KiB.
const MAX_REQUEST_BYTES: u64 = 8192;
/// A client that sends nothing for this long is dropped.
const CLIENT_TIMEOUT: Duration = Duration::from_secs(10);
/// Largest rank the shader endpoints accept (the container's rank is far below).
const MAX_SHADER_RANK: usize = 256;

/// Options of `prt view`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Open the printed URL in a browser with WebGL2. The page draws the scene \
mesh (BAKE_DIR/scene.mesh) lit by the MBD container (BAKE_DIR/mbd/), decoded on the GPU with \
prt-shaders' GLSL: the raw basis is relit for the sky by a fragment pass whenever the sky turns, \
then each voxel's incident radiance is Σ c_l(x) b̃_l(x) (valid voxels only, as `prt render` \
does) and each pixel shows emission + albedo/π · E(n). With BAKE_DIR/volumes/ (prt bake \
--keep-volumes) the reference, BPCA and CPCA volumes and a difference view are offered too.\n\n\
URL parameters fix a frame for screenshots: ?camera=N&rotate=DEG&method=mbd|reference|bpca|cpca\
&size=PX, optionally &sky=K (0 = default, then the --envmap skies in order), &exposure=E (else \
automatic, as prt render), &diff=1&diffScale=S (|method − reference| · S); the canvas then fills \
the page and the title becomes `ready` once that frame is drawn. &bench=N then also times N \
frames with the sky turning, N with it still and N relighting passes, and this server prints \
the means (wall clock). `prt render BAKE_DIR --camera N --rotate DEG --method M --size PX` \
renders the same frame on the CPU. Ctrl-C stops the server."
)]
pub struct ViewArgs {
    /// The folder `prt bake --out DIR` wrote (scene.mesh, mbd/, volumes/).
    pub bake_dir: PathBuf,
    /// TCP port on 127.0.0.1 (0: any free port; the URL printed says which).
    #[arg(long, default_value_t = 8000)]
    pub port: u16,
    /// Environment map (.hdr or .exr lat-long) offered as a sky, projected to order-3 SH like
    /// `prt render --sky FILE`; repeat for several. The default sky is always offered first.
    #[arg(long)]
    pub envmap: Vec<PathBuf>,
}

/// What the server answers from: the bake folder and the JSON computed at start.
struct Site {
    root: PathBuf,
    skies_json: String,
    views_json: String,
    bench: Mutex<Bench>,
}

/// Wall-clock timing of the page's `?bench=N` capture, measured here: the page marks the end of
/// each timed step with a synchronous request (its own clock stands still under a headless
/// browser's virtual time), and the time since the previous mark is added to the step's label.
#[derive(Default)]
struct Bench {
    last: Option<Instant>,
    steps: BTreeMap<String, (u32, f64)>,
}

impl Bench {
    /// Records mark `label`: `start` resets, `done` returns the summary, others add a step.
    fn mark(&mut self, label: &str) -> Option<String> {
        let now = Instant::now();
        let since = self.last.map(|t| (now - t).as_secs_f64() * 1e3);
        self.last = Some(now);
        match label {
            "start" => {
                self.steps.clear();
                None
            }
            "done" => Some(
                self.steps
                    .iter()
                    .map(|(label, (n, ms))| {
                        format!(
                            "bench: {label}: {:.1} ms per step over {n}",
                            ms / f64::from(*n)
                        )
                    })
                    .collect::<Vec<_>>()
                    .join("\n"),
            ),
            _ => {
                let step = self.steps.entry(label.to_string()).or_default();
                step.0 += 1;
                step.1 += since.unwrap_or(0.0);
                None
            }
        }
    }
}

/// The skies the page offers, as JSON: name and `sh[c][j]` per sky.
fn skies_json(skies: &[(String, Sky)]) -> String {
    let list: Vec<_> = skies
        .iter()
        .map(|(name, sky)| json!({ "name": name, "sh": sky.sh }))
        .collect();
    serde_json::Value::Array(list).to_string()
}

/// The scene's views in `prt render --camera` order, as JSON.
fn views_json(bake_dir: &Path) -> Result<String> {
    let path = bake_dir.join(SCENE_MESH);
    let scene = read_mesh(&path, &Limits::default())
        .with_context(|| format!("cannot read {}", path.display()))?;
    let list: Vec<_> = views(&scene)
        .iter()
        .map(|v| {
            json!({
                "name": v.name,
                "position": v.view.position.to_array(),
                "forward": v.view.forward.to_array(),
                "up": v.view.up.to_array(),
                "yfov": v.view.yfov,
            })
        })
        .collect();
    Ok(serde_json::Value::Array(list).to_string())
}

pub fn run(args: &ViewArgs) -> Result<()> {
    let root = args
        .bake_dir
        .canonicalize()
        .with_context(|| format!("cannot open the bake folder {}", args.bake_dir.display()))?;
    if !root.join("mbd").join("manifest.json").is_file() {
        bail!(
            "{} has no mbd/manifest.json: is it a folder written by `prt bake --out`?",
            root.display()
        );
    }
    let mut skies = vec![("default".to_string(), Sky::default())];
    for path in &args.envmap {
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into(),
        );
        let spec = path
            .to_str()
            .with_context(|| format!("--envmap {} is not UTF-8", path.display()))?;
        skies.push((name, parse_sky(spec)?));
    }
    let site = Arc::new(Site {
        views_json: views_json(&root)?,
        skies_json: skies_json(&skies),
        root,
        bench: Mutex::default(),
    });
    let listener = TcpListener::bind(SocketAddr::from((Ipv4Addr::LOCALHOST, args.port)))
        .with_context(|| format!("cannot listen on 127.0.0.1:{}", args.port))?;
    let port = listener.local_addr()?.port();
    // Polling accept lets Ctrl-C (which sets the cancellation flag) end the loop.
    listener.set_nonblocking(true)?;
    println!(
        "serving {} at http://127.0.0.1:{port}/ (Ctrl-C stops)",
        site.root.display()
    );
    std::io::stdout().flush()?;
    while !crate::progress::cancelled() {
        match listener.accept() {
            Ok((stream, _)) => {
                let site = Arc::clone(&site);
                std::thread::spawn(move || {
                    // A client that hangs up mid-answer is no error of the server's.
                    let _ = serve(stream, &site);
                });
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => eprintln!("warning: accept failed: {e}"),
        }
    }
    eprintln!("stopped");
    Ok(())
}

/// An answer: status, content type and body.
struct Response {
    status: &'static str,
    content_type: &'static str,
    body: Vec<u8>,
}

impl Response {
    fn ok(content_type: &'static str, body: impl Into<Vec<u8>>) -> Self {
        Self {
            status: "200 OK",
            content_type,
            body: body.into(),
        }
    }

    fn error(status: &'static str) -> Self {
        Self {
            status,
            content_type: "text/plain; charset=utf-8",
            body: format!("{status}\n").into_bytes(),
        }
    }
}

/// Reads one request from `stream` and answers it.
fn serve(stream: TcpStream, site: &Site) -> std::io::Result<()> {
    stream.set_nonblocking(false)?;
    stream.set_read_timeout(Some(CLIENT_TIMEOUT))?;
    stream.set_write_timeout(Some(CLIENT_TIMEOUT))?;
    let mut reader = BufReader::new((&stream).take(MAX_REQUEST_BYTES));
    let mut line = String::new();
    reader.read_line(&mut line)?;
    // Drain the headers (we use none); a head longer than the limit ends at the limit.
    let mut header = String::new();
    loop {
        header.clear();
        if reader.read_line(&mut header)? == 0 || header.trim_end().is_empty() {
            break;
        }
    }
    let (head_only, response) = answer(&line, site);
    let mut out = &stream;
    write!(
        out,
        "HTTP/1.1 {}\r\nContent-Type: {}\r\nContent-Length: {}\r\nCache-Control: no-store\r\n\
         X-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n",
        response.status,
        response.content_type,
        response.body.len()
    )?;
    if !head_only {
        out.write_all(&response.body)?;
    }
    out.flush()
}

/// The answer to a request line (`METHOD TARGET HTTP/1.x`); `true` for HEAD (no body).
fn answer(request_line: &str, site: &Site) -> (bool, Response) {
    let mut parts = request_line.split_whitespace();
    let (Some(method), Some(target), Some(version)) = (parts.next(), parts.next(), parts.next())
    else {
        return (false, Response::error("400 Bad Request"));
    };
    if !version.starts_with("HTTP/1.") || parts.next().is_some() {
        return (false, Response::error("400 Bad Request"));
    }
    let head_only = match method {
        "GET" => false,
        "HEAD" => true,
        _ => return (false, Response::error("405 Method Not Allowed")),
    };
    let (path, query) = target.split_once('?').unwrap_or((target, ""));
    (head_only, route(path, query, site))
}

fn route(path: &str, query: &str, site: &Site) -> Response {
    match path {
        "/" | "/index.html" => Response::ok("text/html; charset=utf-8", INDEX_HTML),
        "/viewer.js" => Response::ok("text/javascript; charset=utf-8", VIEWER_JS),
        "/skies.json" => Response::ok("application/json", site.skies_json.clone()),
        "/views.json" => Response::ok("application/json", site.views_json.clone()),
        "/bench" => {
            let report = site
                .bench
                .lock()
                .map(|mut b| b.mark(&percent_decode(query)));
            if let Ok(Some(report)) = report {
                println!("{report}");
                let _ = std::io::stdout().flush();
            }
            Response::ok("text/plain; charset=utf-8", "ok\n")
        }
        "/shaders/common.glsl" | "/shaders/reconstruct.glsl" | "/shaders/relight.glsl" => {
            let rank = query
                .split('&')
                .find_map(|kv| kv.strip_prefix("rank="))
                .and_then(|r| r.parse::<usize>().ok())
                .filter(|r| (1..=MAX_SHADER_RANK).contains(r));
            let Some(rank) = rank else {
                return Response::error("400 Bad Request");
            };
            let source = match path {
                "/shaders/common.glsl" => glsl_common(rank),
                "/shaders/reconstruct.glsl" => {
                    // The coefficient volume's layout: dense unless `layout=bricks`.
                    let layout = if query.split('&').any(|kv| kv == "layout=bricks") {
                        prt_shaders::CoefficientLayout::Bricks
                    } else {
                        prt_shaders::CoefficientLayout::Dense
                    };
                    prt_shaders::glsl_reconstruct_for(rank, layout)
                }
                _ => prt_shaders::glsl_relight(rank),
            };
            Response::ok("text/plain; charset=utf-8", source)
        }
        _ => match path
            .strip_prefix("/bake/")
            .and_then(|p| bake_file(&site.root, p))
        {
            Some(file) => match std::fs::read(&file) {
                Ok(bytes) => Response::ok(content_type(&file), bytes),
                Err(_) => Response::error("404 Not Found"),
            },
            None => Response::error("404 Not Found"),
        },
    }
}

/// `%XX` escapes decoded (invalid ones kept as they are), lossy UTF-8.
fn percent_decode(text: &str) -> String {
    let bytes = text.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hex = bytes
            .get(i + 1..i + 3)
            .and_then(|h| std::str::from_utf8(h).ok())
            .and_then(|h| u8::from_str_radix(h, 16).ok());
        match (bytes[i], hex) {
            (b'%', Some(b)) => {
                out.push(b);
                i += 3;
            }
            (b, _) => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// The GLSL ES 3.00 header and prt-shaders' common functions (tile addressing, irradiance) for
/// the viewer's own passes, which need no reconstruction bindings.
fn glsl_common(rank: usize) -> String {
    format!(
        "{}#define RANK {rank}\n{}",
        prt_shaders::glsl::ES_HEADER,
        prt_shaders::glsl::COMMON
    )
}

/// The file `relative` (a URL path below `/bake/`) names inside `root`, if it is a regular file
/// there: every component plain (`[A-Za-z0-9._-]`, not `.` or `..`, no percent escapes), and the
/// resolved path (symbolic links followed) still inside `root`.
fn bake_file(root: &Path, relative: &str) -> Option<PathBuf> {
    let plain = |c: &str| {
        !c.is_empty()
            && c != "."
            && c != ".."
            && c.bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"._-".contains(&b))
    };
    if !relative.split('/').all(plain) {
        return None;
    }
    let file = root.join(relative).canonicalize().ok()?;
    (file.starts_with(root) && file.is_file()).then_some(file)
}

fn content_type(path: &Path) -> &'static str {
    match path.extension().and_then(|e| e.to_str()) {
        Some("json") => "application/json",
        Some("md") => "text/markdown; charset=utf-8",
        Some("png") => "image/png",
        Some("ktx2") => "image/ktx2",
        _ => "application/octet-stream",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn site(root: &Path) -> Site {
        Site {
            root: root.canonicalize().expect("root"),
            skies_json: skies_json(&[("default".into(), Sky::default())]),
            views_json: "[]".into(),
            bench: Mutex::default(),
        }
    }

    /// A bake-like folder (and a file beside it) of its own per test: tests run in parallel.
    fn scratch(test: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("prt-view-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("bake/mbd")).expect("dirs");
        std::fs::write(dir.join("bake/mbd/manifest.json"), b"{}").expect("manifest");
        std::fs::write(dir.join("secret.txt"), b"outside").expect("secret");
        dir
    }

    #[test]
    fn bake_paths_stay_inside_the_bake_folder() {
        let dir = scratch("paths");
        let site = site(&dir.join("bake"));
        let get = |target: &str| answer(&format!("GET {target} HTTP/1.1"), &site).1;
        let ok = get("/bake/mbd/manifest.json");
        assert_eq!(ok.status, "200 OK");
        assert_eq!(ok.content_type, "application/json");
        assert_eq!(ok.body, b"{}");
        for bad in [
            "/bake/../secret.txt",
            "/bake/mbd/../../secret.txt",
            "/bake/%2e%2e/secret.txt",
            "/bake/..%2fsecret.txt",
            "/bake//etc/passwd",
            "/bake/mbd",
            "/bake/./mbd/manifest.json",
            "/bake/mbd\\..\\..\\secret.txt",
            "/../secret.txt",
            "/bake/",
        ] {
            assert_eq!(get(bad).status, "404 Not Found", "{bad}");
        }
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(dir.join("secret.txt"), dir.join("bake/link.txt"))
                .expect("symlink");
            assert_eq!(get("/bake/link.txt").status, "404 Not Found");
        }
    }

    #[test]
    fn bad_requests_get_errors_not_panics() {
        let dir = scratch("requests");
        let site = site(&dir.join("bake"));
        for (line, status) in [
            ("", "400 Bad Request"),
            ("GET", "400 Bad Request"),
            ("GET / FTP/1.0", "400 Bad Request"),
            ("GET / HTTP/1.1 extra", "400 Bad Request"),
            ("POST / HTTP/1.1", "405 Method Not Allowed"),
            ("GET /shaders/relight.glsl HTTP/1.1", "400 Bad Request"),
            (
                "GET /shaders/relight.glsl?rank=0 HTTP/1.1",
                "400 Bad Request",
            ),
            (
                "GET /shaders/relight.glsl?rank=x HTTP/1.1",
                "400 Bad Request",
            ),
            ("GET /nope HTTP/1.1", "404 Not Found"),
            ("GET \u{1F600} HTTP/1.1", "404 Not Found"),
        ] {
            assert_eq!(answer(line, &site).1.status, status, "{line:?}");
        }
        assert_eq!(percent_decode("a%20b%3D1%zz%4"), "a b=1%zz%4");
        assert_eq!(percent_decode("%E2%80%94"), "\u{2014}");
        let (head_only, page) = answer("HEAD / HTTP/1.0", &site);
        assert!(head_only);
        assert_eq!(page.content_type, "text/html; charset=utf-8");
        let skies = answer("GET /skies.json HTTP/1.1", &site).1;
        let parsed: serde_json::Value = serde_json::from_slice(&skies.body).expect("json");
        assert_eq!(parsed[0]["name"], "default");
        assert_eq!(parsed[0]["sh"].as_array().map(Vec::len), Some(3));
    }

    #[test]
    fn the_server_answers_over_tcp() {
        let dir = scratch("tcp");
        let site = Arc::new(site(&dir.join("bake")));
        let listener = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind");
        let addr = listener.local_addr().expect("addr");
        let server = {
            let site = Arc::clone(&site);
            std::thread::spawn(move || {
                for _ in 0..2 {
                    let (stream, _) = listener.accept().expect("accept");
                    let _ = serve(stream, &site);
                }
            })
        };
        let fetch = |request: &[u8]| {
            let mut s = TcpStream::connect(addr).expect("connect");
            s.write_all(request).expect("send");
            let mut out = String::new();
            s.read_to_string(&mut out).expect("read");
            out
        };
        let page = fetch(b"GET /viewer.js HTTP/1.1\r\nHost: x\r\n\r\n");
        assert!(page.starts_with("HTTP/1.1 200 OK\r\n"), "{page}");
        assert!(page.contains("Content-Type: text/javascript"));
        let traversal = fetch(b"GET /bake/../secret.txt HTTP/1.1\r\n\r\n");
        assert!(traversal.starts_with("HTTP/1.1 404"), "{traversal}");
        assert!(!traversal.contains("outside"));
        server.join().expect("server thread");
    }
}

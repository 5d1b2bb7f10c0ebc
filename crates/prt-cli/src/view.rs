//! `prt view`: serves a bake folder and the WebGL2 viewer page on 127.0.0.1.
//!
//! A minimal HTTP/1.1 server on std::net (GET and HEAD, one request per connection): the page
//! and its script come from `viewer/` (compiled in), the GLSL from prt-shaders, the skies and
//! views as JSON, and `/bake/...` from the bake folder (streamed), refusing any path that could
//! leave it. It answers only requests addressed to itself (`Host: 127.0.0.1:PORT` or
//! `localhost:PORT`: a DNS-rebinding page gets 403), serves at most [`ServerLimits::connections`]
//! connections at once with a fixed pool of threads, and gives each client one deadline for its
//! whole request and one for the whole answer.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, ErrorKind, Read, Write};
use std::net::{Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use prt_bake::BakeFolder;
use prt_render::views;
use prt_sphere::Sky;
use prt_texture::Limits;
use prt_trace::mesh::read_mesh;
use serde_json::json;

use crate::sky::parse_sky;

pub mod lightmap;

/// The viewer page, compiled into the binary (no build step, no network).
const INDEX_HTML: &str = include_str!("../viewer/index.html");
/// The page's script, compiled in too: every ES module by the path it is served at (the page
/// loads main.js, which imports the rest).
const VIEWER_MODULES: [(&str, &str); 8] = [
    ("/main.js", include_str!("../viewer/main.js")),
    ("/page.js", include_str!("../viewer/page.js")),
    ("/formats.js", include_str!("../viewer/formats.js")),
    ("/gl.js", include_str!("../viewer/gl.js")),
    ("/shaders.js", include_str!("../viewer/shaders.js")),
    ("/math.js", include_str!("../viewer/math.js")),
    ("/methods.js", include_str!("../viewer/methods.js")),
    ("/draw.js", include_str!("../viewer/draw.js")),
];

/// The page of a lightmap folder and its one module.
const LIGHTMAP_HTML: &str = include_str!("../viewer/lightmap.html");
const LIGHTMAP_MODULE: (&str, &str) = ("/lightmap.js", include_str!("../viewer/lightmap.js"));

/// Largest request head we read; browsers send well under 2 KiB.
const MAX_REQUEST_BYTES: usize = 8192;
/// Buffer of a streamed answer: files are sent in writes of at most this many bytes.
const STREAM_BUFFER: usize = 64 * 1024;
/// How often the accept loop looks for Ctrl-C while it has nothing to do.
const POLL: Duration = Duration::from_millis(20);
/// Largest rank the shader endpoints accept (the container's rank is far below).
const MAX_SHADER_RANK: usize = 256;

/// Options of `prt view`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Open the printed URL in a browser with WebGL2. The page draws the scene \
mesh (BAKE_DIR/scene.mesh) lit by the MBD container (BAKE_DIR/mbd/), decoded on the GPU with \
prt-shaders' GLSL: the raw basis is lit by the sky in a fragment pass whenever the sky turns, \
then each voxel's incident radiance is Σ c_l(x) b̃_l(x) (valid voxels only, as `prt render` \
does) and each pixel shows emission + albedo/π · E(n). With BAKE_DIR/volumes/ (prt bake \
--keep-volumes) the reference, BPCA and CPCA volumes and a difference view are offered too.\n\n\
URL parameters fix a frame for screenshots: ?camera=N&rotate=DEG&method=mbd|reference|bpca|cpca\
&size=PX, optionally &sky=K (0 = default, then the --envmap skies in order), &exposure=E (else \
automatic, as prt render), &diff=1&diffScale=S (|method − reference| · S); the canvas then fills \
the page and the title becomes `ready` once that frame is drawn. &bench=N then also times N \
frames with the sky turning, N with it still and N lighting passes, and this server prints \
the means (wall clock). `prt render BAKE_DIR --camera N --rotate DEG --method M --size PX` \
renders the same frame on the CPU. Ctrl-C stops the server."
)]
pub struct ViewArgs {
    /// The folder `prt bake --out DIR` wrote (scene.mesh, mbd/, volumes/), or one `prt lightmap
    /// --out DIR` writes (view_mesh.bin): the scene lit by its lightmap, albedo/π · E, redrawn
    /// whenever the bake writes a preview.
    pub bake_dir: PathBuf,
    /// TCP port on 127.0.0.1 (0: any free port; the URL printed says which).
    #[arg(long, default_value_t = 8000)]
    pub port: u16,
    /// Environment map (.hdr or .exr lat-long) offered as a sky, projected to order-3 SH like
    /// `prt render --sky FILE`; repeat for several. The default sky is always offered first.
    #[arg(long)]
    pub envmap: Vec<PathBuf>,
}

/// How much of the server one client can hold, and for how long.
#[derive(Clone, Copy, Debug)]
struct ServerLimits {
    /// Connections served at once (the threads of the pool); further ones wait in the listen
    /// queue until one ends, which each does by its deadlines at the latest.
    connections: usize,
    /// Time from accepting a connection to the end of its request head, all reads together (a
    /// client that sends a byte now and then is cut off too).
    request: Duration,
    /// Time to send the whole answer, all writes together (a client that reads slowly is cut
    /// off).
    response: Duration,
}

impl Default for ServerLimits {
    fn default() -> Self {
        Self {
            connections: 16,
            request: Duration::from_secs(10),
            response: Duration::from_secs(120),
        }
    }
}

/// What the server answers from: the bake folder and the JSON computed at start.
struct Site {
    root: PathBuf,
    /// A lightmap folder (`view_mesh.bin`) rather than a bake.
    lightmap: bool,
    /// The `Host` header values the server answers (compared ignoring ASCII case): itself, on
    /// its port.
    hosts: Vec<String>,
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
    let path = BakeFolder::new(bake_dir).existing_scene_mesh()?;
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
    let folder = BakeFolder::new(&root);
    let lightmap = lightmap::is_lightmap_folder(&root);
    if !lightmap && !folder.has_container() {
        bail!(
            "{} has no {}/manifest.json nor {}: is it a folder written by `prt bake --out` or `prt lightmap --out`?",
            root.display(),
            BakeFolder::CONTAINER,
            lightmap::MESH_FILE
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
    let listener = TcpListener::bind(SocketAddr::from((Ipv4Addr::LOCALHOST, args.port)))
        .with_context(|| format!("cannot listen on 127.0.0.1:{}", args.port))?;
    let port = listener.local_addr()?.port();
    let site = Arc::new(Site {
        views_json: if lightmap {
            "[]".to_string()
        } else {
            views_json(&root)?
        },
        skies_json: skies_json(&skies),
        root,
        lightmap,
        hosts: own_hosts(port),
        bench: Mutex::default(),
    });
    println!(
        "serving {} at http://127.0.0.1:{port}/ (Ctrl-C stops)",
        site.root.display()
    );
    std::io::stdout().flush()?;
    serve_connections(
        &listener,
        &site,
        ServerLimits::default(),
        &crate::progress::cancelled,
    )?;
    eprintln!("stopped");
    Ok(())
}

/// The `Host` values of requests addressed to this server on 127.0.0.1:`port` (it binds no IPv6
/// address, so `[::1]` is not among them). A page on another origin that has rebound its name
/// to 127.0.0.1 sends its own name, and is refused.
fn own_hosts(port: u16) -> Vec<String> {
    let mut hosts = vec![format!("127.0.0.1:{port}"), format!("localhost:{port}")];
    if port == 80 {
        hosts.extend(["127.0.0.1".into(), "localhost".into()]);
    }
    hosts
}

/// A counting semaphore: the connections being served.
struct Slots {
    free: Mutex<usize>,
    freed: Condvar,
}

/// One connection's place among [`Slots`], given back when dropped.
struct Slot(Arc<Slots>);

impl Slots {
    fn new(count: usize) -> Arc<Self> {
        Arc::new(Self {
            free: Mutex::new(count),
            freed: Condvar::new(),
        })
    }

    /// A free slot, waiting at most `wait` for one.
    fn acquire(self: &Arc<Self>, wait: Duration) -> Option<Slot> {
        let free = self.free.lock().unwrap_or_else(PoisonError::into_inner);
        let (mut free, _) = self
            .freed
            .wait_timeout_while(free, wait, |free| *free == 0)
            .unwrap_or_else(PoisonError::into_inner);
        (*free > 0).then(|| {
            *free -= 1;
            Slot(Arc::clone(self))
        })
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        *self.0.free.lock().unwrap_or_else(PoisonError::into_inner) += 1;
        self.0.freed.notify_one();
    }
}

/// Answers connections on `listener` until `stop()`: a pool of `limits.connections` threads
/// serves them, and a connection is accepted only when one of them is free (the others wait in
/// the listen queue), so no client can make the server start threads or hold more than one
/// thread for longer than its deadlines.
fn serve_connections(
    listener: &TcpListener,
    site: &Arc<Site>,
    limits: ServerLimits,
    stop: &dyn Fn() -> bool,
) -> std::io::Result<()> {
    // Polling accept lets `stop` (Ctrl-C sets the cancellation flag) end the loop.
    listener.set_nonblocking(true)?;
    let slots = Slots::new(limits.connections);
    let (jobs, queue) = mpsc::channel::<(TcpStream, Instant, Slot)>();
    let queue = Arc::new(Mutex::new(queue));
    for worker in 0..limits.connections {
        let (queue, site) = (Arc::clone(&queue), Arc::clone(site));
        std::thread::Builder::new()
            .name(format!("prt-view-{worker}"))
            .spawn(move || {
                loop {
                    let job = queue.lock().unwrap_or_else(PoisonError::into_inner).recv();
                    // The accept loop has ended.
                    let Ok((stream, accepted, slot)) = job else {
                        break;
                    };
                    // A client that hangs up or runs out of time is no error of the server's;
                    // a panic (a bug) loses the connection, not the thread.
                    let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        serve(&stream, &site, &limits, accepted)
                    }));
                    drop(slot);
                }
            })?;
    }
    while !stop() {
        let Some(slot) = slots.acquire(POLL) else {
            continue;
        };
        match listener.accept() {
            Ok((stream, _)) => {
                if jobs.send((stream, Instant::now(), slot)).is_err() {
                    break;
                }
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => std::thread::sleep(POLL),
            Err(e) => {
                eprintln!("warning: accept failed: {e}");
                std::thread::sleep(POLL);
            }
        }
    }
    Ok(())
}

/// A stream whose reads and writes all end by one deadline: each gets what is left of it as
/// its timeout, so a client that trickles bytes cannot stretch its time.
struct Deadline<'a> {
    stream: &'a TcpStream,
    deadline: Instant,
}

impl Deadline<'_> {
    fn left(&self) -> std::io::Result<Duration> {
        self.deadline
            .checked_duration_since(Instant::now())
            .filter(|left| !left.is_zero())
            .ok_or_else(|| std::io::Error::new(ErrorKind::TimedOut, "deadline passed"))
    }
}

impl Read for Deadline<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.stream.set_read_timeout(Some(self.left()?))?;
        self.stream.read(buf)
    }
}

impl Write for Deadline<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.stream.set_write_timeout(Some(self.left()?))?;
        self.stream.write(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.stream.flush()
    }
}

/// What an answer carries: bytes made here, or a file streamed from disk.
enum Body {
    Bytes(Vec<u8>),
    /// An open file and the length its metadata gave when opened (the Content-Length sent).
    File(File, u64),
}

impl Body {
    fn len(&self) -> u64 {
        match self {
            Self::Bytes(bytes) => bytes.len() as u64,
            Self::File(_, len) => *len,
        }
    }
}

/// An answer: status, content type and body.
struct Response {
    status: &'static str,
    content_type: &'static str,
    body: Body,
}

impl Response {
    fn ok(content_type: &'static str, body: impl Into<Vec<u8>>) -> Self {
        Self {
            status: "200 OK",
            content_type,
            body: Body::Bytes(body.into()),
        }
    }

    /// The file at `path`, opened to be streamed, or 404.
    fn file(path: &Path) -> Self {
        let opened = File::open(path).and_then(|file| Ok((file.metadata()?.len(), file)));
        match opened {
            Ok((len, file)) => Self {
                status: "200 OK",
                content_type: content_type(path),
                body: Body::File(file, len),
            },
            Err(_) => Self::error("404 Not Found"),
        }
    }

    fn error(status: &'static str) -> Self {
        Self {
            status,
            content_type: "text/plain; charset=utf-8",
            body: Body::Bytes(format!("{status}\n").into_bytes()),
        }
    }
}

/// Reads one request from `stream` and answers it, within `limits`' deadlines (the request's
/// counted from `accepted`).
fn serve(
    stream: &TcpStream,
    site: &Site,
    limits: &ServerLimits,
    accepted: Instant,
) -> std::io::Result<()> {
    stream.set_nonblocking(false)?;
    let mut input = Deadline {
        stream,
        deadline: accepted + limits.request,
    };
    let (head_only, response) = match read_head(&mut input) {
        Ok(head) => respond(&head, site),
        // No request at all: nothing to answer.
        Err(e) if e.kind() == ErrorKind::UnexpectedEof => return Ok(()),
        Err(e) if e.kind() == ErrorKind::InvalidData => (
            false,
            Response::error("431 Request Header Fields Too Large"),
        ),
        // Linux reports a read timeout as WouldBlock.
        Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock) => {
            (false, Response::error("408 Request Timeout"))
        }
        Err(e) => return Err(e),
    };
    let mut output = Deadline {
        stream,
        deadline: Instant::now() + limits.response,
    };
    write_response(&mut output, head_only, response)?;
    stream.shutdown(std::net::Shutdown::Write)
}

/// A request head (request line and headers, up to the blank line or the end of the input),
/// at most [`MAX_REQUEST_BYTES`]: longer is `InvalidData`, nothing at all `UnexpectedEof`.
fn read_head(input: &mut impl Read) -> std::io::Result<String> {
    let mut head = Vec::with_capacity(1024);
    let mut chunk = [0u8; 1024];
    loop {
        let n = input.read(&mut chunk)?;
        if n == 0 {
            if head.is_empty() {
                return Err(ErrorKind::UnexpectedEof.into());
            }
            break;
        }
        // The blank line may straddle the previous read.
        let from = head.len().saturating_sub(3);
        head.extend_from_slice(&chunk[..n]);
        let find = |end: &[u8]| {
            head[from..]
                .windows(end.len())
                .position(|w| w == end)
                .map(|at| from + at)
        };
        if let Some(end) = [find(b"\r\n\r\n"), find(b"\n\n")]
            .into_iter()
            .flatten()
            .min()
        {
            head.truncate(end);
            break;
        }
        if head.len() > MAX_REQUEST_BYTES {
            break;
        }
    }
    if head.len() > MAX_REQUEST_BYTES {
        return Err(std::io::Error::new(
            ErrorKind::InvalidData,
            "request head too long",
        ));
    }
    Ok(String::from_utf8_lossy(&head).into_owned())
}

/// Writes `response` (its head, and its body unless `head_only`) to `out`, a file streamed in
/// writes of at most [`STREAM_BUFFER`] bytes.
fn write_response(
    out: &mut impl Write,
    head_only: bool,
    response: Response,
) -> std::io::Result<()> {
    let mut out = BufWriter::with_capacity(STREAM_BUFFER, out);
    write!(
        out,
        "HTTP/1.1 {}\r\nContent-Type: {}\r\nContent-Length: {}\r\nCache-Control: no-store\r\n\
         X-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n",
        response.status,
        response.content_type,
        response.body.len()
    )?;
    if !head_only {
        match response.body {
            Body::Bytes(bytes) => out.write_all(&bytes)?,
            Body::File(file, len) => {
                // Never more than the length announced; a file that shrank since ends the
                // connection early (the client sees a short body).
                if std::io::copy(&mut file.take(len), &mut out)? < len {
                    return Err(ErrorKind::UnexpectedEof.into());
                }
            }
        }
    }
    out.flush()
}

/// The answer to a request head: refused unless it carries exactly one `Host` header naming
/// this server, else [`answer`] to its request line.
fn respond(head: &str, site: &Site) -> (bool, Response) {
    let mut lines = head.lines();
    let request_line = lines.next().unwrap_or_default();
    let hosts: Vec<&str> = lines
        .filter_map(|line| line.split_once(':'))
        .filter(|(name, _)| name.trim().eq_ignore_ascii_case("host"))
        .map(|(_, value)| value.trim())
        .collect();
    match hosts[..] {
        [host] if site.hosts.iter().any(|h| h.eq_ignore_ascii_case(host)) => {
            answer(request_line, site)
        }
        [_] => (false, Response::error("403 Forbidden")),
        _ => (false, Response::error("400 Bad Request")),
    }
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
    if site.lightmap {
        match path {
            "/" | "/index.html" => return Response::ok("text/html; charset=utf-8", LIGHTMAP_HTML),
            "/lightmap/state" => {
                return Response::ok("application/json", lightmap::state_json(&site.root));
            }
            "/lightmap/shown" => {
                // The page says which lightmap it now shows: the terminal follows the refreshes.
                let mut out = std::io::stdout();
                let _ = writeln!(
                    out,
                    "lightmap: the page shows {} samples per texel",
                    percent_decode(query)
                );
                let _ = out.flush();
                return Response::ok("text/plain; charset=utf-8", "ok\n");
            }
            _ if path == LIGHTMAP_MODULE.0 => {
                return Response::ok("text/javascript; charset=utf-8", LIGHTMAP_MODULE.1);
            }
            _ => {}
        }
    }
    if let Some((_, source)) = VIEWER_MODULES.iter().find(|(served, _)| *served == path) {
        return Response::ok("text/javascript; charset=utf-8", *source);
    }
    match path {
        "/" | "/index.html" => Response::ok("text/html; charset=utf-8", INDEX_HTML),
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
        "/shaders/common.glsl" | "/shaders/reconstruct.glsl" | "/shaders/light.glsl" => {
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
                        prt_shaders::CoefficientStorage::Bricks
                    } else {
                        prt_shaders::CoefficientStorage::Dense
                    };
                    prt_shaders::glsl_reconstruct_for(rank, layout)
                }
                _ => prt_shaders::glsl_light(rank),
            };
            Response::ok("text/plain; charset=utf-8", source)
        }
        _ => match path
            .strip_prefix("/bake/")
            .and_then(|p| bake_file(&site.root, p))
        {
            Some(file) => Response::file(&file),
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
    use std::sync::atomic::{AtomicBool, Ordering};

    /// The site of `root` served on `port`.
    fn site_on(root: &Path, port: u16) -> Site {
        Site {
            root: root.canonicalize().expect("root"),
            lightmap: lightmap::is_lightmap_folder(root),
            hosts: own_hosts(port),
            skies_json: skies_json(&[("default".into(), Sky::default())]),
            views_json: "[]".into(),
            bench: Mutex::default(),
        }
    }

    fn site(root: &Path) -> Site {
        site_on(root, 8000)
    }

    /// A body's bytes (a file's read here).
    fn bytes(body: Body) -> Vec<u8> {
        match body {
            Body::Bytes(bytes) => bytes,
            Body::File(mut file, _) => {
                let mut bytes = Vec::new();
                file.read_to_end(&mut bytes).expect("read");
                bytes
            }
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
    fn a_lightmap_folder_serves_its_page_files_and_state() {
        let dir = scratch("lightmap");
        let root = dir.join("bake");
        std::fs::write(root.join(lightmap::MESH_FILE), b"PRTLMV1\n").expect("mesh");
        let site = site(&root);
        assert!(site.lightmap);
        let get = |target: &str| answer(&format!("GET {target} HTTP/1.1"), &site).1;
        let page = get("/");
        assert_eq!(page.content_type, "text/html; charset=utf-8");
        assert!(
            String::from_utf8(bytes(page.body))
                .unwrap()
                .contains("lightmap.js")
        );
        assert_eq!(get("/lightmap.js").status, "200 OK");
        assert_eq!(get("/page.js").status, "200 OK");
        assert_eq!(get("/bake/view_mesh.bin").status, "200 OK");
        // No irradiance yet, then one of 24 samples per texel; the stamp follows the file.
        let state = |site: &Site| -> serde_json::Value {
            let r = answer("GET /lightmap/state HTTP/1.1", site).1;
            assert_eq!(r.content_type, "application/json");
            serde_json::from_slice(&bytes(r.body)).unwrap()
        };
        assert_eq!(state(&site)["samples"], serde_json::Value::Null);
        let mut map = prt_lightmap::Lightmap {
            width: 2,
            height: 1,
            basis: prt_lightmap::LightmapBasis::Irradiance,
            coefficients: Vec::new(),
            irradiance: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            covered: vec![true; 2],
            samples_per_texel: 24,
        };
        lightmap::write_irradiance(&root, &map).expect("write");
        let first = state(&site);
        assert_eq!(first["samples"], 24);
        let file = bytes(get("/bake/view_irradiance.bin").body);
        assert_eq!(file.len(), 20 + 6 * 4);
        assert_eq!(&file[..8], b"PRTLMI1\n");
        map.samples_per_texel = 32;
        lightmap::write_irradiance(&root, &map).expect("write");
        let second = state(&site);
        assert_eq!(second["samples"], 32);
        assert_ne!(first["stamp"], second["stamp"]);
        // A bake folder has none of these.
        let bake = site_on(&dir.join("bake/mbd"), 8000);
        assert!(!bake.lightmap);
        let get = |target: &str| answer(&format!("GET {target} HTTP/1.1"), &bake).1;
        assert_eq!(get("/lightmap/state").status, "404 Not Found");
        assert_eq!(get("/lightmap.js").status, "404 Not Found");
    }

    #[test]
    fn bake_paths_stay_inside_the_bake_folder() {
        let dir = scratch("paths");
        let site = site(&dir.join("bake"));
        let get = |target: &str| answer(&format!("GET {target} HTTP/1.1"), &site).1;
        let ok = get("/bake/mbd/manifest.json");
        assert_eq!(ok.status, "200 OK");
        assert_eq!(ok.content_type, "application/json");
        assert_eq!(bytes(ok.body), b"{}");
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
            ("GET /shaders/light.glsl HTTP/1.1", "400 Bad Request"),
            ("GET /shaders/light.glsl?rank=0 HTTP/1.1", "400 Bad Request"),
            ("GET /shaders/light.glsl?rank=x HTTP/1.1", "400 Bad Request"),
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
        let parsed: serde_json::Value = serde_json::from_slice(&bytes(skies.body)).expect("json");
        assert_eq!(parsed[0]["name"], "default");
        assert_eq!(parsed[0]["sh"].as_array().map(Vec::len), Some(3));
    }

    /// `serve_connections` on a free port in a thread, stopped when dropped.
    struct TestServer {
        addr: SocketAddr,
        stop: Arc<AtomicBool>,
    }

    impl TestServer {
        fn start(root: &Path, limits: ServerLimits) -> Self {
            let listener = TcpListener::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind");
            let addr = listener.local_addr().expect("addr");
            let site = Arc::new(site_on(root, addr.port()));
            let stop = Arc::new(AtomicBool::new(false));
            let stopped = Arc::clone(&stop);
            std::thread::spawn(move || {
                serve_connections(&listener, &site, limits, &|| {
                    stopped.load(Ordering::Relaxed)
                })
                .expect("serve");
            });
            Self { addr, stop }
        }

        fn connect(&self) -> TcpStream {
            let stream = TcpStream::connect(self.addr).expect("connect");
            // A test that goes wrong fails instead of hanging.
            stream
                .set_read_timeout(Some(Duration::from_secs(20)))
                .expect("timeout");
            stream
        }

        /// The answer to `request` on a new connection, read to its end.
        fn fetch(&self, request: &str) -> String {
            let mut stream = self.connect();
            stream.write_all(request.as_bytes()).expect("send");
            read_all(&mut stream)
        }

        /// `GET target` with `Host: host`.
        fn get(&self, target: &str, host: &str) -> String {
            self.fetch(&format!("GET {target} HTTP/1.1\r\nHost: {host}\r\n\r\n"))
        }
    }

    impl Drop for TestServer {
        fn drop(&mut self) {
            self.stop.store(true, Ordering::Relaxed);
        }
    }

    /// What `stream` sends until it closes (or resets: what came before is kept).
    fn read_all(stream: &mut TcpStream) -> String {
        let mut out = Vec::new();
        let mut chunk = [0u8; 4096];
        while let Ok(n @ 1..) = stream.read(&mut chunk) {
            out.extend_from_slice(&chunk[..n]);
        }
        String::from_utf8_lossy(&out).into_owned()
    }

    /// Limits that let a test see the deadlines pass within a second or two.
    const QUICK: ServerLimits = ServerLimits {
        connections: 2,
        request: Duration::from_millis(600),
        response: Duration::from_secs(5),
    };

    #[test]
    fn only_requests_addressed_to_the_server_are_answered() {
        let dir = scratch("hosts");
        // Larger than the stream buffer: it crosses the network in several writes.
        let data: Vec<u8> = (0..3 * STREAM_BUFFER + 17)
            .map(|i| b"bake-file-content\n"[i % 18])
            .collect();
        std::fs::write(dir.join("bake/data.bin"), &data).expect("data");
        let server = TestServer::start(&dir.join("bake"), ServerLimits::default());
        let port = server.addr.port();
        for host in [
            format!("127.0.0.1:{port}"),
            format!("localhost:{port}"),
            format!("LocalHost:{port}"),
        ] {
            let answer = server.get("/bake/data.bin", &host);
            let (head, body) = answer.split_once("\r\n\r\n").expect("a head");
            assert!(head.starts_with("HTTP/1.1 200 OK\r\n"), "{host}: {head}");
            assert!(
                head.contains(&format!("\r\nContent-Length: {}\r\n", data.len())),
                "{head}"
            );
            assert_eq!(body.as_bytes(), data, "{host}");
        }
        let page = server.fetch(&format!(
            "GET /main.js HTTP/1.0\r\nhOsT:127.0.0.1:{port}\r\n\r\n"
        ));
        assert!(page.starts_with("HTTP/1.1 200 OK\r\n"), "{page}");
        assert!(page.contains("Content-Type: text/javascript"));
        // A DNS-rebinding page sends its own name (or the address on another port).
        for host in [
            format!("evil.example:{port}"),
            "evil.example".into(),
            format!("localhost.evil.example:{port}"),
            format!("127.0.0.1:{port}.evil.example"),
            format!("127.0.0.2:{port}"),
            format!("127.0.0.1:{}", port.wrapping_add(1)),
            format!("[::1]:{port}"),
            "127.0.0.1".into(),
            "localhost".into(),
            String::new(),
        ] {
            let modules = VIEWER_MODULES.iter().map(|(path, _)| *path);
            for target in ["/bake/data.bin", "/", "/skies.json"]
                .into_iter()
                .chain(modules)
            {
                let answer = server.get(target, &host);
                assert!(
                    answer.starts_with("HTTP/1.1 403 Forbidden\r\n"),
                    "{host}: {answer}"
                );
                assert!(
                    answer.ends_with("\r\n\r\n403 Forbidden\n"),
                    "{host}: {answer}"
                );
            }
        }
        // No Host, or two of them (the right one and another).
        let good = format!("Host: 127.0.0.1:{port}\r\n");
        for request in [
            "GET /bake/data.bin HTTP/1.1\r\n\r\n".to_string(),
            format!("GET /bake/data.bin HTTP/1.1\r\n{good}Host: evil.example\r\n\r\n"),
            format!("GET /bake/data.bin HTTP/1.1\r\nHost: evil.example\r\n{good}\r\n"),
        ] {
            let answer = server.fetch(&request);
            assert!(
                answer.starts_with("HTTP/1.1 400 Bad Request\r\n"),
                "{request:?}: {answer}"
            );
            assert!(!answer.contains("bake-file-content"));
        }
        let traversal = server.get("/bake/../secret.txt", &format!("127.0.0.1:{port}"));
        assert!(traversal.starts_with("HTTP/1.1 404"), "{traversal}");
        assert!(!traversal.contains("outside"));
        // A head longer than the limit is refused whole.
        let long = format!(
            "GET / HTTP/1.1\r\n{good}X-Padding: {}\r\n\r\n",
            "a".repeat(MAX_REQUEST_BYTES)
        );
        assert!(server.fetch(&long).starts_with("HTTP/1.1 431 "));
    }

    #[test]
    fn the_page_and_every_module_it_imports_are_served() {
        let dir = scratch("modules");
        let server = TestServer::start(&dir.join("bake"), ServerLimits::default());
        let host = format!("127.0.0.1:{}", server.addr.port());
        for (path, source) in VIEWER_MODULES {
            let answer = server.get(path, &host);
            let (head, body) = answer.split_once("\r\n\r\n").expect("a head");
            assert!(head.starts_with("HTTP/1.1 200 OK\r\n"), "{path}: {head}");
            // Browsers run a module only with a JavaScript MIME type (and the server says nosniff).
            assert!(
                head.contains("\r\nContent-Type: text/javascript; charset=utf-8\r\n"),
                "{path}: {head}"
            );
            assert_eq!(body, source, "{path}");
        }
        // What the page and the modules name is in the table: a module left out of it would fail
        // only in a browser.
        let served: Vec<&str> = VIEWER_MODULES.iter().map(|(path, _)| *path).collect();
        let named = |source: &str, before: &str, after: char| -> Vec<String> {
            source
                .split(before)
                .skip(1)
                .map(|rest| format!("/{}", rest.split(after).next().unwrap_or_default()))
                .collect()
        };
        let scripts = named(INDEX_HTML, "<script type=\"module\" src=\"", '"');
        assert_eq!(scripts, ["/main.js"]);
        for (path, source) in VIEWER_MODULES {
            let imports = named(source, " from './", '\'');
            for import in imports {
                assert!(served.contains(&import.as_str()), "{path} imports {import}");
            }
        }
        let reached = VIEWER_MODULES
            .iter()
            .flat_map(|(_, source)| named(source, " from './", '\''))
            .chain(scripts)
            .collect::<std::collections::BTreeSet<_>>();
        assert_eq!(
            reached.len(),
            served.len(),
            "served but never imported: {reached:?}"
        );
    }

    #[test]
    fn idle_connections_cannot_lock_the_server() {
        let dir = scratch("idle");
        let server = TestServer::start(&dir.join("bake"), QUICK);
        // More idle connections than the pool has threads: two are served (and time out), the
        // third waits in the listen queue, and so does the request behind them.
        let opened = Instant::now();
        let mut idle: Vec<TcpStream> = (0..QUICK.connections + 1)
            .map(|_| server.connect())
            .collect();
        std::thread::sleep(Duration::from_millis(100));
        let start = Instant::now();
        let answer = server.get(
            "/bake/mbd/manifest.json",
            &format!("127.0.0.1:{}", server.addr.port()),
        );
        let waited = start.elapsed();
        assert!(answer.starts_with("HTTP/1.1 200 OK\r\n"), "{answer}");
        assert!(answer.ends_with("\r\n\r\n{}"), "{answer}");
        // It waited for the first two to time out (the pool is bounded), and no longer.
        assert!(
            waited >= QUICK.request / 2 && waited < QUICK.request + Duration::from_secs(3),
            "answered after {waited:?}"
        );
        for stream in &mut idle {
            let answer = read_all(stream);
            assert!(
                answer.starts_with("HTTP/1.1 408 Request Timeout\r\n"),
                "{answer}"
            );
        }
        // The third was accepted only when a thread became free (its deadline counts from
        // then): the server holds no more connections than it serves.
        let last = opened.elapsed();
        assert!(
            last >= QUICK.request * 3 / 2,
            "the third idle connection was cut off after {last:?}"
        );
    }

    #[test]
    fn a_client_that_trickles_its_request_is_cut_off_at_the_deadline() {
        let dir = scratch("trickle");
        let server = TestServer::start(&dir.join("bake"), QUICK);
        let mut stream = server.connect();
        let start = Instant::now();
        let mut writer = stream.try_clone().expect("clone");
        // A byte every 50 ms, far quicker than any per-read timeout, for up to 5 s.
        let trickle = std::thread::spawn(move || {
            let head = format!(
                "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: {}",
                "a".repeat(100)
            );
            for byte in head.bytes() {
                if writer.write_all(&[byte]).is_err() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(50));
            }
        });
        let answer = read_all(&mut stream);
        let cut = start.elapsed();
        assert!(
            cut >= QUICK.request - Duration::from_millis(100)
                && cut < QUICK.request + Duration::from_secs(2),
            "cut off after {cut:?}"
        );
        assert!(
            answer.is_empty() || answer.starts_with("HTTP/1.1 408 "),
            "{answer}"
        );
        drop(stream);
        trickle.join().expect("trickle");
    }

    /// A writer that keeps what it is given and counts the writes.
    #[derive(Default)]
    struct Recorder {
        out: Vec<u8>,
        writes: usize,
        largest: usize,
    }

    impl Write for Recorder {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.out.extend_from_slice(buf);
            self.writes += 1;
            self.largest = self.largest.max(buf.len());
            Ok(buf.len())
        }

        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn files_are_streamed_in_bounded_writes() {
        let dir = scratch("stream");
        let data: Vec<u8> = (0..16 * STREAM_BUFFER + 123)
            .map(|i| (i * 31 % 251) as u8)
            .collect();
        std::fs::write(dir.join("bake/big.ktx2"), &data).expect("data");
        let site = site(&dir.join("bake"));
        let request = "GET /bake/big.ktx2 HTTP/1.1\r\nHost: localhost:8000";
        let (head_only, response) = respond(request, &site);
        assert!(!head_only);
        // Opened, not read: the length comes from the file's metadata.
        assert!(matches!(response.body, Body::File(_, len) if len == data.len() as u64));
        let mut out = Recorder::default();
        write_response(&mut out, head_only, response).expect("write");
        let text = String::from_utf8_lossy(&out.out[..200]).into_owned();
        let (head, _) = text.split_once("\r\n\r\n").expect("a head");
        assert!(
            head.starts_with("HTTP/1.1 200 OK\r\nContent-Type: image/ktx2\r\n"),
            "{head}"
        );
        assert!(head.contains(&format!("\r\nContent-Length: {}\r\n", data.len())));
        assert_eq!(out.out[head.len() + 4..], data[..]);
        assert!(
            out.largest <= STREAM_BUFFER,
            "a write of {} bytes",
            out.largest
        );
        assert!(out.writes > 16, "{} writes", out.writes);
        // HEAD: the same head, no body.
        let (head_only, response) = respond(&request.replacen("GET", "HEAD", 1), &site);
        let mut out = Recorder::default();
        write_response(&mut out, head_only, response).expect("write");
        assert_eq!(String::from_utf8_lossy(&out.out), format!("{head}\r\n\r\n"));
    }

    #[test]
    fn request_heads_end_at_the_blank_line_or_the_limit() {
        let read = |input: &[u8]| read_head(&mut &input[..]).map_err(|e| e.kind());
        assert_eq!(
            read(b"GET / HTTP/1.1\r\nHost: a\r\n\r\nbody\n\n").as_deref(),
            Ok("GET / HTTP/1.1\r\nHost: a")
        );
        assert_eq!(
            read(b"GET / HTTP/1.0\n\nrest").as_deref(),
            Ok("GET / HTTP/1.0")
        );
        assert_eq!(
            read(b"GET / HTTP/1.0\r\n").as_deref(),
            Ok("GET / HTTP/1.0\r\n")
        );
        assert_eq!(read(b""), Err(ErrorKind::UnexpectedEof));
        let long = [b'a'; MAX_REQUEST_BYTES + 1];
        assert_eq!(read(&long), Err(ErrorKind::InvalidData));
    }
}

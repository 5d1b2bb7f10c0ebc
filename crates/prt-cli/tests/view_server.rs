//! `prt view` over raw TCP, as a DNS-rebinding page would reach it: it answers requests
//! addressed to itself on the port it printed (`Host: 127.0.0.1:PORT` or `localhost:PORT`) and
//! refuses every other `Host` with 403 and no content. The server's connection bound and
//! deadlines are tested in src/view.rs (they need limits small enough for a test).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

fn prt() -> Command {
    Command::new(env!("CARGO_BIN_EXE_prt"))
}

/// `prt view DIR --port 0` and the port it printed, stopped when dropped.
struct View(Child, u16);

impl View {
    fn start(bake: &Path) -> Self {
        let mut child = prt()
            .arg("view")
            .arg(bake)
            .args(["--port", "0"])
            .stdout(Stdio::piped())
            .spawn()
            .expect("prt view starts");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("stdout"))
            .read_line(&mut line)
            .expect("prt view prints its URL");
        let port = line
            .split_whitespace()
            .find_map(|w| w.strip_prefix("http://127.0.0.1:"))
            .and_then(|rest| rest.trim_end_matches('/').parse().ok())
            .unwrap_or_else(|| panic!("no URL in {line:?}"));
        View(child, port)
    }

    /// The whole answer to `GET target` with `Host: host`.
    fn get(&self, target: &str, host: &str) -> String {
        let mut stream = TcpStream::connect(("127.0.0.1", self.1)).expect("connect");
        stream
            .set_read_timeout(Some(Duration::from_secs(20)))
            .expect("timeout");
        write!(stream, "GET {target} HTTP/1.1\r\nHost: {host}\r\n\r\n").expect("send");
        let mut answer = String::new();
        stream.read_to_string(&mut answer).expect("read");
        answer
    }
}

impl Drop for View {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn prt_view_answers_only_requests_addressed_to_it() {
    let dir = std::env::temp_dir().join(format!("prt-view-server-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let bake = dir.join("bake");
    // The smallest bake that `prt view` accepts (a fraction of a second).
    let out = prt()
        .args(["bake", "--res", "4", "--rays", "12", "--cache-rays", "8"])
        .args(["--rank", "2", "--basis-nodes", "2", "--iterations", "4"])
        .args(["--no-baselines", "--keep-volumes", "never", "--out"])
        .arg(&bake)
        .output()
        .expect("prt bake runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let manifest = std::fs::read_to_string(bake.join("mbd/manifest.json")).expect("manifest");
    let view = View::start(&bake);
    let port = view.1;
    for host in [format!("127.0.0.1:{port}"), format!("localhost:{port}")] {
        let answer = view.get("/bake/mbd/manifest.json", &host);
        let (head, body) = answer.split_once("\r\n\r\n").expect("a head");
        assert!(head.starts_with("HTTP/1.1 200 OK\r\n"), "{host}: {head}");
        assert!(head.contains(&format!("\r\nContent-Length: {}\r\n", manifest.len())));
        assert_eq!(body, manifest, "{host}");
    }
    for host in [
        format!("attacker.example:{port}"),
        format!("127.0.0.1:{}", port.wrapping_add(1)),
        "127.0.0.1".to_string(),
    ] {
        for target in ["/bake/mbd/manifest.json", "/", "/views.json"] {
            let answer = view.get(target, &host);
            assert!(
                answer.starts_with("HTTP/1.1 403 Forbidden\r\n")
                    && answer.ends_with("\r\n\r\n403 Forbidden\n"),
                "{host} {target}: {answer}"
            );
        }
    }
    drop(view);
    let _ = std::fs::remove_dir_all(&dir);
}

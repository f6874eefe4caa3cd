//! nginx as a static host in tests (Debian's `nginx`, which `./run test` installs):
//! started by the test on a free loopback port with a generated minimal config (pid,
//! logs and temporary files in a temporary directory, `daemon off`, one process run
//! as the current user), serving a directory. Its access log records every request's
//! `Range` header, so a test can count the Range requests a client made.
//!
//! [`Nginx::balance`] starts it instead as a round-robin load balancer in front of
//! upstream servers (the stateless replicas test); the log then also records which
//! upstreams each request went to and what they answered.
//!
//! Without `/usr/sbin/nginx` (or `$TESSERA_NGINX`) a test prints `SKIPPED`, or fails
//! when `CI` is set, so CI can never pass by skipping (as `gdal_or_skip`).

use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The nginx binary: `$TESSERA_NGINX`, else Debian's.
fn binary() -> PathBuf {
    std::env::var_os("TESSERA_NGINX").map_or_else(|| PathBuf::from("/usr/sbin/nginx"), Into::into)
}

/// Whether nginx is here; `SKIPPED` when not, a failure when `CI` is set.
pub fn nginx_or_skip() -> bool {
    let ok = Command::new(binary())
        .arg("-v")
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        assert!(
            std::env::var_os("CI").is_none(),
            "nginx is missing and CI is set (./run test installs nginx)"
        );
        eprintln!("SKIPPED: nginx is absent (apt-get install nginx)");
    }
    ok
}

/// One line of the access log.
#[derive(Clone, Debug, PartialEq)]
pub struct Logged {
    pub method: String,
    pub uri: String,
    /// The request's `Range` header, `None` when it had none.
    pub range: Option<String>,
    pub status: u16,
    pub bytes_sent: u64,
    /// `$upstream_addr`: the upstreams tried, in order (`A, B` when A failed and B was
    /// asked next); `None` for a file served by nginx itself.
    pub upstream: Option<String>,
    /// `$upstream_status`: what each of them answered (`502, 200` when the first
    /// failed and the second answered).
    pub upstream_status: Option<String>,
    /// `$msec`: when the request ended (was logged), in seconds since the epoch.
    pub ended: f64,
    /// `$request_time`: seconds from its first byte read to its last byte sent.
    pub took: f64,
}

impl Logged {
    /// `bytes=A-B` as `(A, B)`.
    pub fn byte_range(&self) -> Option<(u64, u64)> {
        let (a, b) = self
            .range
            .as_deref()?
            .strip_prefix("bytes=")?
            .split_once('-')?;
        Some((a.parse().ok()?, b.parse().ok()?))
    }

    /// When nginx read the request's first byte, in seconds since the epoch (to the
    /// millisecond).
    pub fn started(&self) -> f64 {
        self.ended - self.took
    }

    /// The upstreams tried, in order (empty for a file served by nginx itself).
    pub fn upstreams(&self) -> Vec<SocketAddr> {
        self.upstream
            .as_deref()
            .unwrap_or_default()
            .split(',')
            .flat_map(|group| group.split(" : ")) // internal redirects
            .filter_map(|a| a.trim().parse().ok())
            .collect()
    }
}

/// A running nginx serving `root` on loopback; killed when dropped.
#[derive(Debug)]
pub struct Nginx {
    dir: tempfile::TempDir,
    addr: SocketAddr,
    child: Option<Child>,
}

impl Nginx {
    /// nginx serving the files of `root` on a free loopback port; `None` (with a
    /// SKIPPED message) when nginx is not installed.
    pub fn serve(root: &Path) -> Option<Self> {
        Self::serve_with(root, "")
    }

    /// [`Nginx::serve`] with `extra` directives in the `server` block (e.g. a
    /// `location` that ignores `Range`: `max_ranges 0;`).
    pub fn serve_with(root: &Path, extra: &str) -> Option<Self> {
        Self::launch(|dir, addr| static_config(dir, addr, root, extra))
    }

    /// nginx on a free loopback port as a round-robin load balancer in front of
    /// `upstreams` (plain HTTP), each listed with `params` (passive health, e.g.
    /// `max_fails=1 fail_timeout=60s`): a request an upstream refuses, drops before
    /// answering, times out or answers 502/503 goes to the next one
    /// (`proxy_next_upstream error timeout http_502 http_503`, two tries), as
    /// deploy/nginx/nginx.conf does (without its cache). `None` (with a SKIPPED
    /// message) when nginx is not installed.
    pub fn balance(upstreams: &[SocketAddr], params: &str) -> Option<Self> {
        Self::launch(|dir, addr| balancer_config(dir, addr, upstreams, params))
    }

    /// Writes `config(dir, addr)` as nginx.conf for a free port and starts nginx.
    fn launch(config: impl Fn(&Path, SocketAddr) -> String) -> Option<Self> {
        if !nginx_or_skip() {
            return None;
        }
        let dir = tempfile::tempdir().unwrap();
        for sub in ["tmp", "logs"] {
            std::fs::create_dir(dir.path().join(sub)).unwrap();
        }
        let mut n = Self {
            dir,
            addr: "127.0.0.1:0".parse().unwrap(),
            child: None,
        };
        // A port that was free a moment ago; another process may take it before
        // nginx binds it, so a failed start tries another.
        let mut why = String::new();
        for _ in 0..5 {
            n.addr = TcpListener::bind("127.0.0.1:0")
                .unwrap()
                .local_addr()
                .unwrap();
            std::fs::write(
                n.dir.path().join("nginx.conf"),
                config(n.dir.path(), n.addr),
            )
            .unwrap();
            match n.start() {
                Ok(()) => return Some(n),
                Err(e) => why = e,
            }
        }
        panic!("nginx did not start on any of 5 ports: {why}");
    }

    /// Starts nginx (again, after [`Nginx::kill`]) on the same port and waits until it
    /// accepts connections.
    pub fn start(&mut self) -> Result<(), String> {
        assert!(self.child.is_none(), "nginx is already running");
        let d = self.dir.path();
        let mut child = Command::new(binary())
            .arg("-p")
            .arg(d)
            .arg("-c")
            .arg(d.join("nginx.conf"))
            .arg("-e")
            .arg(d.join("logs/error.log"))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| e.to_string())?;
        let started = Instant::now();
        while started.elapsed() < Duration::from_secs(10) {
            if let Ok(Some(status)) = child.try_wait() {
                return Err(format!(
                    "nginx exited ({status}): {}",
                    std::fs::read_to_string(d.join("logs/error.log")).unwrap_or_default()
                ));
            }
            if TcpStream::connect_timeout(&self.addr, Duration::from_millis(100)).is_ok() {
                self.child = Some(child);
                return Ok(());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = child.kill();
        let _ = child.wait();
        Err("nginx did not accept connections within 10 s".into())
    }

    /// Kills nginx with SIGKILL (connections drop, as in a crash) and reaps it.
    pub fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// `http://127.0.0.1:PORT/NAME`: a file of the served directory.
    pub fn url(&self, name: &str) -> String {
        format!("http://{}/{name}", self.addr)
    }

    /// Every request logged so far, in order.
    pub fn log(&self) -> Vec<Logged> {
        let text =
            std::fs::read_to_string(self.dir.path().join("logs/access.log")).unwrap_or_default();
        text.lines().filter_map(parse_line).collect()
    }

    /// Empties the access log (nginx appends to the same open file).
    pub fn clear_log(&self) {
        let _ = std::fs::OpenOptions::new()
            .write(true)
            .truncate(true)
            .open(self.dir.path().join("logs/access.log"));
    }
}

impl Drop for Nginx {
    fn drop(&mut self) {
        self.kill();
    }
}

/// The log format: tab-separated, the Range header as sent (`-` when none), then the
/// upstreams tried and their answers (`-` when nginx served the request itself), when
/// it ended and how long it took.
const LOG_FORMAT: &str = "$request_method\\t$uri\\t$http_range\\t$status\\t$body_bytes_sent\\t$upstream_addr\\t$upstream_status\\t$msec\\t$request_time";

fn parse_line(line: &str) -> Option<Logged> {
    let f: Vec<&str> = line.split('\t').collect();
    let [
        method,
        uri,
        range,
        status,
        bytes,
        upstream,
        upstream_status,
        ended,
        took,
    ] = f[..]
    else {
        return None;
    };
    let field = |v: &str| (v != "-").then(|| v.to_string());
    Some(Logged {
        method: method.to_string(),
        uri: uri.to_string(),
        range: field(range),
        status: status.parse().ok()?,
        bytes_sent: bytes.parse().ok()?,
        upstream: field(upstream),
        upstream_status: field(upstream_status),
        ended: ended.parse().ok()?,
        took: took.parse().ok()?,
    })
}

/// What every configuration starts with: one process (`master_process off`: no
/// workers to switch to another user, so it runs as whoever runs the test and reads
/// their temporary files), everything it writes inside `dir`; then the `http` block
/// up to its servers.
fn preamble(dir: &Path) -> String {
    let d = dir.display();
    format!(
        r#"daemon off;
master_process off;
worker_processes 1;
pid {d}/nginx.pid;
error_log {d}/logs/error.log warn;
events {{ worker_connections 1024; }}
http {{
    log_format tessera "{LOG_FORMAT}";
    access_log {d}/logs/access.log tessera;
    client_body_temp_path {d}/tmp/client_body;
    proxy_temp_path {d}/tmp/proxy;
    fastcgi_temp_path {d}/tmp/fastcgi;
    uwsgi_temp_path {d}/tmp/uwsgi;
    scgi_temp_path {d}/tmp/scgi;
    keepalive_requests 100000;
"#
    )
}

/// The load balancer: `upstreams` round robin, with `params` on each.
fn balancer_config(dir: &Path, addr: SocketAddr, upstreams: &[SocketAddr], params: &str) -> String {
    let servers = upstreams
        .iter()
        .map(|u| format!("        server {u} {params};"))
        .collect::<Vec<_>>()
        .join("\n");
    format!(
        r#"{preamble}    upstream replicas {{
{servers}
        keepalive 32;
    }}
    server {{
        listen {addr};
        location / {{
            proxy_pass http://replicas;
            proxy_http_version 1.1;
            proxy_set_header Connection "";
            proxy_set_header Host $host;
            proxy_next_upstream error timeout http_502 http_503;
            proxy_next_upstream_tries 2;
            proxy_connect_timeout 2s;
            proxy_read_timeout 60s;
        }}
    }}
}}
"#,
        preamble = preamble(dir)
    )
}

/// The static host: the files of `root`, with `extra` directives in its `server`.
fn static_config(dir: &Path, addr: SocketAddr, root: &Path, extra: &str) -> String {
    format!(
        r#"{preamble}    types {{ application/octet-stream tess; }}
    default_type application/octet-stream;
    sendfile on;
    server {{
        listen {addr};
        root {root};
        location / {{
            add_header Access-Control-Allow-Origin *;
            add_header Access-Control-Expose-Headers "Content-Range, Content-Length, ETag, Last-Modified";
        }}
        {extra}
    }}
}}
"#,
        preamble = preamble(dir),
        root = root.display()
    )
}

//! Helpers for `serve.rs`: pyramids built once per test binary with the real
//! `tessera-server build`, a real `tessera-server serve` child process per test
//! (killed by a drop guard), and small HTTP helpers (reqwest on a private runtime,
//! plus raw TCP for what a client library would normalise or hide).

use reqwest::header::HeaderMap;
use std::collections::BTreeMap;
use std::ffi::OsString;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};
use tessera_shared::{Level, Morton, Pyramid, TileId, testdata};

pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera-server"))
}

// ---------------------------------------------------------------------------
// Fixtures

/// Pyramids shared by every test of the binary.
#[derive(Debug)]
pub struct Fixtures {
    pub dir: PathBuf,
    /// `synthetic:2049:7 --tile-size 128`: 5 levels, every tile present. Dataset `synth`.
    pub synth: PathBuf,
    /// `synth` with one byte flipped inside [`Self::corrupt_tile`]'s record. Dataset `synth-corrupt`.
    pub corrupt: PathBuf,
    pub corrupt_tile: TileId,
    /// `synth` again, under the corrupt copy's name (`synth-corrupt`): the file after repair.
    pub repaired: PathBuf,
    /// `synthetic:4097:7 --tile-size 128`: ~20 MB in its finest level, more than socket
    /// buffers hold, for the graceful-shutdown test. Dataset `synth4k`.
    pub synth4k: PathBuf,
    /// `bigtujunga.tif --tile-size 64` (1197×643: absent tiles at every level but 0).
    pub bigtujunga: Option<PathBuf>,
    /// `N44W072.hgt --tile-size 64` (EPSG:4326).
    pub n44: Option<PathBuf>,
}

/// Builds the fixtures on first use (all tests of the binary share them).
pub fn fixtures() -> &'static Fixtures {
    static F: OnceLock<Fixtures> = OnceLock::new();
    F.get_or_init(build_fixtures)
}

pub fn build_pyramid(input: &str, out: &Path, tile_size: u32) {
    let o = bin()
        .arg("build")
        .arg(input)
        .arg("-o")
        .arg(out)
        .args(["--tile-size", &tile_size.to_string(), "--quiet"])
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "build {input} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Removes fixture directories left by earlier test runs whose process is gone.
fn remove_stale_dirs(prefix: &str) {
    let Ok(rd) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    for e in rd.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        let Some(pid) = name.strip_prefix(prefix) else {
            continue;
        };
        let Ok(pid) = pid.parse::<u32>() else {
            continue;
        };
        if pid != std::process::id() && !Path::new(&format!("/proc/{pid}")).exists() {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

fn build_fixtures() -> Fixtures {
    const PREFIX: &str = "tessera-serve-test-";
    if cfg!(target_os = "linux") {
        remove_stale_dirs(PREFIX);
    }
    let dir = std::env::temp_dir().join(format!("{PREFIX}{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();

    let synth = dir.join("synth.tess");
    let synth4k = dir.join("synth4k.tess");
    let big_in = testdata::dem_or_skip("bigtujunga.tif");
    let n44_in = testdata::dem_or_skip("N44W072.hgt");
    let bigtujunga = big_in.as_ref().map(|_| dir.join("bigtujunga.tess"));
    let n44 = n44_in.as_ref().map(|_| dir.join("N44W072.tess"));
    // The builds are independent: run them side by side.
    std::thread::scope(|s| {
        s.spawn(|| build_pyramid("synthetic:2049:7", &synth, 128));
        s.spawn(|| build_pyramid("synthetic:4097:7", &synth4k, 128));
        if let (Some(i), Some(o)) = (&big_in, &bigtujunga) {
            s.spawn(|| build_pyramid(i.to_str().unwrap(), o, 64));
        }
        if let (Some(i), Some(o)) = (&n44_in, &n44) {
            s.spawn(|| build_pyramid(i.to_str().unwrap(), o, 64));
        }
    });

    // A copy of `synth` with one byte of one finest-level record flipped. The header
    // checksum covers only the header region, so the file still opens.
    let p = Pyramid::open_file(&synth).unwrap();
    let finest = p.geometry().finest();
    let corrupt_tile = TileId::from_morton(finest, Morton::from_raw(37)).unwrap();
    let e = *p.entry(corrupt_tile).unwrap();
    let mut bytes = std::fs::read(&synth).unwrap();
    let at = (e.offset + u64::from(e.length) / 2) as usize;
    bytes[at] ^= 0x5a;
    let corrupt = dir.join("synth-corrupt.tess");
    std::fs::write(&corrupt, &bytes).unwrap();
    std::fs::create_dir_all(dir.join("repaired")).unwrap();
    let repaired = dir.join("repaired").join("synth-corrupt.tess");
    std::fs::copy(&synth, &repaired).unwrap();

    Fixtures {
        dir,
        synth,
        corrupt,
        corrupt_tile,
        repaired,
        synth4k,
        bigtujunga,
        n44,
    }
}

/// Present and absent Morton codes of one level, from the file's own index.
pub fn present(p: &Pyramid<tessera_shared::FileSource>, level: Level) -> Vec<bool> {
    p.index(level)
        .unwrap()
        .iter()
        .map(tessera_shared::format::IndexEntry::is_present)
        .collect()
}

// ---------------------------------------------------------------------------
// The server process

/// A running `tessera-server serve`, killed on drop.
#[derive(Debug)]
pub struct Server {
    child: Child,
    pub addr: SocketAddr,
    log: Arc<Mutex<Vec<String>>>,
    rt: tokio::runtime::Runtime,
    client: reqwest::Client,
}

/// Every `TESSERA_*` variable `serve` reads; removed from the child's environment so
/// the test runner's own settings cannot leak in.
const ENV_VARS: &[&str] = &[
    "TESSERA_LISTEN",
    "TESSERA_CONFIG",
    "TESSERA_MAX_RANGES",
    "TESSERA_MAX_TILES",
    "TESSERA_MAX_QUERY_BYTES",
    "TESSERA_TIMEOUT_SECS",
    "TESSERA_CONCURRENCY",
    "TESSERA_CACHE_MAX_AGE",
    "TESSERA_HEADER_TIMEOUT_SECS",
    "TESSERA_IDLE_TIMEOUT_SECS",
    "TESSERA_MAX_CONNECTIONS",
    "TESSERA_PUBLIC_URL",
    "TESSERA_TRUST_FORWARDED",
];

impl Server {
    /// Serves `files` with extra flags.
    pub fn start(files: &[&Path], flags: &[&str]) -> Self {
        Self::start_with(files, flags, &[])
    }

    /// Serves `files` with extra flags and environment variables, and waits for the
    /// `listening on http://ADDR` line.
    pub fn start_with(files: &[&Path], flags: &[&str], env: &[(&str, &str)]) -> Self {
        Self::spawn(bin(), files, flags, env)
    }

    // Only some of the test binaries that share this module use it.
    #[allow(dead_code)]
    /// Serves `files` with the process's open-file limit set to `nofile` (through the
    /// shell's `ulimit`, so the limit is the server's own, as an operator would set it).
    pub fn start_with_fd_limit(files: &[&Path], flags: &[&str], nofile: u32) -> Self {
        let mut cmd = Command::new("sh");
        cmd.arg("-c")
            .arg(format!("ulimit -n {nofile} && exec \"$0\" \"$@\""))
            .arg(env!("CARGO_BIN_EXE_tessera-server"));
        Self::spawn(cmd, files, flags, &[])
    }

    fn spawn(mut cmd: Command, files: &[&Path], flags: &[&str], env: &[(&str, &str)]) -> Self {
        cmd.arg("serve")
            .args(files.iter().map(|f| OsString::from(f.as_os_str())))
            .args(["--listen", "127.0.0.1:0"])
            .args(flags)
            .env("RUST_LOG", "info")
            .env("NO_COLOR", "1")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        for v in ENV_VARS {
            cmd.env_remove(v);
        }
        for (k, v) in env {
            cmd.env(k, v);
        }
        let mut child = cmd.spawn().unwrap();

        // Drain stderr (request logs) into memory so the pipe never fills; shown if a test fails.
        let log = Arc::new(Mutex::new(Vec::new()));
        let stderr = child.stderr.take().unwrap();
        let sink = log.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                sink.lock().unwrap().push(line);
            }
        });
        let stdout = child.stdout.take().unwrap();
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut sent = false;
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if !sent && let Some(a) = line.trim().strip_prefix("listening on http://") {
                    let _ = tx.send(a.to_string());
                    sent = true;
                }
            }
        });
        let Ok(addr) = rx.recv_timeout(Duration::from_secs(60)) else {
            let _ = child.kill();
            let status = child.wait().ok();
            // Give the stderr thread a moment to collect the reason.
            std::thread::sleep(Duration::from_millis(200));
            panic!(
                "server did not print its address (exit {status:?}); stderr:\n{}",
                log.lock().unwrap().join("\n")
            );
        };
        let addr: SocketAddr = addr.parse().unwrap();
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let client = reqwest::Client::builder()
            .no_proxy()
            .timeout(Duration::from_secs(60))
            .build()
            .unwrap();
        Self {
            child,
            addr,
            log,
            rt,
            client,
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.addr)
    }

    pub fn get(&self, path: &str) -> Resp {
        self.get_with(path, &[])
    }

    pub fn get_with(&self, path: &str, headers: &[(&str, &str)]) -> Resp {
        self.send(reqwest::Method::GET, path, headers)
    }

    pub fn send(&self, method: reqwest::Method, path: &str, headers: &[(&str, &str)]) -> Resp {
        let mut req = self.client.request(method, self.url(path));
        for (k, v) in headers {
            req = req.header(*k, *v);
        }
        self.rt.block_on(async {
            let r = req
                .send()
                .await
                .unwrap_or_else(|e| panic!("GET {path}: {e}"));
            let status = r.status().as_u16();
            let headers = r.headers().clone();
            let body = r
                .bytes()
                .await
                .unwrap_or_else(|e| panic!("GET {path} body: {e}"))
                .to_vec();
            Resp {
                path: path.to_string(),
                status,
                headers,
                body,
            }
        })
    }

    /// Waits (bounded) for the process to exit by itself.
    pub fn wait_exit(&mut self, within: Duration) -> ExitStatus {
        let deadline = Instant::now() + within;
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                return s;
            }
            assert!(
                Instant::now() < deadline,
                "server still running {within:?} after it was asked to stop"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// The exit status, if the process has exited.
    pub fn try_wait(&mut self) -> Option<ExitStatus> {
        self.child.try_wait().unwrap()
    }

    /// Sends SIGTERM.
    pub fn terminate(&self) {
        self.signal("TERM");
    }

    /// Sends the signal `name` (e.g. `HUP`).
    pub fn signal(&self, name: &str) {
        let s = Command::new("kill")
            .args([&format!("-{name}"), &self.pid().to_string()])
            .status()
            .unwrap();
        assert!(s.success(), "kill -{name} failed");
    }

    pub fn log(&self) -> String {
        self.log.lock().unwrap().join("\n")
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        if std::thread::panicking() {
            eprintln!("--- server stderr ---\n{}", self.log());
        }
    }
}

// ---------------------------------------------------------------------------
// Responses

#[derive(Debug)]
pub struct Resp {
    pub path: String,
    pub status: u16,
    pub headers: HeaderMap,
    pub body: Vec<u8>,
}

impl Resp {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.get(name).map(|v| v.to_str().unwrap())
    }

    /// A header that must be present.
    pub fn must(&self, name: &str) -> &str {
        self.header(name)
            .unwrap_or_else(|| panic!("{}: no {name} header in {:?}", self.path, self.headers))
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).to_string()
    }

    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("{}: body is not JSON ({e}): {}", self.path, self.text()))
    }

    /// Asserts the status and returns the response.
    pub fn expect(self, status: u16) -> Self {
        assert_eq!(
            self.status,
            status,
            "GET {}: body {}",
            self.path,
            &self.text().chars().take(500).collect::<String>()
        );
        self
    }

    /// Asserts an error response: `status`, a JSON content type, and a body
    /// `{"error": "<message>"}`; returns the message.
    pub fn error(&self, status: u16) -> String {
        assert_eq!(
            self.status,
            status,
            "GET {}: body {}",
            self.path,
            self.text()
        );
        self.json_error()
    }

    /// Asserts a JSON error body (whatever the status) and returns its message.
    pub fn json_error(&self) -> String {
        let ct = self.header("content-type").unwrap_or("");
        assert!(
            ct.starts_with("application/json"),
            "GET {}: error content type {ct:?}",
            self.path
        );
        let j = self.json();
        let msg = j["error"]
            .as_str()
            .unwrap_or_else(|| panic!("GET {}: no \"error\" string in {j}", self.path))
            .to_string();
        assert!(!msg.is_empty(), "GET {}: empty error message", self.path);
        msg
    }
}

// ---------------------------------------------------------------------------
// Raw HTTP/1.1 over TCP

/// A raw response: status, head (lower-cased header names), body.
#[derive(Debug)]
pub struct RawResp {
    pub status: u16,
    pub headers: BTreeMap<String, String>,
    pub body: Vec<u8>,
}

/// Position of `needle` in `hay`.
pub fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Parses a response head (`HTTP/1.1 200 OK\r\nName: value\r\n…`).
pub fn parse_head(head: &str) -> (u16, BTreeMap<String, String>) {
    let mut lines = head.split("\r\n");
    let status_line = lines.next().unwrap();
    let status = status_line
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("bad status line {status_line:?}"));
    let headers = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    (status, headers)
}

/// Sends `GET target` exactly as written (no normalisation) with `Connection: close`
/// and reads the whole response.
pub fn raw_get(addr: SocketAddr, target: &str) -> RawResp {
    raw_request(addr, target, &format!("Host: {addr}\r\n"))
}

/// Sends `GET target` with exactly the header lines `headers` (each ending in CRLF,
/// `Host` included or not) plus `Connection: close`, and reads the whole response.
pub fn raw_request(addr: SocketAddr, target: &str, headers: &str) -> RawResp {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(
        s,
        "GET {target} HTTP/1.1\r\n{headers}Connection: close\r\n\r\n"
    )
    .unwrap();
    let mut all = Vec::new();
    s.read_to_end(&mut all).unwrap();
    let end = find(&all, b"\r\n\r\n").expect("a response head");
    let (status, headers) = parse_head(std::str::from_utf8(&all[..end]).unwrap());
    let body = all[end + 4..].to_vec();
    if let Some(len) = headers.get("content-length") {
        assert_eq!(body.len(), len.parse::<usize>().unwrap(), "GET {target}");
    }
    RawResp {
        status,
        headers,
        body,
    }
}

// ---------------------------------------------------------------------------
// Prometheus text format

/// One sample line: name, labels, value.
#[derive(Debug, Clone)]
pub struct Sample {
    pub name: String,
    pub labels: BTreeMap<String, String>,
    pub value: f64,
}

/// Parses the sample lines of the text exposition format (label values without
/// escaped quotes, which is all ours need).
pub fn parse_metrics(text: &str) -> Vec<Sample> {
    let mut out = Vec::new();
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (series, value) = line.rsplit_once(' ').unwrap();
        let value: f64 = value.parse().unwrap();
        let (name, labels) = match series.split_once('{') {
            Some((n, rest)) => {
                let rest = rest.strip_suffix('}').unwrap();
                let labels = rest
                    .split("\",")
                    .filter(|kv| !kv.is_empty())
                    .map(|kv| {
                        let (k, v) = kv.split_once('=').unwrap();
                        (k.trim().to_string(), v.trim().trim_matches('"').to_string())
                    })
                    .collect();
                (n.to_string(), labels)
            }
            None => (series.to_string(), BTreeMap::new()),
        };
        out.push(Sample {
            name,
            labels,
            value,
        });
    }
    out
}

/// The value of an unlabelled metric (0 when absent).
pub fn metric(samples: &[Sample], name: &str) -> f64 {
    samples
        .iter()
        .filter(|s| s.name == name && s.labels.is_empty())
        .map(|s| s.value)
        .sum()
}

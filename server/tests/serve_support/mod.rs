//! Helpers for the `serve_*` and `abuse_*` tests: pyramids built with the real
//! `tessera-server build` and shared by every test, a real `tessera-server serve`
//! child process per test (killed by a drop guard), and small HTTP helpers (reqwest
//! on a private runtime, plus raw TCP for what a client library would normalise or
//! hide; [`http`]), the Prometheus text format ([`metrics`]) and the readers of what
//! the server sends ([`stream`]).

mod http;
mod metrics;
mod stream;

// Each test binary uses some of these.
#[allow(unused_imports)]
pub use http::{CACHEABLE, RawResp, Resp, find, gunzip, parse_head, raw_get, raw_request};
#[allow(unused_imports)]
pub use metrics::{Sample, compute, metric, parse_metrics};
#[allow(unused_imports)]
pub use stream::{decode_stream, etag_is_strong, level, open, split_trailer};

use std::ffi::OsString;
use std::io::{BufRead, BufReader, Read};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use tessera_shared::{Level, Morton, Pyramid, TileId, testdata};

/// reqwest is built without a TLS crypto provider of its own (the server's object
/// stores install `ring`, server/Cargo.toml): tests that build HTTP clients install
/// it first. Idempotent.
pub fn install_tls_provider() {
    let _ = rustls::crypto::ring::default_provider().install_default();
}

pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera-server"))
}

// ---------------------------------------------------------------------------
// Fixtures

/// Pyramids shared by every test. They are never written to: a test that changes a
/// file works on a copy in its own `tempfile` directory.
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

/// Finds or builds the fixtures on first use (all tests of the binary share them).
pub fn fixtures() -> &'static Fixtures {
    static F: OnceLock<Fixtures> = OnceLock::new();
    F.get_or_init(find_or_build_fixtures)
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

/// `<size>-<mtime>` of a file, in hex.
fn identity(path: &Path) -> String {
    let m = std::fs::metadata(path).unwrap();
    let t = m.modified().unwrap().duration_since(UNIX_EPOCH).unwrap();
    format!("{:x}-{:x}", m.len(), t.as_nanos())
}

/// A fixture set unused for this long is removed by the next test binary to start.
const UNUSED_FOR: Duration = Duration::from_secs(3600);

/// Where the fixtures live. Building them is most of a test binary's work, and the
/// serve and abuse tests are several binaries, so one set is built per
/// `tessera-server` binary and set of DEMs (their sizes and modification times name
/// its directory) under Cargo's scratch directory for integration tests, and shared
/// by every test binary and every run with that server. A set is built in a
/// `tempfile` directory beside it and renamed into place whole, so no test sees half
/// a set and two binaries building at once end with one. Sets unused for an hour
/// (older servers) and builds abandoned as long are removed.
fn fixtures_dir(dems: &[Option<&Path>]) -> PathBuf {
    let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("serve-fixtures");
    std::fs::create_dir_all(&root).unwrap();
    let mut key = identity(Path::new(env!("CARGO_BIN_EXE_tessera-server")));
    for d in dems {
        key.push('_');
        key.push_str(&d.map_or_else(|| "absent".to_string(), identity));
    }
    let dir = root.join(key);
    if !dir.is_dir() {
        let staging = tempfile::Builder::new()
            .prefix(".building-")
            .tempdir_in(&root)
            .unwrap();
        build_fixture_files(staging.path(), dems[0], dems[1]);
        match std::fs::rename(staging.path(), &dir) {
            Ok(()) => {
                let _ = staging.keep();
            }
            // Another test binary renamed the same set into place first: use that one
            // (ours is removed with `staging`).
            Err(_) if dir.is_dir() => {}
            Err(e) => panic!("moving the fixtures to {}: {e}", dir.display()),
        }
    }
    // Mark the set as in use (creating an entry updates the directory's mtime).
    let mark = dir.join(format!(".in-use-{}", std::process::id()));
    std::fs::write(&mark, b"").unwrap();
    let _ = std::fs::remove_file(&mark);
    for e in std::fs::read_dir(&root).unwrap().flatten() {
        let unused = e
            .metadata()
            .and_then(|m| m.modified())
            .ok()
            .and_then(|t| SystemTime::now().duration_since(t).ok())
            .is_some_and(|age| age > UNUSED_FOR);
        if e.path() != dir && unused {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
    dir
}

/// Builds the fixture files into `dir`.
fn build_fixture_files(dir: &Path, big_in: Option<&Path>, n44_in: Option<&Path>) {
    let synth = dir.join("synth.tess");
    let synth4k = dir.join("synth4k.tess");
    // The builds are independent: run them side by side.
    std::thread::scope(|s| {
        s.spawn(|| build_pyramid("synthetic:2049:7", &synth, 128));
        s.spawn(|| build_pyramid("synthetic:4097:7", &synth4k, 128));
        if let Some(i) = big_in {
            s.spawn(|| build_pyramid(i.to_str().unwrap(), &dir.join("bigtujunga.tess"), 64));
        }
        if let Some(i) = n44_in {
            s.spawn(|| build_pyramid(i.to_str().unwrap(), &dir.join("N44W072.tess"), 64));
        }
    });

    // A copy of `synth` with one byte of one finest-level record flipped. The header
    // checksum covers only the header region, so the file still opens.
    let (_, e) = corrupt_tile(&synth);
    let mut bytes = std::fs::read(&synth).unwrap();
    let at = (e.offset + u64::from(e.length) / 2) as usize;
    bytes[at] ^= 0x5a;
    std::fs::write(dir.join("synth-corrupt.tess"), &bytes).unwrap();
    std::fs::create_dir_all(dir.join("repaired")).unwrap();
    std::fs::copy(&synth, dir.join("repaired").join("synth-corrupt.tess")).unwrap();
}

/// The tile whose record the corrupt copy of `synth` has damaged, and its index entry.
fn corrupt_tile(synth: &Path) -> (TileId, tessera_shared::format::IndexEntry) {
    let p = Pyramid::open_file(synth).unwrap();
    let finest = p.geometry().finest();
    let tile = TileId::from_morton(finest, Morton::from_raw(37)).unwrap();
    (tile, *p.entry(tile).unwrap())
}

fn find_or_build_fixtures() -> Fixtures {
    let big_in = testdata::dem_or_skip("bigtujunga.tif");
    let n44_in = testdata::dem_or_skip("N44W072.hgt");
    let dir = fixtures_dir(&[big_in.as_deref(), n44_in.as_deref()]);
    let synth = dir.join("synth.tess");
    let (corrupt_tile, _) = corrupt_tile(&synth);
    Fixtures {
        corrupt: dir.join("synth-corrupt.tess"),
        corrupt_tile,
        repaired: dir.join("repaired").join("synth-corrupt.tess"),
        synth4k: dir.join("synth4k.tess"),
        bigtujunga: big_in.map(|_| dir.join("bigtujunga.tess")),
        n44: n44_in.map(|_| dir.join("N44W072.tess")),
        synth,
        dir,
    }
}

/// The pyramid of one shared DEM (`../shared/data/dem/<dem>`) at `tile_size`, named
/// by the DEM's stem (dataset `N46E008` for `N46E008.tif`); `None` (and `SKIPPED`)
/// when the DEM is absent. Built once per server binary and DEM, beside the other
/// fixtures, and renamed into place whole like them.
pub fn dem_pyramid(dem: &str, tile_size: u32) -> Option<PathBuf> {
    let input = testdata::dem_or_skip(dem)?;
    let stem = Path::new(dem).file_stem().unwrap().to_str().unwrap();
    let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("serve-fixtures");
    std::fs::create_dir_all(&root).unwrap();
    let dir = root.join(format!(
        "dem-{}_{}_{tile_size}",
        identity(Path::new(env!("CARGO_BIN_EXE_tessera-server"))),
        identity(&input)
    ));
    let file = dir.join(format!("{stem}.tess"));
    if !file.is_file() {
        let staging = tempfile::Builder::new()
            .prefix(".building-")
            .tempdir_in(&root)
            .unwrap();
        build_pyramid(
            input.to_str().unwrap(),
            &staging.path().join(format!("{stem}.tess")),
            tile_size,
        );
        if std::fs::rename(staging.path(), &dir).is_ok() {
            let _ = staging.keep();
        }
        assert!(file.is_file(), "building {} failed", file.display());
    }
    // Mark the set as in use, so no other test binary removes it as stale.
    let mark = dir.join(format!(".in-use-{}", std::process::id()));
    std::fs::write(&mark, b"").unwrap();
    let _ = std::fs::remove_file(&mark);
    Some(file)
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
    /// `https` when the server said `listening on https://…` (`--tls-cert`), else `http`.
    pub scheme: &'static str,
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
    "TESSERA_CORS_ORIGIN",
    "TESSERA_TLS_CERT",
    "TESSERA_TLS_KEY",
    "TESSERA_EMPTY_TILES",
    "TESSERA_ATTRIBUTION",
    "TESSERA_SOURCE_CACHE_MIB",
    "TESSERA_TILE_CACHE_MIB",
    "TESSERA_BLOCK_CACHE_MIB",
    "TESSERA_NO_VIEWER",
    "TESSERA_VIEWER_ASSETS",
    "TESSERA_WATER",
    "TESSERA_SEA_LEVEL",
    "TESSERA_NO_DATA_WATER",
    "TESSERA_MAX_POINTS",
    "TESSERA_MAX_BODY_MIB",
    "TESSERA_MAX_COMPUTE",
    "TESSERA_MAX_COMPUTE_MIB",
    "TESSERA_COMPUTE_QUEUE",
    "TESSERA_COMPUTE_QUEUE_SECS",
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
                if !sent && let Some(a) = line.trim().strip_prefix("listening on ") {
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
        let (scheme, addr) = addr
            .split_once("://")
            .unwrap_or_else(|| panic!("listening line without a scheme: {addr:?}"));
        let scheme = match scheme {
            "http" => "http",
            "https" => "https",
            other => panic!("listening on an unknown scheme {other:?}"),
        };
        let addr: SocketAddr = addr.parse().unwrap();
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        install_tls_provider();
        let client = reqwest::Client::builder()
            .no_proxy()
            .timeout(Duration::from_secs(60))
            // Below the server's 10 s header timeout, which closes idle keep-alive
            // connections: a request on a pooled connection the server is closing
            // fails to send (a POST after 25 s of GDAL work in serve_elevation did).
            .pool_idle_timeout(Duration::from_secs(5))
            .build()
            .unwrap();
        Self {
            child,
            addr,
            scheme,
            log,
            rt,
            client,
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// The URL of `path` on this server; an absolute URL that already names this
    /// server (what the TileJSON gives) as it is.
    pub fn url(&self, path: &str) -> String {
        let me = format!("{}://{}", self.scheme, self.addr);
        if path.starts_with(&format!("{me}/")) {
            return path.to_string();
        }
        format!("{me}{path}")
    }

    pub fn get(&self, path: &str) -> Resp {
        self.get_with(path, &[])
    }

    pub fn get_with(&self, path: &str, headers: &[(&str, &str)]) -> Resp {
        self.send(reqwest::Method::GET, path, headers)
    }

    pub fn send(&self, method: reqwest::Method, path: &str, headers: &[(&str, &str)]) -> Resp {
        self.send_body(method, path, headers, Vec::new())
    }

    /// `POST` of `body` with its `Content-Type`.
    pub fn post(&self, path: &str, content_type: &str, body: Vec<u8>) -> Resp {
        self.send_body(
            reqwest::Method::POST,
            path,
            &[("content-type", content_type)],
            body,
        )
    }

    /// A request with a body (none when empty).
    pub fn send_body(
        &self,
        method: reqwest::Method,
        path: &str,
        headers: &[(&str, &str)],
        body: Vec<u8>,
    ) -> Resp {
        let mut req = self.client.request(method, self.url(path));
        if !body.is_empty() {
            req = req.body(body);
        }
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

/// Runs `serve ARGS` expecting it to refuse to start: returns its stderr. Fails if it
/// prints its listening line instead (the old behaviour), without waiting for a
/// timeout.
pub fn serve_must_refuse(args: &[&str]) -> String {
    serve_must_refuse_with(args, &[])
}

/// [`serve_must_refuse`] with extra environment variables.
pub fn serve_must_refuse_with(args: &[&str], env: &[(&str, &str)]) -> String {
    let mut child = bin()
        .arg("serve")
        .args(args)
        .args(["--listen", "127.0.0.1:0"])
        .envs(env.iter().copied())
        .env("NO_COLOR", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    for line in BufReader::new(stdout).lines().map_while(Result::ok) {
        if line.starts_with("listening on") {
            let _ = child.kill();
            let _ = child.wait();
            panic!("serve {args:?} started instead of refusing");
        }
    }
    let status = child.wait().unwrap();
    let err = take_stderr(&mut child);
    assert!(!status.success(), "serve {args:?} exited 0: {err}");
    assert!(!err.contains("panicked"), "serve {args:?} panicked: {err}");
    err
}

/// Everything a (finished or killed) child wrote to its piped stderr.
pub fn take_stderr(child: &mut Child) -> String {
    let mut err = String::new();
    child
        .stderr
        .take()
        .expect("stderr is piped")
        .read_to_string(&mut err)
        .unwrap();
    err
}

/// The server's `/metrics`, parsed.
pub fn metrics(srv: &Server) -> Vec<Sample> {
    parse_metrics(&srv.get("/metrics").expect(200).text())
}

/// Waits (at most a minute) until `/metrics` satisfies `ok`: tests wait for states,
/// they never time them.
pub fn until(srv: &Server, what: &str, ok: impl Fn(&[Sample]) -> bool) -> Vec<Sample> {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let m = metrics(srv);
        if ok(&m) {
            return m;
        }
        assert!(Instant::now() < deadline, "never: {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Kilobytes of a process's resident memory (`VmRSS:`, or its peak `VmHWM:`).
pub fn rss_kib(pid: u32, field: &str) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    status
        .lines()
        .find_map(|l| l.strip_prefix(field)?.trim().strip_suffix("kB"))
        .and_then(|v| v.trim().parse().ok())
        .unwrap()
}

/// `(side, RGBA)` of a square PNG in RGBA, RGB, grey and alpha, or grey (rendered
/// hillshade tiles are grey and alpha).
pub fn png_rgba(bytes: &[u8]) -> (u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.width, info.height, "a square tile");
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    buf.truncate(info.buffer_size());
    let rgba = match info.color_type {
        png::ColorType::Rgba => buf,
        png::ColorType::Rgb => buf
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect(),
        png::ColorType::GrayscaleAlpha => buf
            .chunks_exact(2)
            .flat_map(|p| [p[0], p[0], p[0], p[1]])
            .collect(),
        png::ColorType::Grayscale => buf.iter().flat_map(|&g| [g, g, g, 255]).collect(),
        other @ png::ColorType::Indexed => panic!("unexpected PNG colour type {other:?}"),
    };
    (info.width, rgba)
}

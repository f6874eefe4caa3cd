//! A real S3 server on loopback for tests: `moto_server` (PyPI `moto[server]`),
//! started and stopped by the test itself (DECISIONS.md "Object storage": why moto
//! and not s3s-fs). Enabled by the `testdata` feature.
//!
//! `./run test` installs moto into `${XDG_CACHE_HOME:-~/.cache}/tessera/deploy-venv`
//! once (`deploy/check.sh --tools-only`). A test calls [`S3Server::start_or_skip`]: without moto it prints a visible
//! `SKIPPED` line, but when `CI` is set that is a failure, so CI cannot pass by
//! skipping. moto keeps objects in memory: a killed server loses them, and a test that
//! restarts it puts the same bytes back ([`S3Server::restart`] only restarts).
//! Objects are put with boto3 from moto's own venv (signed, one PUT each).

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Where `moto_server` is: `$TESSERA_MOTO_SERVER`, the deploy tools' venv that `./run
/// test` makes (deploy/check.sh --tools-only; pinned in deploy/requirements.txt), an
/// older `moto-venv`, or `PATH`. Its venv must also hold boto3 (moto brings it).
pub fn moto_server() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("TESSERA_MOTO_SERVER") {
        return Some(PathBuf::from(p));
    }
    let cache = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))?;
    for venv in ["deploy-venv", "moto-venv"] {
        let p = cache.join("tessera").join(venv).join("bin/moto_server");
        if p.is_file() {
            return Some(p);
        }
    }
    let on_path = std::env::var_os("PATH")?;
    std::env::split_paths(&on_path)
        .map(|d| d.join("moto_server"))
        .find(|p| p.is_file())
}

static PUTS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// A running `moto_server`, killed on drop.
#[derive(Debug)]
pub struct S3Server {
    program: PathBuf,
    addr: SocketAddr,
    child: Option<Child>,
}

impl S3Server {
    /// Starts one on a free port, or `None` (after a visible message) when moto is
    /// not installed, outside CI.
    ///
    /// # Panics
    /// When moto is missing and `CI` is set, or it does not start.
    pub fn start_or_skip() -> Option<Self> {
        let Some(program) = moto_server() else {
            assert!(
                std::env::var_os("CI").is_none(),
                "moto_server is missing and CI is set (./run test installs it with \
                 deploy/check.sh --tools-only)"
            );
            eprintln!("SKIPPED: no moto_server (deploy/check.sh --tools-only installs it)");
            return None;
        };
        let port = TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("a free port")
            .port();
        let mut s = Self {
            program,
            addr: SocketAddr::from(([127, 0, 0, 1], port)),
            child: None,
        };
        s.spawn();
        Some(s)
    }

    fn spawn(&mut self) {
        let child = Command::new(&self.program)
            .args(["-H", "127.0.0.1", "-p", &self.addr.port().to_string()])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", self.program.display()));
        self.child = Some(child);
        let deadline = Instant::now() + Duration::from_secs(30);
        while Instant::now() < deadline {
            if self
                .request("GET", "/", &[])
                .is_ok_and(|(status, _)| status == 200)
            {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        panic!("moto_server did not answer on {} within 30 s", self.addr);
    }

    /// `http://127.0.0.1:PORT`.
    pub fn endpoint(&self) -> String {
        format!("http://{}", self.addr)
    }

    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The environment a `tessera-server` needs to reach this store (any credentials
    /// do: moto does not check them).
    pub fn env(&self) -> Vec<(String, String)> {
        self.env_for(&self.endpoint())
    }

    /// [`S3Server::env`] with another endpoint (e.g. a proxy in front of this one).
    pub fn env_for(&self, endpoint: &str) -> Vec<(String, String)> {
        [
            ("AWS_ENDPOINT_URL", endpoint),
            ("AWS_ALLOW_HTTP", "true"),
            ("AWS_ACCESS_KEY_ID", "tessera-test"),
            ("AWS_SECRET_ACCESS_KEY", "tessera-test"),
            ("AWS_REGION", "us-east-1"),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
    }

    /// Creates a bucket.
    ///
    /// # Panics
    /// When the server refuses.
    pub fn create_bucket(&self, bucket: &str) {
        self.boto3(&format!("s3.create_bucket(Bucket={bucket:?})"), None);
    }

    /// Puts an object whole with one signed PUT (through boto3, which moto brings:
    /// moto refuses unsigned overwrites), so the same bytes always get the same ETag.
    ///
    /// # Panics
    /// When the server refuses.
    pub fn put(&self, bucket: &str, key: &str, bytes: &[u8]) {
        let file = std::env::temp_dir().join(format!(
            "tessera-s3-put-{}-{}",
            std::process::id(),
            PUTS.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
        ));
        std::fs::write(&file, bytes).expect("a temporary file");
        self.boto3(
            &format!(
                "s3.put_object(Bucket={bucket:?}, Key={key:?}, ACL='public-read', Body=open(sys.argv[1], 'rb').read())"
            ),
            Some(&file),
        );
        let _ = std::fs::remove_file(&file);
    }

    /// Runs one boto3 statement against this server with the venv's Python.
    fn boto3(&self, statement: &str, arg: Option<&std::path::Path>) {
        let python = self.program.with_file_name("python3");
        let script = format!(
            "import sys, boto3\n\
             s3 = boto3.client('s3', endpoint_url={:?}, aws_access_key_id='tessera-test', \
             aws_secret_access_key='tessera-test', region_name='us-east-1')\n{statement}\n",
            self.endpoint()
        );
        let mut cmd = Command::new(&python);
        cmd.arg("-c").arg(script);
        if let Some(a) = arg {
            cmd.arg(a);
        }
        let o = cmd
            .output()
            .unwrap_or_else(|e| panic!("cannot run {}: {e}", python.display()));
        assert!(
            o.status.success(),
            "boto3 {statement}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }

    /// An object's bytes (unsigned GET); `None` unless 200.
    pub fn get(&self, bucket: &str, key: &str) -> Option<Vec<u8>> {
        match self.request("GET", &format!("/{bucket}/{key}"), &[]) {
            Ok((200, body)) => Some(body),
            _ => None,
        }
    }

    /// Kills the server (SIGKILL): every connection drops, every object is gone.
    pub fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Starts it again on the same port (empty: moto keeps nothing).
    pub fn restart(&mut self) {
        self.kill();
        self.spawn();
    }

    /// One HTTP/1.1 request with `Connection: close`: status and body.
    fn request(&self, method: &str, path: &str, body: &[u8]) -> std::io::Result<(u16, Vec<u8>)> {
        let mut s = TcpStream::connect_timeout(&self.addr, Duration::from_secs(2))?;
        s.set_read_timeout(Some(Duration::from_secs(30)))?;
        write!(
            s,
            "{method} {path} HTTP/1.1\r\nHost: {}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
            self.addr,
            body.len()
        )?;
        s.write_all(body)?;
        let mut raw = Vec::new();
        s.read_to_end(&mut raw)?;
        let split = raw
            .windows(4)
            .position(|w| w == b"\r\n\r\n")
            .ok_or_else(|| std::io::Error::other("no response head"))?;
        let head = String::from_utf8_lossy(&raw[..split]).to_string();
        let status = head
            .split_whitespace()
            .nth(1)
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| std::io::Error::other(format!("bad status line: {head}")))?;
        let mut rest = raw[split + 4..].to_vec();
        if head
            .to_ascii_lowercase()
            .contains("transfer-encoding: chunked")
        {
            rest = dechunk(&rest);
        }
        Ok((status, rest))
    }
}

/// A chunked body's bytes.
fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    while let Some(eol) = b.windows(2).position(|w| w == b"\r\n") {
        let size = usize::from_str_radix(
            String::from_utf8_lossy(&b[..eol])
                .split(';')
                .next()
                .unwrap_or("")
                .trim(),
            16,
        )
        .unwrap_or(0);
        if size == 0 || eol + 2 + size > b.len() {
            break;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + size]);
        b = &b[(eol + 4 + size).min(b.len())..];
    }
    out
}

impl Drop for S3Server {
    fn drop(&mut self) {
        self.kill();
    }
}

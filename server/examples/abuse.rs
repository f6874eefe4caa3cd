//! The heavy-and-hostile campaign against computed responses
//! (DECISIONS.md "Expensive work"), repeatable: `./run abuse` builds the pyramids and
//! runs this against the release server (figures in RELIABILITY.md "Expensive work").
//!
//! ```text
//! cargo run --release -p tessera-server --example abuse -- SERVER_BIN N46E008.tess moon.tess [SERVE FLAGS...]
//! ```
//!
//! Each scenario starts a fresh `SERVER_BIN serve` of both pyramids with default flags
//! (plus any given), watches its memory from `/proc` (killing it at 6 GiB, as the
//! campaign that found the problems did, since the machine has no swap), and prints
//! one line of figures:
//!
//! - `distinct`: 1 024 concurrent distinct Cesium tiles at zooms 0–8 of both
//!   datasets, while a stored tile is requested over and over on its own connection:
//!   statuses, 503s without `Retry-After`, peak RSS, the stored tile's p50/p99/max.
//! - `identical`: one request for a tile, then (fresh server) 64 identical ones:
//!   peak RSS of each, and the computations `/metrics` counts.
//! - `reset`: 240 HTTP/2 streams for distinct moon tiles on one connection, each
//!   reset 30 ms after it is sent, against the same 240 completed (fresh server):
//!   CPU seconds after the last reset against the completed run's total.
//! - `bootstrap`: 1 024 distinct `?focus=` bootstraps read whole, then 150 HTTP/2
//!   streams (window 0) that never read theirs, held 10 s: peak RSS.

#![allow(clippy::unwrap_used, clippy::too_many_lines)] // a measuring tool: a failed unwrap is a failed run

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

const KILL_AT: u64 = 6 << 30;

struct Server {
    child: Child,
    url: String,
    peak: Arc<AtomicU64>,
    threads: Arc<AtomicU64>,
    killed: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
}

fn status_field(pid: u32, key: &str) -> Option<u64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    s.lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
}

/// utime + stime of `pid`, in seconds.
fn cpu_seconds(pid: u32) -> f64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let after = s.rsplit_once(')').map_or("", |x| x.1);
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

impl Server {
    fn start(bin: &str, files: &[String], flags: &[String]) -> Self {
        let mut child = Command::new(bin)
            .arg("serve")
            .args(files)
            .args(["--listen", "127.0.0.1:0", "--quiet"])
            .args(flags)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let url = line
            .trim()
            .strip_prefix("listening on ")
            .unwrap_or_else(|| panic!("no listening line: {line:?}"))
            .to_string();
        let (peak, threads) = (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
        let (killed, stop) = (
            Arc::new(AtomicBool::new(false)),
            Arc::new(AtomicBool::new(false)),
        );
        let pid = child.id();
        {
            let (peak, threads, killed, stop) =
                (peak.clone(), threads.clone(), killed.clone(), stop.clone());
            std::thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    let Some(rss) = status_field(pid, "VmRSS:") else {
                        break;
                    };
                    peak.fetch_max(rss * 1024, Ordering::Relaxed);
                    threads.fetch_max(
                        status_field(pid, "Threads:").unwrap_or(0),
                        Ordering::Relaxed,
                    );
                    if rss * 1024 > KILL_AT {
                        killed.store(true, Ordering::Relaxed);
                        let _ = Command::new("kill").args(["-9", &pid.to_string()]).status();
                        break;
                    }
                    std::thread::sleep(Duration::from_millis(10));
                }
            });
        }
        Self {
            child,
            url,
            peak,
            threads,
            killed,
            stop,
        }
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Peak RSS in MiB: the kernel's high-water mark while alive, else the sampled one.
    fn peak_mib(&self) -> u64 {
        status_field(self.pid(), "VmHWM:").map_or(self.peak.load(Ordering::Relaxed), |k| k * 1024)
            >> 20
    }

    fn alive(&mut self) -> bool {
        self.child.try_wait().ok().flatten().is_none() && !self.killed.load(Ordering::Relaxed)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A metric's value summed over series whose text contains every `parts`.
async fn metric(c: &reqwest::Client, url: &str, name: &str, parts: &[&str]) -> Option<f64> {
    let text = c
        .get(format!("{url}/metrics"))
        .send()
        .await
        .ok()?
        .text()
        .await
        .ok()?;
    let v: Vec<f64> = text
        .lines()
        .filter(|l| l.starts_with(name) && parts.iter().all(|p| l.contains(p)))
        .filter_map(|l| l.rsplit_once(' ')?.1.parse().ok())
        .collect();
    (!v.is_empty()).then(|| v.iter().sum())
}

/// Terrain computations the server counted (`None` from a server without the metric).
async fn meshes(c: &reqwest::Client, url: &str) -> Option<f64> {
    metric(c, url, "tessera_compute_total", &["terrain", "started"]).await
}

/// Every available tile of zooms 0..=8 of a dataset's layer.json.
async fn terrain_tiles(c: &reqwest::Client, url: &str, name: &str) -> Vec<String> {
    let text = c
        .get(format!("{url}/v1/datasets/{name}/cesium/layer.json"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    let layer: serde_json::Value = serde_json::from_str(&text).unwrap();
    let mut out = Vec::new();
    for (z, ranges) in layer["available"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
        .take(9)
    {
        for r in ranges.as_array().unwrap() {
            let g = |k: &str| r[k].as_u64().unwrap();
            for y in g("startY")..=g("endY") {
                for x in g("startX")..=g("endX") {
                    out.push(format!("/v1/datasets/{name}/cesium/{z}/{x}/{y}.terrain"));
                }
            }
        }
    }
    out
}

/// A cheap deterministic shuffle (xorshift), so that runs ask for the same tiles.
fn shuffle<T>(v: &mut [T]) {
    let mut s = 0x9E37_79B9_7F4A_7C15_u64;
    for i in (1..v.len()).rev() {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        v.swap(i, (s % (i as u64 + 1)) as usize);
    }
}

fn pct(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// Sends every path at once; returns (status or 0 for a failed request, has Retry-After).
async fn flood(c: &reqwest::Client, url: &str, paths: Vec<String>) -> Vec<(u16, bool)> {
    let tasks: Vec<_> = paths
        .into_iter()
        .map(|p| {
            let (c, u) = (c.clone(), format!("{url}{p}"));
            tokio::spawn(async move {
                match c.get(u).send().await {
                    Ok(r) => {
                        let s = r.status().as_u16();
                        let retry = r.headers().contains_key("retry-after");
                        let _ = r.bytes().await;
                        (s, retry)
                    }
                    Err(_) => (0, false),
                }
            })
        })
        .collect();
    let mut out = Vec::new();
    for t in tasks {
        out.push(t.await.unwrap());
    }
    out
}

fn statuses(r: &[(u16, bool)]) -> String {
    let mut m = std::collections::BTreeMap::new();
    for (s, _) in r {
        *m.entry(*s).or_insert(0) += 1;
    }
    let no_retry = r.iter().filter(|(s, retry)| *s == 503 && !retry).count();
    let parts: Vec<String> = m
        .iter()
        .map(|(s, n)| {
            format!(
                "{}:{n}",
                if *s == 0 {
                    "failed".into()
                } else {
                    s.to_string()
                }
            )
        })
        .collect();
    format!("{} (503 without Retry-After: {no_retry})", parts.join(" "))
}

fn client() -> reqwest::Client {
    reqwest::Client::builder()
        .pool_max_idle_per_host(2048)
        .timeout(Duration::from_secs(90))
        .build()
        .unwrap()
}

async fn distinct(bin: &str, files: &[String], flags: &[String]) {
    let mut srv = Server::start(bin, files, flags);
    let c = client();
    let mut paths = terrain_tiles(&c, &srv.url, "N46E008").await;
    paths.extend(terrain_tiles(&c, &srv.url, "moon").await);
    shuffle(&mut paths);
    paths.truncate(1024);
    let done = Arc::new(AtomicBool::new(false));
    let prober = {
        let (done, url) = (done.clone(), srv.url.clone());
        tokio::spawn(async move {
            let c = reqwest::Client::builder()
                .timeout(Duration::from_secs(90))
                .build()
                .unwrap();
            let mut lat = Vec::new();
            let mut failed = 0;
            while !done.load(Ordering::Relaxed) {
                let t = Instant::now();
                match c
                    .get(format!("{url}/v1/datasets/N46E008/tiles/0/0/0"))
                    .send()
                    .await
                {
                    Ok(r) if r.status() == 200 => {
                        if r.bytes().await.is_err() {
                            failed += 1;
                            continue;
                        }
                        lat.push(t.elapsed().as_secs_f64() * 1e3);
                    }
                    _ => failed += 1,
                }
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
            (lat, failed)
        })
    };
    let t = Instant::now();
    let r = flood(&c, &srv.url, paths).await;
    let wall = t.elapsed().as_secs_f64();
    done.store(true, Ordering::Relaxed);
    let (mut lat, failed) = prober.await.unwrap();
    lat.sort_by(f64::total_cmp);
    let alive = srv.alive();
    let started = meshes(&c, &srv.url).await;
    println!(
        "distinct: 1024 terrain tiles in {wall:.1} s: {}; computations {started:?}; peak RSS {} MiB, {} threads; stored tile during the flood: {} answered, {failed} failed, p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms; alive {alive}",
        statuses(&r),
        srv.peak_mib(),
        srv.threads.load(Ordering::Relaxed),
        lat.len(),
        pct(&lat, 0.5),
        pct(&lat, 0.99),
        lat.last().copied().unwrap_or(f64::NAN),
    );
}

async fn identical(bin: &str, files: &[String], flags: &[String]) {
    for (path, label) in [
        (
            "/v1/datasets/N46E008/cesium/5/33/24.terrain",
            "N46E008 5/33/24",
        ),
        ("/v1/datasets/moon/cesium/5/41/18.terrain", "moon 5/41/18"),
    ] {
        let one = {
            let srv = Server::start(bin, files, flags);
            let base = srv.peak_mib();
            let r = flood(&client(), &srv.url, vec![path.to_string()]).await;
            (srv.peak_mib(), base, cpu_seconds(srv.pid()), statuses(&r))
        };
        let srv = Server::start(bin, files, flags);
        let c = client();
        let r = flood(&c, &srv.url, vec![path.to_string(); 64]).await;
        let started = meshes(&c, &srv.url).await;
        let peak = srv.peak_mib();
        println!(
            "identical {label}: one request peak RSS {} MiB (idle {} MiB), {:.2} CPU-s, {}; 64 requests peak RSS {peak} MiB ({:.2}x), {:.2} CPU-s, {}; computations {started:?}",
            one.0,
            one.1,
            one.2,
            one.3,
            peak as f64 / one.0 as f64,
            cpu_seconds(srv.pid()),
            statuses(&r),
        );
    }
}

/// Waits until the server's CPU time stops growing (1 s unchanged, at most 60 s).
async fn settle(pid: u32) -> f64 {
    let mut last = cpu_seconds(pid);
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let now = cpu_seconds(pid);
        if now - last < 0.02 || Instant::now() > deadline {
            return now;
        }
        last = now;
    }
}

async fn reset(bin: &str, files: &[String], flags: &[String]) {
    let h2 = |timeout: Option<Duration>| {
        let mut b = reqwest::Client::builder().http2_prior_knowledge();
        if let Some(t) = timeout {
            b = b.timeout(t);
        }
        b.build().unwrap()
    };
    let mut paths = {
        let srv = Server::start(bin, files, flags);
        terrain_tiles(&client(), &srv.url, "moon").await
    };
    paths.retain(|p| !p.contains("/cesium/0/") && !p.contains("/cesium/1/"));
    shuffle(&mut paths);
    paths.truncate(240);
    // Completed: the cost of the same requests when every one is answered (a few
    // at a time, so that none is refused as busy).
    let completed = {
        let srv = Server::start(bin, files, flags);
        let before = cpu_seconds(srv.pid());
        let c = h2(None);
        let mut r = Vec::new();
        for chunk in paths.chunks(2) {
            r.extend(flood(&c, &srv.url, chunk.to_vec()).await);
        }
        (settle(srv.pid()).await - before, statuses(&r))
    };
    let mut srv = Server::start(bin, files, flags);
    let before = cpu_seconds(srv.pid());
    let c = h2(Some(Duration::from_millis(30)));
    let t = Instant::now();
    let r = flood(&c, &srv.url, paths).await;
    let sent = t.elapsed().as_secs_f64();
    let at_reset = cpu_seconds(srv.pid());
    let end = settle(srv.pid()).await;
    let cancelled = metric(
        &client(),
        &srv.url,
        "tessera_compute_total",
        &["terrain", "cancelled"],
    )
    .await;
    println!(
        "reset: 240 moon streams on one HTTP/2 connection, each reset after 30 ms, sent in {sent:.2} s ({}): CPU {:.2} s until the last reset, {:.2} s after it ({:.1}% of the {:.2} s the same requests cost completed: {}); cancelled {cancelled:?}; peak RSS {} MiB, {} threads; alive {}",
        statuses(&r),
        at_reset - before,
        end - at_reset,
        100.0 * (end - at_reset) / completed.0,
        completed.0,
        completed.1,
        srv.peak_mib(),
        srv.threads.load(Ordering::Relaxed),
        srv.alive(),
    );
}

async fn bootstrap(bin: &str, files: &[String], flags: &[String]) {
    let foci: Vec<String> = (0..1024)
        .map(|i| {
            let (u, v) = ((i % 32) as f64 / 32.0 + 0.01, (i / 32) as f64 / 32.0 + 0.01);
            format!("/v1/datasets/moon/bootstrap?focus={u:.4},{v:.4}")
        })
        .collect();
    {
        let mut srv = Server::start(bin, files, flags);
        let t = Instant::now();
        let r = flood(&client(), &srv.url, foci.clone()).await;
        println!(
            "bootstrap: 1024 distinct foci read whole in {:.1} s: {}; peak RSS {} MiB; alive {}",
            t.elapsed().as_secs_f64(),
            statuses(&r),
            srv.peak_mib(),
            srv.alive()
        );
    }
    let mut srv = Server::start(bin, files, flags);
    let c = reqwest::Client::builder()
        .http2_prior_knowledge()
        .http2_initial_stream_window_size(Some(0))
        .build()
        .unwrap();
    let tasks: Vec<_> = foci[..150]
        .iter()
        .map(|p| {
            let (c, u) = (c.clone(), format!("{}{p}", srv.url));
            tokio::spawn(async move { c.get(u).send().await })
        })
        .collect();
    // The responses are kept (dropping one would reset its stream): their bodies stay
    // unread.
    let mut held = Vec::new();
    for t in tasks {
        held.push(t.await.unwrap());
    }
    tokio::time::sleep(Duration::from_secs(10)).await;
    let status = |s: u16| {
        held.iter()
            .filter(|r| r.as_ref().is_ok_and(|r| r.status().as_u16() == s))
            .count()
    };
    let (ok, busy) = (status(200), status(503));
    let rss = status_field(srv.pid(), "VmRSS:").unwrap_or(0) >> 10;
    let reserved = metric(&client(), &srv.url, "tessera_compute_memory_bytes", &[]).await;
    println!(
        "bootstrap: 150 non-reading HTTP/2 streams (window 0), held 10 s: {ok} heads 200, {busy} 503; RSS while held {rss} MiB (reserved {:.0} MiB), peak {} MiB; alive {}",
        reserved.unwrap_or(f64::NAN) / f64::from(1 << 20),
        srv.peak_mib(),
        srv.alive()
    );
    drop(held);
    drop(c);
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [bin, n46, moon, flags @ ..] = args.as_slice() else {
        eprintln!(
            "usage: abuse SERVER_BIN N46E008.tess moon.tess [SERVE FLAGS...] (SCENARIOS=distinct,identical,reset,bootstrap)"
        );
        std::process::exit(2);
    };
    let files = [n46.clone(), moon.clone()];
    // reqwest's TLS has no provider of its own here (rustls-no-provider, as the server).
    let _ = rustls::crypto::ring::default_provider().install_default();
    let which =
        std::env::var("SCENARIOS").unwrap_or_else(|_| "distinct,identical,reset,bootstrap".into());
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        for s in which.split(',') {
            match s {
                "distinct" => distinct(bin, &files, flags).await,
                "identical" => identical(bin, &files, flags).await,
                "reset" => reset(bin, &files, flags).await,
                "bootstrap" => bootstrap(bin, &files, flags).await,
                other => eprintln!("unknown scenario {other}"),
            }
        }
    });
}

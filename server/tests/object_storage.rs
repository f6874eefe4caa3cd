//! Serving and building pyramids in object storage, against a real S3 server
//! (`moto_server`) on loopback that each test starts itself: every record served
//! from S3 equals the local file's; one ranged GET per cold Morton range; the block
//! cache's hits; a store killed and restarted (503 with a reason, then 200); a
//! delaying proxy's latency in `/metrics`; a truncated or replaced object detected;
//! `build -o s3://…` uploads exactly the verified pyramid, or nothing.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

#[allow(dead_code)] // each test binary uses some of the shared helpers
mod serve_support;

use serve_support::{Server, bin, dem_pyramid, fixtures, metric, parse_metrics};
use std::path::Path;
use std::time::Duration;
use tessera_shared::s3_server::S3Server;
use tessera_shared::{Level, Pyramid};

const BUCKET: &str = "tessera";

fn refs(env: &[(String, String)]) -> Vec<(&str, &str)> {
    env.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect()
}

/// A store holding the shared `synth` fixture as `synth.tess`, put with one PUT.
fn store_with_synth() -> Option<(S3Server, Vec<u8>)> {
    let s3 = S3Server::start_or_skip()?;
    s3.create_bucket(BUCKET);
    let bytes = std::fs::read(&fixtures().synth).unwrap();
    s3.put(BUCKET, "synth.tess", &bytes);
    Some((s3, bytes))
}

fn store_metrics(server: &Server) -> Vec<serve_support::Sample> {
    parse_metrics(&server.get("/metrics").expect(200).text())
}

fn gets(server: &Server) -> f64 {
    let m = store_metrics(server);
    m.iter()
        .filter(|s| {
            s.name == "tessera_store_requests_total"
                && s.labels.get("op").map(String::as_str) == Some("get")
        })
        .map(|s| s.value)
        .sum()
}

/// Every level's whole Morton range, in requests the server's limits allow.
fn all_ranges(p: &Pyramid<tessera_shared::FileSource>) -> Vec<(Level, String)> {
    let mut out = Vec::new();
    for level in p.geometry().levels() {
        let slots = level.tile_slots();
        let mut a = 0u64;
        while a < slots {
            let z = (a + 1024).min(slots) - 1;
            out.push((level, format!("{a}-{z}")));
            a = z + 1;
        }
    }
    out
}

#[test]
fn every_record_served_from_s3_equals_the_local_files() {
    let Some((s3, bytes)) = store_with_synth() else {
        return;
    };
    let f = fixtures();
    let e = s3.env();
    let remote = Server::start_with(&[Path::new("s3://tessera/synth.tess")], &[], &refs(&e));
    let local = Server::start(&[&f.synth], &[]);
    let p = serve_support::open(&f.synth);
    for (level, ranges) in all_ranges(&p) {
        for kind in ["tiles", "errors"] {
            let path = format!("/v1/datasets/synth/levels/{level}/{kind}?ranges={ranges}");
            let a = remote.get(&path).expect(200);
            let b = local.get(&path).expect(200);
            assert_eq!(a.body, b.body, "{path}: S3 and the local file differ");
            assert_eq!(a.header("etag"), b.header("etag"), "{path}");
        }
    }
    // Single tiles, metadata and the raw file with a Range.
    for path in [
        "/v1/datasets/synth",
        "/v1/datasets/synth/tiles/2/1/3",
        "/v1/datasets/synth/tilejson.json",
    ] {
        // One Host for both: the TileJSON's absolute URLs are built from it.
        let host = [("host", "tiles.test")];
        assert_eq!(
            remote.get_with(path, &host).expect(200).body,
            local.get_with(path, &host).expect(200).body,
            "{path}"
        );
    }
    let r = remote.get_with(
        "/v1/datasets/synth/pyramid",
        &[("range", "bytes=1000-250000")],
    );
    let r = r.expect(206);
    assert_eq!(r.body, bytes[1000..=250_000]);
    // Everything was fetched once; a second pass is served from the block cache.
    let (cold_gets, m) = (gets(&remote), store_metrics(&remote));
    let misses = metric(&m, "tessera_block_cache_misses_total");
    assert!(
        cold_gets >= 1.0 && misses >= 1.0,
        "gets {cold_gets}, misses {misses}"
    );
    for (level, ranges) in all_ranges(&p) {
        remote
            .get(&format!(
                "/v1/datasets/synth/levels/{level}/tiles?ranges={ranges}"
            ))
            .expect(200);
    }
    let m = store_metrics(&remote);
    assert_eq!(gets(&remote), cold_gets, "the warm pass went to the store");
    assert!(metric(&m, "tessera_block_cache_hits_total") > 0.0);
    assert!(metric(&m, "tessera_block_cache_bytes") > 0.0);
    assert_eq!(
        metric(&m, "tessera_block_cache_capacity_bytes"),
        f64::from(256u32 << 20)
    );
    let ready = remote.get("/healthz/ready").expect(200).json();
    assert_eq!(ready["status"], "ready");
}

#[test]
fn a_cold_morton_range_is_one_ranged_get() {
    let Some((s3, _)) = store_with_synth() else {
        return;
    };
    let e = s3.env();
    let p = serve_support::open(&fixtures().synth);
    let finest = p.geometry().finest();
    for cache in ["0", "64"] {
        let server = Server::start_with(
            &[Path::new("s3://tessera/synth.tess")],
            &["--block-cache-mib", cache],
            &refs(&e),
        );
        // Three ranges: two touching (coalesced into one read) and one apart.
        let requests = [
            ("ranges=16-31", 1.0),
            ("ranges=64-79,80-95", 1.0),
            ("ranges=128-131,200-203", 2.0),
        ];
        for (q, want) in requests {
            let before = gets(&server);
            server
                .get(&format!("/v1/datasets/synth/levels/{finest}/tiles?{q}"))
                .expect(200);
            assert_eq!(
                gets(&server) - before,
                want,
                "--block-cache-mib {cache}: {q}"
            );
        }
    }
}

#[test]
fn a_killed_store_is_a_503_with_a_reason_until_it_is_back() {
    let Some((mut s3, bytes)) = store_with_synth() else {
        return;
    };
    let e = s3.env();
    // No block cache, so every request goes to the store.
    let server = Server::start_with(
        &[Path::new("s3://tessera/synth.tess")],
        &["--block-cache-mib", "0"],
        &refs(&e),
    );
    let path = "/v1/datasets/synth/levels/3/tiles?ranges=0-63";
    let good = server.get(path).expect(200).body;
    s3.kill();
    let down = server.get(path);
    let reason = down.error(503);
    assert!(reason.contains("s3://tessera/synth.tess"), "{reason}");
    assert!(server.get("/v1/datasets/synth/tiles/3/0/0").status == 503);
    let ready = server.get("/healthz/ready");
    assert_eq!(ready.status, 503);
    let why = ready.json();
    assert!(
        why["failing"]["synth"]
            .as_str()
            .unwrap()
            .contains("s3://tessera/synth.tess"),
        "{why}"
    );
    server.get("/healthz/live").expect(200);
    server.get("/healthz").expect(200);
    // Back with the same object (moto keeps nothing, so it is put again, the same bytes
    // with the same ETag): the same dataset answers again, without a restart.
    s3.restart();
    s3.create_bucket(BUCKET);
    s3.put(BUCKET, "synth.tess", &bytes);
    assert_eq!(server.get(path).expect(200).body, good);
    server.get("/healthz/ready").expect(200);
    let m = store_metrics(&server);
    let failed: f64 = m
        .iter()
        .filter(|s| {
            s.name == "tessera_store_requests_total"
                && s.labels.get("outcome").map(String::as_str) == Some("error")
        })
        .map(|s| s.value)
        .sum();
    assert!(failed >= 2.0, "failed store requests counted: {failed}");
    assert!(!server.log().contains("panicked"));
}

#[test]
fn a_slow_store_shows_in_the_get_latency_metric() {
    let Some((s3, _)) = store_with_synth() else {
        return;
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let hold = Duration::from_millis(150);
    let proxy = rt
        .block_on(tessera_proxy::Proxy::start(tessera_proxy::Config {
            responses: tessera_proxy::Responses::Delay(tessera_proxy::Delay::new(hold)),
            ..tessera_proxy::Config::new(s3.addr())
        }))
        .unwrap();
    let e = s3.env_for(&format!("http://{}", proxy.addr()));
    let server = Server::start_with(
        &[Path::new("s3://tessera/synth.tess")],
        &["--block-cache-mib", "0"],
        &refs(&e),
    );
    for q in ["0-15", "16-31", "32-47", "48-63"] {
        server
            .get(&format!("/v1/datasets/synth/levels/3/tiles?ranges={q}"))
            .expect(200);
    }
    let m = store_metrics(&server);
    let count = metric(&m, "tessera_store_get_duration_seconds_count");
    let sum = metric(&m, "tessera_store_get_duration_seconds_sum");
    assert!(count >= 4.0, "{count} GETs");
    assert!(
        sum / count >= hold.as_secs_f64(),
        "mean GET {:.3} s behind a {hold:?} proxy",
        sum / count
    );
    // Nothing was held on the way to the client: the held responses are the store's.
    assert!(proxy.stats().held >= 4);
}

#[test]
fn a_truncated_object_is_refused_and_a_replaced_one_is_noticed() {
    let Some((s3, bytes)) = store_with_synth() else {
        return;
    };
    let e = s3.env();
    s3.put(BUCKET, "cut.tess", &bytes[..bytes.len() - 4096]);
    let err = serve_support::serve_must_refuse_with(&["s3://tessera/cut.tess"], &refs(&e));
    assert!(err.contains("s3://tessera/cut.tess"), "{err}");
    let err = serve_support::serve_must_refuse_with(&["s3://tessera/missing.tess"], &refs(&e));
    assert!(err.contains("s3://tessera/missing.tess"), "{err}");
    // Replaced under a running server: the next read from the store fails its ETag
    // condition, and the dataset answers 503 until a reload, never mixed bytes.
    let server = Server::start_with(
        &[Path::new("s3://tessera/synth.tess")],
        &["--block-cache-mib", "0"],
        &refs(&e),
    );
    server
        .get("/v1/datasets/synth/levels/2/tiles?ranges=0-15")
        .expect(200);
    let mut other = bytes.clone();
    let n = other.len();
    other[n - 10] ^= 0xff;
    s3.put(BUCKET, "synth.tess", &other);
    let reason = server
        .get("/v1/datasets/synth/levels/3/tiles?ranges=0-63")
        .error(503);
    assert!(reason.contains("changed"), "{reason}");
    assert_eq!(server.get("/healthz/ready").status, 503);
    // The reload reopens the object as it is now.
    s3.put(BUCKET, "synth.tess", &bytes);
    server.signal("HUP");
    let mut ok = false;
    for _ in 0..100 {
        if server
            .get("/v1/datasets/synth/levels/3/tiles?ranges=0-63")
            .status
            == 200
        {
            ok = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(ok, "the reloaded dataset answers");
}

#[test]
fn build_uploads_the_verified_pyramid_or_nothing() {
    let Some(s3) = S3Server::start_or_skip() else {
        return;
    };
    s3.create_bucket(BUCKET);
    let e = s3.env();
    let dir = tempfile::tempdir().unwrap();
    let local = dir.path().join("up.tess");
    let run = |input: &str, out: &str| {
        bin()
            .args(["build", input, "-o", out, "--tile-size", "128", "--quiet"])
            .envs(e.iter().map(|(k, v)| (k.as_str(), v.as_str())))
            .output()
            .unwrap()
    };
    let o = run("synthetic:1025:3", local.to_str().unwrap());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = run("synthetic:1025:3", "s3://tessera/dir/up.tess");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        s3.get(BUCKET, "dir/up.tess").expect("the object exists"),
        std::fs::read(&local).unwrap(),
        "the uploaded object is the local build, byte for byte"
    );
    // A build that fails leaves no object; a bucket that does not exist is an error
    // naming the URL.
    let o = run("/nonexistent/dem.tif", "s3://tessera/bad.tess");
    assert!(!o.status.success());
    assert!(s3.get(BUCKET, "bad.tess").is_none());
    let o = run("synthetic:1025:3", "s3://no-such-bucket/x.tess");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("s3://no-such-bucket/x.tess"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn http_and_file_urls_serve_the_same_records() {
    let Some((s3, _)) = store_with_synth() else {
        return;
    };
    let f = fixtures();
    let local = Server::start(&[&f.synth], &[]);
    // Plain HTTP with Range (object_store's HTTP store; moto answers anonymous GETs),
    // and a file:// URL.
    let http = format!("{}/tessera/synth.tess", s3.endpoint());
    let file = format!("file://{}", f.synth.canonicalize().unwrap().display());
    for url in [http, file] {
        let remote = Server::start(&[Path::new(&url)], &[]);
        for path in [
            "/v1/datasets/synth",
            "/v1/datasets/synth/levels/3/tiles?ranges=0-63",
            "/v1/datasets/synth/levels/4/errors?ranges=100-255",
            "/v1/datasets/synth/tiles/2/1/3",
        ] {
            assert_eq!(
                remote.get(path).expect(200).body,
                local.get(path).expect(200).body,
                "{url}: {path}"
            );
        }
        remote.get("/healthz/ready").expect(200);
    }
}

/// Elevation queries read a pyramid in object storage as they read a local one: the
/// server's answers and `tessera-server query s3://…`'s equal the local file's.
#[test]
fn elevations_from_s3_equal_the_local_files() {
    let Some(local_file) = dem_pyramid("N46E008.tif", 512) else {
        return;
    };
    let Some(s3) = S3Server::start_or_skip() else {
        return;
    };
    s3.create_bucket(BUCKET);
    s3.put(BUCKET, "N46E008.tess", &std::fs::read(&local_file).unwrap());
    let e = s3.env();
    let remote = Server::start_with(&[Path::new("s3://tessera/N46E008.tess")], &[], &refs(&e));
    let local = Server::start(&[&local_file], &[]);
    let points: Vec<[f64; 2]> = (0..1000)
        .map(|i| {
            [
                46.0 + f64::from(i) * 0.000_997,
                8.0 + f64::from(i * 7 % 1000) * 0.000_999,
            ]
        })
        .collect();
    let body =
        serde_json::to_vec(&serde_json::json!({"locations": points, "interpolation": "cubic"}))
            .unwrap();
    let path = "/v1/datasets/N46E008/elevation";
    let a = remote
        .post(path, "application/json", body.clone())
        .expect(200)
        .json();
    let b = local
        .post(path, "application/json", body)
        .expect(200)
        .json();
    assert_eq!(a, b, "S3 and the local file answer differently");
    assert!(gets(&remote) >= 1.0, "nothing was read from the store");
    let o = bin()
        .args([
            "query",
            "s3://tessera/N46E008.tess",
            "--at",
            "46.5,8.1|46.61,8.237",
            "--format",
            "json",
        ])
        .envs(e.iter().map(|(k, v)| (k.as_str(), v.as_str())))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cli: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let http = local
        .get(&format!("{path}?locations=46.5,8.1|46.61,8.237"))
        .expect(200)
        .json();
    assert_eq!(cli, http);
}

/// `export s3://… --pmtiles s3://…`: read from the store, uploaded to it, byte for
/// byte the local export of the local file; a failed export leaves no object.
#[test]
fn export_reads_from_and_uploads_to_the_store() {
    let Some(local_file) = dem_pyramid("N46E008.tif", 512) else {
        return;
    };
    let Some(s3) = S3Server::start_or_skip() else {
        return;
    };
    s3.create_bucket(BUCKET);
    s3.put(BUCKET, "N46E008.tess", &std::fs::read(&local_file).unwrap());
    let e = s3.env();
    let dir = tempfile::tempdir().unwrap();
    let local = dir.path().join("n46.pmtiles");
    let run = |input: &str, out: &str, more: &[&str]| {
        bin()
            .args([
                "export",
                input,
                "--pmtiles",
                out,
                "--quiet",
                "--minzoom",
                "8",
            ])
            .args(more)
            .envs(e.iter().map(|(k, v)| (k.as_str(), v.as_str())))
            .output()
            .unwrap()
    };
    let o = run(local_file.to_str().unwrap(), local.to_str().unwrap(), &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = run(
        "s3://tessera/N46E008.tess",
        "s3://tessera/web/n46.pmtiles",
        &[],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        s3.get(BUCKET, "web/n46.pmtiles")
            .expect("the archive was uploaded"),
        std::fs::read(&local).unwrap(),
        "the uploaded archive is the local export, byte for byte"
    );
    let o = run(
        "s3://tessera/N46E008.tess",
        "s3://tessera/web/bad.pmtiles",
        &["--maxzoom", "30"],
    );
    assert!(!o.status.success());
    assert!(
        s3.get(BUCKET, "web/bad.pmtiles").is_none(),
        "a failed export left an object"
    );
}

//! `build` reading its inputs from object storage and HTTP (DECISIONS.md "Inputs in
//! object storage"), against a real S3 server (`moto_server`) and a real nginx on
//! loopback: N46E008 cut by GDAL into 64 Cloud-Optimized GeoTIFF pieces (64² tiles,
//! deflate, with overviews) builds byte for byte as the same pieces on local disk do,
//! listed by prefix, by glob, from a list of URLs and through a VRT naming them, while
//! fetching only the full-resolution tiles (no overview) and a small header; a striped
//! GeoTIFF is fetched whole into a spool; a missing key, an unreachable store and an
//! object replaced while the build runs (behind a delaying proxy, so the test can
//! act between the build's two openings of it) are one-line errors naming the URL,
//! with nothing left behind.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

mod gdal;
#[path = "../../tests/src/nginx.rs"]
#[allow(dead_code)] // the e2e tests' nginx, of which this binary uses the static host
mod nginx;

use gdal::{gdal_or_skip, path_str, run};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use tessera_shared::s3_server::S3Server;
use tessera_shared::testdata;

const BUCKET: &str = "dem";

/// The 64 pieces, in a folder of their own.
struct Pieces {
    dir: PathBuf,
    names: Vec<String>,
    /// Bytes of the full-resolution tiles of every piece (its first image's
    /// `TileByteCounts`), overviews and headers not counted.
    tile_bytes: u64,
}

/// The pieces, made once for every test of this binary, in cargo's folder for test
/// data under this process's id (two runs at once must not share one); the folders of
/// runs that have ended are removed first.
fn pieces() -> Option<&'static Pieces> {
    static P: std::sync::OnceLock<Option<Pieces>> = std::sync::OnceLock::new();
    P.get_or_init(make_pieces).as_ref()
}

fn make_pieces() -> Option<Pieces> {
    if !gdal_or_skip() {
        return None;
    }
    let n46 = testdata::dem_or_skip("N46E008.tif")?;
    let root = Path::new(env!("CARGO_TARGET_TMPDIR"));
    for old in std::fs::read_dir(root).into_iter().flatten().flatten() {
        let name = old.file_name().to_string_lossy().into_owned();
        if let Some(pid) = name.strip_prefix("remote_inputs_pieces-")
            && !Path::new("/proc").join(pid).exists()
        {
            let _ = std::fs::remove_dir_all(old.path());
        }
    }
    let dir = root.join(format!("remote_inputs_pieces-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut names = Vec::new();
    let mut tile_bytes = 0;
    // 1201 samples: seven pieces of 150 and one of 151 on each side.
    for j in 0..8u32 {
        for i in 0..8u32 {
            let size = |k: u32| if k == 7 { 151 } else { 150 };
            let name = format!("p{j}{i}.tif");
            let out = dir.join(&name);
            run(
                "gdal_translate",
                &[
                    "-q",
                    "-of",
                    "COG",
                    "-co",
                    "BLOCKSIZE=64",
                    "-co",
                    "COMPRESS=DEFLATE",
                    "-srcwin",
                    &(i * 150).to_string(),
                    &(j * 150).to_string(),
                    &size(i).to_string(),
                    &size(j).to_string(),
                    path_str(&n46),
                    path_str(&out),
                ],
            );
            tile_bytes += main_tile_bytes(&out);
            names.push(name);
        }
    }
    Some(Pieces {
        dir,
        names,
        tile_bytes,
    })
}

/// The stored bytes of a TIFF's first image's tiles, and a check that it has
/// overviews (further images) that a reader could wrongly fetch.
fn main_tile_bytes(path: &Path) -> u64 {
    let mut d = tiff::decoder::Decoder::new(std::fs::File::open(path).unwrap()).unwrap();
    let counts = d.get_tag_u64_vec(tiff::tags::Tag::TileByteCounts).unwrap();
    assert!(d.more_images(), "{}: no overviews", path.display());
    counts.iter().sum()
}

fn build(input: &[&str], out: &Path, env: &[(String, String)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .arg("build")
        .args(input)
        .args(["--quiet", "-o"])
        .arg(out)
        .envs(env.iter().map(|(k, v)| (k.as_str(), v.as_str())))
        .output()
        .unwrap()
}

fn built(input: &[&str], out: &Path, env: &[(String, String)]) -> (Vec<u8>, String) {
    let o = build(input, out, env);
    assert!(
        o.status.success(),
        "build {input:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    (
        std::fs::read(out).unwrap(),
        String::from_utf8(o.stdout).unwrap(),
    )
}

/// `(ranged, spooled)` bytes from the build's "read … bytes of inputs" line.
fn fetched(stdout: &str) -> (u64, u64) {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("read "))
        .unwrap_or_else(|| panic!("no fetched-bytes line in {stdout:?}"));
    let numbers: Vec<u64> = line
        .split(|c: char| !c.is_ascii_digit())
        .filter_map(|t| t.parse().ok())
        .collect();
    assert_eq!(numbers.len(), 3, "{line}");
    assert_eq!(numbers[0], numbers[1] + numbers[2], "{line}");
    (numbers[1], numbers[2])
}

fn store_with(p: &Pieces) -> Option<S3Server> {
    let s3 = S3Server::start_or_skip()?;
    s3.create_bucket(BUCKET);
    for n in &p.names {
        s3.put(
            BUCKET,
            &format!("pieces/{n}"),
            &std::fs::read(p.dir.join(n)).unwrap(),
        );
    }
    Some(s3)
}

#[test]
fn a_cog_mosaic_in_s3_builds_as_on_local_disk_reading_only_its_tiles() {
    let Some(p) = pieces() else { return };
    let Some(s3) = store_with(p) else { return };
    let env = s3.env();
    let out = tempfile::tempdir().unwrap();
    let local_dir = format!("{}/", p.dir.display());
    let (local, _) = built(&[&local_dir], &out.path().join("local.tess"), &[]);

    let (by_prefix, stdout) = built(
        &[&format!("s3://{BUCKET}/pieces/")],
        &out.path().join("prefix.tess"),
        &env,
    );
    assert!(
        by_prefix == local,
        "built from s3://…/pieces/ differs from the local build"
    );
    let (ranged, spooled) = fetched(&stdout);
    assert_eq!(spooled, 0, "COGs are read in place");
    // Every full-resolution tile, once, plus a header per piece; no overview.
    assert!(
        ranged >= p.tile_bytes && ranged as f64 <= 1.1 * p.tile_bytes as f64,
        "fetched {ranged} bytes for {} bytes of tiles ({:.3}×)",
        p.tile_bytes,
        ranged as f64 / p.tile_bytes as f64
    );
    eprintln!(
        "64 COG pieces from S3: {ranged} bytes fetched for {} bytes of full-resolution tiles ({:.3}×)",
        p.tile_bytes,
        ranged as f64 / p.tile_bytes as f64
    );

    // By glob, and from a list naming URLs: the same pieces in the same order.
    let (by_glob, _) = built(
        &[&format!("s3://{BUCKET}/pieces/p*.tif")],
        &out.path().join("glob.tess"),
        &env,
    );
    assert!(by_glob == local, "built from a glob differs");
    let list = out.path().join("list.txt");
    let urls: Vec<String> = p
        .names
        .iter()
        .map(|n| format!("s3://{BUCKET}/pieces/{n}"))
        .collect();
    std::fs::write(&list, urls.join("\n")).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .args(["build", "--inputs"])
        .arg(&list)
        .args(["--quiet", "-o"])
        .arg(out.path().join("list.tess"))
        .envs(env.iter().map(|(k, v)| (k.as_str(), v.as_str())))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        std::fs::read(out.path().join("list.tess")).unwrap() == local,
        "built from a list of URLs differs"
    );
}

#[test]
fn http_inputs_vrts_naming_urls_and_spooled_non_cogs() {
    let Some(p) = pieces() else { return };
    let n46 = testdata::dem_or_skip("N46E008.tif").unwrap();
    // The web server's folder: the pieces, the striped original and a VRT (the other
    // tests build the pieces' folder as it is).
    let www = tempfile::tempdir().unwrap();
    for n in &p.names {
        std::fs::copy(p.dir.join(n), www.path().join(n)).unwrap();
    }
    std::fs::copy(&n46, www.path().join("N46E008.tif")).unwrap();
    let Some(web) = nginx::Nginx::serve(www.path()) else {
        return;
    };
    let base = format!("http://{}", web.addr());
    let out = tempfile::tempdir().unwrap();

    // A striped GeoTIFF (N46E008 as USGS ships it) is fetched whole, once.
    let (local, _) = built(&[path_str(&n46)], &out.path().join("local.tess"), &[]);
    let (remote, stdout) = built(
        &[&format!("{base}/N46E008.tif")],
        &out.path().join("remote.tess"),
        &[],
    );
    assert!(
        remote == local,
        "the spooled striped GeoTIFF built differently"
    );
    let size = std::fs::metadata(&n46).unwrap().len();
    let (ranged, spooled) = fetched(&stdout);
    assert_eq!(spooled, size, "fetched whole exactly once");
    assert!(
        ranged < 16 << 10,
        "{ranged} bytes by range to find it is not tiled"
    );

    // A VRT whose sources are the pieces' URLs (relative names resolved against a
    // remote VRT's URL, absolute ones and GDAL's /vsicurl/ names as they are).
    let names: Vec<PathBuf> = p.names.iter().map(|n| www.path().join(n)).collect();
    let vrt = www.path().join("all.vrt");
    let mut args = vec!["-q".to_string(), path_str(&vrt).to_string()];
    args.extend(names.iter().map(|n| path_str(n).to_string()));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    run("gdalbuildvrt", &args);
    let (local_vrt, _) = built(&[path_str(&vrt)], &out.path().join("lv.tess"), &[]);
    let text = std::fs::read_to_string(&vrt).unwrap();
    let relative = r#"relativeToVRT="1">"#;
    assert!(
        text.contains(relative),
        "gdalbuildvrt wrote no relative names: {text}"
    );
    let remote_vrt = out.path().join("all.vrt");
    std::fs::write(
        &remote_vrt,
        text.replacen(
            relative,
            &format!(r#"relativeToVRT="0">/vsicurl/{base}/"#),
            1,
        )
        .replace(relative, &format!(r#"relativeToVRT="0">{base}/"#)),
    )
    .unwrap();
    let (via_urls, _) = built(&[path_str(&remote_vrt)], &out.path().join("rv.tess"), &[]);
    assert!(via_urls == local_vrt, "a VRT naming URLs built differently");
    let (remote_whole, _) = built(
        &[&format!("{base}/all.vrt")],
        &out.path().join("rw.tess"),
        &[],
    );
    assert!(
        remote_whole == local_vrt,
        "a VRT read over HTTP built differently"
    );

    // HTTP cannot be listed.
    let o = build(&[&format!("{base}/")], &out.path().join("x.tess"), &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("cannot be listed"),
        "{err}"
    );
}

#[test]
fn missing_objects_and_unreachable_stores_are_errors_naming_the_url() {
    let Some(s3) = S3Server::start_or_skip() else {
        return;
    };
    s3.create_bucket(BUCKET);
    let out = tempfile::tempdir().unwrap();
    let target = out.path().join("x.tess");
    let one_line = |o: &Output, url: &str, what: &str| {
        assert_eq!(o.status.code(), Some(1));
        let err = String::from_utf8_lossy(&o.stderr);
        let last = err.lines().last().unwrap_or("");
        assert!(
            last.contains(url) && last.contains(what),
            "want {url} and {what:?} in the error: {err}"
        );
        assert!(!target.exists(), "an output was left behind");
        let left: Vec<_> = std::fs::read_dir(out.path()).unwrap().collect();
        assert!(left.is_empty(), "left behind: {left:?}");
    };
    let url = format!("s3://{BUCKET}/no/such.tif");
    one_line(&build(&[&url], &target, &s3.env()), &url, "no such object");
    let url = format!("s3://{BUCKET}/empty/");
    one_line(
        &build(&[&url], &target, &s3.env()),
        &url,
        "holds no DEM files",
    );
    // A store nobody answers on.
    let closed = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let dead = format!("http://{}", closed.local_addr().unwrap());
    drop(closed);
    let url = format!("s3://{BUCKET}/p.tif");
    one_line(
        &build(&[&url], &target, &s3.env_for(&dead)),
        &url,
        "cannot open the object",
    );
}

#[test]
fn an_object_replaced_during_the_build_stops_it_naming_the_url() {
    let Some(p) = pieces() else { return };
    let Some(s3) = store_with(p) else { return };
    // Every store answer held 20 ms, and the last piece (read last, at the mosaic's
    // bottom right) replaced once the build has opened it to plan: the build reads
    // every other piece before it opens that one again.
    let rt = tokio::runtime::Runtime::new().unwrap();
    let log = tessera_proxy::RequestLog::default();
    let proxy = rt
        .block_on(tessera_proxy::Proxy::start(tessera_proxy::Config {
            responses: tessera_proxy::Responses::Delay(tessera_proxy::Delay::new(
                std::time::Duration::from_millis(20),
            )),
            requests: Some(log.clone()),
            ..tessera_proxy::Config::new(s3.addr())
        }))
        .unwrap();
    let env = s3.env_for(&format!("http://{}", proxy.addr()));
    let out = tempfile::tempdir().unwrap();
    let target = out.path().join("x.tess");
    let child = Command::new(env!("CARGO_BIN_EXE_tessera-server"))
        .args(["build", &format!("s3://{BUCKET}/pieces/"), "--quiet", "-o"])
        .arg(&target)
        .envs(env.iter().map(|(k, v)| (k.as_str(), v.as_str())))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let last = format!("/{BUCKET}/pieces/p77.tif");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    while !log.targets().iter().any(|t| t.starts_with(&last)) {
        assert!(std::time::Instant::now() < deadline, "p77.tif never read");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let mut changed = std::fs::read(p.dir.join("p77.tif")).unwrap();
    let end = changed.len() - 1;
    changed[end] ^= 1;
    s3.put(BUCKET, "pieces/p77.tif", &changed);
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let line = err.lines().last().unwrap_or("");
    assert!(
        line.contains(&format!("s3://{BUCKET}/pieces/p77.tif")) && line.contains("changed"),
        "{err}"
    );
    assert!(!target.exists(), "an output was left behind");
    let left: Vec<_> = std::fs::read_dir(out.path()).unwrap().collect();
    assert!(left.is_empty(), "left behind: {left:?}");
}

/// An input that must be fetched whole (not a tiled GeoTIFF) and is larger than the
/// free space of TMPDIR is refused before a byte of it is fetched, naming the URL and
/// the space, with nothing left in TMPDIR. The object is a sparse file twice the size
/// of the free space, served by a real nginx (its blocks are never written).
#[test]
fn a_non_cog_larger_than_tmpdir_is_refused_before_fetching() {
    let www = tempfile::tempdir().unwrap();
    let scratch = tempfile::tempdir().unwrap();
    let st = rustix::fs::statvfs(scratch.path()).unwrap();
    let free = st.f_bavail * st.f_frsize;
    let huge = std::fs::File::create(www.path().join("N46E008.hgt")).unwrap();
    if huge.set_len(2 * free).is_err() {
        eprintln!(
            "SKIPPED: the file system holds no sparse file of {} bytes",
            2 * free
        );
        return;
    }
    let Some(web) = nginx::Nginx::serve(www.path()) else {
        return;
    };
    let url = format!("http://{}/N46E008.hgt", web.addr());
    let out = scratch.path().join("out.tess");
    let env = [(
        "TMPDIR".to_string(),
        scratch.path().to_string_lossy().into_owned(),
    )];
    let o = build(&[&url], &out, &env);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "built from {url}: {err}");
    let lines: Vec<&str> = err.trim().lines().collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(
        lines[0].contains(&url) && lines[0].contains("bytes free") && lines[0].contains("TMPDIR"),
        "{err}"
    );
    let left: Vec<_> = std::fs::read_dir(scratch.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert!(left.is_empty(), "left in TMPDIR: {left:?}");
}

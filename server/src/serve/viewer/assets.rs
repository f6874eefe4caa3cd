//! The viewer's static files under `/viewer/assets/{lib}/…`:
//!
//! - `tessera/`: the viewer's own script and style sheet, compiled into the binary;
//! - `maplibre/` and `cesium/`: MapLibre GL JS and CesiumJS, exactly the npm versions
//!   the browser tests pin (tests/browser/package-lock.json), from a directory that
//!   `server/viewer-assets.sh` prepares. They are not in the binary (CesiumJS's build
//!   is 23 MB; DECISIONS.md "Real clients").
//!
//! A request path can never leave the directory: `..`, `.`, empty and hidden
//! segments, backslashes and NUL are refused before the file system is asked, and the
//! resolved path (symbolic links followed) must still lie inside it.

use super::super::AppState;
use super::super::routes::Segments;
use crate::http::cache::{self, LastModified};
use crate::http::error::{ApiError, ApiResult};
use axum::body::Body;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderValue, header};
use axum::response::Response;
use bytes::Bytes;
use futures_util::StreamExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use std::time::SystemTime;
use tokio::io::AsyncReadExt;

/// `Cache-Control` of every asset: a day (the files change only with a new
/// version of the server or of the prepared directory; ETags revalidate them).
const MAX_AGE: &str = "public, max-age=86400";

/// The script that prepares the directory, from the repository's root.
pub const SCRIPT: &str = "server/viewer-assets.sh";

/// Files whose presence makes a directory complete.
const REQUIRED: [&str; 5] = [
    "maplibre/maplibre-gl.mjs",
    "maplibre/maplibre-gl-worker.mjs",
    "maplibre/maplibre-gl.css",
    "cesium/Cesium.js",
    "cesium/Widgets/widgets.css",
];

/// The viewer's own files, in the binary.
const OWN: [(&str, &str, &str); 2] = [
    (
        "viewer.js",
        "text/javascript; charset=utf-8",
        include_str!("viewer.js"),
    ),
    (
        "viewer.css",
        "text/css; charset=utf-8",
        include_str!("viewer.css"),
    ),
];

/// Where the third-party files are, or why they are not.
#[derive(Debug, Clone)]
pub struct Assets {
    /// The directory found complete (canonical).
    pub dir: Option<PathBuf>,
    /// Every directory looked at, in order.
    pub searched: Vec<PathBuf>,
    /// Why no directory was used (`None` when `dir` is set).
    pub missing: Option<String>,
    /// The library versions the script recorded (`versions.txt`), for the pages.
    pub versions: Option<String>,
}

impl Assets {
    /// No assets (the viewer is off).
    pub fn disabled() -> Self {
        Self {
            dir: None,
            searched: Vec::new(),
            missing: Some("the viewer is off (--no-viewer)".into()),
            versions: None,
        }
    }

    /// The directory named by `--viewer-assets`, else the first complete one of
    /// `<exe dir>/../viewer-assets` (so `target/debug/tessera-server` and
    /// `target/release/tessera-server` find `target/viewer-assets`) and
    /// `<exe dir>/../share/tessera/viewer-assets` (an installed layout, e.g.
    /// `/usr/local/bin` and `/usr/local/share/tessera/viewer-assets`).
    pub fn locate(explicit: Option<&Path>) -> Self {
        let searched = match explicit {
            Some(d) => vec![d.to_path_buf()],
            None => default_dirs(),
        };
        let mut reasons = Vec::new();
        for d in &searched {
            match complete(d) {
                Ok(dir) => {
                    let versions = std::fs::read_to_string(dir.join("versions.txt"))
                        .ok()
                        .map(|v| v.split_whitespace().collect::<Vec<_>>().join(" "));
                    return Self {
                        dir: Some(dir),
                        searched,
                        missing: None,
                        versions,
                    };
                }
                Err(why) => reasons.push(format!("{}: {why}", d.display())),
            }
        }
        if searched.is_empty() {
            reasons.push("the executable's directory is unknown".into());
        }
        Self {
            dir: None,
            searched,
            missing: Some(reasons.join("; ")),
            versions: None,
        }
    }

    /// The directories searched, for messages.
    pub fn searched_list(&self) -> String {
        self.searched
            .iter()
            .map(|d| d.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The exact command that prepares the first directory searched (from a Tessera
    /// checkout's root; it needs npm).
    pub fn prepare_command(&self) -> String {
        match self.searched.first() {
            Some(d) => format!("{SCRIPT} {}", shell_quote(&d.display().to_string())),
            None => SCRIPT.to_string(),
        }
    }
}

/// `s` quoted for a POSIX shell when it needs it.
fn shell_quote(s: &str) -> String {
    if !s.is_empty()
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"/._-+:=,@".contains(&b))
    {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}

/// The default directories, beside the running executable.
fn default_dirs() -> Vec<PathBuf> {
    let Some(exe_dir) = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf))
    else {
        return Vec::new();
    };
    let up = exe_dir.parent().unwrap_or(&exe_dir);
    vec![
        up.join("viewer-assets"),
        up.join("share").join("tessera").join("viewer-assets"),
    ]
}

/// Why a directory is not the viewer's assets ([`complete`]).
#[derive(Debug, thiserror::Error)]
enum Incomplete {
    #[error("cannot open it ({0})")]
    Unopenable(std::io::Error),
    /// The required files it lacks.
    #[error("it lacks {}", .0.join(", "))]
    Lacks(Vec<&'static str>),
}

/// The canonical `dir` if it holds every required file, else what is missing.
fn complete(dir: &Path) -> Result<PathBuf, Incomplete> {
    let canonical = dir.canonicalize().map_err(Incomplete::Unopenable)?;
    let missing: Vec<&'static str> = REQUIRED
        .iter()
        .copied()
        .filter(|f| !canonical.join(f).is_file())
        .collect();
    if missing.is_empty() {
        Ok(canonical)
    } else {
        Err(Incomplete::Lacks(missing))
    }
}

/// The `?v=` of an own file's URL: a hash of its bytes, so a new binary's files are
/// fetched anew despite the day of caching.
pub fn own_version(name: &str) -> &'static str {
    static VERSIONS: OnceLock<Vec<(String, String)>> = OnceLock::new();
    let all = VERSIONS.get_or_init(|| {
        OWN.iter()
            .map(|(n, _, text)| {
                (
                    (*n).to_string(),
                    format!("{:016x}", xxhash_rust::xxh3::xxh3_64(text.as_bytes())),
                )
            })
            .collect()
    });
    all.iter()
        .find(|(n, _)| n == name)
        .map_or("", |(_, v)| v.as_str())
}

/// The media type of a file by its extension (what CesiumJS and MapLibre load).
pub fn content_type(path: &str) -> &'static str {
    let ext = path
        .rsplit_once('.')
        .map(|(_, e)| e.to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "js" | "mjs" | "cjs" => "text/javascript; charset=utf-8",
        "css" => "text/css; charset=utf-8",
        "json" | "map" | "geojson" | "czml" => "application/json",
        "wasm" => "application/wasm",
        "png" => "image/png",
        "jpg" | "jpeg" => "image/jpeg",
        "gif" => "image/gif",
        "webp" => "image/webp",
        "svg" => "image/svg+xml",
        "ico" => "image/x-icon",
        "ktx2" => "image/ktx2",
        "xml" => "application/xml",
        "html" | "htm" => "text/html; charset=utf-8",
        "txt" | "md" => "text/plain; charset=utf-8",
        "glb" => "model/gltf-binary",
        "gltf" => "model/gltf+json",
        "woff" => "font/woff",
        "woff2" => "font/woff2",
        "ttf" => "font/ttf",
        _ => "application/octet-stream",
    }
}

/// `raw` (the decoded path after `/viewer/assets/{lib}/`) as a relative path that
/// stays inside its directory, or `None`: no empty, `.`, `..` or hidden segment, no
/// backslash, NUL, colon or control character, at most 512 bytes.
pub fn safe_relative(raw: &str) -> Option<PathBuf> {
    if raw.is_empty() || raw.len() > 512 || raw.starts_with('/') {
        return None;
    }
    let mut out = PathBuf::new();
    for seg in raw.split('/') {
        let bad = seg.is_empty()
            || seg.starts_with('.')
            || seg.chars().any(|c| c == '\\' || c == ':' || c.is_control());
        if bad {
            return None;
        }
        out.push(seg);
    }
    Some(out)
}

fn not_found(lib: &str, path: &str) -> ApiError {
    ApiError::not_found(format!(
        "no viewer asset {} in {}",
        crate::http::error::quoted(path),
        crate::http::error::quoted(lib)
    ))
}

/// `GET /viewer/assets/{lib}/{*path}`.
pub async fn get(
    State(state): State<Arc<AppState>>,
    Segments((lib, path)): Segments<(String, String)>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let Some(rel) = safe_relative(&path) else {
        return Err(not_found(&lib, &path));
    };
    if lib == "tessera" {
        let Some((name, kind, text)) = OWN.iter().find(|(n, _, _)| *n == path) else {
            return Err(not_found(&lib, &path));
        };
        let etag = cache::etag(own_version(name), "");
        return Ok(respond(
            &headers,
            &etag,
            LastModified::UNKNOWN,
            kind,
            Some(text.len() as u64),
            Body::from(*text),
        ));
    }
    if lib != "maplibre" && lib != "cesium" {
        return Err(not_found(&lib, &path));
    }
    let Some(dir) = &state.viewer.assets.dir else {
        return Err(ApiError::not_found(format!(
            "the viewer's assets are not installed (searched {}); prepare them with `{}`",
            state.viewer.assets.searched_list(),
            state.viewer.assets.prepare_command()
        )));
    };
    let root = dir.join(&lib);
    let file = root.join(&rel);
    // Symbolic links are followed (a hard-linked or symlinked copy of node_modules
    // works), but the file must still be inside the library's directory.
    let (Ok(root), Ok(real)) = (
        tokio::fs::canonicalize(&root).await,
        tokio::fs::canonicalize(&file).await,
    ) else {
        return Err(not_found(&lib, &path));
    };
    if !real.starts_with(&root) {
        return Err(not_found(&lib, &path));
    }
    let Ok(f) = tokio::fs::File::open(&real).await else {
        return Err(not_found(&lib, &path));
    };
    let meta = f.metadata().await.map_err(|_| not_found(&lib, &path))?;
    if !meta.is_file() {
        return Err(not_found(&lib, &path));
    }
    let modified = meta.modified().ok();
    let nanos = modified
        .and_then(|t| t.duration_since(SystemTime::UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_nanos());
    let tag =
        xxhash_rust::xxh3::xxh3_64(format!("{} {} {nanos}", real.display(), meta.len()).as_bytes());
    let etag = cache::etag(&format!("{tag:016x}"), "");
    let len = meta.len();
    // Read in 64 KiB pieces as the connection takes them (CesiumJS's Cesium.js is
    // 6 MB: never held whole per request), never more than the Content-Length said
    // (a file that grew since is cut there). Fused: the compression layer may poll
    // again after the end.
    let stream = futures_util::stream::unfold((f, len), |(mut f, left)| async move {
        if left == 0 {
            return None;
        }
        let mut buf = vec![0u8; (64u64 << 10).min(left) as usize];
        match f.read(&mut buf).await {
            Ok(0) => None,
            Ok(n) => {
                buf.truncate(n);
                Some((
                    Ok::<_, std::io::Error>(Bytes::from(buf)),
                    (f, left - n as u64),
                ))
            }
            Err(e) => Some((Err(e), (f, 0))),
        }
    })
    .fuse();
    Ok(respond(
        &headers,
        &etag,
        LastModified::new(modified),
        content_type(&path),
        Some(len),
        Body::from_stream(stream),
    ))
}

/// A 200 (or, when the request's validators match, a 304) with the asset headers.
fn respond(
    headers: &HeaderMap,
    etag: &str,
    modified: LastModified,
    kind: &'static str,
    len: Option<u64>,
    body: Body,
) -> Response {
    let mut r = if cache::not_modified(headers, etag, modified) {
        let mut r = Response::new(Body::empty());
        *r.status_mut() = axum::http::StatusCode::NOT_MODIFIED;
        r
    } else {
        let mut r = Response::new(body);
        let h = r.headers_mut();
        h.insert(header::CONTENT_TYPE, HeaderValue::from_static(kind));
        if let Some(n) = len {
            h.insert(header::CONTENT_LENGTH, HeaderValue::from(n));
        }
        r
    };
    let h = r.headers_mut();
    if let Ok(v) = HeaderValue::from_str(etag) {
        h.insert(header::ETAG, v);
    }
    if let Some(v) = modified.header_value() {
        h.insert(header::LAST_MODIFIED, v);
    }
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static(MAX_AGE));
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_cannot_leave_the_directory() {
        assert_eq!(
            safe_relative("Workers/createVerticesFromQuantizedTerrainMesh.js"),
            Some(PathBuf::from(
                "Workers/createVerticesFromQuantizedTerrainMesh.js"
            ))
        );
        assert!(safe_relative("maplibre-gl.mjs").is_some());
        for bad in [
            "",
            "..",
            "../etc/passwd",
            "a/../../b",
            "a/./b",
            "/etc/passwd",
            "a//b",
            "a\\..\\b",
            ".tessera-assets",
            "a/.hidden",
            "C:/x",
            "a\0b",
            "a/",
        ] {
            assert_eq!(safe_relative(bad), None, "{bad:?}");
        }
        assert_eq!(safe_relative(&"a/".repeat(300)), None);
    }

    #[test]
    fn types_are_what_browsers_need() {
        assert_eq!(content_type("Cesium.js"), "text/javascript; charset=utf-8");
        assert_eq!(
            content_type("maplibre-gl.mjs"),
            "text/javascript; charset=utf-8"
        );
        assert_eq!(
            content_type("Widgets/widgets.css"),
            "text/css; charset=utf-8"
        );
        assert_eq!(
            content_type("ThirdParty/draco_decoder.wasm"),
            "application/wasm"
        );
        assert_eq!(
            content_type("Assets/Textures/NaturalEarthII/0/0/0.JPG"),
            "image/jpeg"
        );
        assert_eq!(content_type("tilemapresource.xml"), "application/xml");
        assert_eq!(content_type("a.ktx2"), "image/ktx2");
        assert_eq!(content_type("a.glb"), "model/gltf-binary");
        assert_eq!(content_type("LICENSE"), "application/octet-stream");
    }

    #[test]
    fn a_missing_directory_says_where_and_how() {
        let dir = tempfile::tempdir().unwrap();
        let a = Assets::locate(Some(dir.path()));
        assert!(a.dir.is_none());
        let why = a.missing.clone().unwrap();
        assert!(why.contains("maplibre/maplibre-gl.mjs"), "{why}");
        assert_eq!(
            a.prepare_command(),
            format!("{SCRIPT} {}", dir.path().display())
        );
        assert_eq!(shell_quote("/a b/c"), "'/a b/c'");
        for f in REQUIRED {
            let p = dir.path().join(f);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(p, b"x").unwrap();
        }
        std::fs::write(
            dir.path().join("versions.txt"),
            "maplibre-gl 6.20.0\ncesium 1.145.0\n",
        )
        .unwrap();
        let a = Assets::locate(Some(dir.path()));
        assert_eq!(a.dir, Some(dir.path().canonicalize().unwrap()));
        assert_eq!(
            a.versions.as_deref(),
            Some("maplibre-gl 6.20.0 cesium 1.145.0")
        );
    }
}

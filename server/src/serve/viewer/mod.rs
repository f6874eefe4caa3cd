//! The built-in viewer (DECISIONS.md "Real clients"): a landing page at `/` listing every
//! dataset with a preview and links to each interface it offers, and `/viewer/{name}`, a
//! page that shows one dataset in MapLibre GL JS (3D terrain, hillshade) and, at the
//! press of a button, in CesiumJS over its quantized-mesh terrain.
//!
//! - [`landing`]: the landing page; [`page`]: the viewer page; both HTML made here,
//!   every dataset-derived string escaped.
//! - The pages link only the interfaces [`super::interfaces`] finds a dataset offers.
//! - [`preview`]: `GET /v1/datasets/{name}/preview.png`, a computed picture.
//! - [`assets`]: the viewer's static files: its own (`viewer.js`, `viewer.css`, in
//!   the binary) and the third-party libraries from a directory the project's script
//!   prepares (`server/viewer-assets.sh`; DECISIONS.md "Real clients").
//!
//! Nothing on the pages comes from another host: the libraries are served by this
//! server, and every URL is relative to the page.

pub mod assets;
pub mod landing;
pub mod page;
pub mod preview;

use super::AppState;
use crate::http::cache;
use axum::Router;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use std::path::PathBuf;
use std::sync::Arc;
use tessera_shared::api::routes;

/// `--no-viewer` and `--viewer-assets`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ViewerConfig {
    /// Whether `/` and `/viewer/…` are served at all.
    pub enabled: bool,
    /// The third-party files' directory (`--viewer-assets`), else found beside the
    /// executable ([`assets::Assets::locate`]).
    pub assets: Option<PathBuf>,
}

impl Default for ViewerConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            assets: None,
        }
    }
}

/// The viewer as a server runs it.
#[derive(Debug)]
pub struct Viewer {
    pub enabled: bool,
    pub assets: assets::Assets,
}

impl Viewer {
    /// Finds the assets (when the viewer is on) and warns, once, when they are missing.
    pub fn new(config: &ViewerConfig) -> Self {
        let assets = if config.enabled {
            let a = assets::Assets::locate(config.assets.as_deref());
            if let Some(why) = &a.missing {
                tracing::warn!(
                    searched = %a.searched_list(),
                    prepare = %a.prepare_command(),
                    "viewer assets (MapLibre GL JS, CesiumJS) not found: {why}; /viewer pages will say how to prepare them"
                );
            }
            a
        } else {
            assets::Assets::disabled()
        };
        Self {
            enabled: config.enabled,
            assets,
        }
    }
}

/// The viewer's routes (only mounted when it is on), all on the cheap routes' capacity.
pub fn routes() -> Router<Arc<AppState>> {
    Router::new()
        .route(routes::LANDING, get(landing::get))
        .route(routes::VIEWER, get(page::get))
        .route(routes::VIEWER_ASSET, get(assets::get))
}

/// An HTML page: `ETag` from its bytes and `Cache-Control: no-cache` (its content
/// follows the datasets served and the server's settings, so a browser revalidates it,
/// and gets a 304 while nothing changed).
pub fn html(headers: &HeaderMap, body: String) -> Response {
    let etag = cache::etag(
        &format!("{:016x}", xxhash_rust::xxh3::xxh3_64(body.as_bytes())),
        "",
    );
    let no_cache = HeaderValue::from_static("no-cache");
    let mut r = if cache::not_modified(headers, &etag, cache::LastModified::UNKNOWN) {
        StatusCode::NOT_MODIFIED.into_response()
    } else {
        let mut r = body.into_response();
        r.headers_mut().insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/html; charset=utf-8"),
        );
        r
    };
    let h = r.headers_mut();
    if let Ok(v) = HeaderValue::from_str(&etag) {
        h.insert(header::ETAG, v);
    }
    h.insert(header::CACHE_CONTROL, no_cache);
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    r
}

/// `s` escaped for HTML text and attribute values.
pub fn esc(s: &str) -> String {
    super::routes::xml_escape(s)
}

/// `value` as JSON safe inside an HTML `<script>` element (no `<`, `>` or `&` that
/// could close it or start a comment).
pub fn script_json(value: &serde_json::Value) -> String {
    value
        .to_string()
        .replace('<', "\\u003c")
        .replace('>', "\\u003e")
        .replace('&', "\\u0026")
}

/// A byte count as people read it (`2.1 MB`).
pub fn bytes(n: u64) -> String {
    const UNITS: [&str; 5] = ["B", "kB", "MB", "GB", "TB"];
    let mut v = n as f64;
    let mut u = 0;
    while v >= 1000.0 && u + 1 < UNITS.len() {
        v /= 1000.0;
        u += 1;
    }
    if u == 0 {
        format!("{n} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn script_json_cannot_close_the_script() {
        let v = serde_json::json!({"s": "</script><!-- & -->"});
        let out = script_json(&v);
        assert!(
            !out.contains('<') && !out.contains('>') && !out.contains('&'),
            "{out}"
        );
        let back: serde_json::Value = serde_json::from_str(&out).unwrap();
        assert_eq!(back, v);
    }

    #[test]
    fn sizes_read_well() {
        assert_eq!(bytes(999), "999 B");
        assert_eq!(bytes(2_145_866), "2.1 MB");
        assert_eq!(bytes(14_495_864), "14.5 MB");
    }
}

//! `GET /viewer/{name}`: one dataset in MapLibre GL JS (3D terrain from its Web
//! Mercator TileJSON, hillshade, an elevation readout) with a switch to CesiumJS over
//! its quantized-mesh terrain (viewer.js). The page carries what the script needs as
//! JSON (relative URLs, the WGS 84 bounds, the body's radii).
//!
//! A dataset with no place on a map gets a page saying why (and its preview), and so
//! does every dataset when the third-party libraries are missing: that page names
//! the directories searched and the command that prepares them.

use super::super::AppState;
use super::super::dataset::Dataset;
use super::super::routes::{Segments, dataset};
use super::{assets, esc, html, script_json};
use crate::http::error::ApiResult;
use crate::serve::interfaces::{Offered, cesium_dir, grid_tilejson, offered};
use axum::extract::State;
use axum::http::HeaderMap;
use axum::response::Response;
use std::fmt::Write;
use std::sync::Arc;
use tessera_shared::api::{fill, routes};

const TEMPLATE: &str = include_str!("viewer.html");

/// A server-relative route as a URL relative to `/viewer/{name}`.
fn rel(path: &str) -> String {
    format!("..{path}")
}

/// The pieces of a page: extra `<head>` lines, the header's controls, `<main>`'s
/// content and the scripts.
struct Parts {
    head: String,
    controls: String,
    main: String,
    scripts: String,
}

/// The URL of one of the viewer's own files, versioned by its hash.
fn own(file: &str) -> String {
    format!("assets/tessera/{file}?v={}", assets::own_version(file))
}

/// The template filled: fixed values first, then the parts (which carry data, so no
/// placeholder is looked for in them afterwards but the ones that follow).
fn fill_page(ds: &Dataset, parts: &Parts) -> String {
    TEMPLATE
        .replace("{{css}}", &own("viewer.css"))
        .replace(
            "{{document}}",
            &esc(&rel(&fill(routes::DATASET, &[("name", &ds.name)]))),
        )
        .replace("{{name}}", &esc(&ds.name))
        .replace("{{head}}", &parts.head)
        .replace("{{controls}}", &parts.controls)
        .replace("{{scripts}}", &parts.scripts)
        .replace("{{main}}", &parts.main)
}

/// The dataset's preview, for the notice pages.
fn preview_img(ds: &Dataset) -> String {
    format!(
        "<img class=\"preview\" src=\"{}?v={}\" alt=\"Shaded relief of {}\">",
        esc(&rel(&fill(routes::PREVIEW, &[("name", &ds.name)]))),
        esc(ds.content_hash()),
        esc(&ds.name)
    )
}

/// A page with no map: `message` (HTML) and the preview.
fn notice(ds: &Dataset, class: &str, message: &str) -> String {
    fill_page(
        ds,
        &Parts {
            head: String::new(),
            controls: String::new(),
            main: format!(
                "<section class=\"notice {class}\">\n{message}\n{}\n<p><a href=\"../\">Every dataset</a></p>\n</section>",
                preview_img(ds)
            ),
            scripts: String::new(),
        },
    )
}

/// What viewer.js reads (`#tessera-config`).
fn config(ds: &Dataset, offered: &Offered, bounds: [f64; 4]) -> serde_json::Value {
    let m = ds.pyramid.metadata();
    let (cesium, cesium_unavailable) = match &offered.terrain {
        Ok(_) => (Some(rel(&cesium_dir(&ds.name))), None),
        Err(why) => (None, Some(why.to_string())),
    };
    serde_json::json!({
        "name": ds.name,
        "tilejson": format!("{}&size=512", rel(&grid_tilejson(&ds.name, "webmercator", "terrarium"))),
        "bounds": bounds,
        "cesium": cesium,
        "cesiumUnavailable": cesium_unavailable,
        "earth": offered.on_earth(),
        "radii": offered.radii,
        "minHeight": m.min_height,
        "maxHeight": m.max_height,
        "assets": { "maplibre": "assets/maplibre/", "cesium": "assets/cesium/" },
    })
}

/// The page for `ds`.
pub fn render(state: &AppState, ds: &Dataset) -> String {
    let offered = offered(state, ds);
    let fp = match &offered.grids {
        Ok(fp) => fp.clone(),
        Err(why) => {
            return notice(
                ds,
                "no-map",
                &format!(
                    "<h2>No map view</h2>\n<p>{} has no place on a map: {}. The dataset document \
                     and its own-grid tiles are still served.</p>",
                    esc(&ds.name),
                    esc(&why.to_string())
                ),
            );
        }
    };
    let a = &state.viewer.assets;
    if a.dir.is_none() {
        let searched = a.searched.iter().fold(String::new(), |mut s, d| {
            let _ = write!(s, "<li><code>{}</code></li>", esc(&d.display().to_string()));
            s
        });
        return notice(
            ds,
            "no-assets",
            &format!(
                "<h2>The viewer's libraries are not installed</h2>\n\
                 <p>MapLibre GL JS and CesiumJS are served by this server from a directory \
                 that was not found. Searched:</p>\n<ul class=\"searched\">{searched}</ul>\n\
                 <p>({})</p>\n<p>Prepare it from a Tessera checkout (needs npm; the versions \
                 are those of <code>tests/browser/package-lock.json</code>):</p>\n\
                 <pre class=\"command\">{}</pre>\n<p>then restart the server, or point \
                 <code>--viewer-assets DIR</code> at a prepared directory.</p>",
                esc(a.missing.as_deref().unwrap_or("")),
                esc(&a.prepare_command())
            ),
        );
    }
    let cesium_button = match &offered.terrain {
        Ok(_) => "<button type=\"button\" id=\"mode-cesium\" aria-pressed=\"false\">Globe · CesiumJS</button>".to_string(),
        Err(why) => format!(
            "<button type=\"button\" id=\"mode-cesium\" aria-pressed=\"false\" disabled title=\"{}\">Globe · CesiumJS</button>",
            esc(&format!("no Cesium terrain: {why}"))
        ),
    };
    let note = if offered.on_earth() {
        String::new()
    } else {
        "<p class=\"body-note\">Not on the Earth: the map shows the data at its own longitudes and latitudes on the Earth's Web Mercator grid; the globe uses its own body.</p>".to_string()
    };
    fill_page(
        ds,
        &Parts {
            head: "<link rel=\"stylesheet\" href=\"assets/maplibre/maplibre-gl.css\">".into(),
            controls: format!(
                "<nav class=\"modes\">\n<button type=\"button\" id=\"mode-maplibre\" aria-pressed=\"true\">Map · MapLibre</button>\n{cesium_button}\n</nav>"
            ),
            main: format!(
                "<div id=\"map\" class=\"view\"></div>\n<div id=\"globe\" class=\"view\" hidden></div>\n\
                 <div id=\"status\" role=\"status\">Loading…</div>\n\
                 <output id=\"readout\">Point at the terrain for its height</output>\n{note}"
            ),
            scripts: format!(
                "<script type=\"application/json\" id=\"tessera-config\">{}</script>\n\
                 <script type=\"module\" src=\"{}\"></script>",
                script_json(&config(ds, &offered, fp.lon_lat)),
                own("viewer.js")
            ),
        },
    )
}

/// `GET /viewer/{name}`: the page, or the API's 400/404/503 JSON for a name that is
/// invalid, unknown or unavailable.
pub async fn get(
    State(state): State<Arc<AppState>>,
    Segments(name): Segments<String>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    let ds = dataset(&state, &name)?;
    Ok(html(&headers, render(&state, &ds)))
}

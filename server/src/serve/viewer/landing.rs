//! `GET /`: the landing page. Every dataset the server serves, with its preview, its
//! extent (WGS 84 and its own CRS), CRS, size, heights and vertical datum, and links
//! to every interface it offers; those it does not offer are named with the reason.
//! Needs no script at all (the third-party libraries are for `/viewer/{name}` only).

use super::super::AppState;
use super::super::dataset::Dataset;
use super::super::routes::datasets::describe_served;
use super::{assets, bytes, esc, html};
use crate::serve::interfaces::{Offered, grid_tilejson, offered};
use axum::extract::State;
use axum::http::HeaderMap;
use axum::response::Response;
use std::fmt::Write;
use std::sync::Arc;
use tessera_shared::api::{DatasetInfo, fill, routes};

const TEMPLATE: &str = include_str!("index.html");

/// A server-relative route as a URL relative to the landing page (`/`): the leading
/// `/` dropped, so the page also works behind a proxy that serves it under a prefix.
fn rel(path: &str) -> String {
    path.trim_start_matches('/').to_string()
}

/// `lon` and `lat` as `8.5000° E`, `46.5000° N`.
fn lon(v: f64) -> String {
    format!("{:.4}° {}", v.abs(), if v < 0.0 { "W" } else { "E" })
}

fn lat(v: f64) -> String {
    format!("{:.4}° {}", v.abs(), if v < 0.0 { "S" } else { "N" })
}

/// A coordinate of the dataset's own CRS, with as many decimals as it needs.
fn coord(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.into() }
}

/// A height to the decimetre.
fn metres(v: f64) -> String {
    let s = format!("{v:.1}");
    s.strip_suffix(".0").unwrap_or(&s).to_string()
}

/// One `<li>` of links: `label` then each `(text, href, data-link)`.
fn links_item(out: &mut String, label: &str, links: &[(&str, String, &str)]) {
    let _ = write!(out, "<li><span class=\"what\">{}</span> ", esc(label));
    for (k, (text, href, key)) in links.iter().enumerate() {
        if k > 0 {
            out.push_str(" · ");
        }
        let _ = write!(
            out,
            "<a href=\"{}\" data-link=\"{}\">{}</a>",
            esc(href),
            esc(key),
            esc(text)
        );
    }
    out.push_str("</li>\n");
}

/// A `<li>` for an interface the dataset does not offer, and why.
fn unavailable_item(out: &mut String, label: &str, why: &dyn std::fmt::Display) {
    let _ = writeln!(
        out,
        "<li class=\"unavailable\"><span class=\"what\">{}</span> unavailable: {}</li>",
        esc(label),
        esc(&why.to_string())
    );
}

/// The facts of one dataset as `<dt>`/`<dd>` pairs.
fn facts(out: &mut String, info: &DatasetInfo, offered: &Offered) {
    let mut row = |k: &str, v: &str| {
        let _ = writeln!(out, "<dt>{}</dt><dd>{v}</dd>", esc(k));
    };
    match &offered.grids {
        Ok(fp) => {
            let [w, s, e, n] = fp.lon_lat;
            row(
                "Extent (WGS 84)",
                &esc(&format!("{} … {}, {} … {}", lon(w), lon(e), lat(s), lat(n))),
            );
        }
        Err(_) => row("Extent (WGS 84)", "none (no place on a map)"),
    }
    let crs = match (&info.crs, &info.georef) {
        (Some(c), Some(g)) => match &g.proj {
            Some(p) => format!("{c} ({p})"),
            None => c.clone(),
        },
        (None, Some(g)) => g
            .proj
            .clone()
            .or_else(|| g.crs_name.clone())
            .unwrap_or_else(|| "unnamed".into()),
        (_, None) => "none (no georeferencing)".into(),
    };
    row("CRS", &esc(&crs));
    if let Some([w, s, e, n]) = info.extent {
        row(
            "Extent (own CRS)",
            &esc(&format!(
                "west {}, south {}, east {}, north {}",
                coord(w),
                coord(s),
                coord(e),
                coord(n)
            )),
        );
    }
    if !offered.on_earth()
        && let Some([a, _, b]) = offered.radii
    {
        row(
            "Body",
            &esc(&format!(
                "not the Earth: an ellipsoid of {:.1} × {:.1} km. The standard grids (Web Mercator, CRS84) are the Earth's and place the data at its own longitudes and latitudes there; Cesium terrain is on its own ellipsoid (layer.json metadata.ellipsoidRadii).",
                a / 1000.0,
                b / 1000.0
            )),
        );
    }
    row(
        "Size",
        &esc(&format!(
            "{} × {} samples, {} level{} of {}-cell tiles, {}",
            info.width,
            info.height,
            info.levels,
            if info.levels == 1 { "" } else { "s" },
            info.tile_size,
            bytes(info.bytes)
        )),
    );
    if let Some(gs) = &info.ground_spacing {
        row(
            "Sample spacing",
            &esc(&format!(
                "{:.2} m east–west, {:.2} m north–south",
                gs.x, gs.y
            )),
        );
    }
    row(
        "Heights",
        &esc(&format!(
            "{} … {} m; vertical datum {}",
            metres(info.min_height),
            metres(info.max_height),
            info.vertical_datum.name()
        )),
    );
    row("Source", &esc(&info.source));
    row("Content hash", &esc(&info.content_hash));
}

/// The `<li>` of one dataset.
fn dataset_item(out: &mut String, state: &AppState, ds: &Dataset) {
    let info = describe_served(state, ds);
    let offered = offered(state, ds);
    let name = &ds.name;
    let at = |template: &str| rel(&fill(template, &[("name", name)]));
    let viewer = at(routes::VIEWER);
    // The picture and the name open the viewer where there is a map to view, else the
    // dataset document.
    let open = if offered.grids.is_ok() {
        viewer.clone()
    } else {
        at(routes::DATASET)
    };
    let preview = format!("{}?v={}", at(routes::PREVIEW), info.content_hash);
    let plan = super::preview::plan(
        ds.pyramid.geometry(),
        info.ground_spacing.map(|s| (s.x, s.y)),
    );
    let _ = write!(
        out,
        "<li class=\"dataset\" id=\"dataset-{n}\" data-dataset=\"{n}\">\n\
         <a class=\"thumb\" href=\"{v}\"><img src=\"{p}\" width=\"{w}\" height=\"{h}\" alt=\"Shaded relief of {n}\" loading=\"lazy\"></a>\n\
         <div class=\"about\">\n<h2><a href=\"{v}\">{n}</a></h2>\n<dl>\n",
        n = esc(name),
        v = esc(&open),
        p = esc(&preview),
        w = plan.size.0,
        h = plan.size.1,
    );
    facts(out, &info, &offered);
    out.push_str("</dl>\n<ul class=\"links\">\n");
    match &offered.grids {
        Ok(_) => {
            links_item(
                out,
                "Viewer",
                &[("MapLibre GL JS and CesiumJS", viewer.clone(), "viewer")],
            );
            for (label, grid) in [
                ("TileJSON WebMercatorQuad", "webmercator"),
                ("TileJSON WorldCRS84Quad", "crs84"),
            ] {
                let link = |enc: &'static str| {
                    (
                        enc,
                        rel(&grid_tilejson(name, grid, enc)),
                        if grid == "webmercator" {
                            if enc == "terrarium" {
                                "webmercator-terrarium"
                            } else {
                                "webmercator-mapbox"
                            }
                        } else if enc == "terrarium" {
                            "crs84-terrarium"
                        } else {
                            "crs84-mapbox"
                        },
                    )
                };
                links_item(out, label, &[link("terrarium"), link("mapbox")]);
            }
            links_item(
                out,
                "WMTS 1.0.0",
                &[
                    ("this dataset", at(routes::DATASET_WMTS), "wmts"),
                    ("all datasets", rel(routes::WMTS), "wmts-all"),
                ],
            );
            links_item(
                out,
                "OGC API – Tiles",
                &[
                    ("landing page", rel(routes::OGC_LANDING), "ogcapi"),
                    (
                        "collection",
                        at(routes::OGC_COLLECTION),
                        "ogcapi-collection",
                    ),
                    ("tilesets", at(routes::OGC_TILESETS), "ogcapi-tilesets"),
                ],
            );
        }
        Err(why) => {
            unavailable_item(out, "Viewer (map and globe)", why);
            unavailable_item(out, "Standard grids (TileJSON), WMTS, OGC API – Tiles", why);
        }
    }
    match &offered.terrain {
        Ok(_) => links_item(
            out,
            "Cesium terrain",
            &[("layer.json", at(routes::CESIUM_LAYER), "cesium")],
        ),
        Err(why) => unavailable_item(out, "Cesium terrain", why),
    }
    links_item(
        out,
        "Pyramid",
        &[
            ("the file, with HTTP Range", at(routes::PYRAMID), "pyramid"),
            ("own-grid TileJSON", at(routes::TILEJSON), "tilejson"),
            ("bootstrap", at(routes::BOOTSTRAP), "bootstrap"),
        ],
    );
    let _ = writeln!(
        out,
        "<li><span class=\"what\">Morton tile API</span> <code>{}?ranges=…</code> \
         (<a href=\"{}\" data-link=\"document\">the dataset document</a> links its templates; API.md \
         <q>GET /v1/datasets/{{name}}/levels/{{level}}/tiles?ranges=…</q>)</li>",
        esc(&at(routes::TILES)),
        esc(&at(routes::DATASET)),
    );
    links_item(
        out,
        "Dataset document",
        &[
            ("JSON", at(routes::DATASET), "dataset"),
            ("preview (PNG)", preview, "preview"),
        ],
    );
    out.push_str("</ul>\n</div>\n</li>\n");
}

/// The whole page.
pub fn render(state: &AppState) -> String {
    let registry = state.registry();
    let mut items = String::new();
    let mut unavailable = String::new();
    let mut n = 0;
    for ds in registry.datasets.values() {
        match ds.available() {
            Ok(()) => {
                n += 1;
                dataset_item(&mut items, state, ds);
            }
            Err(why) => {
                let _ = writeln!(
                    unavailable,
                    "<li class=\"unavailable\" data-dataset=\"{}\">{}: unavailable: {}</li>",
                    esc(&ds.name),
                    esc(&ds.name),
                    esc(&why.to_string())
                );
            }
        }
    }
    if !unavailable.is_empty() {
        items.push_str(&unavailable);
    }
    let a = &state.viewer.assets;
    let libraries = match (&a.dir, &a.versions) {
        (Some(_), Some(v)) => format!("Viewer libraries: {}.", esc(v)),
        (Some(d), None) => format!("Viewer libraries from {}.", esc(&d.display().to_string())),
        (None, _) => format!(
            "The viewer's libraries (MapLibre GL JS, CesiumJS) are not installed: searched {}; prepare them with <code>{}</code>.",
            esc(&a.searched_list()),
            esc(&a.prepare_command())
        ),
    };
    TEMPLATE
        .replace("{{version}}", env!("CARGO_PKG_VERSION"))
        .replace("{{count}}", &n.to_string())
        .replace("{{plural}}", if n == 1 { "" } else { "s" })
        .replace(
            "{{css}}",
            &format!(
                "viewer/assets/tessera/viewer.css?v={}",
                assets::own_version("viewer.css")
            ),
        )
        .replace("{{datasets_json}}", &rel(routes::DATASETS))
        .replace("{{wmts}}", &rel(routes::WMTS))
        .replace("{{ogcapi}}", &rel(routes::OGC_LANDING))
        .replace("{{libraries}}", &libraries)
        .replace("{{datasets}}", &items)
}

/// `GET /`.
pub async fn get(State(state): State<Arc<AppState>>, headers: HeaderMap) -> Response {
    html(&headers, render(&state))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coordinates_read_well() {
        assert_eq!(lon(-72.5), "72.5000° W");
        assert_eq!(lat(46.000_416), "46.0004° N");
        assert_eq!(coord(2_600_000.0), "2600000");
        assert_eq!(coord(45.999_583_333), "45.999583");
        assert_eq!(rel("/v1/datasets"), "v1/datasets");
        assert_eq!(metres(502.020_996), "502");
        assert_eq!(metres(4_216.284_18), "4216.3");
    }
}

//! `tessera-server serve`: pyramids over HTTP (docs/ARCHITECTURE.md#serving, API.md).

pub mod allocator;
pub mod attached_imagery;
pub mod compute;
pub mod config;
pub mod dataset;
pub mod interfaces;
pub mod metrics;
pub mod registry;
pub mod routes;
pub mod viewer;
pub mod web_cache;

use crate::http::error::ApiError;
use crate::http::{conn, conventions, tls};
use axum::Router;
use axum::extract::{MatchedPath, Request, State};
use axum::http::{StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use config::Settings;
use metrics::Metrics;
use registry::Registry;
use std::path::PathBuf;
use std::sync::{Arc, PoisonError, RwLock};
use std::time::Instant;
use tessera_shared::api::routes as paths;
use tessera_shared::range_query::RangeLimits;
use tower::ServiceBuilder;
use tower::limit::GlobalConcurrencyLimitLayer;
use tower_http::catch_panic::CatchPanicLayer;
use tower_http::timeout::TimeoutLayer;

/// What every handler shares.
#[derive(Debug)]
pub struct AppState {
    /// Swapped whole by [`AppState::reload`]; a request keeps the registry (and the
    /// open files) it started with.
    registry: RwLock<Arc<Registry>>,
    /// What the registry is loaded from, for reloads.
    pub paths: Vec<PathBuf>,
    pub metrics: Metrics,
    /// The object-store block cache, metrics and retry settings every object
    /// dataset shares (kept across reloads).
    pub store: Arc<crate::storage::StoreContext>,
    pub limits: RangeLimits,
    pub cache_max_age: u64,
    pub max_query_bytes: usize,
    pub public_url: Option<String>,
    pub trust_forwarded: bool,
    /// Whether the server speaks HTTPS (`--tls-cert`): the scheme of URLs built from `Host`.
    pub tls: bool,
    /// Standard-grid web tiles: footprints and caches.
    pub web: web_cache::WebTiles,
    /// Admission, sharing and cancellation of computed responses.
    pub compute: Arc<compute::Compute>,
    /// The built-in viewer (`/`, `/viewer/…`): on or off, and its assets.
    pub viewer: viewer::Viewer,
    /// Points and body size of elevation requests.
    pub elevation: routes::elevation::ElevationLimits,
}

impl AppState {
    /// The datasets being served now.
    pub fn registry(&self) -> Arc<Registry> {
        self.registry
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    /// Reopens every dataset from the configured paths and swaps them in at once.
    /// On any error the old datasets stay in service and the error says why.
    pub fn reload(&self) -> anyhow::Result<usize> {
        let fresh = Registry::load(&self.paths, &self.store)?;
        log_datasets(&fresh);
        let n = fresh.datasets.len();
        *self
            .registry
            .write()
            .unwrap_or_else(PoisonError::into_inner) = Arc::new(fresh);
        Ok(n)
    }
}

fn log_datasets(registry: &Registry) {
    for (name, ds) in &registry.datasets {
        let m = ds.pyramid.metadata();
        tracing::info!(dataset = %name, file = %ds.path.display(), width = m.width, height = m.height, levels = m.levels, "serving");
    }
}

/// Tiles a response carried, for the request log and metrics (a response extension).
#[derive(Clone, Copy, Debug)]
pub struct TilesServed(pub u64);

/// The whole API as a router.
///
/// The routes that compute their responses (Cesium terrain, grid and PNG tiles,
/// bootstrap) are admitted by [`compute::Compute`] and counted apart from the cheap
/// ones (stored tiles, ranges, metadata, health, metrics): each group has its own
/// `--concurrency`, so a flood of one never starves the other.
pub fn app(state: Arc<AppState>, settings: &Settings) -> Router {
    let cheap_slots = Arc::new(tokio::sync::Semaphore::new(settings.concurrency));
    let computed_slots = Arc::new(tokio::sync::Semaphore::new(settings.concurrency));
    let computed = Router::new()
        .route(paths::BOOTSTRAP, get(routes::bootstrap::get))
        .route(paths::WEB_TILE, get(routes::web_tiles::png))
        .route(paths::GRID_TILE, get(routes::web_grid::tile))
        .route(paths::RENDERED_TILE, get(routes::rendered::tile))
        .route(paths::CONTOUR_TILE, get(routes::contours::tile))
        .route(paths::CESIUM_TILE, get(routes::cesium::tile))
        .route(paths::TILES3D_TILE, get(routes::cesium_tiles3d::tile))
        .route(paths::OGC_TILE, get(routes::ogc_api::tile))
        .route(paths::PREVIEW, get(viewer::preview::get))
        .route(
            paths::ELEVATION,
            get(routes::elevation::get).post(routes::elevation::post),
        )
        .route_layer(GlobalConcurrencyLimitLayer::with_semaphore(computed_slots));
    let cheap = Router::new()
        .route("/healthz", get(routes::health::healthz))
        .route("/healthz/live", get(routes::health::live))
        .route("/healthz/ready", get(routes::health::ready))
        .route("/metrics", get(routes::health::metrics))
        .route(paths::DATASETS, get(routes::datasets::list))
        .route(paths::DATASET, get(routes::datasets::get_one))
        .route(paths::TILEJSON, get(routes::web_tiles::tilejson))
        .route(paths::PYRAMID, get(routes::pyramid::raw))
        .route(paths::COVERAGE, get(routes::coverage::get))
        .route(paths::TILES, get(routes::tiles::ranges))
        .route(paths::ERRORS, get(routes::tiles::errors))
        .route(paths::IMAGERY_TILES, get(routes::tiles::imagery))
        .route(paths::TILE, get(routes::tiles::single))
        .route(paths::GRID_TILEJSON, get(routes::web_grid::tilejson))
        .route(paths::RENDERED_TILEJSON, get(routes::rendered::tilejson))
        .route(paths::CONTOUR_TILEJSON, get(routes::contours::tilejson))
        .route(paths::CESIUM_LAYER, get(routes::cesium::layer))
        .route(paths::TILES3D_TILESET, get(routes::cesium_tiles3d::tileset))
        .route(paths::WMTS, get(routes::wmts::all))
        .route(paths::DATASET_WMTS, get(routes::wmts::one))
        .route(paths::OGC_LANDING, get(routes::ogc_api::landing))
        .route(paths::OGC_CONFORMANCE, get(routes::ogc_api::conformance))
        .route(
            paths::OGC_TILE_MATRIX_SETS,
            get(routes::ogc_api::tile_matrix_sets),
        )
        .route(
            paths::OGC_TILE_MATRIX_SET,
            get(routes::ogc_api::tile_matrix_set),
        )
        .route(paths::OGC_COLLECTIONS, get(routes::ogc_api::collections))
        .route(paths::OGC_COLLECTION, get(routes::ogc_api::collection))
        .route(paths::OGC_TILESETS, get(routes::ogc_api::tilesets))
        .route(paths::OGC_TILESET, get(routes::ogc_api::tileset));
    // `--no-viewer`: its pages are not routed at all (the fallback's 404).
    let cheap = if state.viewer.enabled {
        cheap.merge(viewer::routes())
    } else {
        cheap
    }
    .route_layer(GlobalConcurrencyLimitLayer::with_semaphore(cheap_slots));
    let api = cheap
        .merge(computed)
        .fallback(|| async { ApiError::not_found("no such endpoint; see API.md") })
        .with_state(state.clone());
    api.layer(
        ServiceBuilder::new()
            // HTTP conventions for browsers and CDNs (http/conventions.rs; API.md "HTTP conventions").
            .layer(middleware::from_fn(conventions::options))
            .layer(conventions::cors(&settings.cors))
            .layer(middleware::from_fn(conventions::representation))
            .layer(conventions::compression())
            .layer(CatchPanicLayer::custom(|_| {
                ApiError::internal("internal error").into_response()
            }))
            .layer(middleware::from_fn_with_state(state, observe))
            .layer(TimeoutLayer::with_status_code(
                StatusCode::REQUEST_TIMEOUT,
                settings.timeout,
            )),
    )
}

/// Rejects over-long query strings, then logs one line per request and records metrics.
async fn observe(State(state): State<Arc<AppState>>, req: Request, next: Next) -> Response {
    let started = Instant::now();
    let method = req.method().clone();
    let uri = req.uri().clone();
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_string(), |m| m.as_str().to_string());
    let query_len = uri.query().map_or(0, str::len);
    let response = if query_len > state.max_query_bytes {
        ApiError::new(
            StatusCode::URI_TOO_LONG,
            format!(
                "query string of {query_len} bytes exceeds the {}-byte limit",
                state.max_query_bytes
            ),
        )
        .into_response()
    } else {
        json_if_empty(next.run(req).await)
    };
    let status = response.status();
    // Bodies of known size (all of ours) say so in their size hint, even when hyper
    // has not yet written the Content-Length header.
    let bytes = response
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok()?.parse::<u64>().ok())
        .or_else(|| axum::body::HttpBody::size_hint(response.body()).exact())
        .unwrap_or(0);
    let tiles = response
        .extensions()
        .get::<TilesServed>()
        .map_or(0, |t| t.0);
    let elapsed = started.elapsed();
    let m = &state.metrics;
    m.requests
        .with_label_values(&[route.as_str(), status.as_str()])
        .inc();
    m.latency
        .with_label_values(&[route.as_str()])
        .observe(elapsed.as_secs_f64());
    m.bytes.inc_by(bytes);
    m.tiles.inc_by(tiles);
    tracing::info!(
        %method,
        uri = %LoggedUri(&uri),
        status = status.as_u16(),
        bytes,
        tiles,
        ms = elapsed.as_secs_f64() * 1e3,
        "request"
    );
    response
}

/// Longest request target a log line carries whole.
const LOGGED_URI_BYTES: usize = 512;

/// The request target as the request log shows it: whole up to
/// [`LOGGED_URI_BYTES`], else its start, an ellipsis and its length, so that a client
/// sending 64 KB targets cannot make every log line 64 KB. Formatted only when the
/// line is logged (nothing is done for it under `--quiet`).
struct LoggedUri<'a>(&'a axum::http::Uri);

impl std::fmt::Display for LoggedUri<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self.0.to_string();
        if s.len() <= LOGGED_URI_BYTES {
            return f.write_str(&s);
        }
        // A URI is ASCII, but cut on a character boundary whatever it holds.
        let mut end = LOGGED_URI_BYTES;
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        write!(f, "{}… ({} bytes)", &s[..end], s.len())
    }
}

/// Gives the few responses the framework makes itself (405 wrong method, 408 timeout,
/// any other error without a JSON body) a JSON reason like every other error.
fn json_if_empty(response: Response) -> Response {
    let status = response.status();
    if !(status.is_client_error() || status.is_server_error()) {
        return response;
    }
    let is_json = response
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|t| t.starts_with("application/json"));
    if is_json {
        return response;
    }
    match status {
        StatusCode::METHOD_NOT_ALLOWED => {
            let allow = response.headers().get(header::ALLOW).cloned();
            let mut r = ApiError::new(status, "method not allowed: this API is read-only (GET)")
                .into_response();
            if let Some(a) = allow {
                r.headers_mut().insert(header::ALLOW, a);
            }
            r
        }
        StatusCode::REQUEST_TIMEOUT => ApiError::new(status, "request timed out").into_response(),
        // The framework's own text may quote raw input or internals: say only what
        // the status means.
        _ => ApiError::new(
            status,
            status
                .canonical_reason()
                .unwrap_or("request failed")
                .to_ascii_lowercase(),
        )
        .into_response(),
    }
}

/// Resolves once SIGINT or SIGTERM arrives.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {},
        () = term => {},
    }
    tracing::info!("shutting down: finishing in-flight requests");
}

/// The shared state for `settings`' datasets and limits.
pub fn state(settings: &Settings) -> anyhow::Result<Arc<AppState>> {
    let metrics = Metrics::new();
    let store = Arc::new(crate::storage::StoreContext::new(
        settings.block_cache_bytes,
        crate::storage::StoreOptions::default(),
        metrics.registry(),
    ));
    let registry = Registry::load(&settings.datasets, &store)?;
    log_datasets(&registry);
    let web = web_cache::WebTiles::new(settings.web.clone(), metrics.registry());
    let compute = Arc::new(compute::Compute::new(
        settings.compute.clone(),
        metrics.registry(),
    ));
    Ok(Arc::new(AppState {
        registry: RwLock::new(Arc::new(registry)),
        paths: settings.datasets.clone(),
        metrics,
        store,
        web,
        compute,
        viewer: viewer::Viewer::new(&settings.viewer),
        elevation: settings.elevation,
        limits: RangeLimits {
            max_ranges: settings.max_ranges,
            max_tiles: settings.max_tiles,
        },
        cache_max_age: settings.cache_max_age,
        max_query_bytes: settings.max_query_bytes,
        public_url: settings.public_url.clone(),
        trust_forwarded: settings.trust_forwarded,
        tls: settings.tls.is_some(),
    }))
}

/// Serves on an already bound listener until `shutdown` resolves, then lets
/// in-flight responses finish. (Tests and embedders use this directly.)
pub async fn serve_until(
    listener: tokio::net::TcpListener,
    state: Arc<AppState>,
    settings: &Settings,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let tls = settings.tls.as_ref().map(tls::server_config).transpose()?;
    serve_on(listener, state, settings, tls, shutdown).await
}

/// [`serve_until`] with a TLS configuration already loaded (`None`: plain HTTP).
pub async fn serve_on(
    listener: tokio::net::TcpListener,
    state: Arc<AppState>,
    settings: &Settings,
    tls: Option<Arc<rustls::ServerConfig>>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    let limits = conn::ConnLimits::new(
        settings.header_timeout,
        settings.idle_timeout,
        settings.max_connections,
        &settings.cors,
        state.registry().datasets.len(),
    )?;
    conn::serve(listener, app(state, settings), limits, tls, shutdown).await;
    Ok(())
}

/// Reloads the datasets on every SIGHUP (the safe deploy: rename a new file over the
/// old one, then signal). Installed before the server says it is listening, so a
/// SIGHUP can never fall on the default action, which would kill the process.
#[cfg(unix)]
fn reload_on_sighup(state: Arc<AppState>) -> anyhow::Result<()> {
    use tokio::signal::unix::{SignalKind, signal};
    let mut hup = signal(SignalKind::hangup())
        .map_err(|e| anyhow::anyhow!("cannot install the SIGHUP handler: {e}"))?;
    tokio::spawn(async move {
        while hup.recv().await.is_some() {
            let s = state.clone();
            // Opening pyramids reads files: keep it off the async workers.
            match tokio::task::spawn_blocking(move || s.reload()).await {
                Ok(Ok(n)) => tracing::info!(datasets = n, "SIGHUP: datasets reloaded"),
                Ok(Err(e)) => {
                    tracing::error!("SIGHUP: reload failed, still serving the old datasets: {e:#}");
                }
                Err(e) => tracing::error!("SIGHUP: reload task failed: {e}"),
            }
        }
    });
    Ok(())
}

/// Loads the datasets and serves until SIGINT/SIGTERM, letting in-flight responses
/// finish; SIGHUP reloads the datasets.
pub async fn run(settings: Settings) -> anyhow::Result<()> {
    allocator::return_large_buffers();
    // Certificate problems stop the server before it says it is listening.
    let tls = settings.tls.as_ref().map(tls::server_config).transpose()?;
    let state = state(&settings)?;
    #[cfg(unix)]
    reload_on_sighup(state.clone())?;
    let listener = tokio::net::TcpListener::bind(settings.listen)
        .await
        .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", settings.listen))?;
    let addr = listener.local_addr()?;
    // Tools and tests read this line to find an ephemeral port.
    let scheme = if tls.is_some() { "https" } else { "http" };
    println!("listening on {scheme}://{addr}");
    tracing::info!(%addr, tls = tls.is_some(), "listening");
    serve_on(listener, state, &settings, tls, shutdown_signal()).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_targets_are_logged_in_part() {
        let short: axum::http::Uri = "/v1/datasets/a?x=1".parse().unwrap();
        assert_eq!(LoggedUri(&short).to_string(), "/v1/datasets/a?x=1");
        let long: axum::http::Uri = format!("/v1/datasets/{}", "n".repeat(60_000))
            .parse()
            .unwrap();
        let shown = LoggedUri(&long).to_string();
        assert!(shown.len() < LOGGED_URI_BYTES + 40, "{}", shown.len());
        assert!(shown.ends_with("… (60013 bytes)"), "{shown}");
    }
}

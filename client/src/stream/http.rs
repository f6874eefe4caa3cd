//! The HTTP client a streamer and its imagery feed use, and the runtime a streamer
//! owns when it is not given one.

use std::time::Duration;

/// The HTTP client of a streamer. HTTPS goes through rustls with the `ring`
/// provider, installed here once for the process (reqwest has no provider of its
/// own; one installed already serves as well). With `h2c`, HTTP/2 with prior
/// knowledge on `http://` URLs.
pub(super) fn http_client(timeout: Duration, h2c: bool) -> reqwest::Result<reqwest::Client> {
    static PROVIDER: std::sync::Once = std::sync::Once::new();
    PROVIDER.call_once(|| {
        let _ = rustls::crypto::ring::default_provider().install_default();
    });
    let b = reqwest::Client::builder().timeout(timeout);
    let b = if h2c { b.http2_prior_knowledge() } else { b };
    b.build()
}

pub(super) fn own_runtime() -> std::io::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
}

//! Where the absolute URLs in documents (TileJSON, WMTS capabilities) point: the
//! scheme and authority clients must use to reach this server (API.md "Absolute
//! URLs", DECISIONS.md "Real clients").
//!
//! In order:
//! 1. `--public-url`, when configured (what deployments behind a CDN set);
//! 2. `X-Forwarded-Host`/`X-Forwarded-Proto`, only with `--trust-forwarded` (a proxy
//!    in front sets them; otherwise any client could);
//! 3. the request's own `Host` (HTTP/2: `:authority`), checked to be a plain
//!    `host[:port]`. It is whatever the client sent, so a response built from it is
//!    marked [`private`] with `Vary: Host`: no shared cache hands one client's
//!    `Host` to another, and a client that lies about it fools only itself.
//!
//! Relative URLs would need no trust at all, but web maps do not resolve them
//! against the document (MapLibre fetches a TileJSON's relative `tiles` from the
//! *page's* origin), and WMTS clients do not either: a page on another origin than
//! the tiles is the usual case, so the default has to be absolute.

use crate::http::error::{ApiError, ApiResult};
use crate::serve::AppState;
use axum::http::{HeaderMap, HeaderValue, Uri, header};

/// Whether `s` is a plain `host[:port]`: host names, IPv4 and bracketed IPv6
/// addresses and ports only (RFC 9110 §7.2), nothing that could change a URL's meaning.
pub fn valid_host(s: &str) -> bool {
    !s.is_empty()
        && s.len() <= 255
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b".-_:[]".contains(&b))
}

/// The first element of the only `name` header, if there is exactly one such header.
fn forwarded<'a>(headers: &'a HeaderMap, name: &str) -> ApiResult<Option<&'a str>> {
    let mut all = headers.get_all(name).iter();
    let Some(v) = all.next() else {
        return Ok(None);
    };
    let bad = || ApiError::bad_request(format!("invalid {name} header"));
    if all.next().is_some() {
        return Err(bad());
    }
    let s = v.to_str().map_err(|_| bad())?;
    // A chain of proxies appends; the first element is what the client used.
    Ok(Some(s.split(',').next().unwrap_or("").trim()))
}

/// The configured base (steps 1 and 2 of the module doc), or `""` when there is
/// none: what documents whose links JSON clients resolve themselves (OGC API, the
/// dataset document) use, as they stay shareable by every cache.
pub fn configured(state: &AppState, headers: &HeaderMap) -> ApiResult<String> {
    if let Some(u) = &state.public_url {
        return Ok(u.clone());
    }
    if !state.trust_forwarded {
        return Ok(String::new());
    }
    let Some(host) = forwarded(headers, "x-forwarded-host")? else {
        return Ok(String::new());
    };
    if !valid_host(host) {
        return Err(ApiError::bad_request("invalid X-Forwarded-Host header"));
    }
    let proto = match forwarded(headers, "x-forwarded-proto")? {
        None => "http",
        Some(p) if p.eq_ignore_ascii_case("http") => "http",
        Some(p) if p.eq_ignore_ascii_case("https") => "https",
        Some(_) => {
            return Err(ApiError::bad_request(
                "invalid X-Forwarded-Proto header: want http or https",
            ));
        }
    };
    Ok(format!("{proto}://{host}"))
}

/// An absolute base, configured or from the request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Base {
    /// Scheme and authority, no trailing slash.
    pub url: String,
    /// Whether it came from the request's `Host`: the response must be [`private`].
    pub from_host: bool,
}

/// The absolute base of the module doc; `None` when nothing is configured and the
/// request has no single valid `Host` (an HTTP/1.0 client, a forged header).
pub fn absolute(state: &AppState, headers: &HeaderMap, uri: &Uri) -> ApiResult<Option<Base>> {
    let url = configured(state, headers)?;
    if !url.is_empty() {
        return Ok(Some(Base {
            url,
            from_host: false,
        }));
    }
    let mut hosts = headers.get_all(header::HOST).iter();
    let host = match (hosts.next(), hosts.next()) {
        (Some(h), None) => h.to_str().ok().map(str::to_string),
        (None, _) => uri.authority().map(|a| a.as_str().to_string()),
        (Some(_), Some(_)) => None,
    };
    let scheme = if state.tls { "https" } else { "http" };
    Ok(host.filter(|h| valid_host(h)).map(|h| Base {
        url: format!("{scheme}://{h}"),
        from_host: true,
    }))
}

/// Marks a response built from the request's `Host` as private to that client
/// (`Cache-Control: private, max-age=…`, `Vary: Host`); 304s included, so a shared
/// cache never stores either.
pub fn private(h: &mut HeaderMap, from_host: bool, max_age: u64) {
    if from_host {
        if let Ok(v) = HeaderValue::from_str(&format!("private, max-age={max_age}")) {
            h.insert(header::CACHE_CONTROL, v);
        }
        h.append(header::VARY, HeaderValue::from_static("host"));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hosts_are_checked() {
        for good in ["tiles.example:8080", "[::1]:80", "127.0.0.1"] {
            assert!(valid_host(good), "{good:?}");
        }
        for bad in ["evil/path", "a b", "x@y", "", "a\"b", "h?x", "h#x"] {
            assert!(!valid_host(bad), "{bad:?}");
        }
    }
}

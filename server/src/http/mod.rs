//! HTTP plumbing under the API, apart from what it serves: the connection layer
//! ([`conn`], with hyper's own errors made JSON by [`own_errors`], and [`tls`]),
//! what browsers and CDNs expect of every response ([`conventions`]: CORS,
//! compression, `OPTIONS`), caching validators ([`cache`]: ETag, `Last-Modified`,
//! 304), `Range` headers ([`range`]) and the JSON error every failure answers
//! ([`error`]). None of it knows about datasets; `serve` builds the API on it.

pub mod cache;
pub mod conn;
pub mod conventions;
pub mod error;
pub mod own_errors;
pub mod range;
pub mod tls;

//! Where a pyramid lives (docs/ARCHITECTURE.md#storage, docs/ARCHITECTURE.md#scale-out):
//! a local path or an object URL, and the store that answers it.
//!
//! A location is a local path or a URL: `s3://`, `gs://`, `az://`/`abfs://`,
//! `file://`, or `http(s)://` to any server that answers `Range`. Stores come from
//! the `object_store` crate, configured from the standard environment variables
//! (`AWS_*`, `GOOGLE_*`, `AZURE_*`; e.g. `AWS_ENDPOINT_URL` and `AWS_ALLOW_HTTP=true`
//! for a store on loopback), with retries and timeouts set here ([`StoreOptions`]).

use anyhow::Context;
use object_store::{
    BackoffConfig, ClientConfigKey, ClientOptions, ObjectStore, ObjectStoreScheme, RetryConfig,
    path::Path,
};
use std::path::PathBuf;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

/// Where a pyramid is: a local file (or directory) or an object in a store.
#[derive(Debug, Clone)]
pub enum Location {
    Local(PathBuf),
    Object(ObjectLocation),
}

/// An object: the store that holds it and its key there.
#[derive(Clone)]
pub struct ObjectLocation {
    /// The URL as given (for messages, and the dataset's label).
    pub url: String,
    pub store: Arc<dyn ObjectStore>,
    pub key: Path,
}

impl std::fmt::Debug for ObjectLocation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ObjectLocation")
            .field("url", &self.url)
            .finish_non_exhaustive()
    }
}

impl ObjectLocation {
    /// The key's last segment without its extension: the dataset's name.
    pub fn stem(&self) -> String {
        let file = self.key.filename().unwrap_or("");
        file.rsplit_once('.').map_or(file, |(s, _)| s).to_string()
    }

    /// The object beside this one in the same store with `extension` instead of its
    /// own (`s3://b/dem.tess` → `s3://b/dem.tessimg`), as a local file's sibling
    /// (`Path::with_extension`). `None` when the file name has no extension to
    /// replace, or the URL does not end with it (a query string, as in a presigned
    /// URL, cannot be carried over to another object).
    pub fn sibling(&self, extension: &str) -> Option<Self> {
        let file = self.key.filename()?;
        let (stem, _) = file.rsplit_once('.').filter(|(s, _)| !s.is_empty())?;
        let key = self.key.as_ref();
        let dir = &key[..key.len() - file.len()];
        let url = self.url.strip_suffix(file)?;
        Some(Self {
            url: format!("{url}{stem}.{extension}"),
            store: self.store.clone(),
            key: Path::from(format!("{dir}{stem}.{extension}")),
        })
    }
}

/// Retries and timeouts of store requests.
#[derive(Debug, Clone, Copy)]
pub struct StoreOptions {
    /// Retries of a request that failed with a 5xx, a timeout or a broken connection
    /// (`object_store` backs off exponentially between them).
    pub max_retries: usize,
    /// No retry starts after this long since the first attempt.
    pub retry_timeout: Duration,
    /// One attempt's limit, connection included.
    pub request_timeout: Duration,
    pub connect_timeout: Duration,
}

impl Default for StoreOptions {
    fn default() -> Self {
        Self {
            max_retries: 4,
            retry_timeout: Duration::from_secs(10),
            request_timeout: Duration::from_secs(20),
            connect_timeout: Duration::from_secs(2),
        }
    }
}

/// Whether `raw` names an object by URL (`scheme://…`) rather than a local path.
pub fn is_url(raw: &str) -> bool {
    raw.split_once("://").is_some_and(|(scheme, _)| {
        !scheme.is_empty()
            && scheme
                .chars()
                .next()
                .is_some_and(|c| c.is_ascii_alphabetic())
            && scheme
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'))
    })
}

/// A local path or an object URL, with the store for it built from the environment.
/// An object must be a pyramid (its key ends in `.tess`).
pub fn locate(raw: &str, opts: StoreOptions) -> anyhow::Result<Location> {
    locate_kind(raw, opts, "tess")
}

/// [`locate`] for a file of another kind: an object's key must end in `.{extension}`
/// (`pmtiles` for `export`'s archives).
pub fn locate_kind(raw: &str, opts: StoreOptions, extension: &str) -> anyhow::Result<Location> {
    if !is_url(raw) {
        return Ok(Location::Local(PathBuf::from(raw)));
    }
    let object = object_at(raw, opts)?;
    anyhow::ensure!(
        std::path::Path::new(object.key.as_ref())
            .extension()
            .is_some_and(|e| e == extension),
        "{raw}: the object's key must end in .{extension} (got {:?})",
        object.key.as_ref()
    );
    Ok(Location::Object(object))
}

/// The object (or, for listing, the prefix) a URL names, with the store for it built
/// from the environment: any key (build inputs are GeoTIFFs, VRTs, lists).
pub fn object_at(raw: &str, opts: StoreOptions) -> anyhow::Result<ObjectLocation> {
    let url = url::Url::parse(raw).with_context(|| format!("{raw}: not a valid URL"))?;
    let (scheme, key) = ObjectStoreScheme::parse(&url).map_err(|e| {
        anyhow::anyhow!(
            "{raw}: not a storage URL this server knows ({e}); use s3://BUCKET/KEY, \
             gs://BUCKET/KEY, az://CONTAINER/KEY, file:///PATH or http(s)://HOST/PATH"
        )
    })?;
    ensure_crypto_provider();
    let retry = RetryConfig {
        backoff: BackoffConfig {
            init_backoff: Duration::from_millis(50),
            max_backoff: Duration::from_secs(2),
            base: 2.0,
        },
        max_retries: opts.max_retries,
        retry_timeout: opts.retry_timeout,
    };
    // Timeouts as config keys, not `with_client_options`, which would replace the
    // client settings the builders read from the environment (AWS_ALLOW_HTTP, proxies).
    let timeouts = [
        (
            ClientConfigKey::Timeout,
            format!("{}ms", opts.request_timeout.as_millis()),
        ),
        (
            ClientConfigKey::ConnectTimeout,
            format!("{}ms", opts.connect_timeout.as_millis()),
        ),
    ];
    let built: Result<Arc<dyn ObjectStore>, object_store::Error> = match scheme {
        ObjectStoreScheme::Local => Ok(Arc::new(object_store::local::LocalFileSystem::new())),
        ObjectStoreScheme::AmazonS3 => {
            use object_store::aws::{AmazonS3Builder, AmazonS3ConfigKey};
            let mut b = AmazonS3Builder::from_env().with_url(raw).with_retry(retry);
            for (k, v) in timeouts {
                b = b.with_config(AmazonS3ConfigKey::Client(k), v);
            }
            b.build().map(|s| Arc::new(s) as _)
        }
        ObjectStoreScheme::GoogleCloudStorage => {
            use object_store::gcp::{GoogleCloudStorageBuilder, GoogleConfigKey};
            let mut b = GoogleCloudStorageBuilder::from_env()
                .with_url(raw)
                .with_retry(retry);
            for (k, v) in timeouts {
                b = b.with_config(GoogleConfigKey::Client(k), v);
            }
            b.build().map(|s| Arc::new(s) as _)
        }
        ObjectStoreScheme::MicrosoftAzure => {
            use object_store::azure::{AzureConfigKey, MicrosoftAzureBuilder};
            let mut b = MicrosoftAzureBuilder::from_env()
                .with_url(raw)
                .with_retry(retry);
            for (k, v) in timeouts {
                b = b.with_config(AzureConfigKey::Client(k), v);
            }
            b.build().map(|s| Arc::new(s) as _)
        }
        ObjectStoreScheme::Http => object_store::http::HttpBuilder::new()
            .with_url(&url[..url::Position::BeforePath])
            .with_retry(retry)
            .with_client_options(
                ClientOptions::new()
                    .with_timeout(opts.request_timeout)
                    .with_connect_timeout(opts.connect_timeout)
                    .with_allow_http(url.scheme() == "http"),
            )
            .build()
            .map(|s| Arc::new(s) as _),
        other => anyhow::bail!("{raw}: {other:?} URLs are not supported"),
    };
    let store = built.map_err(|e| anyhow::anyhow!("{raw}: cannot configure the store: {e}"))?;
    Ok(ObjectLocation {
        url: raw.to_string(),
        store,
        key,
    })
}

/// HTTPS to stores uses rustls with the `ring` provider (as the server's own TLS
/// does); reqwest is built without a provider of its own, so install it once.
fn ensure_crypto_provider() {
    static DONE: OnceLock<()> = OnceLock::new();
    DONE.get_or_init(|| {
        // An `Err` means another provider is already installed, which serves as well.
        let _ = rustls::crypto::ring::default_provider().install_default();
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_and_paths_are_told_apart() {
        for url in [
            "s3://bucket/a.tess",
            "gs://b/k.tess",
            "az://c/k.tess",
            "file:///tmp/a.tess",
            "https://cdn.example.org/p/a.tess",
        ] {
            assert!(is_url(url), "{url}");
        }
        for path in [
            "a.tess",
            "/tmp/a.tess",
            "./s3:/x.tess",
            "dir/",
            "C:\\x.tess",
        ] {
            assert!(!is_url(path), "{path}");
        }
    }

    #[test]
    fn a_sibling_replaces_the_file_names_extension_only() {
        let at = |url: &str| match locate(url, StoreOptions::default()).expect(url) {
            Location::Object(o) => o,
            Location::Local(_) => panic!("{url}: not an object"),
        };
        let s = at("s3://bucket/dir.v2/moon8k.tess")
            .sibling("tessimg")
            .expect("has an extension");
        assert_eq!(s.url, "s3://bucket/dir.v2/moon8k.tessimg");
        assert_eq!(s.key.as_ref(), "dir.v2/moon8k.tessimg");
        let s = at("https://cdn.example.org/p/a.b.tess")
            .sibling("tessimg")
            .unwrap();
        assert_eq!(s.url, "https://cdn.example.org/p/a.b.tessimg");
        assert_eq!(s.stem(), "a.b");
    }

    #[test]
    fn object_urls_name_their_dataset_and_must_be_pyramids() {
        let Location::Object(o) =
            locate("s3://bucket/dir/moon8k.tess", StoreOptions::default()).expect("an s3 URL")
        else {
            panic!("not an object");
        };
        assert_eq!(o.stem(), "moon8k");
        assert_eq!(o.key.as_ref(), "dir/moon8k.tess");
        let e = locate("s3://bucket/dir/moon8k.tif", StoreOptions::default()).unwrap_err();
        assert!(e.to_string().contains("must end in .tess"), "{e}");
        let e = locate("ftp://host/a.tess", StoreOptions::default()).unwrap_err();
        assert!(e.to_string().contains("ftp://host/a.tess"), "{e}");
        assert!(matches!(
            locate("local/a.tess", StoreOptions::default()),
            Ok(Location::Local(_))
        ));
    }
}

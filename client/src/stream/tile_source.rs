//! Where a flight's tiles come from: a Tessera server and dataset, or a pyramid
//! file's URL (read with HTTP Range, `source`).

/// Where a flight's tiles come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TileSource {
    /// `tessera-server serve`: its root URL (e.g. `http://127.0.0.1:8080`) and the
    /// dataset's name there.
    Server { url: String, dataset: String },
    /// A pyramid file on any host that answers HTTP Range requests (nginx, a CDN, an
    /// object store with public read: `http://host/path/file.tess`), or a local file
    /// (`file:///path/file.tess`). No server runs.
    StaticFile { url: String },
}

impl TileSource {
    pub fn server(url: impl Into<String>, dataset: impl Into<String>) -> Self {
        Self::Server {
            url: url.into(),
            dataset: dataset.into(),
        }
    }

    pub fn pyramid(url: impl Into<String>) -> Self {
        Self::StaticFile { url: url.into() }
    }

    /// The dataset's name: the server's, or the file's stem (as the server would
    /// name it).
    pub fn name(&self) -> &str {
        match self {
            Self::Server { dataset, .. } => dataset,
            Self::StaticFile { url } => file_stem(url),
        }
    }
}

impl std::fmt::Display for TileSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Server { url, dataset } => write!(f, "dataset {dataset} on {url}"),
            Self::StaticFile { url } => write!(f, "pyramid {url}"),
        }
    }
}

/// The last path segment of `url` without its extension (`moon8k` of
/// `http://cdn/x/moon8k.tess?sig=…`).
fn file_stem(url: &str) -> &str {
    let path = url.split(['?', '#']).next().unwrap_or(url);
    let last = path.rsplit('/').next().unwrap_or(path);
    match last.rsplit_once('.') {
        Some((stem, _)) if !stem.is_empty() => stem,
        _ => last,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_file_stems() {
        assert_eq!(file_stem("http://h/a/moon8k.tess"), "moon8k");
        assert_eq!(file_stem("http://h/b/k.tess?X-Amz=1#f"), "k");
        assert_eq!(file_stem("file:///tmp/terrain"), "terrain");
        assert_eq!(TileSource::pyramid("http://h/x.tess").name(), "x");
        assert_eq!(TileSource::server("http://h", "moon").name(), "moon");
    }
}

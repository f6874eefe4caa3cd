//! Arguments and value parsers more than one command shares: where the tiles come
//! from, durations and viewports.

use crate::stream::TileSource;
use anyhow::Context;

/// Where the tiles come from: a server and dataset, or a pyramid file's URL.
#[derive(Debug, clap::Args)]
pub(crate) struct SourceArgs {
    /// Server base URL, e.g. http://127.0.0.1:8080.
    #[arg(long, required_unless_present = "pyramid", requires = "dataset")]
    pub(super) server: Option<String>,
    /// Dataset name on the server.
    #[arg(long, required_unless_present = "pyramid", requires = "server")]
    pub(super) dataset: Option<String>,
    /// Read a pyramid file straight from a static host, CDN or object store with
    /// HTTP Range requests, no Tessera server: http(s)://host/path/file.tess (or
    /// file:///path/file.tess). The host must answer Range requests with 206.
    #[arg(long, value_name = "URL", conflicts_with_all = ["server", "dataset"])]
    pub(super) pyramid: Option<String>,
}

impl SourceArgs {
    pub(crate) fn source(self) -> anyhow::Result<TileSource> {
        match (self.pyramid, self.server, self.dataset) {
            (Some(url), None, None) => Ok(TileSource::pyramid(url)),
            (None, Some(server), Some(dataset)) => Ok(TileSource::server(server, dataset)),
            _ => anyhow::bail!("give --server URL --dataset NAME, or --pyramid URL"),
        }
    }
}

/// A command-line duration that is not one.
#[derive(Debug, thiserror::Error)]
#[error("{0:?} is not a positive duration like 30s, 2m, 1500ms or 1m30s")]
pub(crate) struct BadDuration(String);

/// Parses `30s`, `2m`, `1500ms`, `1m30s` or plain seconds (clap's value parser).
pub(crate) fn parse_duration(s: &str) -> Result<std::time::Duration, BadDuration> {
    crate::loadtest::pacing::parse_duration(s).ok_or_else(|| BadDuration(s.to_string()))
}

pub(crate) fn parse_viewport(v: &str) -> anyhow::Result<(u32, u32)> {
    v.split_once('x')
        .and_then(|(a, b)| Some((a.parse::<u32>().ok()?, b.parse::<u32>().ok()?)))
        .filter(|(w, h)| *w > 0 && *h > 0)
        .with_context(|| format!("viewport {v:?} is not WIDTHxHEIGHT"))
}

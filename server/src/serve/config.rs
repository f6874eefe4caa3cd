//! `serve` settings: command-line flags, then environment variables, then a TOML
//! file (`--config`), then defaults — the first that says something wins.

use anyhow::Context;
use serde::Deserialize;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

/// `tessera-server serve` flags (each also readable from a `TESSERA_*` variable).
#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// Pyramid files (.tess) or directories holding them; datasets are named by file stem.
    pub paths: Vec<PathBuf>,
    /// Address to listen on [default: 127.0.0.1:8080].
    #[arg(long, env = "TESSERA_LISTEN")]
    pub listen: Option<SocketAddr>,
    /// TOML file with any of these settings (keys as the flags, with underscores).
    #[arg(long, env = "TESSERA_CONFIG")]
    pub config: Option<PathBuf>,
    /// Most Morton ranges in one request [default: 256].
    #[arg(long, env = "TESSERA_MAX_RANGES")]
    pub max_ranges: Option<usize>,
    /// Most tiles (Morton codes) in one request [default: 4096].
    #[arg(long, env = "TESSERA_MAX_TILES")]
    pub max_tiles: Option<u64>,
    /// Longest query string accepted, in bytes [default: 8192].
    #[arg(long, env = "TESSERA_MAX_QUERY_BYTES")]
    pub max_query_bytes: Option<usize>,
    /// Seconds before an unfinished request is answered 408 [default: 30].
    #[arg(long, env = "TESSERA_TIMEOUT_SECS")]
    pub timeout_secs: Option<u64>,
    /// Requests handled at once; more wait their turn [default: 1024].
    #[arg(long, env = "TESSERA_CONCURRENCY")]
    pub concurrency: Option<usize>,
    /// Cache-Control max-age for responses whose URL does not pin the content [default: 3600].
    #[arg(long, env = "TESSERA_CACHE_MAX_AGE")]
    pub cache_max_age: Option<u64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileConfig {
    listen: Option<SocketAddr>,
    datasets: Option<Vec<PathBuf>>,
    max_ranges: Option<usize>,
    max_tiles: Option<u64>,
    max_query_bytes: Option<usize>,
    timeout_secs: Option<u64>,
    concurrency: Option<usize>,
    cache_max_age: Option<u64>,
}

/// Resolved settings.
#[derive(Debug, Clone)]
pub struct Settings {
    pub listen: SocketAddr,
    pub datasets: Vec<PathBuf>,
    pub max_ranges: usize,
    pub max_tiles: u64,
    pub max_query_bytes: usize,
    pub timeout: Duration,
    pub concurrency: usize,
    pub cache_max_age: u64,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            listen: SocketAddr::from(([127, 0, 0, 1], 8080)),
            datasets: Vec::new(),
            max_ranges: 256,
            max_tiles: 4096,
            max_query_bytes: 8192,
            timeout: Duration::from_secs(30),
            concurrency: 1024,
            cache_max_age: 3600,
        }
    }
}

impl Settings {
    pub fn resolve(args: &ServeArgs) -> anyhow::Result<Self> {
        let file: FileConfig = match &args.config {
            Some(p) => {
                let text = std::fs::read_to_string(p)
                    .with_context(|| format!("{}: cannot read config", p.display()))?;
                toml::from_str(&text).with_context(|| format!("{}: bad config", p.display()))?
            }
            None => FileConfig::default(),
        };
        let d = Self::default();
        let datasets = if args.paths.is_empty() {
            file.datasets.unwrap_or_default()
        } else {
            args.paths.clone()
        };
        anyhow::ensure!(
            !datasets.is_empty(),
            "no datasets: name .tess files or directories (or `datasets = [...]` in --config)"
        );
        let s = Self {
            listen: args.listen.or(file.listen).unwrap_or(d.listen),
            datasets,
            max_ranges: args.max_ranges.or(file.max_ranges).unwrap_or(d.max_ranges),
            max_tiles: args.max_tiles.or(file.max_tiles).unwrap_or(d.max_tiles),
            max_query_bytes: args
                .max_query_bytes
                .or(file.max_query_bytes)
                .unwrap_or(d.max_query_bytes),
            timeout: args
                .timeout_secs
                .or(file.timeout_secs)
                .map_or(d.timeout, Duration::from_secs),
            concurrency: args
                .concurrency
                .or(file.concurrency)
                .unwrap_or(d.concurrency),
            cache_max_age: args
                .cache_max_age
                .or(file.cache_max_age)
                .unwrap_or(d.cache_max_age),
        };
        anyhow::ensure!(
            s.max_ranges > 0 && s.max_tiles > 0 && s.concurrency > 0,
            "limits must be positive"
        );
        Ok(s)
    }
}

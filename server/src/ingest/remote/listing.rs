//! Input URLs that name many objects: a prefix (a folder) or a glob.

use crate::storage::{StoreOptions, object_at};
use anyhow::{Context, bail};
use futures_util::StreamExt;
use object_store::ObjectStore;
use std::path::{Path, PathBuf};

/// Whether a key names a DEM file by its extension.
fn is_dem_key(key: &str) -> bool {
    Path::new(key)
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| {
            super::super::DEM_EXTENSIONS
                .iter()
                .any(|d| e.eq_ignore_ascii_case(d))
        })
}

/// Expands an input URL: a prefix ending in `/` lists the DEM files directly under it
/// (as a folder does), a key with `*`, `?` or `[` lists those matching it (a `*` does
/// not cross `/`), anything else is one object (opening it says whether it exists).
/// Keys are taken in byte order, as files of a folder are.
pub fn expand(url: &str) -> anyhow::Result<Vec<PathBuf>> {
    let wildcard = url.find(['*', '?', '[']);
    let folder = url.ends_with('/');
    if wildcard.is_none() && !folder {
        return Ok(vec![PathBuf::from(url)]);
    }
    if url.starts_with("http://") || url.starts_with("https://") {
        bail!(
            "{url}: an HTTP server cannot be listed; name each file, or list their URLs in a file \
             given with --inputs"
        );
    }
    // The folder that is listed: up to the last `/` before any wildcard.
    let cut = wildcard.unwrap_or(url.len());
    let slash = url[..cut].rfind('/').map_or(0, |i| i + 1);
    let (prefix_url, rest) = url.split_at(slash);
    let loc = object_at(prefix_url, StoreOptions::default())?;
    let prefix = loc.key.clone();
    let pattern = if rest.is_empty() {
        None
    } else {
        let full = if prefix.as_ref().is_empty() {
            rest.to_string()
        } else {
            format!("{}/{rest}", prefix.as_ref())
        };
        Some(
            glob::Pattern::new(&full)
                .with_context(|| format!("{url}: not a valid glob pattern"))?,
        )
    };
    let (store, recursive) = (loc.store.clone(), pattern.is_some());
    let listed: Result<Vec<String>, object_store::Error> =
        crate::storage::runtime::block_on(async move {
            let p = (!prefix.as_ref().is_empty()).then_some(prefix);
            let mut keys = Vec::new();
            if recursive {
                let mut s = store.list(p.as_ref());
                while let Some(o) = s.next().await {
                    keys.push(o?.location.to_string());
                }
            } else {
                // One level, as a folder.
                let l = store.list_with_delimiter(p.as_ref()).await?;
                keys.extend(l.objects.into_iter().map(|o| o.location.to_string()));
            }
            Ok(keys)
        });
    let listed = listed.map_err(|e| anyhow::anyhow!("{url}: cannot list the store: {e}"))?;
    let options = glob::MatchOptions {
        require_literal_separator: true,
        ..glob::MatchOptions::default()
    };
    let mut keys: Vec<String> = listed
        .into_iter()
        .filter(|k| match &pattern {
            Some(p) => p.matches_with(k, options),
            None => is_dem_key(k),
        })
        .collect();
    keys.sort();
    if keys.is_empty() {
        match &pattern {
            Some(_) => bail!("{url}: no object matches this pattern"),
            None => bail!(
                "{url}: the prefix holds no DEM files (.{})",
                super::super::DEM_EXTENSIONS.join(", .")
            ),
        }
    }
    // Back to URLs: the listed prefix's URL, then the key's part below it.
    let base = loc.key.as_ref().len();
    Ok(keys
        .into_iter()
        .map(|k| {
            let below = k[base..].trim_start_matches('/');
            PathBuf::from(format!("{prefix_url}{below}"))
        })
        .collect())
}

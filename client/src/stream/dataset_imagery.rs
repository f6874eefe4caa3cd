//! The dataset's imagery beside its tiles: the feed a streamer opens for it, from a
//! server's imagery routes or the `.tessimg` file beside a static pyramid.

use super::imagery_tiles;
use super::static_file::{StaticFile, StaticFileError};
use super::streamer::{Backend, Streamer};
use crate::errors::Chain;
use std::sync::Arc;

impl Streamer {
    /// The dataset's imagery, fetched beside the tiles on this streamer's runtime and
    /// connection ([`imagery_tiles::ImageryFeed`]): `None` when the dataset has none. A
    /// static pyramid file's imagery is the file beside it with `.tess` replaced by
    /// `.tessimg` (none for a presigned URL, which names one object); one that
    /// does not open is skipped with a warning, and the tint is drawn instead.
    pub fn imagery_feed(&self, capacity: usize) -> Option<imagery_tiles::ImageryFeed> {
        let url = match &self.backend {
            Backend::Server { url, .. } => url,
            Backend::Static(file) => {
                let (img, info) = self.open_imagery_beside(file)?;
                return Some(imagery_tiles::ImageryFeed::from_file(
                    self.rt.clone(),
                    self.client.clone(),
                    img,
                    info,
                    capacity,
                ));
            }
        };
        let info = self.imagery.clone()?;
        Some(
            imagery_tiles::ImageryFeed::new(
                self.rt.clone(),
                self.client.clone(),
                url.clone(),
                info,
                capacity,
            )
            .recording(self.config.record.clone()),
        )
    }

    /// The imagery pyramid beside the static pyramid `file` (`NAME.tessimg` beside
    /// `NAME.tess`, at the same host), when there is one built for exactly this DEM
    /// (its content hash), as the server attaches it. Imagery is optional: a file
    /// that is not there is `None` quietly; one that does not open, or belongs to
    /// another version of the DEM, is `None` with a warning, and the flight goes on
    /// with the hypsometric tint.
    fn open_imagery_beside(
        &self,
        file: &StaticFile,
    ) -> Option<(Arc<StaticFile>, tessera_shared::api::ImageryInfo)> {
        let (stem, query) = match file.url.split_once('?') {
            Some((s, q)) => (s, Some(q)),
            None => (file.url.as_str(), None),
        };
        // A query (a presigned URL's signature) names one object only.
        if query.is_some() {
            return None;
        }
        let url = format!("{}.tessimg", stem.strip_suffix(".tess")?);
        let opened = self
            .rt
            .block_on(StaticFile::open_imagery(&self.client, &url));
        let img = match opened {
            Ok(img) => img,
            Err(e) => {
                if matches!(e, StaticFileError::NoSuchFile(_)) {
                    tracing::debug!("{url}: no imagery beside the pyramid");
                } else {
                    tracing::warn!("{url}: imagery not used: {}", Chain(&e));
                }
                return None;
            }
        };
        let meta = img.pyramid.imagery()?;
        let dem = &file.pyramid.metadata().content_hash;
        if &meta.dem.content_hash != dem {
            tracing::warn!(
                "{url}: imagery built for another version of the DEM (content hash {}, the pyramid's is {dem}): not used",
                meta.dem.content_hash
            );
            return None;
        }
        let name = file.url.rsplit('/').next().unwrap_or_default();
        let info = tessera_shared::api::ImageryInfo::new(
            name,
            meta,
            tessera_shared::ByteSource::size(img.pyramid.source()).unwrap_or(0),
        );
        Some((Arc::new(img), info))
    }
}

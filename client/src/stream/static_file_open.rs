//! Opening a static pyramid file (module `static_file`): its header region in one
//! Range request, or two for a large one; read whole, once, from a host that
//! ignores `Range` when it is small; or from a local file (`file://`).

use super::static_file::{
    FIRST_RANGE, HeaderRegion, MAX_HEADER_REGION, MAX_WHOLE_BODY, PyramidKind, StaticFile,
    StaticFileError, Transport, Validators, content_range, read_body,
};
use reqwest::StatusCode;
use reqwest::header;
use std::path::Path;
use tessera_shared::format::{FileHeader, HEADER_LEN};
use tessera_shared::{ByteSource, FileSource};

impl StaticFile {
    /// Opens `url` (`http://…` or `file://…`), reading its header region.
    pub async fn open(client: &reqwest::Client, url: &str) -> Result<Self, StaticFileError> {
        Self::open_as(client, url, PyramidKind::Dem).await
    }

    /// Opens the imagery pyramid at `url` as [`StaticFile::open`] opens a DEM's.
    pub async fn open_imagery(
        client: &reqwest::Client,
        url: &str,
    ) -> Result<Self, StaticFileError> {
        Self::open_as(client, url, PyramidKind::Imagery).await
    }

    async fn open_as(
        client: &reqwest::Client,
        url: &str,
        kind: PyramidKind,
    ) -> Result<Self, StaticFileError> {
        if let Some(path) = url.strip_prefix("file://") {
            if !Path::new(path).exists() {
                return Err(StaticFileError::NoSuchFile(url.to_string()));
            }
            return Self::open_local(url, Path::new(path), kind);
        }
        if !(url.starts_with("http://") || url.starts_with("https://")) {
            return Err(StaticFileError::Scheme { url: url.into() });
        }
        let first = client
            .get(url)
            .header(header::RANGE, format!("bytes=0-{}", FIRST_RANGE - 1))
            .send()
            .await
            .map_err(|source| StaticFileError::FetchHeader {
                url: url.into(),
                source,
            })?;
        match first.status() {
            StatusCode::PARTIAL_CONTENT => Self::open_ranged(client, url, first, kind).await,
            StatusCode::OK => Self::open_whole(url, first, kind).await,
            StatusCode::RANGE_NOT_SATISFIABLE => Err(StaticFileError::Empty { url: url.into() }),
            StatusCode::NOT_FOUND | StatusCode::GONE => {
                Err(StaticFileError::NoSuchFile(url.to_string()))
            }
            status => Err(StaticFileError::Status {
                url: url.into(),
                status,
            }),
        }
    }

    /// The usual case: the host answered the first Range request with 206.
    async fn open_ranged(
        client: &reqwest::Client,
        url: &str,
        first: reqwest::Response,
        kind: PyramidKind,
    ) -> Result<Self, StaticFileError> {
        let (start, _, total) = content_range(first.headers())
            .ok_or_else(|| StaticFileError::NoContentRange { url: url.into() })?;
        if start != 0 {
            return Err(StaticFileError::RangeStart {
                url: url.into(),
                start,
            });
        }
        let validators = Validators::of_response(first.headers(), total);
        let mut bytes =
            read_body(first, FIRST_RANGE)
                .await
                .map_err(|source| StaticFileError::ReadHeader {
                    url: url.into(),
                    source,
                })?;
        let header = FileHeader::parse(&bytes).map_err(|e| pyramid_error(url, &e))?;
        let region = header.records_offset;
        if region > MAX_HEADER_REGION {
            return Err(StaticFileError::RegionTooLarge {
                url: url.into(),
                region,
            });
        }
        let mut requests = 1;
        let have = bytes.len() as u64;
        if region > have {
            // One more request for the rest of the indices and the metadata.
            let rest = client
                .get(url)
                .header(header::RANGE, format!("bytes={have}-{}", region - 1))
                .send()
                .await
                .map_err(|source| StaticFileError::FetchIndices {
                    url: url.into(),
                    source,
                })?;
            requests += 1;
            let now = Validators::of_response(
                rest.headers(),
                content_range(rest.headers()).and_then(|r| r.2),
            );
            if let Some(what) = validators.changed(&now) {
                return Err(StaticFileError::PyramidChanged {
                    url: url.into(),
                    what,
                });
            }
            if rest.status() != StatusCode::PARTIAL_CONTENT {
                return Err(StaticFileError::IndicesStatus {
                    url: url.into(),
                    status: rest.status(),
                });
            }
            if content_range(rest.headers()).map(|r| (r.0, r.1)) != Some((have, region - 1)) {
                return Err(StaticFileError::IndicesRange { url: url.into() });
            }
            bytes.extend(read_body(rest, region - have).await?);
        }
        if (bytes.len() as u64) < region {
            return Err(StaticFileError::EndsInRegion {
                url: url.into(),
                have: bytes.len(),
                region,
            });
        }
        let open_bytes = bytes.len() as u64;
        bytes.truncate(region as usize);
        let pyramid = kind
            .open(HeaderRegion {
                bytes,
                total: total.unwrap_or(u64::MAX),
            })
            .map_err(|e| pyramid_error(url, &e))?;
        Ok(Self {
            url: url.to_string(),
            pyramid,
            transport: Transport::Http(validators),
            open_requests: requests,
            open_bytes,
        })
    }

    /// A host that ignores `Range`: a small file is read whole, once; a large one is
    /// refused before its body is read.
    async fn open_whole(
        url: &str,
        resp: reqwest::Response,
        kind: PyramidKind,
    ) -> Result<Self, StaticFileError> {
        let refuse = |n: &dyn std::fmt::Display| StaticFileError::IgnoresRange {
            url: url.into(),
            size: n.to_string(),
        };
        if let Some(n) = resp.content_length().filter(|n| *n > MAX_WHOLE_BODY) {
            return Err(refuse(&n));
        }
        let body = read_body(resp, MAX_WHOLE_BODY + 1).await?;
        if body.len() as u64 > MAX_WHOLE_BODY {
            return Err(refuse(&format!("over-{MAX_WHOLE_BODY}")));
        }
        let total = body.len() as u64;
        let header = FileHeader::parse(&body).map_err(|e| pyramid_error(url, &e))?;
        let region = usize::try_from(header.records_offset)
            .ok()
            .filter(|r| *r <= body.len())
            .ok_or_else(|| StaticFileError::EndsInWholeRegion { url: url.into() })?;
        let pyramid = kind
            .open(HeaderRegion {
                bytes: body[..region].to_vec(),
                total,
            })
            .map_err(|e| pyramid_error(url, &e))?;
        tracing::warn!("{url}: the host ignores HTTP Range; read the whole {total}-byte file");
        Ok(Self {
            url: url.to_string(),
            pyramid,
            transport: Transport::Memory(body),
            open_requests: 1,
            open_bytes: total,
        })
    }

    /// `file://PATH`: the header region read from the file, records with `pread`.
    fn open_local(url: &str, path: &Path, kind: PyramidKind) -> Result<Self, StaticFileError> {
        let file = FileSource::open(path).map_err(|source| StaticFileError::LocalOpen {
            url: url.into(),
            source,
        })?;
        let total = file.size()?;
        let head = file
            .read_vec(0, HEADER_LEN.min(total as usize))
            .map_err(|source| StaticFileError::LocalRead {
                url: url.into(),
                source,
            })?;
        let header = FileHeader::parse(&head).map_err(|e| pyramid_error(url, &e))?;
        if header.records_offset > total.min(MAX_HEADER_REGION) {
            return Err(StaticFileError::LocalRegion {
                url: url.into(),
                region: header.records_offset,
            });
        }
        let bytes = file.read_vec(0, header.records_offset as usize)?;
        let open_bytes = bytes.len() as u64;
        let pyramid = kind
            .open(HeaderRegion { bytes, total })
            .map_err(|e| pyramid_error(url, &e))?;
        Ok(Self {
            url: url.to_string(),
            pyramid,
            transport: Transport::File(std::sync::Arc::new(file)),
            open_requests: 0,
            open_bytes,
        })
    }
}

/// [`StaticFileError::Pyramid`]: a header or header region of `url` that does not
/// parse or fails its checks.
fn pyramid_error(url: &str, e: &dyn std::fmt::Display) -> StaticFileError {
    StaticFileError::Pyramid {
        url: url.into(),
        error: e.to_string(),
    }
}

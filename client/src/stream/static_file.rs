//! A pyramid file read straight from a static host with HTTP Range (serverless reads:
//! DECISIONS.md "Serverless reads", docs/ARCHITECTURE.md#scale-out), the other
//! [`super::TileSource`] beside a Tessera server.
//!
//! A static file is opened with as few requests as the format allows (FORMAT.md
//! "Layout": the header, level table, every level's index and the metadata lie
//! together before `records_offset`): one Range request for the first
//! [`FIRST_RANGE`] bytes, which holds the whole header region of most pyramids, and
//! at most one more for the rest of it. The header checksum covers that whole region,
//! so it is checked as a local file's is ([`Pyramid::open`]). From then on the index
//! is local: a Morton range of present tiles is one byte range ([`Pyramid::byte_range`]),
//! fetched with one Range request and split into records at the index's boundaries;
//! every record is checked against its index checksum. Tiles with no index entry are
//! known absent without asking anyone.
//!
//! The first response's validators (`ETag`, `Last-Modified`) and the file's length are
//! kept, and every later answer's headers are compared with them before its body is
//! read, so a file replaced under the client is reported ("the pyramid changed under
//! the client") rather than read as a mixture of two files. Requests do not carry
//! `If-Range`: a host would answer a changed file with `200` and the whole new file,
//! which it then pushes down the connection until the client drops it; without
//! `If-Range` the answer is the range of the new file, a few records at most, and its
//! headers say it changed just the same.
//!
//! Opening is `static_file_open`; here are the file's parts, its errors and its
//! reads.

use reqwest::StatusCode;
use reqwest::header::{self, HeaderMap};
use std::io;
use tessera_shared::api::DatasetInfo;
use tessera_shared::format::IndexEntry;
use tessera_shared::{ByteSource, FileSource, Pyramid, TileId};

/// Bytes asked for by the first request of an open: the header region of every
/// pyramid up to about 1900 index entries per file (a 4097² DEM in 128-cell tiles,
/// an 8193² one in 256-cell tiles) fits, so it opens with one request; larger
/// ones take one more.
pub const FIRST_RANGE: u64 = 64 * 1024;

/// The largest header region (header, level table, indices, metadata) an open will
/// read: the dense index grows with the finest level's `4^L`; beyond this a file is
/// too big to open serverlessly (serve it with `tessera-server`).
pub const MAX_HEADER_REGION: u64 = 256 << 20;

/// The largest file accepted from a host that ignores `Range` (answers 200 with
/// the whole body): read into memory once. A larger one is refused before its body
/// is read.
pub const MAX_WHOLE_BODY: u64 = 64 << 20;

/// The header region of a remote file: bytes `0..records_offset`, and the file's
/// length. Reads outside the region fail (records are fetched by the streamer).
#[derive(Debug)]
pub(crate) struct HeaderRegion {
    pub(super) bytes: Vec<u8>,
    pub(super) total: u64,
}

impl ByteSource for HeaderRegion {
    fn size(&self) -> io::Result<u64> {
        Ok(self.total)
    }

    fn read_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()> {
        let start = usize::try_from(offset).map_err(|_| io::ErrorKind::UnexpectedEof)?;
        let src = start
            .checked_add(buf.len())
            .and_then(|end| self.bytes.get(start..end))
            .ok_or(io::ErrorKind::UnexpectedEof)?;
        buf.copy_from_slice(src);
        Ok(())
    }
}

/// What identifies one version of a remote file: compared on every response.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct Validators {
    pub etag: Option<String>,
    pub last_modified: Option<String>,
    /// The file's length (`Content-Range`'s total), when the host says.
    pub total: Option<u64>,
}

impl Validators {
    pub(crate) fn of_response(headers: &HeaderMap, total: Option<u64>) -> Self {
        let text = |name| {
            headers
                .get(name)
                .and_then(|v: &header::HeaderValue| v.to_str().ok())
                .map(str::to_string)
        };
        Self {
            etag: text(header::ETAG),
            last_modified: text(header::LAST_MODIFIED),
            total,
        }
    }

    /// `Some(what differs)` when `now` (a later response) is not the file this was
    /// taken from. Validators a response leaves out are not compared.
    pub(crate) fn changed(&self, now: &Self) -> Option<String> {
        let differs = |what: &str, a: &Option<String>, b: &Option<String>| match (a, b) {
            (Some(a), Some(b)) if a != b => Some(format!("{what} {a} at open, now {b}")),
            _ => None,
        };
        differs("ETag", &self.etag, &now.etag)
            .or_else(|| differs("Last-Modified", &self.last_modified, &now.last_modified))
            .or_else(|| match (self.total, now.total) {
                (Some(a), Some(b)) if a != b => Some(format!("{a} bytes at open, now {b}")),
                _ => None,
            })
    }
}

/// How a static file's records are read.
#[derive(Debug)]
pub(crate) enum Transport {
    /// HTTP Range requests, checked against the open's validators.
    Http(Validators),
    /// The whole file, from a host that ignored `Range` (small files only).
    Memory(Vec<u8>),
    /// A local file (`file://`).
    File(std::sync::Arc<FileSource>),
}

/// Why a static pyramid file could not be opened or read: each names the URL (and,
/// for a read, the byte range) and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum StaticFileError {
    /// The file is not there (HTTP 404 or 410, or no such local file): for optional
    /// files, such as the imagery beside a pyramid, to be told from broken ones.
    #[error("{0}: no such file (HTTP 404)")]
    NoSuchFile(String),
    #[error("{url}: a pyramid URL is http://…, https://… or file://…")]
    Scheme { url: String },
    #[error("{url}: cannot fetch the pyramid's header")]
    FetchHeader {
        url: String,
        #[source]
        source: reqwest::Error,
    },
    #[error("{url}: 416 Range Not Satisfiable: the file is empty")]
    Empty { url: String },
    #[error("{url}: HTTP {status}")]
    Status { url: String, status: StatusCode },
    #[error("{url}: 206 without a valid Content-Range")]
    NoContentRange { url: String },
    #[error("{url}: asked for bytes from 0, got them from {start}")]
    RangeStart { url: String, start: u64 },
    #[error("{url}: reading the pyramid's header")]
    ReadHeader {
        url: String,
        #[source]
        source: reqwest::Error,
    },
    /// The header or the header region does not parse, or fails its checks.
    #[error("{url}: {error}")]
    Pyramid { url: String, error: String },
    #[error(
        "{url}: the header region (header, indices, metadata) is {region} bytes, more than the {MAX_HEADER_REGION} a serverless read fetches; serve this pyramid with tessera-server"
    )]
    RegionTooLarge { url: String, region: u64 },
    #[error("{url}: cannot fetch the pyramid's indices")]
    FetchIndices {
        url: String,
        #[source]
        source: reqwest::Error,
    },
    #[error("{url}: the pyramid changed under the client ({what})")]
    PyramidChanged { url: String, what: String },
    #[error("{url}: HTTP {status} to the Range request for the indices")]
    IndicesStatus { url: String, status: StatusCode },
    #[error("{url}: the answer for the indices is not the range asked for")]
    IndicesRange { url: String },
    #[error("{url}: the file ends inside its header region ({have} of {region} bytes)")]
    EndsInRegion {
        url: String,
        have: usize,
        region: u64,
    },
    #[error("{url}: the file ends inside its header region")]
    EndsInWholeRegion { url: String },
    #[error(
        "{url}: the host ignores HTTP Range (it answered 200 with the whole {size}-byte file); serverless reads need Range support (nginx, S3 and CDNs have it), and a file over {MAX_WHOLE_BODY} bytes is not downloaded whole"
    )]
    IgnoresRange { url: String, size: String },
    #[error("{url}: cannot open")]
    LocalOpen {
        url: String,
        #[source]
        source: io::Error,
    },
    #[error("{url}: cannot read")]
    LocalRead {
        url: String,
        #[source]
        source: io::Error,
    },
    #[error("{url}: the header region of {region} bytes does not fit the file or the limit")]
    LocalRegion { url: String, region: u64 },
    #[error("{from}: an empty range")]
    EmptyRange { from: String },
    /// A Range request that failed on its way, or a local read that failed.
    #[error("{from}")]
    Range {
        from: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("{from}: the file changed under the client ({what})")]
    FileChanged { from: String, what: String },
    #[error("{from}: HTTP {status} to a Range request")]
    RangeStatus { from: String, status: StatusCode },
    #[error("{from}: the host answered another range")]
    OtherRange { from: String },
    #[error("{from}: {got} bytes in the answer, {len} asked for")]
    RangeLength { from: String, got: usize, len: u64 },
    #[error("{from}: the file is shorter than its index says")]
    Short { from: String },
    #[error("range too long")]
    RangeTooLong(#[source] std::num::TryFromIntError),
    #[error(transparent)]
    Http(#[from] reqwest::Error),
    #[error(transparent)]
    Io(#[from] io::Error),
    #[error(transparent)]
    Task(#[from] tokio::task::JoinError),
}

/// Which kind of pyramid a static file must be: a DEM's (`.tess`) or its imagery's
/// (`.tessimg`, FORMAT.md "Imagery pyramids"); the container is the same, the magic
/// and metadata differ.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum PyramidKind {
    Dem,
    Imagery,
}

impl PyramidKind {
    pub(super) fn open(
        self,
        region: HeaderRegion,
    ) -> Result<Pyramid<HeaderRegion>, tessera_shared::reader::ReadError> {
        match self {
            Self::Dem => Pyramid::open(region),
            Self::Imagery => Pyramid::open_imagery(region),
        }
    }
}

/// A pyramid file opened for serverless reads: its header region checked and
/// parsed, every level's index in memory, records read on demand.
#[derive(Debug)]
pub(crate) struct StaticFile {
    pub url: String,
    pub pyramid: Pyramid<HeaderRegion>,
    pub transport: Transport,
    /// Requests and bytes the open took.
    pub open_requests: u32,
    pub open_bytes: u64,
}

impl StaticFile {
    /// The dataset's document as the server would send it for this file (API.md):
    /// everything the client learns of a dataset comes from the file's header here.
    pub fn describe(&self, name: &str) -> DatasetInfo {
        let p = &self.pyramid;
        // A host that does not say the file's length (`Content-Range: …/*`): where
        // the last level's records end.
        let bytes = match p.source().total {
            u64::MAX => p
                .geometry()
                .levels()
                .filter_map(|l| p.level_entry(l))
                .map(|e| e.records_offset + e.records_len)
                .max()
                .unwrap_or(0),
            total => total,
        };
        DatasetInfo::new(name, p.metadata(), p.header().version, bytes)
    }

    /// The index entry of `tile`, `None` when it has no record (absent).
    pub fn entry(&self, tile: TileId) -> Option<IndexEntry> {
        self.pyramid.entry(tile).copied()
    }
}

impl StaticFile {
    /// Bytes `start..end` of the file, whole (for reads that are not streamed into
    /// the tile pool, such as imagery records): a Range request checked as
    /// [`super::fetch::fetch_range`] checks its answers (206, the range asked for,
    /// the file the client opened), or the bytes held in memory, or a `pread`.
    pub async fn read_range(
        &self,
        client: &reqwest::Client,
        start: u64,
        end: u64,
    ) -> Result<Vec<u8>, StaticFileError> {
        let from = format!("{} bytes={start}-{}", self.url, end.saturating_sub(1));
        if start >= end {
            return Err(StaticFileError::EmptyRange { from });
        }
        let failed =
            |from: &str, e: Box<dyn std::error::Error + Send + Sync>| StaticFileError::Range {
                from: from.to_string(),
                source: e,
            };
        let len = end - start;
        match &self.transport {
            Transport::Http(validators) => {
                let resp = client
                    .get(&self.url)
                    .header(header::RANGE, format!("bytes={start}-{}", end - 1))
                    .send()
                    .await
                    .map_err(|e| failed(&from, e.into()))?;
                let range = content_range(resp.headers());
                let now = Validators::of_response(resp.headers(), range.and_then(|r| r.2));
                if let Some(what) = validators.changed(&now) {
                    return Err(StaticFileError::FileChanged { from, what });
                }
                if resp.status() != StatusCode::PARTIAL_CONTENT {
                    return Err(StaticFileError::RangeStatus {
                        from,
                        status: resp.status(),
                    });
                }
                if range.map(|r| (r.0, r.1)) != Some((start, end - 1)) {
                    return Err(StaticFileError::OtherRange { from });
                }
                let body = read_body(resp, len + 1)
                    .await
                    .map_err(|e| failed(&from, e.into()))?;
                if body.len() as u64 != len {
                    return Err(StaticFileError::RangeLength {
                        from,
                        got: body.len(),
                        len,
                    });
                }
                Ok(body)
            }
            Transport::Memory(body) => usize::try_from(start)
                .ok()
                .zip(usize::try_from(end).ok())
                .and_then(|(a, b)| body.get(a..b))
                .map(<[u8]>::to_vec)
                .ok_or(StaticFileError::Short { from }),
            Transport::File(src) => {
                let src = src.clone();
                let n = usize::try_from(len).map_err(StaticFileError::RangeTooLong)?;
                tokio::task::spawn_blocking(move || src.read_vec(start, n))
                    .await?
                    .map_err(|e| failed(&from, e.into()))
            }
        }
    }
}

/// `Content-Range: bytes FIRST-LAST/TOTAL` as `(first, last, total)`; the total is
/// `None` for `*` (unknown).
pub(crate) fn content_range(headers: &HeaderMap) -> Option<(u64, u64, Option<u64>)> {
    let v = headers.get(header::CONTENT_RANGE)?.to_str().ok()?;
    let (range, total) = v.trim().strip_prefix("bytes ")?.split_once('/')?;
    let (a, b) = range.split_once('-')?;
    let (a, b) = (a.trim().parse().ok()?, b.trim().parse().ok()?);
    let total = match total.trim() {
        "*" => None,
        t => Some(t.parse().ok()?),
    };
    (a <= b).then_some((a, b, total))
}

/// A response's body, at most `limit` bytes of it (more is an error for a range;
/// [`StaticFile::open_whole`] asks for one byte over its limit to tell).
pub(super) async fn read_body(
    mut resp: reqwest::Response,
    limit: u64,
) -> Result<Vec<u8>, reqwest::Error> {
    let mut out = Vec::new();
    while let Some(chunk) = resp.chunk().await? {
        out.extend_from_slice(&chunk);
        if out.len() as u64 >= limit {
            out.truncate(limit as usize);
            break;
        }
    }
    Ok(out)
}

/// Groups a level's present wanted tiles into runs whose records are contiguous in
/// the file (FORMAT.md: a level's records lie in Morton order without gaps): each
/// run is one byte range, one Range request. Tiles in between that have no record
/// do not break a run. `tiles` comes sorted by offset.
pub(crate) fn byte_runs(tiles: &[(TileId, IndexEntry)]) -> Vec<&[(TileId, IndexEntry)]> {
    let mut runs = Vec::new();
    let mut start = 0;
    for i in 1..=tiles.len() {
        if i == tiles.len() || tiles[i - 1].1.end() != tiles[i].1.offset {
            if i > start {
                runs.push(&tiles[start..i]);
            }
            start = i;
        }
    }
    runs
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::Level;

    #[test]
    fn content_ranges_parse() {
        let mut h = HeaderMap::new();
        h.insert(
            header::CONTENT_RANGE,
            "bytes 0-65535/1234567".parse().unwrap(),
        );
        assert_eq!(content_range(&h), Some((0, 65535, Some(1_234_567))));
        h.insert(header::CONTENT_RANGE, "bytes 10-20/*".parse().unwrap());
        assert_eq!(content_range(&h), Some((10, 20, None)));
        h.insert(header::CONTENT_RANGE, "bytes */100".parse().unwrap());
        assert_eq!(content_range(&h), None);
        h.insert(header::CONTENT_RANGE, "bytes 5-4/100".parse().unwrap());
        assert_eq!(content_range(&h), None);
    }

    #[test]
    fn validators_tell_a_changed_file() {
        let a = Validators {
            etag: Some("\"5f-10\"".into()),
            last_modified: Some("Mon, 01 Jan 2024 00:00:00 GMT".into()),
            total: Some(100),
        };
        assert_eq!(a.changed(&a), None);
        let missing = Validators::default();
        assert_eq!(
            a.changed(&missing),
            None,
            "what is not sent is not compared"
        );
        let mut b = a.clone();
        b.etag = Some("\"60-10\"".into());
        assert!(a.changed(&b).unwrap().contains("ETag"));
        let mut c = a.clone();
        c.total = Some(99);
        assert!(a.changed(&c).unwrap().contains("99"));
    }

    #[test]
    fn runs_break_where_records_are_not_contiguous() {
        let l = Level::new(2).unwrap();
        let t = |m: u64, offset: u64, length: u32| {
            let tile = TileId::from_morton(l, tessera_shared::Morton::from_raw(m)).unwrap();
            (
                tile,
                IndexEntry {
                    offset,
                    length,
                    ..IndexEntry::default()
                },
            )
        };
        // 0 and 1 touch; 3 follows 1 directly (2 has no record); 5 does not (4 is
        // present but not wanted).
        let tiles = [t(0, 100, 10), t(1, 110, 5), t(3, 115, 7), t(5, 140, 3)];
        let runs = byte_runs(&tiles);
        let codes: Vec<Vec<u64>> = runs
            .iter()
            .map(|r| r.iter().map(|(t, _)| t.morton().get()).collect())
            .collect();
        assert_eq!(codes, [vec![0, 1, 3], vec![5]]);
        assert!(byte_runs(&[]).is_empty());
    }
}

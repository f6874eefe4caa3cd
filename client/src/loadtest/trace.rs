//! Request traces (DECISIONS.md "Load testing: replay"): `tessera load --record TRACE`
//! writes one, `tessera load --replay TRACE` sends its requests again without selection
//! or decoding.
//!
//! A trace is JSON Lines: a [`TraceHeader`] on the first line, then one
//! [`TraceRequest`] per line in the order the requests were sent. JSON Lines so that a
//! trace can be read, cut and diffed with the usual tools, and read a line at a time.
//! A request's target is its path and query only, so a trace recorded against one
//! host replays against another (`--server`), or through a proxy.

use serde::{Deserialize, Serialize};
use std::io::{BufRead, Write};
use std::path::Path;
use tessera_shared::wire::Frame;
use tessera_shared::{Level, Morton};

/// The `tessera_trace` value of the traces this build writes and reads.
pub const TRACE_VERSION: u32 = 1;

/// The first line of a trace: where it was recorded and how.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TraceHeader {
    /// Always [`TRACE_VERSION`]; names the file as a trace.
    pub tessera_trace: u32,
    /// The server base URL the requests were recorded against (the default target of
    /// a replay).
    pub server: String,
    /// The dataset the clients flew over.
    pub dataset: String,
    /// Simulated clients; requests name theirs as `0..clients`.
    pub clients: u32,
    /// How long the recording ran.
    pub seconds: f64,
    /// `ranges` or `single`: how the clients asked for tiles.
    pub mode: String,
}

/// What a request asked for (which route of API.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RequestKind {
    /// `GET /v1/datasets/{name}/bootstrap`.
    Bootstrap,
    /// `GET /v1/datasets/{name}` (the dataset's document).
    Document,
    /// A Morton-range request for tiles of one level (a frame stream).
    Tiles,
    /// One tile's stored record.
    Tile,
    /// A Morton-range request for imagery tiles (a frame stream).
    Imagery,
}

impl RequestKind {
    /// Whether the answer is a frame stream (API.md "Frame stream"), whose frames a
    /// replay checks with the shared decoder.
    pub fn is_frame_stream(self) -> bool {
        matches!(self, Self::Tiles | Self::Imagery)
    }
}

/// What the recorded answer was, for a replay to compare against. Absent for requests
/// that did not complete during the recording (cancelled, failed, still in flight).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Expect {
    /// HTTP status.
    pub status: u16,
    /// Tile frames in the body (0 for bodies that are not frame streams).
    pub tiles: u32,
    /// Body bytes.
    pub bytes: u64,
    /// [`StreamDigest`] of the body's tile frames, as 16 hex digits (frame streams
    /// only; for other bodies the XXH3 of the whole body).
    pub digest: String,
}

/// One request of one simulated client.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TraceRequest {
    /// Which simulated client sent it (`0..header.clients`).
    pub client: u32,
    /// When, in milliseconds after the recording started.
    pub t_ms: f64,
    pub kind: RequestKind,
    /// Path and query, e.g. `/v1/datasets/moon/levels/5/tiles?ranges=0-15`.
    pub target: String,
    /// The level a tile request is for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub level: Option<u8>,
    #[serde(default)]
    pub expect: Option<Expect>,
}

/// A whole trace.
#[derive(Clone, Debug, PartialEq)]
pub struct Trace {
    pub header: TraceHeader,
    /// In the order they were sent (non-decreasing `t_ms`).
    pub requests: Vec<TraceRequest>,
}

impl Trace {
    /// Reads a trace, naming the file and line of anything wrong with it.
    pub fn read(path: &Path) -> Result<Self, TraceError> {
        let file = std::fs::File::open(path).map_err(|source| TraceError::Open {
            path: path.into(),
            source,
        })?;
        Self::from_reader(std::io::BufReader::new(file)).map_err(|e| TraceError::File {
            path: path.into(),
            source: Box::new(e),
        })
    }

    /// Reads a trace from JSON Lines.
    pub fn from_reader(reader: impl BufRead) -> Result<Self, TraceError> {
        let mut lines = reader.lines().enumerate();
        let (_, first) = lines.next().ok_or(TraceError::Empty)?;
        let first = first.map_err(|source| TraceError::Read { line: 1, source })?;
        let header: TraceHeader = serde_json::from_str(&first).map_err(TraceError::Header)?;
        if header.tessera_trace != TRACE_VERSION {
            return Err(TraceError::Version {
                version: header.tessera_trace,
            });
        }
        if !(header.seconds.is_finite() && header.seconds >= 0.0) {
            return Err(TraceError::Seconds {
                seconds: header.seconds,
            });
        }
        let mut requests = Vec::new();
        let mut last_t = 0.0f64;
        for (i, line) in lines {
            let n = i + 1;
            let line = line.map_err(|source| TraceError::Read { line: n, source })?;
            if line.trim().is_empty() {
                continue;
            }
            let r: TraceRequest = serde_json::from_str(&line)
                .map_err(|source| TraceError::Request { line: n, source })?;
            if r.client >= header.clients {
                return Err(TraceError::Client {
                    line: n,
                    client: r.client,
                    clients: header.clients,
                });
            }
            check_time(r.t_ms).map_err(|source| TraceError::Time { line: n, source })?;
            if r.t_ms < last_t {
                return Err(TraceError::OutOfOrder {
                    line: n,
                    t_ms: r.t_ms,
                    last_t,
                });
            }
            if !r.target.starts_with('/') || r.target.contains(char::is_whitespace) {
                return Err(TraceError::Target {
                    line: n,
                    target: r.target,
                });
            }
            last_t = r.t_ms;
            requests.push(r);
        }
        Ok(Self { header, requests })
    }

    /// Writes the trace as JSON Lines.
    pub fn write_to(&self, mut w: impl Write) -> Result<(), TraceError> {
        serde_json::to_writer(&mut w, &self.header)?;
        w.write_all(b"\n")?;
        for r in &self.requests {
            serde_json::to_writer(&mut w, r)?;
            w.write_all(b"\n")?;
        }
        w.flush()?;
        Ok(())
    }

    /// Writes the trace to `path` through a temporary file renamed into place, so a
    /// failed recording leaves no partial trace.
    pub fn write(&self, path: &Path) -> Result<(), TraceError> {
        let dir = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let mut tmp = tempfile_in(dir).map_err(|source| TraceError::CreateBeside {
            path: path.into(),
            source,
        })?;
        self.write_to(std::io::BufWriter::new(&mut tmp.1))
            .map_err(|e| TraceError::Write {
                path: path.into(),
                source: Box::new(e),
            })?;
        tmp.1.sync_all()?;
        std::fs::rename(&tmp.0, path).map_err(|source| TraceError::Rename {
            path: path.into(),
            source,
        })?;
        Ok(())
    }

    /// The part of the trace `shard` replays: the requests of its clients.
    pub fn shard(&self, shard: Shard) -> Self {
        Self {
            header: self.header.clone(),
            requests: self
                .requests
                .iter()
                .filter(|r| shard.owns(r.client))
                .cloned()
                .collect(),
        }
    }
}

/// A trace that could not be read or written: each names the file or the line,
/// and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    #[error("trace {}: cannot open", path.display())]
    Open {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// What was wrong in the file at `path`.
    #[error("trace {}", path.display())]
    File {
        path: std::path::PathBuf,
        #[source]
        source: Box<TraceError>,
    },
    #[error("empty file: not a Tessera request trace")]
    Empty,
    #[error("line {line}: cannot read")]
    Read {
        line: usize,
        #[source]
        source: std::io::Error,
    },
    #[error("line 1: not a Tessera request trace header")]
    Header(#[source] serde_json::Error),
    #[error("line 1: trace version {version} (this build reads version {TRACE_VERSION})")]
    Version { version: u32 },
    #[error("line 1: seconds {seconds} is not a duration")]
    Seconds { seconds: f64 },
    #[error("line {line}: not a request")]
    Request {
        line: usize,
        #[source]
        source: serde_json::Error,
    },
    #[error("line {line}: client {client} but the header says {clients} clients")]
    Client {
        line: usize,
        client: u32,
        clients: u32,
    },
    #[error("line {line}: t_ms")]
    Time {
        line: usize,
        #[source]
        source: TimeError,
    },
    #[error(
        "line {line}: t_ms {t_ms} is before the previous request's ({last_t} ms): requests are in the order they were sent"
    )]
    OutOfOrder { line: usize, t_ms: f64, last_t: f64 },
    #[error("line {line}: target {target:?} is not a path and query")]
    Target { line: usize, target: String },
    #[error("trace {}: cannot create a file beside it", path.display())]
    CreateBeside {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("trace {}: cannot write", path.display())]
    Write {
        path: std::path::PathBuf,
        #[source]
        source: Box<TraceError>,
    },
    #[error("trace {}: cannot rename into place", path.display())]
    Rename {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// The latest `t_ms` a trace may hold: [`MAX_RUN`](super::pacing::MAX_RUN), the
/// longest schedule a replay runs, in milliseconds. Without a bound, a time such as
/// 1e300 ms would reach the schedule as an instant no `Duration` can hold.
pub const MAX_T_MS: f64 = super::pacing::MAX_RUN.as_secs() as f64 * 1e3;

/// Why a request's `t_ms` is not a time in a trace.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum TimeError {
    #[error("{0:?} is not a number of milliseconds")]
    NotFinite(f64),
    #[error("{0:?} is negative: times are milliseconds after the recording started")]
    Negative(f64),
    #[error(
        "{t:?} ms is more than {max} ms (7 days, the longest schedule a replay runs) after the recording started",
        max = MAX_T_MS
    )]
    TooLate { t: f64 },
}

/// Checks a request's `t_ms`: finite, ≥ 0 and at most [`MAX_T_MS`].
pub fn check_time(t_ms: f64) -> Result<(), TimeError> {
    if !t_ms.is_finite() {
        Err(TimeError::NotFinite(t_ms))
    } else if t_ms < 0.0 {
        Err(TimeError::Negative(t_ms))
    } else if t_ms > MAX_T_MS {
        Err(TimeError::TooLate { t: t_ms })
    } else {
        Ok(())
    }
}

/// A temporary file in `dir` (path, file), removed by the caller's rename.
fn tempfile_in(dir: &Path) -> std::io::Result<(std::path::PathBuf, std::fs::File)> {
    let pid = std::process::id();
    for n in 0..1000u32 {
        let p = dir.join(format!(".tessera-trace-{pid}-{n}.tmp"));
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&p)
        {
            Ok(f) => return Ok((p, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(e),
        }
    }
    Err(std::io::Error::other("no free temporary name"))
}

/// `--shard K/N`: the K-th of N load processes (K from 0, as a Kubernetes Indexed
/// Job's `JOB_COMPLETION_INDEX`). It replays the clients `c` with `c % N == K`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    index: u32,
    count: u32,
}

impl Shard {
    /// `None` unless `index < count`.
    pub fn new(index: u32, count: u32) -> Option<Self> {
        (index < count).then_some(Self { index, count })
    }

    /// The whole trace.
    pub const ALL: Self = Self { index: 0, count: 1 };

    pub fn index(self) -> u32 {
        self.index
    }

    pub fn count(self) -> u32 {
        self.count
    }

    pub fn owns(self, client: u32) -> bool {
        client % self.count == self.index
    }
}

impl std::str::FromStr for Shard {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || format!("shard {s:?} is not K/N with 0 ≤ K < N (e.g. 0/4)");
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let k = k.trim().parse::<u32>().map_err(|_| bad())?;
        let n = n.trim().parse::<u32>().map_err(|_| bad())?;
        Self::new(k, n).ok_or_else(bad)
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// A digest of a frame stream's tile frames, in order: XXH3-64 over each frame's level,
/// Morton code and record checksum. The frame decoder has already checked each
/// record against its checksum, so equal digests mean the same tiles, in the same
/// order, with the same bytes.
#[derive(Clone, Copy, Debug, Default)]
pub struct StreamDigest {
    state: u64,
    tiles: u32,
}

impl StreamDigest {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a frame; only tile frames count.
    pub fn push(&mut self, frame: &Frame) {
        if let Frame::Tile {
            level,
            morton,
            checksum,
            ..
        } = frame
        {
            self.push_tile(*level, *morton, *checksum);
        }
    }

    /// Adds a tile frame by its header's fields (what a
    /// [`FrameScanner`](tessera_shared::frame_scan::FrameScanner) reports).
    pub fn push_tile(&mut self, level: Level, morton: Morton, checksum: u64) {
        let mut b = [0u8; 25];
        b[..8].copy_from_slice(&self.state.to_le_bytes());
        b[8] = level.get();
        b[9..17].copy_from_slice(&morton.get().to_le_bytes());
        b[17..25].copy_from_slice(&checksum.to_le_bytes());
        self.state = xxhash_rust::xxh3::xxh3_64(&b);
        self.tiles += 1;
    }

    pub fn tiles(&self) -> u32 {
        self.tiles
    }

    /// The digest as [`Expect::digest`] writes it.
    pub fn hex(&self) -> String {
        format!("{:016x}", self.state)
    }
}

/// [`Expect::digest`] of a body that is not a frame stream.
pub fn body_digest(body: &[u8]) -> String {
    format!("{:016x}", xxhash_rust::xxh3::xxh3_64(body))
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::{Level, Morton};

    fn trace() -> Trace {
        Trace {
            header: TraceHeader {
                tessera_trace: TRACE_VERSION,
                server: "http://127.0.0.1:1".into(),
                dataset: "moon".into(),
                clients: 3,
                seconds: 2.0,
                mode: "ranges".into(),
            },
            requests: (0..9)
                .map(|i| TraceRequest {
                    client: i % 3,
                    t_ms: f64::from(i) * 10.0,
                    kind: if i == 0 {
                        RequestKind::Bootstrap
                    } else {
                        RequestKind::Tiles
                    },
                    target: format!("/v1/datasets/moon/levels/{i}/tiles?ranges=0-{i}"),
                    level: (i > 0).then_some(i as u8),
                    expect: (i % 2 == 0).then(|| Expect {
                        status: 200,
                        tiles: i,
                        bytes: u64::from(i) * 100,
                        digest: format!("{i:016x}"),
                    }),
                })
                .collect(),
        }
    }

    #[test]
    fn a_trace_reads_back_as_written() {
        let t = trace();
        let mut buf = Vec::new();
        t.write_to(&mut buf).unwrap();
        assert_eq!(
            buf.split(|&b| b == b'\n').filter(|l| !l.is_empty()).count(),
            10
        );
        assert_eq!(Trace::from_reader(&buf[..]).unwrap(), t);
    }

    #[test]
    fn bad_traces_name_the_line_and_the_problem() {
        let t = trace();
        let mut buf = Vec::new();
        t.write_to(&mut buf).unwrap();
        let text = String::from_utf8(buf).unwrap();
        let err = |s: &str| {
            crate::errors::Chain(&Trace::from_reader(s.as_bytes()).unwrap_err()).to_string()
        };
        assert!(err("").contains("empty file"));
        assert!(err("{\"x\":1}\n").contains("line 1"));
        let v2 = text.replacen("\"tessera_trace\":1", "\"tessera_trace\":2", 1);
        assert!(err(&v2).contains("version 2"));
        let mut lines: Vec<&str> = text.lines().collect();
        lines.swap(3, 4);
        // The request now on line 5 was sent before the one on line 4.
        assert!(err(&lines.join("\n")).contains("line 5"));
        let bad_client = text.replacen("\"client\":2", "\"client\":7", 1);
        assert!(err(&bad_client).contains("client 7"));
        let bad_target = text.replacen("\"target\":\"/", "\"target\":\"", 1);
        assert!(err(&bad_target).contains("not a path"));
    }

    #[test]
    fn times_that_are_no_time_name_the_line_and_the_field() {
        let t = trace();
        let mut buf = Vec::new();
        t.write_to(&mut buf).unwrap();
        let text = String::from_utf8(buf).unwrap();
        // The request on line 3 (t_ms 10) given another time.
        let with = |t_ms: &str| text.replacen("\"t_ms\":10.0", &format!("\"t_ms\":{t_ms}"), 1);
        let err = |s: &str| {
            crate::errors::Chain(&Trace::from_reader(s.as_bytes()).unwrap_err()).to_string()
        };
        // 1e300 ms used to reach the schedule and panic converting it to a Duration.
        let e = err(&with("1e300"));
        assert!(e.contains("line 3: t_ms") && e.contains("7 days"), "{e}");
        let e = err(&with("-5"));
        assert!(e.contains("line 3: t_ms") && e.contains("negative"), "{e}");
        // JSON has no NaN or infinity: such numbers are not a request at all.
        for bad in ["NaN", "Infinity", "-Infinity", "1e400"] {
            let e = err(&with(bad));
            assert!(e.contains("line 3"), "{bad}: {e}");
        }
        // The largest time a trace may hold still reads (the requests after it are
        // then out of order, which is the error).
        let e = err(&with(&MAX_T_MS.to_string()));
        assert!(e.contains("line 4: t_ms"), "{e}");
        assert_eq!(check_time(MAX_T_MS), Ok(()));
        assert_eq!(
            check_time(f64::NAN).unwrap_err().to_string(),
            "NaN is not a number of milliseconds"
        );
        assert!(matches!(
            check_time(f64::INFINITY),
            Err(TimeError::NotFinite(_))
        ));
        assert!(matches!(
            check_time(MAX_T_MS * 1.01),
            Err(TimeError::TooLate { .. })
        ));
    }

    #[test]
    fn a_trace_file_with_a_time_too_late_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("late.jsonl");
        let t = trace();
        let mut buf = Vec::new();
        t.write_to(&mut buf).unwrap();
        let text = String::from_utf8(buf).unwrap();
        let mut lines: Vec<String> = text.lines().map(String::from).collect();
        let last = lines.len() - 1;
        lines[last] = lines[last].replace("\"t_ms\":80.0", "\"t_ms\":1e300");
        std::fs::write(&path, lines.join("\n")).unwrap();
        let e = crate::errors::Chain(&Trace::read(&path).unwrap_err()).to_string();
        assert!(
            e.contains("late.jsonl") && e.contains("line 10: t_ms"),
            "{e}"
        );
    }

    #[test]
    fn shards_split_the_clients_and_cover_them_once() {
        let t = trace();
        let shards: Vec<Trace> = (0..2).map(|k| t.shard(Shard::new(k, 2).unwrap())).collect();
        assert_eq!(
            shards.iter().map(|s| s.requests.len()).sum::<usize>(),
            t.requests.len()
        );
        assert!(shards[0].requests.iter().all(|r| r.client % 2 == 0));
        assert!(shards[1].requests.iter().all(|r| r.client % 2 == 1));
        assert_eq!(t.shard(Shard::ALL), t);
    }

    #[test]
    fn shard_parses_k_of_n() {
        assert_eq!("1/4".parse::<Shard>().unwrap(), Shard::new(1, 4).unwrap());
        for bad in ["4/4", "1", "a/2", "0/0", "-1/2"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
        assert_eq!(Shard::new(2, 3).unwrap().to_string(), "2/3");
    }

    #[test]
    fn the_digest_tells_tiles_order_and_bytes_apart() {
        let frame = |l: u8, m: u64, c: u64| Frame::Tile {
            level: Level::new(l).unwrap(),
            morton: Morton::from_raw(m),
            checksum: c,
            min: 0,
            max: 0,
            record: Vec::new(),
        };
        let digest = |frames: &[Frame]| {
            let mut d = StreamDigest::new();
            for f in frames {
                d.push(f);
            }
            (d.hex(), d.tiles())
        };
        let a = [frame(3, 1, 10), frame(3, 2, 20)];
        let base = digest(&a);
        assert_eq!(base.1, 2);
        assert_eq!(digest(&a), base);
        assert_ne!(digest(&[frame(3, 2, 20), frame(3, 1, 10)]).0, base.0);
        assert_ne!(digest(&[frame(3, 1, 10), frame(3, 2, 21)]).0, base.0);
        assert_ne!(digest(&[frame(4, 1, 10), frame(3, 2, 20)]).0, base.0);
        let trailer = Frame::Trailer {
            tiles: 2,
            errors: 0,
            outside: Vec::new(),
        };
        assert_eq!(digest(&[a[0].clone(), trailer, a[1].clone()]), base);
    }
}

//! What streaming did: running totals, and one frame's work.

/// Running totals.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StreamStats {
    pub requests: u64,
    /// Morton ranges those requests asked for (a server request may name several;
    /// a Range request to a static file is one).
    #[serde(default)]
    pub ranges: u64,
    /// Requests answered in full.
    pub responses: u64,
    pub bytes: u64,
    pub tiles: u64,
    pub failures: u64,
    /// Reports of a corrupt record from the server (error frames, 500s).
    pub corrupt: u64,
    /// Tiles written off after [`StreamConfig::corrupt_attempts`](super::StreamConfig::corrupt_attempts) such reports.
    #[serde(default)]
    pub written_off: u64,
    pub cancelled: u64,
}

/// What one frame's streaming work did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameWork {
    pub accepted: usize,
    pub issued: usize,
    pub stream_us: f64,
    pub in_flight: usize,
    pub prefetch_skipped: bool,
}

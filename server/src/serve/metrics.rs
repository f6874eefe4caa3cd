//! Prometheus metrics, one registry per server (so tests can run many servers in
//! one process).

use prometheus::{
    Encoder, HistogramOpts, HistogramVec, IntCounter, IntCounterVec, Opts, Registry, TextEncoder,
};

#[derive(Debug, Clone)]
pub struct Metrics {
    registry: Registry,
    pub requests: IntCounterVec,
    pub latency: HistogramVec,
    pub bytes: IntCounter,
    pub tiles: IntCounter,
    /// Distinct records found corrupt (each counted once, when first found).
    pub corrupt: IntCounter,
    /// Reads of corrupt records (a record read ten times counts ten).
    pub corrupt_reads: IntCounter,
}

impl Metrics {
    pub fn new() -> Self {
        let registry = Registry::new();
        let requests = IntCounterVec::new(
            Opts::new(
                "tessera_http_requests_total",
                "HTTP requests by route and status",
            ),
            &["route", "status"],
        )
        .expect("valid metric");
        let latency = HistogramVec::new(
            HistogramOpts::new(
                "tessera_http_request_duration_seconds",
                "Time to the response head, by route",
            )
            .buckets(vec![
                0.0002, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5,
                5.0,
            ]),
            &["route"],
        )
        .expect("valid metric");
        let bytes = IntCounter::new("tessera_response_bytes_total", "Response body bytes")
            .expect("valid metric");
        let tiles = IntCounter::new("tessera_tiles_served_total", "Tile records served")
            .expect("valid metric");
        let corrupt = IntCounter::new(
            "tessera_corrupt_records_total",
            "Distinct tile records found corrupt (failing their checksum or not decoding)",
        )
        .expect("valid metric");
        let corrupt_reads = IntCounter::new(
            "tessera_corrupt_record_reads_total",
            "Reads of tile records that are corrupt",
        )
        .expect("valid metric");
        for c in [
            Box::new(requests.clone()) as Box<dyn prometheus::core::Collector>,
            Box::new(latency.clone()),
            Box::new(bytes.clone()),
            Box::new(tiles.clone()),
            Box::new(corrupt.clone()),
            Box::new(corrupt_reads.clone()),
        ] {
            registry.register(c).expect("metric names are unique");
        }
        Self {
            registry,
            requests,
            latency,
            bytes,
            tiles,
            corrupt,
            corrupt_reads,
        }
    }

    /// The registry, for metrics kept by other parts of the server.
    pub fn registry(&self) -> &Registry {
        &self.registry
    }

    /// Counts one read of a corrupt record, and the record itself if this read found it.
    pub fn corrupt_read(&self, first: bool) {
        self.corrupt_reads.inc();
        if first {
            self.corrupt.inc();
        }
    }

    /// The text exposition format.
    pub fn render(&self) -> String {
        let mut buf = Vec::new();
        TextEncoder::new()
            .encode(&self.registry.gather(), &mut buf)
            .expect("text encoding cannot fail");
        String::from_utf8(buf).expect("exposition format is UTF-8")
    }
}

impl Default for Metrics {
    fn default() -> Self {
        Self::new()
    }
}

//! Latency histograms: HDR histograms in microseconds (1 µs to 1 h, 3 significant
//! digits), written into reports in HdrHistogram's V2 encoding, base64, so that
//! merging shards adds the histograms themselves and merged percentiles are those of
//! all the requests, not an average of percentiles.

use base64::Engine;
use hdrhistogram::Histogram;
use hdrhistogram::serialization::{Deserializer, Serializer, V2Serializer};
use serde::{Deserialize, Serialize};
use std::time::Duration;

/// A report's histogram that does not read back.
#[derive(Debug, thiserror::Error)]
pub enum HistogramError {
    #[error("histogram is not base64")]
    NotBase64(#[source] base64::DecodeError),
    #[error("histogram is not an HdrHistogram V2 encoding: {0:?}")]
    NotV2(hdrhistogram::serialization::DeserializeError),
    #[error("histogram does not fit 1 µs .. 1 h at {SIGNIFICANT_DIGITS} digits: {0:?}")]
    DoesNotFit(hdrhistogram::AdditionError),
    #[error("corrected histogram")]
    Corrected(#[source] Box<HistogramError>),
    #[error("uncorrected histogram")]
    Uncorrected(#[source] Box<HistogramError>),
}

/// Largest latency a histogram holds: one hour, in microseconds (longer ones are
/// recorded as one hour).
const MAX_MICROS: u64 = 3_600_000_000;
const SIGNIFICANT_DIGITS: u8 = 3;

/// A latency histogram, in microseconds.
#[derive(Clone, Debug, PartialEq)]
pub struct Latency(Histogram<u64>);

impl Default for Latency {
    fn default() -> Self {
        Self::new()
    }
}

impl Latency {
    pub fn new() -> Self {
        Self(
            Histogram::new_with_bounds(1, MAX_MICROS, SIGNIFICANT_DIGITS)
                .expect("constant bounds are valid"),
        )
    }

    /// Records one latency (below 1 µs counts as 1 µs, above an hour as an hour).
    pub fn record(&mut self, d: Duration) {
        let us = u64::try_from(d.as_micros()).unwrap_or(u64::MAX).max(1);
        self.0.saturating_record(us);
    }

    /// Records a value in microseconds.
    pub fn record_micros(&mut self, us: u64) {
        self.0.saturating_record(us.max(1));
    }

    pub fn count(&self) -> u64 {
        self.0.len()
    }

    /// Adds every value of `other`.
    pub fn add(&mut self, other: &Self) {
        // Both have this module's bounds (from_base64 checks), so the addition
        // cannot fail; saturate rather than panic if it somehow did.
        if self.0.add(&other.0).is_err() {
            for v in other.0.iter_recorded() {
                self.0
                    .saturating_record_n(v.value_iterated_to(), v.count_at_value());
            }
        }
    }

    /// Empties the histogram, keeping its memory.
    pub fn clear(&mut self) {
        self.0.reset();
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// The value at `quantile` (0..=1), in milliseconds (0 when empty).
    pub fn quantile_ms(&self, quantile: f64) -> f64 {
        self.0.value_at_quantile(quantile) as f64 / 1e3
    }

    /// The largest value, in milliseconds.
    pub fn max_ms(&self) -> f64 {
        self.0.max() as f64 / 1e3
    }

    pub fn percentiles(&self) -> Percentiles {
        Percentiles {
            p50: self.quantile_ms(0.5),
            p90: self.quantile_ms(0.9),
            p99: self.quantile_ms(0.99),
            p999: self.quantile_ms(0.999),
            max: self.max_ms(),
        }
    }

    /// HdrHistogram's V2 encoding, base64 (standard alphabet, padded).
    pub fn to_base64(&self) -> String {
        let mut bytes = Vec::new();
        V2Serializer::new()
            .serialize(&self.0, &mut bytes)
            .expect("writing into a Vec cannot fail");
        base64::engine::general_purpose::STANDARD.encode(bytes)
    }

    /// Reads [`Latency::to_base64`]'s encoding.
    pub fn from_base64(s: &str) -> Result<Self, HistogramError> {
        let bytes = base64::engine::general_purpose::STANDARD
            .decode(s)
            .map_err(HistogramError::NotBase64)?;
        let h: Histogram<u64> = Deserializer::new()
            .deserialize(&mut &bytes[..])
            .map_err(HistogramError::NotV2)?;
        let mut l = Self::new();
        l.0.add(&h).map_err(HistogramError::DoesNotFit)?;
        Ok(l)
    }
}

/// Latency percentiles, milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Percentiles {
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
    pub p999: f64,
    pub max: f64,
}

/// The two histograms of a report or of one second, V2-encoded, base64.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Histograms {
    /// Latency from each request's scheduled start.
    pub corrected: String,
    /// Latency from each request's actual send.
    pub uncorrected: String,
}

impl Histograms {
    pub fn of(corrected: &Latency, uncorrected: &Latency) -> Self {
        Self {
            corrected: corrected.to_base64(),
            uncorrected: uncorrected.to_base64(),
        }
    }

    pub fn decode(&self) -> Result<(Latency, Latency), HistogramError> {
        Ok((
            Latency::from_base64(&self.corrected)
                .map_err(|e| HistogramError::Corrected(Box::new(e)))?,
            Latency::from_base64(&self.uncorrected)
                .map_err(|e| HistogramError::Uncorrected(Box::new(e)))?,
        ))
    }
}

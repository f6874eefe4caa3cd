//! Load testing that measures the server, not the load generator
//! (DECISIONS.md "Load testing: replay, open model, merge").
//!
//! - [`trace`]: the request trace `tessera load --record` writes and `--replay`
//!   reads, its digest of a tile stream, and `--shard K/N`.
//! - [`pacing`]: how a replay is paced (as recorded, `--rate`, `--ramp`, `--rate
//!   max`), within which limits.
//! - [`schedule`]: when a replay sends each request.
//! - [`replay`]: the engine: the open model, HDR latency from the scheduled start.
//! - [`check`]: one answer against its recording (errors by kind).
//! - [`replay_report`]: a replay's report (`--json`, `DIR/load.json`).
//! - [`replay_report_file`]: the report read from and written to `load.json`,
//!   checked for plausibility, and `--out DIR`.
//! - [`merge`]: `tessera load merge`, the reports of `--shard K/N` processes added up.
//! - [`latency_plot`]: the latency-over-time plot (`DIR/latency.png`).
//! - [`record`]: `--record`: the full clients' requests collected into a trace.
//! - [`cpu`]: the load process's own CPU use (is a run client-bound?).
//! - [`connections`]: how many connections the open-file limit lets one process hold.
//! - [`latency`]: HDR latency histograms, their percentiles and their encoding in a
//!   report.
//!
//! The full-client mode (many simulated clients flying through the real selection and
//! streaming code) is [`crate::app::load_test`].

pub mod check;
pub mod connections;
pub mod cpu;
pub mod latency;
pub mod latency_plot;
pub mod merge;
pub mod pacing;
pub mod record;
pub mod replay;
pub mod replay_report;
pub mod replay_report_file;
pub mod schedule;
pub mod trace;

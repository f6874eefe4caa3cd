//! Load testing that measures the server, not the load generator (issue 18).
//!
//! - [`trace`]: the request trace `tessera load --record` writes and `--replay`
//!   reads, its digest of a tile stream, and `--shard K/N`.
//! - [`record`]: `--record`: the full clients' requests collected into a trace.
//! - [`cpu`]: the load process's own CPU use (is a run client-bound?).
//!
//! The full-client mode (many simulated clients flying through the real selection and
//! streaming code) is [`crate::app::load_test`].

pub mod cpu;
pub mod record;
pub mod trace;

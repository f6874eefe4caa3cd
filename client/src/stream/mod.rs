//! Streaming tiles from a Tessera server, or straight from a pyramid file on a
//! static host (docs/ARCHITECTURE.md#streaming, docs/ARCHITECTURE.md#scale-out, Kang
//! §6.1).
//!
//! The frame thread never waits on the network. Each frame it calls
//! [`Streamer::frame`], which
//! 1. accepts finished tiles (already decoded by the fetch tasks) into the
//!    [`pool::TilePool`] until the frame's time budget is spent;
//! 2. cancels requests none of whose tiles are still wanted;
//! 3. requests what the selection needs now (required), coalesced into Morton ranges
//!    per level, up to a cap on requests in flight; and then what the enlarged,
//!    predicted view will need (prefetch), but only while the frame is still within
//!    its budget — prefetch stops when over it (Kang §6.1).
//!
//! Failed requests are retried with exponential backoff per tile; a server that is
//! slow, failing or restarting only delays refinement, while the pool keeps drawing
//! what it has. When a range stream breaks on one tile (a frame that fails its
//! checksum or does not decode, or a stream cut short, which breaks on the first tile
//! still missing), only that tile backs off: the tiles that were to follow it are
//! asked for again after the base delay, without it, so that a tile that always
//! arrives damaged cannot hold back the others batched with it.
//!
//! A record the server reports corrupt (an error frame, or a 500 for a single tile)
//! is retried with the same backoff, since a reload or another replica may serve it
//! whole, and written off only after [`StreamConfig::corrupt_attempts`] reports.
//! Tiles that fail or are written off are marked unavailable in the pool, so that
//! the selection draws their children in their place
//! (docs/ARCHITECTURE.md#the-client-never-goes-blind); [`Streamer::last_error`] says what
//! happened.
//!
//! Requested tiles the server has no record of — the trailer's outside ranges, or a
//! 404 for a single tile: outside the DEM or, in format v2, wholly no-data — are
//! marked absent in the pool: they are never asked for again, and selection
//! neither waits for them nor counts them as holes.
//!
//! A server source opens with one request, the dataset's bootstrap (API.md,
//! [`tessera_shared::bootstrap`]): its document, the records of its coarsest levels
//! and the error tables of the next ones. The records are decoded during the open
//! and put in the pool before the first frame ([`Streamer::preload`]), so frame 0
//! draws the root level instead of empty sky, and the first frame's requests already
//! name the tiles its view needs. A server without the route (404) is opened the old
//! way, with its document alone (`--no-bootstrap` asks for that). A static file's
//! root level is fetched during the open too when it is small ([`ROOT_PRELOAD`]).
//!
//! HTTP/2: with [`StreamConfig::http2`] a server reached over `http://` is spoken to
//! in h2c with prior knowledge (the server speaks it beside HTTP/1.1 on one port),
//! so every request shares one connection instead of waiting for one of its own; if
//! the open fails that way (a proxy in between that speaks only HTTP/1.1), the
//! client says so and opens again over HTTP/1.1. Over `https://` HTTP/2 is
//! negotiated by ALPN whenever the server offers it.
//!
//! Two backends feed the same streamer ([`TileSource`]): a Tessera server (one
//! request per batch of Morton ranges, `?ranges=`), and a pyramid file read
//! serverlessly with HTTP Range ([`static_file`]): its index is local, so tiles with no
//! record are absent without a request, and each run of wanted records contiguous in
//! the file (a Morton range, gaps of absent tiles included) is one Range request.
//! A record that fails its index checksum is reported corrupt, as a server's error
//! frame is. Selection, budget, prefetch, retries, cancellation and statistics are
//! the same.
//!
//! The parts: [`Streamer`] (`streamer`), opened by `open` and driven each frame by
//! `frame`; its settings ([`StreamConfig`], `config`) and statistics (`stats`); the
//! requests themselves (`fetch`) over the HTTP client of `http`; [`TileSource`]
//! (`tile_source`) and the static pyramid file ([`static_file`]); the decoded tiles
//! ([`pool`]); and the dataset's imagery ([`imagery_tiles`], opened beside the tiles
//! by `dataset_imagery`).

mod config;
mod dataset_imagery;
mod fetch;
mod frame;
mod http;
pub mod imagery_tiles;
mod open;
pub mod pool;
pub mod static_file;
mod static_file_open;
mod stats;
mod streamer;
mod tile_source;

pub use config::{OpenArgs, RequestMode, StreamConfig};
pub use open::{OpenError, ROOT_PRELOAD};
pub use stats::{FrameWork, StreamStats};
pub use streamer::Streamer;
pub use tile_source::TileSource;

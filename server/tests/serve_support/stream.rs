//! Reading what the server sends: the pyramid files read independently with the
//! shared reader, tile streams decoded and their trailers split off, ETags checked.

use super::Resp;
use std::path::Path;
use tessera_shared::wire::{self, Frame};
use tessera_shared::{FileSource, Level, MortonRange, Pyramid};

pub fn open(path: &Path) -> Pyramid<FileSource> {
    Pyramid::open_file(path).unwrap()
}

pub fn level(l: u8) -> Level {
    Level::new(l).unwrap()
}

/// Decodes a tile stream response after checking its head.
pub fn decode_stream(r: &Resp) -> Vec<Frame> {
    assert_eq!(r.status, 200, "GET {}: {}", r.path, r.text());
    assert_eq!(r.must("content-type"), wire::CONTENT_TYPE, "GET {}", r.path);
    assert_eq!(
        r.must("content-length").parse::<usize>().unwrap(),
        r.body.len(),
        "GET {}: Content-Length",
        r.path
    );
    wire::decode_all(&r.body).unwrap_or_else(|e| panic!("GET {}: {e}", r.path))
}

/// Splits off the trailer, which must be the last frame and the only one.
pub fn split_trailer(frames: &[Frame]) -> (&[Frame], u64, u64, Vec<MortonRange>) {
    let (last, body) = frames.split_last().expect("at least a trailer");
    let Frame::Trailer {
        tiles,
        errors,
        outside,
    } = last
    else {
        panic!("last frame is not the trailer: {last:?}");
    };
    assert!(
        body.iter().all(|f| !matches!(f, Frame::Trailer { .. })),
        "a trailer before the end"
    );
    (body, *tiles, *errors, outside.clone())
}

pub fn etag_is_strong(etag: &str) {
    assert!(
        etag.len() > 2 && etag.starts_with('"') && etag.ends_with('"') && !etag.contains("W/"),
        "not a strong ETag: {etag:?}"
    );
}

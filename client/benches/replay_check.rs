//! What checking an answer costs the replay (one core must drive the server as hard as
//! `wrk`: DECISIONS.md "Load testing: replay"): `loadtest::check::Check` over a frame
//! stream of 16 tile frames of 20 kB records (a batch of the moon 4096² at 128-cell tiles
//! is of this order), fed in chunks of 16, 64 and 256 KiB as a socket delivers them. Each
//! sample checks one whole stream: the shared decoder's checksum of every record, the
//! stream digest, the trailer. Throughput is in bytes of body.
//!
//! ```sh
//! cargo bench -p tessera-client --bench replay_check
//! ```

use divan::Bencher;
use divan::counter::BytesCount;
use tessera_client::loadtest::check::Check;
use tessera_shared::wire::{tile_header, trailer_frame};
use tessera_shared::{Level, Morton};

const TILES: u64 = 16;
const RECORD: u32 = 20_000;

fn stream() -> Vec<u8> {
    let level = Level::new(4).expect("level 4");
    let mut body = Vec::new();
    for m in 0..TILES {
        // Not all zeros, so the checksum has real work (XXH3 has no shortcut anyway).
        let record: Vec<u8> = (0..RECORD).map(|i| (i * 7 + m as u32) as u8).collect();
        body.extend(tile_header(
            level,
            Morton::from_raw(m),
            tessera_shared::format::checksum(&record),
            0,
            0,
            RECORD,
        ));
        body.extend(record);
    }
    body.extend(trailer_frame(level, TILES, 0, &[]));
    body
}

#[divan::bench(args = [16 << 10, 64 << 10, 256 << 10])]
fn check_stream(bencher: Bencher, chunk: usize) {
    let body = stream();
    bencher.counter(BytesCount::of_slice(&body)).bench(|| {
        let mut c = Check::new(None, true, 200);
        for piece in body.chunks(chunk) {
            c.push(divan::black_box(piece));
        }
        let out = c.finish();
        assert_eq!(out.error, None);
        out
    });
}

fn main() {
    divan::main();
}

//! The bootstrap (`application/vnd.tessera.bootstrap`): everything a client needs to draw
//! its first frame, in one response (API.md "`GET /v1/datasets/{name}/bootstrap`";
//! DECISIONS.md "The first view in one round trip").
//!
//! Without it a client makes one round trip for the dataset's document and one more
//! per level before it draws anything. As 3D Tiles' `root.json` carries its root
//! tile and PMTiles packs its header and root directory into the first 16 KB, the
//! bootstrap carries, pinned by the dataset's content hash:
//! - the dataset's document, the same [`DatasetInfo`] as `GET /v1/datasets/{name}`;
//! - the stored records of the coarsest levels, whole (the root level always, then
//!   finer levels while their records fit [`RECORD_BUDGET`]), as tile frames of the
//!   tile stream ([`crate::wire`]): the same verified bytes the Morton-range stream
//!   sends;
//! - the error tables of the next levels while they fit [`TABLE_BUDGET`], as
//!   error-table frames: planning data for what to fetch next.
//!
//! Layout (all integers little-endian), specified in API.md:
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | 8 bytes | magic `TESSBOOT` |
//! | 8 | u16 | version, 1 |
//! | 10 | u8 | `record_levels` R: levels `0..R` are carried as records |
//! | 11 | u8 | `table_levels` E: levels `R..E` are carried as error tables |
//! | 12 | u32 | `J`, length of the document |
//! | 16 | u64 | XXH3-64 of the document |
//! | 24 | J bytes | the document, UTF-8 JSON |
//! | 24 + J | … | a frame stream ([`crate::wire`]) ending in its trailer |
//!
//! The frame stream holds one tile frame per present tile of levels `0..R`, then one
//! error-table frame per present tile of levels `R..E`, each level in ascending
//! Morton order; an error frame stands in for a record that failed its checksum on
//! the server. A bootstrap asked for with a focus ([`crate::focus`]: `?focus=U,V`)
//! also carries, level by level from `R` down to the finest while they fit
//! [`FOCUS_BUDGET`], the records of the tiles around that point: on a table level
//! such a tile's record comes instead of its error table (the record starts with
//! it), and below `E` its tile frames are the only frames of their level. Its trailer's counts are those of the whole stream and its level
//! is 0; it lists no outside ranges: a tile of a carried level that the geometry
//! places inside the DEM and that has no frame has no record (absent, FORMAT.md).

use crate::api::DatasetInfo;
use crate::error_table::ErrorTable;
use crate::format;
use crate::morton::Morton;
use crate::tile::{Level, TileGeometry, TileId};
use crate::wire::{self, Frame, WireError};
use std::collections::HashSet;

/// The media type of a bootstrap.
pub const CONTENT_TYPE: &str = "application/vnd.tessera.bootstrap";
pub const MAGIC: &[u8; 8] = b"TESSBOOT";
pub const VERSION: u16 = 1;
/// Bytes before the document.
pub const HEAD_LEN: usize = 24;
/// The most document bytes a decoder accepts (a document is a few KiB).
pub const MAX_DOCUMENT: usize = 1 << 20;
/// Records of levels below the root level are carried while the levels' records
/// add up to at most this (the root level is carried whatever its size). 2 MiB holds
/// the two coarsest levels of the moon 8192² (1.5 MB): with them resident the first
/// frame already chooses the tiles its view needs, instead of asking for every tile
/// under a root whose errors are large everywhere (BENCHMARKS.md "Streaming").
pub const RECORD_BUDGET: u64 = 2 << 20;
/// Error tables of the levels after the record levels are carried while they add up
/// to at most this: 256 KiB, a few round trips' worth of bytes on a slow link, which
/// holds two more levels (80 tables of 2816 bytes) of the moon 8192²'s 512-cell
/// tiles. The tables say where the finer levels are rough before any of their
/// records is fetched.
pub const TABLE_BUDGET: u64 = 256 << 10;

/// Records a focus adds ([`crate::focus`]) are carried level by level, coarsest
/// first, while they add up to at most this: 12 MiB holds the 4 × 4 tiles around a
/// point on levels 2–4 of the moon 8192² (10.3 MB), i.e. the records a camera 150 m
/// above its ground needs in its first frame. A finer level is carried only with
/// all the coarser ones, since selection reaches a tile only through its ancestors'
/// sibling groups.
pub const FOCUS_BUDGET: u64 = 12 << 20;

/// The most tile slots (`4^l` per level `l`) the carried levels may span: bounds
/// what a decoder walks to list absent tiles, whatever a document claims. The byte
/// budgets stop a server long before (levels 0–9 span 349 525 slots).
pub const MAX_CARRIED_SLOTS: u64 = 1 << 20;

/// Tile slots of levels `0..levels`.
fn slots(levels: u8) -> u64 {
    (0..u32::from(levels).min(31))
        .map(|l| 1u64 << (2 * l))
        .sum()
}

/// A decoded bootstrap.
#[derive(Clone, Debug, PartialEq)]
pub struct Bootstrap {
    pub info: DatasetInfo,
    /// Levels `0..record_levels` are carried as records.
    pub record_levels: u8,
    /// Levels `record_levels..table_levels` are carried as error tables.
    pub table_levels: u8,
    /// Tile, error-table and error frames, in stream order.
    pub frames: Vec<Frame>,
}

/// Why bytes are not a bootstrap.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BootstrapError {
    #[error("bootstrap is truncated: {0}")]
    Truncated(String),
    #[error("not a bootstrap (bad magic bytes)")]
    Magic,
    #[error("bootstrap version {0} is not supported (this client reads version {VERSION})")]
    Version(u16),
    #[error("bootstrap document of {0} bytes exceeds the {MAX_DOCUMENT}-byte limit")]
    DocumentTooLong(usize),
    #[error("bootstrap document fails its checksum")]
    DocumentChecksum,
    #[error("bootstrap document is not a dataset description: {0}")]
    Document(String),
    #[error("bootstrap levels are inconsistent: {0}")]
    Levels(String),
    #[error("bootstrap frame stream: {0}")]
    Frames(#[from] WireError),
    #[error("bootstrap frame {index}: {what}")]
    Frame { index: usize, what: String },
}

/// The head and document of a bootstrap; the frame stream follows it.
pub fn encode_head(info: &DatasetInfo, record_levels: u8, table_levels: u8) -> Vec<u8> {
    let doc = serde_json::to_vec(info).expect("a DatasetInfo always serializes");
    let mut v = Vec::with_capacity(HEAD_LEN + doc.len());
    v.extend_from_slice(MAGIC);
    v.extend_from_slice(&VERSION.to_le_bytes());
    v.push(record_levels);
    v.push(table_levels);
    v.extend_from_slice(&(doc.len() as u32).to_le_bytes());
    v.extend_from_slice(&format::checksum(&doc).to_le_bytes());
    v.extend_from_slice(&doc);
    v
}

/// [`plan_levels`] for `pyramid`: from its level table's record bytes and its
/// geometry's present tiles, what the server's bootstrap of it carries.
pub fn plan<S: crate::reader::ByteSource>(pyramid: &crate::reader::Pyramid<S>) -> (u8, u8) {
    let g = *pyramid.geometry();
    let sizes: Vec<(u64, u64)> = g
        .levels()
        .map(|l| {
            let bytes = pyramid.level_entry(l).map_or(0, |e| e.records_len);
            (bytes, g.present_tiles(l).count() as u64)
        })
        .collect();
    plan_levels(&sizes, ErrorTable::byte_len(g.tile_log2()))
}

/// The levels a bootstrap carries as records and as error tables, from each level's
/// record bytes and present tiles (coarsest first): `(R, E)` of the layout.
pub fn plan_levels(levels: &[(u64, u64)], table_len: usize) -> (u8, u8) {
    let mut records = 0u64;
    let mut r = 0usize;
    while r < levels.len()
        && (r == 0
            || records + levels[r].0 <= RECORD_BUDGET && slots(r as u8 + 1) <= MAX_CARRIED_SLOTS)
    {
        records += levels[r].0;
        r += 1;
    }
    let mut tables = 0u64;
    let mut e = r;
    while e < levels.len()
        && tables + levels[e].1 * table_len as u64 <= TABLE_BUDGET
        && slots(e as u8 + 1) <= MAX_CARRIED_SLOTS
    {
        tables += levels[e].1 * table_len as u64;
        e += 1;
    }
    (r as u8, e as u8)
}

impl Bootstrap {
    /// The whole body (tests and tools; the server writes the same bytes from
    /// [`encode_head`] and [`crate::wire`]'s frames).
    pub fn encode(&self) -> Vec<u8> {
        let mut v = encode_head(&self.info, self.record_levels, self.table_levels);
        let (mut tiles, mut errors) = (0u64, 0u64);
        for f in &self.frames {
            match f {
                Frame::Tile {
                    level,
                    morton,
                    checksum,
                    min,
                    max,
                    record,
                } => {
                    tiles += 1;
                    v.extend_from_slice(&wire::tile_header(
                        *level,
                        *morton,
                        *checksum,
                        *min,
                        *max,
                        record.len() as u32,
                    ));
                    v.extend_from_slice(record);
                }
                Frame::ErrorTable {
                    level,
                    morton,
                    min,
                    max,
                    table,
                } => {
                    tiles += 1;
                    v.extend(wire::error_table_frame(*level, *morton, *min, *max, table));
                }
                Frame::Error {
                    level,
                    morton,
                    message,
                } => {
                    errors += 1;
                    v.extend(wire::error_frame(*level, *morton, 0, message));
                }
                Frame::Trailer { .. } => {}
            }
        }
        let root = Level::new(0).expect("level 0");
        v.extend(wire::trailer_frame(root, tiles, errors, &[]));
        v
    }

    /// Decodes and checks a whole bootstrap: the head, the document's checksum and
    /// shape, every frame's checksum, that each frame's level and code belong to the
    /// levels the head announces and to the dataset's geometry, that no tile comes
    /// twice, and that the trailer's counts match. Any bytes give `Ok` or an error
    /// saying what is wrong; never a panic.
    pub fn decode(bytes: &[u8]) -> Result<Self, BootstrapError> {
        let head = bytes.get(..HEAD_LEN).ok_or_else(|| {
            BootstrapError::Truncated(format!(
                "{} bytes, shorter than the {HEAD_LEN}-byte head",
                bytes.len()
            ))
        })?;
        if &head[..8] != MAGIC {
            return Err(BootstrapError::Magic);
        }
        let version = u16::from_le_bytes([head[8], head[9]]);
        if version != VERSION {
            return Err(BootstrapError::Version(version));
        }
        let (record_levels, table_levels) = (head[10], head[11]);
        let doc_len = u32::from_le_bytes(head[12..16].try_into().expect("4 bytes")) as usize;
        if doc_len > MAX_DOCUMENT {
            return Err(BootstrapError::DocumentTooLong(doc_len));
        }
        let doc_sum = u64::from_le_bytes(head[16..24].try_into().expect("8 bytes"));
        let doc = bytes.get(HEAD_LEN..HEAD_LEN + doc_len).ok_or_else(|| {
            BootstrapError::Truncated(format!(
                "the document is {doc_len} bytes, {} arrived",
                bytes.len() - HEAD_LEN
            ))
        })?;
        if format::checksum(doc) != doc_sum {
            return Err(BootstrapError::DocumentChecksum);
        }
        let info: DatasetInfo =
            serde_json::from_slice(doc).map_err(|e| BootstrapError::Document(e.to_string()))?;
        let geometry = TileGeometry::new(info.width, info.height, info.tile_size)
            .map_err(|e| BootstrapError::Document(e.to_string()))?;
        if record_levels == 0
            || record_levels > table_levels
            || table_levels > geometry.level_count()
            || slots(table_levels) > MAX_CARRIED_SLOTS
        {
            return Err(BootstrapError::Levels(format!(
                "records of levels 0..{record_levels} and error tables of levels {record_levels}..{table_levels} for a pyramid of {} levels",
                geometry.level_count()
            )));
        }
        let all = wire::decode_all(&bytes[HEAD_LEN + doc_len..])?;
        let table_len = ErrorTable::byte_len(geometry.tile_log2());
        let mut frames = Vec::with_capacity(all.len());
        let mut seen = HashSet::new();
        let (mut tiles, mut errors) = (0u64, 0u64);
        for (index, f) in all.into_iter().enumerate() {
            let bad = |what: String| BootstrapError::Frame { index, what };
            let (level, morton) = match &f {
                Frame::Tile { level, morton, .. } => {
                    // Records of finer levels are a focus's ([`crate::focus`]).
                    if level.get() >= geometry.level_count() {
                        return Err(bad(format!(
                            "a record of level {level}, beyond the pyramid's levels 0..{}",
                            geometry.level_count()
                        )));
                    }
                    tiles += 1;
                    (*level, *morton)
                }
                Frame::ErrorTable {
                    level,
                    morton,
                    table,
                    ..
                } => {
                    if !(record_levels..table_levels).contains(&level.get()) {
                        return Err(bad(format!(
                            "an error table of level {level}, not among the table levels {record_levels}..{table_levels}"
                        )));
                    }
                    if table.len() != table_len {
                        return Err(bad(format!(
                            "an error table of {} bytes, not {table_len}",
                            table.len()
                        )));
                    }
                    tiles += 1;
                    (*level, *morton)
                }
                Frame::Error { level, morton, .. } => {
                    if level.get() >= table_levels {
                        return Err(bad(format!(
                            "an error for level {level}, beyond the carried levels 0..{table_levels}"
                        )));
                    }
                    errors += 1;
                    (*level, *morton)
                }
                Frame::Trailer {
                    tiles: t,
                    errors: e,
                    outside,
                } => {
                    if (*t, *e) != (tiles, errors) || !outside.is_empty() {
                        return Err(bad(format!(
                            "the trailer counts {t} tiles and {e} errors (and {} outside ranges); the stream holds {tiles} and {errors} (and none)",
                            outside.len()
                        )));
                    }
                    continue;
                }
            };
            let tile = TileId::from_morton(level, morton)
                .filter(|t| geometry.is_present(*t))
                .ok_or_else(|| bad(format!("code {morton} of level {level} is outside the DEM")))?;
            if !seen.insert(tile) {
                return Err(bad(format!("{tile} comes twice")));
            }
            frames.push(f);
        }
        Ok(Self {
            info,
            record_levels,
            table_levels,
            frames,
        })
    }

    /// The tiles of the carried levels that have no frame: absent (no record).
    pub fn absent(&self) -> Vec<TileId> {
        let Ok(g) = TileGeometry::new(self.info.width, self.info.height, self.info.tile_size)
        else {
            return Vec::new();
        };
        let carried: HashSet<(u8, Morton)> = self
            .frames
            .iter()
            .filter_map(|f| match f {
                Frame::Tile { level, morton, .. }
                | Frame::ErrorTable { level, morton, .. }
                | Frame::Error { level, morton, .. } => Some((level.get(), *morton)),
                Frame::Trailer { .. } => None,
            })
            .collect();
        (0..self.table_levels)
            .filter_map(Level::new)
            .flat_map(|l| g.present_tiles(l).collect::<Vec<_>>())
            .filter(|t| !carried.contains(&(t.level().get(), t.morton())))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bootstrap of a 1025² pyramid of 256-cell tiles (3 levels): two records
    /// of levels 0–1, one corrupt record on level 1, and an error table on level 2.
    fn sample() -> Bootstrap {
        let meta = crate::fixtures::metadata(1025, 1025, 256);
        let info = DatasetInfo::new("t", &meta, 2, 1234);
        let l = |n| Level::new(n).unwrap();
        let record = b"a stored record".to_vec();
        let table = vec![7u8; ErrorTable::byte_len(8)];
        Bootstrap {
            info,
            record_levels: 2,
            table_levels: 3,
            frames: vec![
                Frame::Tile {
                    level: l(0),
                    morton: Morton::from_raw(0),
                    checksum: format::checksum(&record),
                    min: 1,
                    max: 9,
                    record: record.clone(),
                },
                Frame::Tile {
                    level: l(1),
                    morton: Morton::from_raw(0),
                    checksum: format::checksum(&record),
                    min: 2,
                    max: 8,
                    record,
                },
                Frame::Error {
                    level: l(1),
                    morton: Morton::from_raw(3),
                    message: "level 1 (1, 1): record fails its checksum".into(),
                },
                Frame::ErrorTable {
                    level: l(2),
                    morton: Morton::from_raw(5),
                    min: 3,
                    max: 4,
                    table,
                },
            ],
        }
    }

    #[test]
    fn round_trips_and_pins_the_head() {
        let b = sample();
        let bytes = b.encode();
        assert_eq!(&bytes[..8], b"TESSBOOT");
        assert_eq!(u16::from_le_bytes([bytes[8], bytes[9]]), 1);
        assert_eq!((bytes[10], bytes[11]), (2, 3));
        let doc_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        let doc: DatasetInfo = serde_json::from_slice(&bytes[24..24 + doc_len]).unwrap();
        assert_eq!(doc, b.info);
        assert_eq!(Bootstrap::decode(&bytes).unwrap(), b);
    }

    #[test]
    fn absent_tiles_are_the_carried_levels_without_a_frame() {
        let absent = sample().absent();
        // Levels 0..3 hold 1 + 4 + 16 tiles (1025 samples: every tile present); 4 have frames.
        assert_eq!(absent.len(), 21 - 4);
        let l1 = |x, y| TileId::new(Level::new(1).unwrap(), x, y).unwrap();
        assert!(absent.contains(&l1(1, 0)));
        assert!(!absent.contains(&l1(0, 0)) && !absent.contains(&l1(1, 1)));
    }

    #[test]
    fn every_truncation_is_an_error_never_a_panic() {
        let bytes = sample().encode();
        for n in 0..bytes.len() {
            let e = Bootstrap::decode(&bytes[..n]).expect_err("a prefix is not a bootstrap");
            let said = e.to_string();
            assert!(said.contains("truncated"), "{n} bytes: {said}");
        }
    }

    #[test]
    fn damage_is_named() {
        let good = sample().encode();
        let with = |at: usize, f: &dyn Fn(&mut u8)| {
            let mut b = good.clone();
            f(&mut b[at]);
            Bootstrap::decode(&b).expect_err("damaged")
        };
        assert_eq!(with(0, &|b| *b = b'X'), BootstrapError::Magic);
        assert_eq!(with(8, &|b| *b = 2), BootstrapError::Version(2));
        assert_eq!(with(30, &|b| *b ^= 1), BootstrapError::DocumentChecksum);
        assert!(matches!(with(10, &|b| *b = 9), BootstrapError::Levels(_)));
        assert!(matches!(with(10, &|b| *b = 0), BootstrapError::Levels(_)));
        // A bit flipped in the first record: its frame fails its checksum.
        let doc_len = u32::from_le_bytes(good[12..16].try_into().unwrap()) as usize;
        let record_at = HEAD_LEN + doc_len + wire::FRAME_HEADER_LEN;
        assert!(matches!(
            with(record_at, &|b| *b ^= 0x10),
            BootstrapError::Frames(WireError::Checksum { .. })
        ));
        // Bytes after the trailer.
        let mut long = good.clone();
        long.extend_from_slice(&[0; 40]);
        assert!(matches!(
            Bootstrap::decode(&long),
            Err(BootstrapError::Frames(WireError::AfterTrailer))
        ));
    }

    #[test]
    fn frames_must_belong_to_their_levels() {
        let record = |level: u8, morton: u64| Frame::Tile {
            level: Level::new(level).unwrap(),
            morton: Morton::from_raw(morton),
            checksum: format::checksum(b"x"),
            min: 0,
            max: 0,
            record: b"x".to_vec(),
        };
        // A focus's record of a table level: accepted, and no longer absent.
        let mut b = sample();
        b.frames.push(record(2, 1));
        let decoded = Bootstrap::decode(&b.encode()).unwrap();
        let l2 = |m| TileId::from_morton(Level::new(2).unwrap(), Morton::from_raw(m)).unwrap();
        assert!(!decoded.absent().contains(&l2(1)) && decoded.absent().contains(&l2(2)));
        // The same tile as a record and as an error table.
        let mut b = sample();
        b.frames.push(record(2, 5));
        let e = Bootstrap::decode(&b.encode()).unwrap_err();
        assert!(e.to_string().contains("comes twice"), "{e}");
        // A record of a level the pyramid does not have (it has 0..3).
        let mut b = sample();
        b.frames.push(record(3, 0));
        let e = Bootstrap::decode(&b.encode()).unwrap_err();
        assert!(e.to_string().contains("beyond the pyramid's levels"), "{e}");
        let mut b = sample();
        b.frames.push(b.frames[0].clone());
        let e = Bootstrap::decode(&b.encode()).unwrap_err();
        assert!(e.to_string().contains("comes twice"), "{e}");
        let mut b = sample();
        if let Frame::ErrorTable { table, .. } = &mut b.frames[3] {
            table.pop();
        }
        let e = Bootstrap::decode(&b.encode()).unwrap_err();
        assert!(e.to_string().contains("error table of"), "{e}");
    }

    #[test]
    fn levels_are_planned_by_byte_budget() {
        // The moon 8192² in 512-cell tiles: record bytes and present tiles per level.
        let moon = [
            (353_679, 1),
            (1_142_447, 4),
            (4_293_021, 16),
            (13_988_530, 64),
            (39_975_562, 256),
        ];
        // Levels 0–1 as records (1.5 MB), 2–3 as tables (80 × 2816 B = 220 KiB).
        assert_eq!(plan_levels(&moon, ErrorTable::byte_len(9)), (2, 4));
        // A root over the budget is still carried, alone.
        assert_eq!(plan_levels(&[(5 << 20, 1), (1, 4)], 100), (1, 2));
        assert_eq!(plan_levels(&[(10, 1)], 100), (1, 1));
        // However small the records, no more levels than the slot bound allows.
        assert_eq!(plan_levels(&[(0, 0); 14], 0), (10, 10));
    }

    /// Writes the fuzz target's seeds (`fuzz/corpus/bootstrap/seed-*`), run by hand:
    /// `cargo test -p tessera-shared --lib bootstrap::tests::write_fuzz_seeds -- --ignored`.
    #[test]
    #[ignore = "writes files into fuzz/corpus"]
    fn write_fuzz_seeds() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus/bootstrap");
        std::fs::create_dir_all(&dir).unwrap();
        let full = sample();
        let mut root_only = sample();
        root_only.frames.truncate(1);
        root_only.record_levels = 1;
        root_only.table_levels = 1;
        let mut bare = sample();
        bare.frames.clear();
        for (name, b) in [
            ("records-tables-error", full),
            ("root-only", root_only),
            ("all-absent", bare),
        ] {
            let bytes = b.encode();
            assert!(crate::fuzzing::bootstrap(&bytes).is_ok());
            std::fs::write(dir.join(format!("seed-{name}")), bytes).unwrap();
        }
    }

    #[test]
    fn arbitrary_bytes_never_panic() {
        let good = sample().encode();
        // Every single-byte change of a valid bootstrap decodes or errs.
        for at in 0..good.len() {
            for v in [0u8, 0xff, good[at].wrapping_add(1)] {
                let mut b = good.clone();
                b[at] = v;
                let _ = Bootstrap::decode(&b);
            }
        }
    }
}

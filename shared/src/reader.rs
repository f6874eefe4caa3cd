//! Reading a pyramid over any source of byte ranges: a local file now, object
//! storage or HTTP Range requests later (docs/ARCHITECTURE.md#the-file,
//! docs/ARCHITECTURE.md#storage).

use crate::codec::{self, CodecError, TileRecord};
use crate::error_table::ErrorTable;
use crate::format::{
    self, FileHeader, HEADER_LEN, HeaderError, INDEX_ENTRY_LEN, IndexEntry, LEVEL_ENTRY_LEN,
    LevelEntry, MetadataError,
};
use crate::imagery::ImageryMetadata;
use crate::metadata::Metadata;
use crate::morton::MortonRange;
use crate::tile::{GeometryError, Level, TileGeometry, TileId};
use std::io;
use std::path::Path;

/// Anything that can answer "give me bytes `offset..offset+buf.len()`".
pub trait ByteSource: Send + Sync {
    /// Total length in bytes.
    fn size(&self) -> io::Result<u64>;
    /// Fills `buf` from `offset`; an error if the source is shorter.
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()>;

    /// Reads `len` bytes at `offset` into a new buffer.
    fn read_vec(&self, offset: u64, len: usize) -> io::Result<Vec<u8>> {
        let mut v = vec![0; len];
        self.read_at(offset, &mut v)?;
        Ok(v)
    }
}

/// A local file read with positional reads (`pread`), shareable across threads.
#[derive(Debug)]
pub struct FileSource {
    file: std::fs::File,
}

impl FileSource {
    pub fn open(path: &Path) -> io::Result<Self> {
        Ok(Self {
            file: std::fs::File::open(path)?,
        })
    }
}

impl ByteSource for FileSource {
    fn size(&self) -> io::Result<u64> {
        Ok(self.file.metadata()?.len())
    }

    #[cfg(unix)]
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()> {
        std::os::unix::fs::FileExt::read_exact_at(&self.file, buf, offset)
    }

    #[cfg(windows)]
    fn read_at(&self, mut offset: u64, mut buf: &mut [u8]) -> io::Result<()> {
        use std::os::windows::fs::FileExt;
        while !buf.is_empty() {
            match self.file.seek_read(buf, offset)? {
                0 => return Err(io::ErrorKind::UnexpectedEof.into()),
                n => {
                    buf = &mut buf[n..];
                    offset += n as u64;
                }
            }
        }
        Ok(())
    }
}

impl ByteSource for Vec<u8> {
    fn size(&self) -> io::Result<u64> {
        Ok(self.as_slice().len() as u64)
    }

    fn read_at(&self, offset: u64, buf: &mut [u8]) -> io::Result<()> {
        let start = usize::try_from(offset).map_err(|_| io::ErrorKind::UnexpectedEof)?;
        let src = self
            .get(start..start + buf.len())
            .ok_or(io::ErrorKind::UnexpectedEof)?;
        buf.copy_from_slice(src);
        Ok(())
    }
}

/// Why a pyramid could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("I/O error: {0}")]
    Io(#[from] io::Error),
    #[error(transparent)]
    Header(#[from] HeaderError),
    #[error("header checksum mismatch: the header, metadata or index is damaged")]
    HeaderChecksum,
    #[error("metadata does not decode: {0}")]
    Metadata(#[from] MetadataError),
    #[error("bad geometry: {0}")]
    Geometry(#[from] GeometryError),
    #[error("bad structure: {0}")]
    Structure(String),
    #[error("{tile}: checksum mismatch (record is corrupt)")]
    RecordChecksum { tile: TileId },
    #[error("{tile}: {source}")]
    Codec { tile: TileId, source: CodecError },
}

/// An open pyramid: metadata and every level's index in memory, records on demand.
#[derive(Debug)]
pub struct Pyramid<S> {
    source: S,
    header: FileHeader,
    meta: Metadata,
    geometry: TileGeometry,
    levels: Vec<LevelEntry>,
    index: Vec<Vec<IndexEntry>>,
    /// Set for an imagery pyramid ([`Pyramid::open_imagery`]); `meta` is then its DEM's.
    imagery: Option<ImageryMetadata>,
}

impl Pyramid<FileSource> {
    /// Opens a local pyramid file.
    pub fn open_file(path: &Path) -> Result<Self, ReadError> {
        Self::open(FileSource::open(path)?)
    }
}

impl<S: ByteSource> Pyramid<S> {
    /// Reads and checks the header, metadata, level table and indices.
    ///
    /// Checks the header checksum and that the indices describe a well-formed file:
    /// every present tile is one the geometry says exists, and each level's records are
    /// contiguous in Morton order inside that level's record range.
    ///
    /// A DEM pyramid only: an imagery pyramid is refused ([`Pyramid::open_imagery`]).
    pub fn open(source: S) -> Result<Self, ReadError> {
        Self::open_kind(source, Kind::Dem)
    }

    /// Opens an imagery pyramid ([`crate::imagery`]) with the same checks; its
    /// [`Pyramid::metadata`] is the DEM's it was built for, [`Pyramid::imagery`] its own.
    pub fn open_imagery(source: S) -> Result<Self, ReadError> {
        Self::open_kind(source, Kind::Imagery)
    }

    fn open_kind(source: S, kind: Kind) -> Result<Self, ReadError> {
        let file_len = source.size()?;
        let header = read_header(&source, file_len)?;
        let region = source.read_vec(
            HEADER_LEN as u64,
            (header.records_offset - HEADER_LEN as u64) as usize,
        )?;
        if header.compute_checksum(&region) != header.checksum {
            return Err(ReadError::HeaderChecksum);
        }
        // Offsets are absolute; `slice` maps them into the header region.
        let slice = |off: u64, len: u64, what: &str| -> Result<&[u8], ReadError> {
            off.checked_sub(HEADER_LEN as u64)
                .and_then(|s| region.get(s as usize..s.checked_add(len)? as usize))
                .ok_or_else(|| {
                    ReadError::Structure(format!("{what} lies outside the header region"))
                })
        };
        let layout = Layout::read(header, file_len, kind, |o, l, w| {
            slice(o, l, w).map(<[u8]>::to_vec)
        })?;
        let mut index = Vec::new();
        for (level, entry) in layout.geometry.levels().zip(&layout.levels) {
            let bytes = slice(
                entry.index_offset,
                level.tile_slots() * INDEX_ENTRY_LEN as u64,
                &format!("index of level {level}"),
            )?;
            let entries: Vec<IndexEntry> = bytes
                .chunks_exact(INDEX_ENTRY_LEN)
                .map(IndexEntry::parse)
                .collect();
            let mut check = IndexCheck::new(&layout.geometry, level, entry, layout.header.version);
            for (m, e) in entries.iter().enumerate() {
                check.entry(m as u64, e)?;
            }
            check.finish()?;
            index.push(entries);
        }
        let Layout {
            header,
            meta,
            geometry,
            levels,
            imagery,
        } = layout;
        Ok(Self {
            source,
            header,
            meta,
            geometry,
            levels,
            index,
            imagery,
        })
    }

    pub fn metadata(&self) -> &Metadata {
        &self.meta
    }

    /// An imagery pyramid's own metadata; `None` for a DEM pyramid.
    pub fn imagery(&self) -> Option<&ImageryMetadata> {
        self.imagery.as_ref()
    }

    pub fn geometry(&self) -> &TileGeometry {
        &self.geometry
    }

    pub fn header(&self) -> &FileHeader {
        &self.header
    }

    /// How this file's records are laid out (its tile size and format version).
    pub fn record_layout(&self) -> codec::RecordLayout {
        codec::RecordLayout::new(self.geometry.tile_log2(), self.header.version)
    }

    pub fn source(&self) -> &S {
        &self.source
    }

    pub fn level_entry(&self, level: Level) -> Option<&LevelEntry> {
        self.levels.get(usize::from(level.get()))
    }

    /// The dense index of a level, by Morton code.
    pub fn index(&self, level: Level) -> Option<&[IndexEntry]> {
        self.index.get(usize::from(level.get())).map(Vec::as_slice)
    }

    /// The index entry of a present tile.
    pub fn entry(&self, tile: TileId) -> Option<&IndexEntry> {
        self.index(tile.level())?
            .get(tile.morton().get() as usize)
            .filter(|e| e.is_present())
    }

    /// The byte range `(offset, len)` holding every present record of a Morton range,
    /// or `None` when no tile of the range is present.
    pub fn byte_range(&self, level: Level, range: MortonRange) -> Option<(u64, u64)> {
        let idx = self.index(level)?;
        let lo = usize::try_from(range.start().get()).ok()?;
        let hi = usize::try_from(range.end().get())
            .ok()?
            .min(idx.len().checked_sub(1)?);
        let slice = idx.get(lo..=hi)?;
        let first = slice.iter().find(|e| e.is_present())?;
        let last = slice.iter().rev().find(|e| e.is_present())?;
        Some((first.offset, last.end() - first.offset))
    }

    /// The stored bytes of a tile's record, checked against its checksum.
    /// `Ok(None)` for a tile that is absent.
    pub fn read_record(&self, tile: TileId) -> Result<Option<Vec<u8>>, ReadError> {
        let Some(e) = self.entry(tile) else {
            return Ok(None);
        };
        let bytes = self.source.read_vec(e.offset, e.length as usize)?;
        if format::checksum(&bytes) != e.checksum {
            return Err(ReadError::RecordChecksum { tile });
        }
        Ok(Some(bytes))
    }

    /// A tile's error table and heights, checked and decoded.
    pub fn read_tile(&self, tile: TileId) -> Result<Option<TileRecord>, ReadError> {
        let Some(bytes) = self.read_record(tile)? else {
            return Ok(None);
        };
        codec::decode_record(&bytes, self.record_layout())
            .map(Some)
            .map_err(|source| ReadError::Codec { tile, source })
    }

    /// Only a tile's error table (from the checked record).
    pub fn read_error_table(&self, tile: TileId) -> Result<Option<ErrorTable>, ReadError> {
        let Some(bytes) = self.read_record(tile)? else {
            return Ok(None);
        };
        codec::decode_error_table(&bytes, self.geometry.tile_log2())
            .map(Some)
            .map_err(|source| ReadError::Codec { tile, source })
    }
}

/// Index entries read at a time by [`check_streaming`] (2 MiB).
const INDEX_CHUNK: u64 = 1 << 16;

/// Parses the fixed header and checks that its header region lies inside the file.
fn read_header<S: ByteSource>(source: &S, file_len: u64) -> Result<FileHeader, ReadError> {
    let head = source.read_vec(0, HEADER_LEN.min(file_len as usize))?;
    let header = FileHeader::parse(&head).map_err(ReadError::Header)?;
    if header.records_offset > file_len || header.records_offset < HEADER_LEN as u64 {
        return Err(ReadError::Structure(format!(
            "header points outside the file ({file_len} bytes)"
        )));
    }
    Ok(header)
}

/// Which kind of pyramid a caller expects (the header's magic and flag say which
/// one a file is).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Dem,
    Imagery,
}

/// The small parts of a header region: header, metadata, geometry and level table.
struct Layout {
    header: FileHeader,
    meta: Metadata,
    geometry: TileGeometry,
    levels: Vec<LevelEntry>,
    imagery: Option<ImageryMetadata>,
}

impl Layout {
    /// `read(offset, len, what)` returns header-region bytes, an error when they lie
    /// outside it.
    fn read(
        header: FileHeader,
        file_len: u64,
        kind: Kind,
        read: impl Fn(u64, u64, &str) -> Result<Vec<u8>, ReadError>,
    ) -> Result<Self, ReadError> {
        let is_imagery = header.flags & format::FILE_IMAGERY != 0;
        match (kind, is_imagery) {
            (Kind::Dem, true) => {
                return Err(ReadError::Structure(
                    "this is an imagery pyramid (.tessimg), not a DEM pyramid".into(),
                ));
            }
            (Kind::Imagery, false) => {
                return Err(ReadError::Structure(
                    "this is a DEM pyramid, not an imagery pyramid".into(),
                ));
            }
            _ => {}
        }
        let meta_bytes = read(header.meta_offset, header.meta_len, "metadata")?;
        let (meta, imagery) = if is_imagery {
            let imagery = format::decode_imagery_metadata_of(&meta_bytes, header.version)
                .map_err(ReadError::Metadata)?;
            (imagery.dem.clone(), Some(imagery))
        } else {
            let meta = format::decode_metadata_of(&meta_bytes, header.version)
                .map_err(ReadError::Metadata)?;
            (meta, None)
        };
        let geometry = TileGeometry::new(meta.width, meta.height, meta.tile_size)?;
        if header.level_count != u32::from(geometry.level_count())
            || meta.levels != geometry.level_count()
            || header.index_entry_len != INDEX_ENTRY_LEN as u32
        {
            return Err(ReadError::Structure(format!(
                "{} levels in the header, {} in the metadata, {} from the geometry",
                header.level_count,
                meta.levels,
                geometry.level_count()
            )));
        }
        let mut levels = Vec::new();
        for level in geometry.levels() {
            // Checked: the offset is the file's claim (`read` bounds-checks the rest).
            let off = header
                .level_table_offset
                .checked_add(u64::from(level.get()) * LEVEL_ENTRY_LEN as u64)
                .ok_or_else(|| ReadError::Structure("level table lies outside the file".into()))?;
            let entry = LevelEntry::parse(&read(off, LEVEL_ENTRY_LEN as u64, "level table")?);
            let slots = level.tile_slots();
            if entry.level != level.get()
                || entry.tiles_per_side != level.tiles_per_side()
                || entry.index_entries != slots
                || entry.records_offset < header.records_offset
                || entry
                    .records_offset
                    .checked_add(entry.records_len)
                    .is_none_or(|end| end > file_len)
            {
                return Err(ReadError::Structure(format!(
                    "level table entry for level {level} is inconsistent"
                )));
            }
            levels.push(entry);
        }
        Ok(Self {
            header,
            meta,
            geometry,
            levels,
            imagery,
        })
    }
}

/// Checks one level's index entry by entry, in Morton order: presence must match the
/// geometry, and records must be contiguous inside the level's record range.
struct IndexCheck<'g> {
    geometry: &'g TileGeometry,
    level: Level,
    /// From version 2 a tile inside the DEM may be absent: it is wholly no-data.
    no_data_absent: bool,
    next: u64,
    end: u64,
}

impl<'g> IndexCheck<'g> {
    fn new(geometry: &'g TileGeometry, level: Level, entry: &LevelEntry, version: u32) -> Self {
        Self {
            geometry,
            level,
            no_data_absent: version >= 2,
            next: entry.records_offset,
            end: entry.records_offset + entry.records_len,
        }
    }

    fn entry(&mut self, m: u64, e: &IndexEntry) -> Result<TileId, ReadError> {
        let level = self.level;
        let tile = TileId::from_morton(level, crate::Morton::from_raw(m))
            .ok_or_else(|| ReadError::Structure(format!("index slot {m} of level {level}")))?;
        let present = self.geometry.is_present(tile);
        let allowed = e.is_present() == present || (self.no_data_absent && !e.is_present());
        if !allowed {
            return Err(ReadError::Structure(format!(
                "{tile} is {} in the index but {} by the geometry",
                if e.is_present() { "present" } else { "absent" },
                if present { "present" } else { "absent" },
            )));
        }
        if e.is_present() {
            if e.offset != self.next {
                return Err(ReadError::Structure(format!(
                    "{tile}: record at offset {} but the previous one ends at {}",
                    e.offset, self.next
                )));
            }
            self.next = e.end();
        }
        Ok(tile)
    }

    fn finish(self) -> Result<(), ReadError> {
        if self.next != self.end {
            return Err(ReadError::Structure(format!(
                "level {} records end at {}, the level table says {}",
                self.level, self.next, self.end
            )));
        }
        Ok(())
    }
}

/// Checks a whole pyramid without holding its index in memory: the header checksum, the
/// metadata and level table, every level's index (read a chunk at a time) and every
/// record's checksum. `each` sees every present tile's checked record, levels ascending,
/// Morton order. Memory stays a few MiB whatever the file's size, which is what lets a
/// build verify its output under `--memory` (docs/ARCHITECTURE.md#bad-input-is-an-error).
pub fn check_streaming<S: ByteSource>(
    source: &S,
    each: impl FnMut(TileId, &IndexEntry, &[u8]) -> Result<(), ReadError>,
) -> Result<Metadata, ReadError> {
    check_streaming_kind(source, Kind::Dem, each).map(|l| l.meta)
}

/// [`check_streaming`] of an imagery pyramid: returns its own metadata.
pub fn check_streaming_imagery<S: ByteSource>(
    source: &S,
    each: impl FnMut(TileId, &IndexEntry, &[u8]) -> Result<(), ReadError>,
) -> Result<ImageryMetadata, ReadError> {
    check_streaming_kind(source, Kind::Imagery, each)
        .map(|l| l.imagery.expect("an imagery layout has imagery metadata"))
}

fn check_streaming_kind<S: ByteSource>(
    source: &S,
    kind: Kind,
    mut each: impl FnMut(TileId, &IndexEntry, &[u8]) -> Result<(), ReadError>,
) -> Result<Layout, ReadError> {
    let file_len = source.size()?;
    let header = read_header(source, file_len)?;
    let region_end = header.records_offset;
    let in_region = |off: u64, len: u64, what: &str| -> Result<(), ReadError> {
        match off.checked_add(len) {
            Some(end) if off >= HEADER_LEN as u64 && end <= region_end => Ok(()),
            _ => Err(ReadError::Structure(format!(
                "{what} lies outside the header region"
            ))),
        }
    };
    // The header checksum, streamed over the region.
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    h.update(&header.to_bytes()[..56]);
    let mut at = HEADER_LEN as u64;
    let mut buf = Vec::new();
    while at < region_end {
        let n = (region_end - at).min(1 << 21) as usize;
        buf.resize(n, 0);
        source.read_at(at, &mut buf)?;
        h.update(&buf);
        at += n as u64;
    }
    if h.digest() != header.checksum {
        return Err(ReadError::HeaderChecksum);
    }
    let layout = Layout::read(header, file_len, kind, |off, len, what| {
        in_region(off, len, what)?;
        Ok(source.read_vec(off, len as usize)?)
    })?;
    for (level, entry) in layout.geometry.levels().zip(&layout.levels) {
        in_region(
            entry.index_offset,
            level.tile_slots() * INDEX_ENTRY_LEN as u64,
            &format!("index of level {level}"),
        )?;
        let mut check = IndexCheck::new(&layout.geometry, level, entry, layout.header.version);
        let slots = level.tile_slots();
        let mut m = 0u64;
        while m < slots {
            let n = (slots - m).min(INDEX_CHUNK);
            let bytes = source.read_vec(
                entry.index_offset + m * INDEX_ENTRY_LEN as u64,
                (n as usize) * INDEX_ENTRY_LEN,
            )?;
            for e in bytes.chunks_exact(INDEX_ENTRY_LEN).map(IndexEntry::parse) {
                let tile = check.entry(m, &e)?;
                if e.is_present() {
                    let record = source.read_vec(e.offset, e.length as usize)?;
                    if format::checksum(&record) != e.checksum {
                        return Err(ReadError::RecordChecksum { tile });
                    }
                    each(tile, &e, &record)?;
                }
                m += 1;
            }
        }
        check.finish()?;
    }
    Ok(layout)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file written by the version 1 writer (`tessera-server build synthetic:129
    /// --tile-size 64`, before format v2) still opens, checks and decodes: its metadata
    /// in the old shape, its records without mask sections, every cell valid.
    #[test]
    fn version_1_files_still_read() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("testdata/v1-synthetic-129-t64.tess");
        let p = Pyramid::open_file(&path).unwrap();
        assert_eq!(p.header().version, 1);
        let m = p.metadata();
        assert_eq!(
            (m.width, m.height, m.tile_size, m.levels),
            (129, 129, 64, 2)
        );
        assert!(m.source.contains("synthetic:129"), "{}", m.source);
        assert_eq!(m.vertical_datum, crate::VerticalDatum::Unknown);
        assert!(m.level_counts.is_empty() && m.ground_spacing.is_none());
        let mut tiles = 0;
        for level in p.geometry().levels() {
            for tile in p.geometry().present_tiles(level) {
                let rec = p
                    .read_tile(tile)
                    .unwrap()
                    .expect("every v1 tile in the DEM is present");
                assert_eq!(rec.heights.len(), 65 * 65);
                assert!(rec.mask.is_all_valid());
                tiles += 1;
            }
        }
        assert_eq!(tiles, 5);
        // Its content hash is still its identity: hashed in the shape v1 stored.
        let mut sums = Vec::new();
        let meta = check_streaming(&FileSource::open(&path).unwrap(), |_, e, _| {
            sums.push(e.checksum);
            Ok(())
        })
        .unwrap();
        assert_eq!(&meta, m);
        assert_eq!(format::content_hash(m, 1, sums.iter()), m.content_hash);
        assert_ne!(format::content_hash(m, 2, sums.iter()), m.content_hash);
    }

    /// A version 2 file (written by `tessera-server build synthetic:129 --tile-size 64`
    /// before format v3) still opens, checks and decodes: its metadata in the version 2
    /// shape (no sources), its content hash still its identity.
    #[test]
    fn version_2_files_still_read() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("testdata/v2-synthetic-129-t64.tess");
        let p = Pyramid::open_file(&path).unwrap();
        assert_eq!(p.header().version, 2);
        let m = p.metadata();
        assert_eq!(
            (m.width, m.height, m.tile_size, m.levels),
            (129, 129, 64, 2)
        );
        assert!(m.source.contains("synthetic:129"), "{}", m.source);
        assert!(m.sources.is_empty());
        assert_eq!(m.level_counts.len(), 2);
        let mut tiles = 0;
        for level in p.geometry().levels() {
            for tile in p.geometry().present_tiles(level) {
                let rec = p
                    .read_tile(tile)
                    .unwrap()
                    .expect("synthetic terrain has no voids");
                assert_eq!(rec.heights.len(), 65 * 65);
                tiles += 1;
            }
        }
        assert_eq!(tiles, 5);
        let mut sums = Vec::new();
        let meta = check_streaming(&FileSource::open(&path).unwrap(), |_, e, _| {
            sums.push(e.checksum);
            Ok(())
        })
        .unwrap();
        assert_eq!(&meta, m);
        assert_eq!(format::content_hash(m, 2, sums.iter()), m.content_hash);
        assert_ne!(format::content_hash(m, 3, sums.iter()), m.content_hash);
    }
}

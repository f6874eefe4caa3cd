//! A pyramid's update state, `OUT.tess.state` (`build --state`; FORMAT.md "Update
//! state"): what `build --update` needs besides the pyramid to rebuild only the tiles
//! a changed input touches.
//!
//! - **Errors a record does not keep.** A level-`l` record stores its errors for the
//!   `t + 1` spacings it meshes at; its ancestors pool its errors for the `l` coarser
//!   spacings too (their cells reach past the tile, and are measured against the
//!   finest samples). Those `64 · l` values (metres, `f32`, as records store errors)
//!   are kept here for every stored tile, so a tile that did not change is rebuilt
//!   from its record and its entry, without reading its samples.
//! - **The inputs**: each file's path, size and ETag (or modification time) and its
//!   window on the pyramid's grid, so an update finds what changed, was added or was
//!   removed, and where.
//!
//! Layout: entries (`u8` level, 3 zero bytes, `u32` value count, `u64` Morton code, the
//! `f32` values), then a JSON trailer, then a 32-byte footer: trailer offset and length
//! (`u64`), the XXH3-64 of every byte before the footer, and the magic `TESSSTA1`.

use crate::builder::node::Node;
use anyhow::{Context, bail, ensure};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use tessera_shared::tile::BLOCKS;
use tessera_shared::{Level, Morton, TileGeometry};
use xxhash_rust::xxh3::Xxh3;

/// Last bytes of a state file.
pub const MAGIC: [u8; 8] = *b"TESSSTA1";
const FOOTER_LEN: u64 = 32;
const ENTRY_HEAD: usize = 16;
/// Bound on a trailer (its input list is the variable part).
const MAX_TRAILER: u64 = 256 << 20;

/// The state file of the pyramid at `pyramid`: `pyramid` + `.state`.
pub fn path_of(pyramid: &Path) -> PathBuf {
    let mut s = pyramid.as_os_str().to_owned();
    s.push(".state");
    PathBuf::from(s)
}

/// One input as the build read it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct InputRecord {
    /// The path or URL as the build named it.
    pub path: String,
    /// Its size in bytes, and its ETag (an object) or modification time (a file).
    pub size: u64,
    pub tag: String,
    /// Its window on the pyramid's grid, `[x, y, width, height]` samples.
    pub window: [u32; 4],
}

#[derive(Debug, Serialize, Deserialize)]
struct Trailer {
    /// The pyramid's content hash: a state belongs to one pyramid.
    content_hash: String,
    width: u32,
    height: u32,
    tile_size: u32,
    inputs: Vec<InputRecord>,
    entries: u64,
}

/// The errors a level-`l` node's record does not keep: spacings `L − l + t + 1 ..= t
/// + L`, 64 blocks each.
fn extra_spacings(g: &TileGeometry, level: Level) -> std::ops::RangeInclusive<u32> {
    let t = g.tile_log2();
    let finest = u32::from(g.finest().get());
    finest - u32::from(level.get()) + t + 1..=t + finest
}

/// Writes a state file beside its final name, moved into place by [`finish`].
///
/// [`finish`]: StateWriter::finish
pub struct StateWriter {
    out: BufWriter<File>,
    temp: PathBuf,
    target: PathBuf,
    hash: Xxh3,
    entries: u64,
    geometry: TileGeometry,
    /// Moved into place: nothing to remove.
    done: bool,
}

impl std::fmt::Debug for StateWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StateWriter")
            .field("target", &self.target)
            .field("entries", &self.entries)
            .finish_non_exhaustive()
    }
}

impl StateWriter {
    pub fn create(target: &Path, geometry: TileGeometry) -> anyhow::Result<Self> {
        let name = target
            .file_name()
            .map_or_else(|| "state".into(), |n| n.to_string_lossy().into_owned());
        let temp = target.with_file_name(format!(".{name}.partial-{}", std::process::id()));
        let file =
            File::create(&temp).with_context(|| format!("cannot create {}", temp.display()))?;
        Ok(Self {
            out: BufWriter::new(file),
            temp,
            target: target.to_path_buf(),
            hash: Xxh3::new(),
            entries: 0,
            geometry,
            done: false,
        })
    }

    fn write(&mut self, bytes: &[u8]) -> anyhow::Result<()> {
        self.hash.update(bytes);
        self.out
            .write_all(bytes)
            .with_context(|| format!("cannot write {}", self.temp.display()))
    }

    /// The entry of a stored level-`level` tile's node (the root keeps nothing).
    pub(in crate::builder) fn push(
        &mut self,
        level: Level,
        m: Morton,
        node: &Node,
    ) -> anyhow::Result<()> {
        let mut values = Vec::new();
        for k in extra_spacings(&self.geometry, level) {
            for by in 0..BLOCKS {
                for bx in 0..BLOCKS {
                    values.push(node.errors.get(k, bx, by) as f32);
                }
            }
        }
        self.copy(level, m, &values)
    }

    /// An entry as an earlier state file holds it.
    pub fn copy(&mut self, level: Level, m: Morton, values: &[f32]) -> anyhow::Result<()> {
        if values.is_empty() {
            return Ok(());
        }
        let mut head = [0u8; ENTRY_HEAD];
        head[0] = level.get();
        head[4..8].copy_from_slice(&(values.len() as u32).to_le_bytes());
        head[8..16].copy_from_slice(&m.get().to_le_bytes());
        self.write(&head)?;
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.write(&bytes)?;
        self.entries += 1;
        Ok(())
    }

    /// Writes the trailer and footer and moves the file into place: the state of the
    /// pyramid whose content hash is `content_hash`, read from `inputs`.
    pub fn finish(
        mut self,
        content_hash: &str,
        inputs: Vec<InputRecord>,
    ) -> anyhow::Result<PathBuf> {
        let trailer = serde_json::to_vec(&Trailer {
            content_hash: content_hash.to_string(),
            width: self.geometry.width(),
            height: self.geometry.height(),
            tile_size: self.geometry.tile_size(),
            inputs,
            entries: self.entries,
        })?;
        self.out
            .flush()
            .with_context(|| format!("cannot write {}", self.temp.display()))?;
        let offset = self.out.get_ref().metadata()?.len();
        self.write(&trailer)?;
        let mut footer = [0u8; FOOTER_LEN as usize];
        footer[0..8].copy_from_slice(&offset.to_le_bytes());
        footer[8..16].copy_from_slice(&(trailer.len() as u64).to_le_bytes());
        footer[16..24].copy_from_slice(&self.hash.digest().to_le_bytes());
        footer[24..32].copy_from_slice(&MAGIC);
        self.out
            .write_all(&footer)
            .with_context(|| format!("cannot write {}", self.temp.display()))?;
        self.out
            .flush()
            .and_then(|()| self.out.get_ref().sync_all())
            .with_context(|| format!("cannot write {}", self.temp.display()))?;
        std::fs::rename(&self.temp, &self.target).with_context(|| {
            format!(
                "cannot move {} to {}",
                self.temp.display(),
                self.target.display()
            )
        })?;
        self.done = true;
        Ok(self.target.clone())
    }
}

impl Drop for StateWriter {
    fn drop(&mut self) {
        // A build that failed leaves no partial state.
        if !self.done {
            let _ = std::fs::remove_file(&self.temp);
        }
    }
}

/// A state file, checked whole, its entries found by level and Morton code.
#[derive(Debug)]
pub struct State {
    file: File,
    path: PathBuf,
    pub content_hash: String,
    pub width: u32,
    pub height: u32,
    pub tile_size: u32,
    pub inputs: Vec<InputRecord>,
    /// Where each entry's values start, and how many.
    at: HashMap<(u8, u64), (u64, u32)>,
}

impl State {
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let mut file = File::open(path).with_context(|| {
            format!(
                "{}: cannot open the update state (build the old pyramid with --state to \
                 update it later)",
                path.display()
            )
        })?;
        let len = file.metadata()?.len();
        let bad =
            |why: &str| anyhow::anyhow!("{}: not a Tessera update state: {why}", path.display());
        if len < FOOTER_LEN {
            return Err(bad("shorter than its footer"));
        }
        let mut footer = [0u8; FOOTER_LEN as usize];
        file.read_exact_at(&mut footer, len - FOOTER_LEN)?;
        if footer[24..32] != MAGIC {
            return Err(bad("no TESSSTA1 footer"));
        }
        let word = |i: usize| u64::from_le_bytes(footer[i..i + 8].try_into().expect("8 bytes"));
        let (offset, tlen, sum) = (word(0), word(8), word(16));
        ensure!(
            tlen <= MAX_TRAILER && offset.checked_add(tlen) == Some(len - FOOTER_LEN),
            bad("its footer does not match its length (truncated?)")
        );
        let mut hash = Xxh3::new();
        let mut buf = vec![0u8; 1 << 20];
        let mut left = len - FOOTER_LEN;
        while left > 0 {
            let n = (left as usize).min(buf.len());
            file.read_exact(&mut buf[..n])?;
            hash.update(&buf[..n]);
            left -= n as u64;
        }
        if hash.digest() != sum {
            bail!(
                "{}: the update state's checksum does not match (damaged)",
                path.display()
            );
        }
        let mut trailer = vec![0u8; tlen as usize];
        file.read_exact_at(&mut trailer, offset)?;
        let t: Trailer = serde_json::from_slice(&trailer).map_err(|e| bad(&e.to_string()))?;
        let mut at = HashMap::new();
        let mut pos = 0u64;
        let mut head = [0u8; ENTRY_HEAD];
        while pos < offset {
            file.read_exact_at(&mut head, pos)?;
            let count = u32::from_le_bytes(head[4..8].try_into().expect("4 bytes"));
            let m = u64::from_le_bytes(head[8..16].try_into().expect("8 bytes"));
            at.insert((head[0], m), (pos + ENTRY_HEAD as u64, count));
            pos += ENTRY_HEAD as u64 + 4 * u64::from(count);
        }
        ensure!(
            pos == offset && at.len() as u64 == t.entries,
            bad("its entries do not add up")
        );
        Ok(Self {
            file,
            path: path.to_path_buf(),
            content_hash: t.content_hash,
            width: t.width,
            height: t.height,
            tile_size: t.tile_size,
            inputs: t.inputs,
            at,
        })
    }

    /// The values of the tile's entry (empty for the root).
    pub fn values(&self, level: Level, m: Morton) -> anyhow::Result<Vec<f32>> {
        if level == Level::ROOT {
            return Ok(Vec::new());
        }
        let &(at, count) = self.at.get(&(level.get(), m.get())).with_context(|| {
            format!(
                "{}: no entry for tile {m:?} of level {}",
                self.path.display(),
                level.get()
            )
        })?;
        let mut bytes = vec![0u8; 4 * count as usize];
        self.file.read_exact_at(&mut bytes, at)?;
        Ok(bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }

    /// Puts an entry's values back into `node`'s errors.
    pub(in crate::builder) fn restore(
        g: &TileGeometry,
        level: Level,
        values: &[f32],
        node: &mut Node,
    ) -> anyhow::Result<()> {
        let spacings = extra_spacings(g, level);
        ensure!(
            values.len()
                == (spacings.end() + 1 - spacings.start()) as usize * (BLOCKS * BLOCKS) as usize,
            "an update state entry of {} values for a level-{} tile",
            values.len(),
            level.get()
        );
        let mut v = values.iter();
        for k in spacings {
            for by in 0..BLOCKS {
                for bx in 0..BLOCKS {
                    *node.errors.slot_mut(k, bx, by) = f64::from(*v.next().expect("counted"));
                }
            }
        }
        Ok(())
    }
}

//! Whether a build can finish, decided before any sample is read
//! (DECISIONS.md "Build plausibility").
//!
//! A header is cheap to write and expensive to believe: a 374-byte VRT declaring
//! 1201 × 20 000 000 samples over one small source used to spool no-data for hours
//! until the disk filled. So once the inputs' headers are read, and before anything
//! is spooled, two things are checked against what the raster declares:
//!
//! - **`--max-samples`** ([`DEFAULT_MAX_SAMPLES`]): width × height of the raster
//!   (and of the source a `--to` reads whole).
//! - **Free disk space** (`statvfs`) of the folder that holds the spool and of the
//!   folder that gets the output, against what the build writes there ([`DiskNeed`]).
//!   Only what the build writes *whatever the data* is refused: the spool, 4 bytes a
//!   sample, and the reprojection spool, 4 bytes a source sample. What depends on
//!   the data — the validity flags (1 byte a sample, written when the input has any
//!   no-data) and the records (compressed, and absent where a tile holds no data) —
//!   enters only an upper bound, which, when it does not fit, is a warning.
//!
//! Both errors name the input and the figures, e.g. `tiles.vrt: declares 1201 ×
//! 20000000 samples (24.0 G samples): spooling them writes 96.1 GB to /tmp (4 bytes
//! a sample), but only 79.0 GB are free there; …`.

use anyhow::bail;
use std::path::{Path, PathBuf};
use tessera_shared::TileGeometry;
use tessera_shared::error_table::ErrorTable;

/// The default `--max-samples`: 2⁴⁰ (1.1 T samples). A planet at 1″ (1 296 001 ×
/// 648 001 = 0.84 T samples) passes; a header that declares more than any DEM made
/// so far is refused before it costs anything.
pub const DEFAULT_MAX_SAMPLES: u64 = 1 << 40;

/// Bytes a sample takes in the spool: its value as `f32` ([`super::spool`]).
pub const SPOOL_BYTES_PER_SAMPLE: u64 = 4;
/// Bytes a sample takes in the spool's validity file, written when the input has any
/// no-data (unknown until it is read).
pub const VALIDITY_BYTES_PER_SAMPLE: u64 = 1;
/// Bytes a source sample takes in the reprojection spool (`--to`: `f32`).
pub const REPROJECT_BYTES_PER_SAMPLE: u64 = 4;

/// A raster's size as its header declares it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Declared {
    pub width: u32,
    pub height: u32,
}

impl Declared {
    pub fn samples(self) -> u64 {
        u64::from(self.width) * u64::from(self.height)
    }

    /// `1201 × 20000000 samples (24.0 G samples)`.
    pub fn describe(self) -> String {
        format!(
            "{} × {} samples ({} samples)",
            self.width,
            self.height,
            count(self.samples() as f64)
        )
    }
}

/// Refuses a raster of more than `max` samples; `label` names the input and `what`
/// says which raster it is ("declares", or "--to makes").
pub fn check_samples(label: &str, what: &str, size: Declared, max: u64) -> anyhow::Result<()> {
    if size.samples() > max {
        bail!(
            "{label}: {what} {}, more than --max-samples {max} ({} samples); if the size \
             is real, raise --max-samples",
            size.describe(),
            count(max as f64)
        );
    }
    Ok(())
}

/// What a build writes to one folder: at least `least` bytes whatever the data, at
/// most `most`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DiskNeed {
    pub least: u64,
    pub most: u64,
}

impl std::ops::Add for DiskNeed {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self {
            least: self.least.saturating_add(o.least),
            most: self.most.saturating_add(o.most),
        }
    }
}

/// The spool of a `size` raster ([`super::spool`]): its values always, its validity
/// flags when the input has any no-data.
pub fn spool_need(size: Declared) -> DiskNeed {
    let n = size.samples();
    DiskNeed {
        least: n.saturating_mul(SPOOL_BYTES_PER_SAMPLE),
        most: n.saturating_mul(SPOOL_BYTES_PER_SAMPLE + VALIDITY_BYTES_PER_SAMPLE),
    }
}

/// The reprojection spool of a `size` source (`--to` spools the source whole).
pub fn reproject_need(size: Declared) -> DiskNeed {
    let n = size.samples().saturating_mul(REPROJECT_BYTES_PER_SAMPLE);
    DiskNeed { least: n, most: n }
}

/// The largest record of a tile: its error table and block ranges, the mask and the
/// heights at their uncompressed size plus LZ4's worst-case growth (FORMAT.md "Tile
/// record").
fn max_record_bytes(geometry: &TileGeometry) -> u64 {
    let lz4 = |n: u64| n + n / 255 + 16;
    let t = u64::from(geometry.tile_size());
    let side = t + 1;
    ErrorTable::byte_len(geometry.tile_log2()) as u64 + 4 + lz4(t * t / 8) + lz4(2 * side * side)
}

/// What writing `1/share` of the pyramid of `geometry` can take: nothing for certain
/// (a tile that holds no data is absent, and records compress), at most every tile
/// inside the DEM at its largest record, with its index entry, and the coarser
/// levels twice (each is written to a spill file first, then copied after the
/// finest level: [`super::writer`]).
pub fn output_need(geometry: &TileGeometry, share: u32) -> DiskNeed {
    let record = max_record_bytes(geometry) + tessera_shared::format::INDEX_ENTRY_LEN as u64;
    let t = u64::from(geometry.tile_size());
    let (cells_w, cells_h) = (
        u64::from(geometry.width() - 1),
        u64::from(geometry.height() - 1),
    );
    let finest = geometry.finest().get();
    let mut most = 0u64;
    for level in 0..=finest {
        let span = t << (finest - level);
        let tiles = cells_w.div_ceil(span).max(1) * cells_h.div_ceil(span).max(1);
        let copies = if level == finest { 1 } else { 2 };
        most = most.saturating_add(tiles.saturating_mul(record).saturating_mul(copies));
    }
    DiskNeed {
        least: 0,
        most: most.div_ceil(u64::from(share.max(1))),
    }
}

/// Bytes free to an unprivileged writer in the file system holding `dir`, and that
/// file system's identity (so two folders on one disk are counted together). `None`
/// when it cannot be asked, or the file system reports no size at all (sysfs, procfs
/// and some FUSE or network file systems say 0 blocks): then nothing is checked, and
/// the build still stops cleanly if the disk fills.
fn free_space(dir: &Path) -> Option<(u64, u64)> {
    let st = rustix::fs::statvfs(dir).ok().filter(|st| st.f_blocks > 0)?;
    let dev = std::os::unix::fs::MetadataExt::dev(&std::fs::metadata(dir).ok()?);
    Some((st.f_bavail.saturating_mul(st.f_frsize), dev))
}

/// Where a build writes: the folder of its spools and the folder of its output (the
/// same for a whole build, TMPDIR and the parts folder for a part).
#[derive(Clone, Debug)]
pub struct Folders {
    pub spool: PathBuf,
    pub output: PathBuf,
}

/// Refuses a build whose certain writes do not fit in the free space of their
/// folders; warns when the most it may write does not. `spool` is written to
/// `folders.spool`, `output` to `folders.output` (summed when they share a disk).
/// `why` describes the raster for the message ("declares 1201 × … samples").
pub fn check_disk(
    label: &str,
    why: &str,
    folders: &Folders,
    spool: DiskNeed,
    output: DiskNeed,
) -> anyhow::Result<()> {
    let Some((spool_free, spool_dev)) = free_space(&folders.spool) else {
        return Ok(());
    };
    let output_at = free_space(&folders.output);
    let shared = output_at.is_none_or(|(_, dev)| dev == spool_dev);
    let mut checks = vec![(
        folders.spool.as_path(),
        spool_free,
        if shared { spool + output } else { spool },
    )];
    if let (false, Some((free, _))) = (shared, output_at) {
        checks.push((folders.output.as_path(), free, output));
    }
    for (dir, free, need) in checks {
        if need.least > free {
            bail!(
                "{label}: {why}: spooling them writes {} to {} ({SPOOL_BYTES_PER_SAMPLE} bytes a \
                 sample, before any tile is written), but only {} are free there; free some \
                 space, or build where there is more (the spool goes {})",
                bytes(need.least),
                dir.display(),
                bytes(free),
                if folders.spool == folders.output {
                    "beside the output: -o"
                } else {
                    "in TMPDIR"
                }
            );
        }
        if need.most > free {
            tracing::warn!(
                "{label}: {why}: the build may write up to {} to {} (spool with no-data \
                 flags, and every tile stored uncompressed), and {} are free there; if the \
                 disk fills, the build stops and removes what it wrote",
                bytes(need.most),
                dir.display(),
                bytes(free)
            );
        }
    }
    Ok(())
}

/// A count with an SI prefix: `24.0 G`.
fn count(n: f64) -> String {
    si(n, "")
}

/// Bytes with an SI prefix: `96.1 GB`.
pub fn bytes(n: u64) -> String {
    si(n as f64, "B")
}

fn si(n: f64, unit: &str) -> String {
    const PREFIXES: [(f64, &str); 5] =
        [(1e15, "P"), (1e12, "T"), (1e9, "G"), (1e6, "M"), (1e3, "k")];
    PREFIXES.iter().find(|(scale, _)| n >= *scale).map_or_else(
        || format!("{n} {unit}").trim_end().to_string(),
        |(scale, p)| format!("{:.1} {p}{unit}", n / scale),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_figures_read_as_people_write_them() {
        assert_eq!(count(1201.0 * 20_000_000.0), "24.0 G");
        assert_eq!(bytes(96_080_000_000), "96.1 GB");
        assert_eq!(bytes(512), "512 B");
        assert_eq!(count(7.0), "7");
    }

    #[test]
    fn more_samples_than_the_limit_are_refused_naming_the_input_and_the_size() {
        let size = Declared {
            width: 1201,
            height: 20_000_000,
        };
        let e = check_samples("tiles.vrt", "declares", size, 1 << 30)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("tiles.vrt: declares 1201 × 20000000 samples (24.0 G samples)"),
            "{e}"
        );
        assert!(e.contains("--max-samples 1073741824"), "{e}");
        // The default lets a planet at 1″ through, and this VRT too.
        let planet = Declared {
            width: 1_296_001,
            height: 648_001,
        };
        assert!(check_samples("planet.vrt", "declares", planet, DEFAULT_MAX_SAMPLES).is_ok());
        assert!(check_samples("tiles.vrt", "declares", size, DEFAULT_MAX_SAMPLES).is_ok());
    }

    #[test]
    fn the_spool_is_certain_and_the_records_only_bound_above() {
        let size = Declared {
            width: 1201,
            height: 1201,
        };
        let s = spool_need(size);
        assert_eq!(s.least, 1201 * 1201 * 4);
        assert_eq!(s.most, 1201 * 1201 * 5);
        let g = TileGeometry::new(1201, 1201, 512).unwrap();
        let o = output_need(&g, 1);
        assert_eq!(o.least, 0);
        // 3 × 3 finest tiles, 2 × 2 and 1 above (twice each), each at most its raw
        // heights and table: between 2 and 3 bytes a sample of each level.
        let raw = 2 * 513 * 513;
        assert!(
            o.most > (9 + 2 * 5) * raw && o.most < (9 + 2 * 5) * (raw + raw / 2),
            "{o:?}"
        );
        assert_eq!(output_need(&g, 4).most, o.most.div_ceil(4));
    }

    #[test]
    fn a_spool_larger_than_the_free_space_is_refused_naming_the_folder_and_the_figures() {
        let dir = tempfile::tempdir().unwrap();
        let folders = Folders {
            spool: dir.path().to_path_buf(),
            output: dir.path().to_path_buf(),
        };
        let size = Declared {
            width: 1201,
            height: u32::MAX,
        };
        let e = check_disk(
            "tiles.vrt",
            &format!("declares {}", size.describe()),
            &folders,
            spool_need(size),
            DiskNeed::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("tiles.vrt: declares 1201 × 4294967295 samples (5.2 T samples): spooling them writes 20.6 TB to "),
            "{e}"
        );
        assert!(e.contains(&dir.path().display().to_string()), "{e}");
        assert!(e.contains(" are free there"), "{e}");
        // What fits passes.
        let small = Declared {
            width: 65,
            height: 65,
        };
        check_disk(
            "s.tif",
            "declares",
            &folders,
            spool_need(small),
            DiskNeed::default(),
        )
        .unwrap();
    }
}

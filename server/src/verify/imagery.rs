//! `tessera-server verify NAME.tessimg`: an imagery pyramid's structure (the same
//! checks as a DEM pyramid's: header checksum, level table, indices), every record's
//! checksum and decoding (a JPEG of the metadata's texel size), the index's summary
//! fields (zero but the partial flag, FORMAT.md "Imagery pyramids") and the content
//! hash.

use super::VerifyReport;
use std::path::Path;
use tessera_shared::Pyramid;
use tessera_shared::format::{self, ContentHasher};
use tessera_shared::reader::ReadError;

/// Whether `path` starts with an imagery pyramid's header (`Err`: not a pyramid).
pub fn is_imagery(path: &Path) -> Result<bool, ReadError> {
    use tessera_shared::ByteSource;
    let src = tessera_shared::FileSource::open(path)?;
    let head = src.read_vec(0, format::HEADER_LEN.min(src.size()? as usize))?;
    let header = format::FileHeader::parse(&head).map_err(ReadError::Header)?;
    Ok(header.flags & format::FILE_IMAGERY != 0)
}

/// Checks an imagery pyramid; structural damage is an `Err`, the rest is listed.
pub fn verify(path: &Path) -> Result<VerifyReport, ReadError> {
    let p = Pyramid::open_imagery(tessera_shared::FileSource::open(path)?)?;
    let meta = p.imagery().expect("an imagery pyramid").clone();
    let g = *p.geometry();
    let mut report = VerifyReport::default();
    let mut hash = ContentHasher::imagery_of_version(&meta, p.header().version);
    for level in g.levels() {
        for tile in g.present_tiles(level) {
            let Some(entry) = p.entry(tile).copied() else {
                continue;
            };
            hash.record(entry.checksum);
            report.tiles += 1;
            report.bytes += u64::from(entry.length);
            let bad = |report: &mut VerifyReport, what: String| report.bad.push((tile, what));
            if (entry.min, entry.max, entry.full_res_error) != (0, 0, 0.0)
                || entry.flags & !format::FLAG_PARTIAL != 0
            {
                bad(
                    &mut report,
                    "index holds height summaries or reserved flags".into(),
                );
            }
            match p.read_record(tile) {
                Ok(Some(bytes)) => {
                    if let Err(e) = check_record(&bytes, meta.texels) {
                        bad(&mut report, e.to_string());
                    }
                }
                Ok(None) => {}
                Err(ReadError::RecordChecksum { .. }) => {
                    bad(&mut report, "checksum mismatch".into());
                }
                Err(e) => bad(&mut report, e.to_string()),
            }
        }
    }
    let recomputed = hash.finish();
    if recomputed != meta.content_hash {
        report.problems.push(format!(
            "content_hash {} does not match the file's content ({recomputed})",
            meta.content_hash
        ));
    }
    Ok(report)
}

/// Why an imagery record is bad ([`check_record`]).
#[derive(Debug, thiserror::Error)]
enum BadRecord {
    #[error("does not decode as JPEG: {0}")]
    NotJpeg(image::ImageError),
    #[error("image is {width}×{height}, the metadata says {texels}² texels")]
    Size {
        width: u32,
        height: u32,
        texels: u32,
    },
}

/// A record is a JPEG of `texels × texels` RGB.
fn check_record(bytes: &[u8], texels: u32) -> Result<(), BadRecord> {
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Jpeg)
        .map_err(BadRecord::NotJpeg)?;
    if (img.width(), img.height()) != (texels, texels) {
        return Err(BadRecord::Size {
            width: img.width(),
            height: img.height(),
            texels,
        });
    }
    Ok(())
}

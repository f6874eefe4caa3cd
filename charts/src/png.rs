//! RGBA8 images to PNG files, written to a temporary name and renamed into place,
//! so a failed run never leaves a partial image behind.

use anyhow::Context;
use std::path::Path;

pub fn write_png(path: &Path, rgba: &[u8], width: u32, height: u32) -> anyhow::Result<()> {
    anyhow::ensure!(
        rgba.len() == width as usize * height as usize * 4,
        "{}: {} bytes is not a {width}x{height} RGBA image",
        path.display(),
        rgba.len()
    );
    write_atomically(path, |file| {
        let mut enc = png::Encoder::new(file, width, height);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::Fast);
        let mut w = enc.write_header()?;
        w.write_image_data(rgba)?;
        w.finish()?;
        Ok(())
    })
    .with_context(|| format!("{}: cannot write PNG", path.display()))
}

/// Runs `write` on a buffered file at a temporary name beside `path`, then renames
/// it into place; on any error the temporary file is removed, so `path` is either
/// the whole new file or untouched (any PNG, still or animated).
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path.file_name().context("the path has no file name")?;
    let tmp = dir.join(format!(
        ".{}.partial-{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| -> anyhow::Result<()> {
        let mut file = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        write(&mut file)?;
        file.into_inner()
            .map_err(std::io::IntoInnerError::into_error)?;
        std::fs::rename(&tmp, path)?;
        Ok(())
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Reads an 8-bit RGBA or RGB PNG as RGBA8 (for golden images).
pub fn read_png(path: &Path) -> anyhow::Result<(Vec<u8>, u32, u32)> {
    let file =
        std::fs::File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
    let mut dec = png::Decoder::new(std::io::BufReader::new(file));
    dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = dec
        .read_info()
        .with_context(|| format!("{}: not a PNG", path.display()))?;
    let mut buf = vec![0; reader.output_buffer_size().context("PNG too large")?];
    let info = reader
        .next_frame(&mut buf)
        .with_context(|| format!("{}: corrupt PNG", path.display()))?;
    buf.truncate(info.buffer_size());
    let rgba = match info.color_type {
        png::ColorType::Rgba => buf,
        png::ColorType::Rgb => buf
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect(),
        other => anyhow::bail!("{}: {other:?} PNG, expected RGB or RGBA", path.display()),
    };
    Ok((rgba, info.width, info.height))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_leaves_nothing_partial() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.png");
        let img: Vec<u8> = (0..3 * 2 * 4).map(|i| (i * 11) as u8).collect();
        write_png(&p, &img, 3, 2).unwrap();
        assert_eq!(read_png(&p).unwrap(), (img.clone(), 3, 2));
        assert!(write_png(&p, &img, 4, 2).is_err());
        assert!(write_png(&dir.path().join("missing/b.png"), &img, 3, 2).is_err());
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["a.png"]);
    }
}

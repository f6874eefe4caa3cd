//! The flight as an animation: an animated PNG (APNG) of its frames, downscaled
//! and reduced to one 256-colour palette so that a few seconds of flight stay a
//! few megabytes, and any browser or image viewer plays it.
//!
//! - Frames are area-averaged down to at most `max_width` pixels wide (the
//!   contact sheet's resampler), and every `step`-th frame is kept so that at most
//!   `max_frames` remain; the frame delay keeps the flight's real pace.
//! - The palette is a median cut (Heckbert, "Color image quantization for frame
//!   buffer display", 1982) of the colours of all kept frames, each reduced to 5
//!   bits a channel first, so one palette serves the whole animation (APNG frames
//!   share the PLTE chunk). Pixels take the nearest palette colour, without
//!   dithering: dither noise changes every frame and compresses badly.

use super::contact_sheet::area_resample;
use crate::errors::PngError;
use std::path::{Path, PathBuf};
use tessera_charts::png::read_png;

/// What the animation is made of.
#[derive(Clone, Copy, Debug)]
pub struct AnimationOptions {
    /// Widest frame, in pixels (frames narrower than this keep their size).
    pub max_width: u32,
    /// Most frames kept (every `step`-th frame, `step` the smallest that fits).
    pub max_frames: usize,
    /// Frames per second of the flight the frames come from.
    pub fps: u32,
}

impl Default for AnimationOptions {
    fn default() -> Self {
        Self {
            max_width: 480,
            max_frames: 120,
            fps: 30,
        }
    }
}

/// What [`write_animation`] wrote.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Animation {
    pub frames: u32,
    pub width: u32,
    pub height: u32,
    /// Every `step`-th input frame was kept.
    pub step: usize,
    pub bytes: u64,
}

/// Colours reduced to 5 bits a channel, packed `r << 10 | g << 5 | b`.
fn key(p: &[u8]) -> usize {
    (usize::from(p[0] >> 3) << 10) | (usize::from(p[1] >> 3) << 5) | usize::from(p[2] >> 3)
}

/// The centre of a 5-bit key's cell, as 8-bit RGB.
fn unkey(k: usize) -> [u8; 3] {
    [10, 5, 0].map(|s| ((((k >> s) & 31) << 3) | 4) as u8)
}

/// Median cut of a histogram of keys into at most `colours` boxes; each box's
/// colour is the count-weighted mean of the colours in it.
fn median_cut(histogram: &[u32], colours: usize) -> Vec<[u8; 3]> {
    let mut boxes: Vec<Vec<usize>> =
        vec![(0..histogram.len()).filter(|&k| histogram[k] > 0).collect()];
    let channel = |k: usize, c: usize| unkey(k)[c];
    loop {
        if boxes.len() >= colours {
            break;
        }
        // Split the box with the widest channel range (weighted by its pixels, so
        // common colours get more palette entries), at its median pixel.
        let widest = boxes
            .iter()
            .enumerate()
            .filter(|(_, b)| b.len() > 1)
            .map(|(i, b)| {
                let (c, range) = (0..3)
                    .map(|c| {
                        let lo = b.iter().map(|&k| channel(k, c)).min().unwrap_or(0);
                        let hi = b.iter().map(|&k| channel(k, c)).max().unwrap_or(0);
                        (c, hi - lo)
                    })
                    .max_by_key(|&(_, r)| r)
                    .unwrap_or((0, 0));
                let pixels: u64 = b.iter().map(|&k| u64::from(histogram[k])).sum();
                (
                    i,
                    c,
                    u64::from(range) * pixels.max(1).ilog2() as u64 + u64::from(range),
                )
            })
            .max_by_key(|&(_, _, score)| score);
        let Some((i, c, _)) = widest else { break };
        let mut b = boxes.swap_remove(i);
        b.sort_by_key(|&k| channel(k, c));
        let total: u64 = b.iter().map(|&k| u64::from(histogram[k])).sum();
        let mut seen = 0u64;
        let cut = b
            .iter()
            .position(|&k| {
                seen += u64::from(histogram[k]);
                2 * seen >= total
            })
            .unwrap_or(0)
            .clamp(0, b.len() - 2)
            + 1;
        let upper = b.split_off(cut);
        boxes.push(b);
        boxes.push(upper);
    }
    boxes
        .iter()
        .map(|b| {
            let mut sum = [0u64; 3];
            let mut n = 0u64;
            for &k in b {
                let w = u64::from(histogram[k]);
                for (s, v) in sum.iter_mut().zip(unkey(k)) {
                    *s += w * u64::from(v);
                }
                n += w;
            }
            sum.map(|s| ((s + n / 2) / n.max(1)) as u8)
        })
        .collect()
}

/// Index of the palette colour nearest (squared RGB distance) to `c`.
fn nearest(palette: &[[u8; 3]], c: [u8; 3]) -> u8 {
    let d = |p: &[u8; 3]| -> u32 {
        (0..3)
            .map(|i| (i32::from(p[i]) - i32::from(c[i])).pow(2) as u32)
            .sum()
    };
    (0..palette.len())
        .min_by_key(|&i| d(&palette[i]))
        .unwrap_or(0) as u8
}

/// Why an animation could not be made.
#[derive(Debug, thiserror::Error)]
pub enum AnimationError {
    #[error("{}: cannot list frames", dir.display())]
    List {
        dir: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: no frame PNGs", dir.display())]
    NoFrames { dir: PathBuf },
    #[error("no frames to animate")]
    Nothing,
    #[error("Condition failed: `opts.fps > 0 && opts.max_width > 0 && opts.max_frames > 0`")]
    Options,
    #[error(transparent)]
    Png(#[from] PngError),
    #[error("{}: {}×{}, but the first frame is {}×{}", path.display(), size.0, size.1, first.0, first.1)]
    Size {
        path: PathBuf,
        size: (u32, u32),
        first: (u32, u32),
    },
    #[error("{}: cannot write the animation", out.display())]
    Write {
        out: PathBuf,
        #[source]
        source: PngError,
    },
}

/// The frame PNGs of a directory (`frame_NNNNN.png` from `tessera fly --out`), in
/// name order.
pub fn frame_files(dir: &Path) -> Result<Vec<PathBuf>, AnimationError> {
    let mut names: Vec<_> = std::fs::read_dir(dir)
        .map_err(|source| AnimationError::List {
            dir: dir.into(),
            source,
        })?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    names.sort();
    if names.is_empty() {
        return Err(AnimationError::NoFrames { dir: dir.into() });
    }
    Ok(names)
}

/// The size frames of `width × height` are downscaled to: at most `max_width`
/// wide, the aspect ratio kept.
pub fn animation_size(width: u32, height: u32, max_width: u32) -> (u32, u32) {
    if width <= max_width {
        return (width, height);
    }
    let h = (u64::from(height) * u64::from(max_width) + u64::from(width) / 2) / u64::from(width);
    (max_width, (h as u32).max(1))
}

/// Writes `frames` (PNG files, all the same size) as an animated PNG at `out`,
/// looping forever.
pub fn write_animation(
    frames: &[PathBuf],
    out: &Path,
    opts: AnimationOptions,
) -> Result<Animation, AnimationError> {
    if frames.is_empty() {
        return Err(AnimationError::Nothing);
    }
    if !(opts.fps > 0 && opts.max_width > 0 && opts.max_frames > 0) {
        return Err(AnimationError::Options);
    }
    let step = frames.len().div_ceil(opts.max_frames);
    let mut size = None;
    let mut small = Vec::new();
    for path in frames.iter().step_by(step) {
        let (rgba, w, h) = read_png(path).map_err(PngError::from)?;
        let first = *size.get_or_insert((w, h));
        if (w, h) != first {
            return Err(AnimationError::Size {
                path: path.clone(),
                size: (w, h),
                first,
            });
        }
        let (dw, dh) = animation_size(w, h, opts.max_width);
        small.push(area_resample(&rgba, w, h, dw, dh));
    }
    let (w, h) = size.unwrap_or_default();
    let (dw, dh) = animation_size(w, h, opts.max_width);
    let mut histogram = vec![0u32; 1 << 15];
    for f in &small {
        for p in f.chunks_exact(4) {
            histogram[key(p)] = histogram[key(p)].saturating_add(1);
        }
    }
    let palette = median_cut(&histogram, 256);
    // Every 5-bit colour seen, mapped once to its nearest palette entry.
    let lookup: Vec<u8> = histogram
        .iter()
        .enumerate()
        .map(|(k, &n)| {
            if n > 0 {
                nearest(&palette, unkey(k))
            } else {
                0
            }
        })
        .collect();
    tessera_charts::png::write_atomically(out, |file| {
        let mut encoder = png::Encoder::new(file, dw, dh);
        encoder.set_color(png::ColorType::Indexed);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_palette(palette.iter().flatten().copied().collect::<Vec<u8>>());
        encoder.set_compression(png::Compression::High);
        encoder.set_animated(small.len() as u32, 0)?;
        let delay = u16::try_from(step).unwrap_or(u16::MAX);
        let fps = u16::try_from(opts.fps).unwrap_or(u16::MAX);
        encoder.set_frame_delay(delay, fps)?;
        let mut writer = encoder.write_header()?;
        for f in &small {
            let indices: Vec<u8> = f.chunks_exact(4).map(|p| lookup[key(p)]).collect();
            writer.write_image_data(&indices)?;
        }
        writer.finish()?;
        Ok(())
    })
    .map_err(|e| AnimationError::Write {
        out: out.into(),
        source: e.into(),
    })?;
    let bytes = std::fs::metadata(out).map_or(0, |m| m.len());
    Ok(Animation {
        frames: small.len() as u32,
        width: dw,
        height: dh,
        step,
        bytes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_charts::png::write_png;

    /// A frame unlike its neighbours: a diagonal gradient that shifts with `f`,
    /// a sky band, and a bright square whose place is the frame number.
    fn frame(f: u32, w: u32, h: u32) -> Vec<u8> {
        let mut v = Vec::with_capacity((w * h * 4) as usize);
        for y in 0..h {
            for x in 0..w {
                let px = if y < h / 4 {
                    [90, 140, 220]
                } else if (x / 16) == f % (w / 16) && y / 16 == 3 {
                    [250, 250, 250]
                } else {
                    [
                        ((x * 255 / w + f * 23) % 200) as u8 + 30,
                        ((y * 255 / h) % 200) as u8 + 20,
                        ((x + y + f * 17) % 90) as u8 + 40,
                    ]
                };
                v.extend_from_slice(&[px[0], px[1], px[2], 255]);
            }
        }
        v
    }

    /// A decoded frame: width, height, RGB.
    type DecodedFrame = (u32, u32, Vec<u8>);

    /// Decodes an APNG: its frame count from `acTL`, then every frame as RGB.
    fn decode(path: &Path) -> (u32, (u16, u16), Vec<DecodedFrame>) {
        let mut decoder =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
        decoder.set_transformations(png::Transformations::EXPAND);
        let mut reader = decoder.read_info().unwrap();
        let actl = reader.info().animation_control.expect("an animated PNG");
        let fctl = reader.info().frame_control.expect("frame control");
        let delay = (fctl.delay_num, fctl.delay_den);
        let mut frames = Vec::new();
        for _ in 0..actl.num_frames {
            let mut buf = vec![0; reader.output_buffer_size().unwrap()];
            let info = reader.next_frame(&mut buf).unwrap();
            assert_eq!(info.color_type, png::ColorType::Rgb);
            buf.truncate(info.buffer_size());
            frames.push((info.width, info.height, buf));
        }
        assert!(reader.next_frame(&mut [0; 16]).is_err(), "no more frames");
        (actl.num_frames, delay, frames)
    }

    #[test]
    fn writes_an_apng_of_downscaled_frames_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let frames_dir = dir.path().join("frames");
        std::fs::create_dir(&frames_dir).unwrap();
        let (w, h) = (320, 180);
        for f in 0..25 {
            write_png(
                &frames_dir.join(format!("frame_{f:05}.png")),
                &frame(f, w, h),
                w,
                h,
            )
            .unwrap();
        }
        let files = frame_files(&frames_dir).unwrap();
        let out = dir.path().join("flight.png");
        let opts = AnimationOptions {
            max_width: 160,
            max_frames: 10,
            fps: 30,
        };
        let a = write_animation(&files, &out, opts).unwrap();
        // 25 frames, at most 10: every third (0, 3, …, 24), each 1/10 s.
        assert_eq!((a.frames, a.width, a.height, a.step), (9, 160, 90, 3));
        let (n, delay, decoded) = decode(&out);
        assert_eq!(n, 9);
        assert_eq!(delay, (3, 30));
        assert_eq!(decoded.len(), 9);
        for (i, (fw, fh, rgb)) in decoded.iter().enumerate() {
            assert_eq!((*fw, *fh), (160, 90), "frame {i}");
            // The downscaled input frame it should be, and the ones it should not.
            let diff = |f: u32| {
                let want = area_resample(&frame(f, w, h), w, h, 160, 90);
                let sum: u64 = want
                    .chunks_exact(4)
                    .zip(rgb.chunks_exact(3))
                    .map(|(p, q)| (0..3).map(|c| u64::from(p[c].abs_diff(q[c]))).sum::<u64>())
                    .sum();
                sum as f64 / (160.0 * 90.0 * 3.0)
            };
            let own = diff(3 * i as u32);
            // A 256-colour palette for these colourful frames costs ~5 levels a channel.
            assert!(own < 6.0, "frame {i}: mean abs diff {own} from its input");
            for other in [3 * i as u32 + 1, 3 * i as u32 + 30] {
                assert!(
                    diff(other) > 2.0 * own,
                    "frame {i} looks like input {other}"
                );
            }
        }
        // Frames of another size are refused, naming the file.
        write_png(
            &frames_dir.join("frame_00025.png"),
            &frame(0, 64, 36),
            64,
            36,
        )
        .unwrap();
        let files = frame_files(&frames_dir).unwrap();
        let e = write_animation(&files, &out, AnimationOptions::default()).unwrap_err();
        assert!(format!("{e:#}").contains("frame_00025.png: 64×36"), "{e:#}");
        assert!(frame_files(dir.path().join("none").as_path()).is_err());
    }

    #[test]
    fn median_cut_gives_each_colour_its_own_entry_when_there_is_room() {
        let mut histogram = vec![0u32; 1 << 15];
        let colours = [[0u8, 0, 0], [248, 0, 0], [0, 248, 0], [128, 128, 248]];
        for (i, c) in colours.iter().enumerate() {
            histogram[key(&[c[0], c[1], c[2], 255])] = 10 * (i as u32 + 1);
        }
        let mut palette = median_cut(&histogram, 256);
        palette.sort_unstable();
        let mut want: Vec<[u8; 3]> = colours.iter().map(|c| c.map(|v| v | 4)).collect();
        want.sort_unstable();
        assert_eq!(palette, want);
        // Fewer entries than colours: every colour still maps near itself.
        let two = median_cut(&histogram, 2);
        assert_eq!(two.len(), 2);
    }
}

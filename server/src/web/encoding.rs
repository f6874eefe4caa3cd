//! How heights become pixels of web tiles: Mapzen Terrarium and Mapbox Terrain-RGB
//! colours (exact formulas below), what pixels without data look like ([`NoData`]),
//! and the image formats (PNG, lossless WebP) they travel in.

/// A query value that names no encoding or no-data mode this module knows (a 400
/// for the server, which bounds the quoted value in its answer).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown {param} {value:?}: allowed values are {allowed}")]
pub struct UnknownValue {
    /// The query parameter (`encoding`, `nodata`).
    pub param: &'static str,
    /// The value as the request gave it.
    pub value: String,
    /// What the parameter accepts, for the message.
    pub allowed: &'static str,
}

/// How heights become the colours of a PNG tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Encoding {
    /// Mapzen Terrarium: `h = R·256 + G + B/256 − 32768` (1/256 m steps).
    Terrarium,
    /// Mapbox Terrain-RGB: `h = −10000 + (R·65536 + G·256 + B)·0.1` (0.1 m steps).
    Mapbox,
}

impl Encoding {
    /// What `?encoding=` accepts.
    pub const ALLOWED: &str = "terrarium, mapbox";

    /// The encoding a query asks for (Terrarium when it names none).
    pub fn from_query(value: Option<&str>) -> Result<Self, UnknownValue> {
        match value {
            None | Some("terrarium") => Ok(Self::Terrarium),
            Some("mapbox") => Ok(Self::Mapbox),
            Some(other) => Err(UnknownValue {
                param: "encoding",
                value: other.to_string(),
                allowed: Self::ALLOWED,
            }),
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            Self::Terrarium => "terrarium",
            Self::Mapbox => "mapbox",
        }
    }

    /// The colour of a height in metres.
    pub fn rgb(self, h: f64) -> [u8; 3] {
        match self {
            Self::Terrarium => terrarium(h),
            Self::Mapbox => mapbox(h),
        }
    }
}

/// Terrarium colour of a height in metres: `v = h + 32768` clamped to
/// `[0, 65536 − 1/256]`, `R = ⌊v / 256⌋`, `G = ⌊v⌋ mod 256`, `B = ⌊frac(v)·256⌋`.
/// Decoding gives `h` to within 1/256 m (rounded down) inside the range.
pub fn terrarium(h: f64) -> [u8; 3] {
    let v = (h + 32768.0).clamp(0.0, 65536.0 - 1.0 / 256.0);
    let v = if v.is_nan() { 0.0 } else { v };
    // Truncation is floor for v ≥ 0 (and needs no libm call, per pixel).
    let whole = v as u32;
    [
        (whole >> 8) as u8,
        whole as u8,
        ((v - f64::from(whole)) * 256.0) as u8,
    ]
}

/// Terrain-RGB colour of a height in metres: `v = round((h + 10000) / 0.1)` clamped
/// to `0..=2^24 − 1`, `R = v >> 16`, `G = (v >> 8) & 255`, `B = v & 255`.
/// Decoding gives `h` to within 0.05 m inside the range.
pub fn mapbox(h: f64) -> [u8; 3] {
    // Round half away from zero, as f64::round, for the values that matter (≥ 0):
    // the cast truncates, and saturates below 0 (and NaN casts to 0).
    let v = (((h + 10000.0) / 0.1 + 0.5) as u32).min(16_777_215);
    [(v >> 16) as u8, (v >> 8) as u8, v as u8]
}

/// What the pixels without data look like (`?nodata=`): they always carry a
/// plausible height in their colour (resample.rs, step 6); alpha marks them only
/// when asked.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum NoData {
    /// Opaque, like the data: what web maps need. MapLibre, deck.gl and OpenLayers
    /// read elevation tiles through a premultiplied 2D canvas, where a transparent
    /// pixel's colour is lost (it would decode as −32768 m).
    #[default]
    Opaque,
    /// Alpha 0, colour still the fill height: for clients that read PNG pixels
    /// exactly and honour alpha (GDAL's WMTS and OGC API drivers). Lossless WebP may
    /// drop the colour of fully transparent pixels.
    Transparent,
}

impl NoData {
    /// What `?nodata=` accepts.
    pub const ALLOWED: &str = "opaque, transparent";

    /// The mode a query asks for (opaque when it names none).
    pub fn from_query(value: Option<&str>) -> Result<Self, UnknownValue> {
        match value {
            None | Some("opaque") => Ok(Self::Opaque),
            Some("transparent") => Ok(Self::Transparent),
            Some(other) => Err(UnknownValue {
                param: "nodata",
                value: other.to_string(),
                allowed: Self::ALLOWED,
            }),
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            Self::Opaque => "opaque",
            Self::Transparent => "transparent",
        }
    }
}

/// The colour of every height, RGBA. A pixel with data is opaque; one without
/// (`data[k]` false) is opaque or transparent as `nodata` says, and its colour is
/// its height when it has one (a void's fill) or `fill` (beyond the data).
pub fn rgba(
    heights: &[f64],
    data: &[bool],
    encoding: Encoding,
    nodata: NoData,
    fill: f64,
) -> Vec<u8> {
    debug_assert_eq!(heights.len(), data.len());
    let fill_rgb = encoding.rgb(fill);
    let hidden = match nodata {
        NoData::Opaque => 255,
        NoData::Transparent => 0,
    };
    let mut out = Vec::with_capacity(heights.len() * 4);
    for (&h, &d) in heights.iter().zip(data) {
        let [r, g, b] = if h.is_nan() {
            fill_rgb
        } else {
            encoding.rgb(h)
        };
        out.extend_from_slice(&[r, g, b, if d { 255 } else { hidden }]);
    }
    out
}

/// The image container of a web tile, from its URL's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ImageFormat {
    Png,
    /// Lossless WebP (VP8L): the same pixels as the PNG, usually smaller.
    Webp,
}

/// What a made tile is: an image, or a Mapbox Vector Tile (contours,
/// web/contour/).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TileFormat {
    Image(ImageFormat),
    Mvt,
}

impl TileFormat {
    pub const fn mime(self) -> &'static str {
        match self {
            Self::Image(f) => f.mime(),
            Self::Mvt => "application/vnd.mapbox-vector-tile",
        }
    }
}

impl ImageFormat {
    /// `"12.png"` → (`"12"`, PNG); `None` for another extension.
    pub fn split(last_segment: &str) -> Option<(&str, Self)> {
        if let Some(y) = last_segment.strip_suffix(".png") {
            Some((y, Self::Png))
        } else {
            last_segment.strip_suffix(".webp").map(|y| (y, Self::Webp))
        }
    }

    pub const fn extension(self) -> &'static str {
        match self {
            Self::Png => "png",
            Self::Webp => "webp",
        }
    }

    pub const fn mime(self) -> &'static str {
        match self {
            Self::Png => "image/png",
            Self::Webp => "image/webp",
        }
    }

    /// `side × side` RGBA pixels in this format. PNG uses the fast deflate level:
    /// height colours compress little whatever the level, and tiles are made per
    /// request.
    /// A `side × side` image of grey and alpha pairs (hillshade): half the bytes
    /// of RGBA before compression.
    pub fn encode_grey_alpha(self, la: &[u8], side: u32) -> Result<Vec<u8>, ImageEncodeError> {
        let mut out = Vec::new();
        match self {
            Self::Png => {
                let mut enc = png::Encoder::new(&mut out, side, side);
                enc.set_color(png::ColorType::GrayscaleAlpha);
                enc.set_depth(png::BitDepth::Eight);
                enc.set_compression(png::Compression::Fast);
                let mut w = enc.write_header()?;
                w.write_image_data(la)?;
                w.finish()?;
            }
            Self::Webp => {
                image_webp::WebPEncoder::new(&mut out).encode(
                    la,
                    side,
                    side,
                    image_webp::ColorType::La8,
                )?;
            }
        }
        Ok(out)
    }

    pub fn encode(self, rgba: &[u8], side: u32) -> Result<Vec<u8>, ImageEncodeError> {
        let mut out = Vec::new();
        match self {
            Self::Png => {
                let mut enc = png::Encoder::new(&mut out, side, side);
                enc.set_color(png::ColorType::Rgba);
                enc.set_depth(png::BitDepth::Eight);
                enc.set_compression(png::Compression::Fast);
                let mut w = enc.write_header()?;
                w.write_image_data(rgba)?;
                w.finish()?;
            }
            Self::Webp => {
                image_webp::WebPEncoder::new(&mut out).encode(
                    rgba,
                    side,
                    side,
                    image_webp::ColorType::Rgba8,
                )?;
            }
        }
        Ok(out)
    }
}

/// Why a tile's pixels could not be encoded ([`ImageFormat::encode`]): the encoder's
/// own error.
#[derive(Debug, thiserror::Error)]
pub enum ImageEncodeError {
    #[error(transparent)]
    Png(#[from] png::EncodingError),
    #[error(transparent)]
    Webp(#[from] image_webp::EncodingError),
}

#[cfg(test)]
mod tests {
    use super::*;

    fn terrarium_height([r, g, b]: [u8; 3]) -> f64 {
        f64::from(r) * 256.0 + f64::from(g) + f64::from(b) / 256.0 - 32768.0
    }

    fn mapbox_height([r, g, b]: [u8; 3]) -> f64 {
        -10000.0 + f64::from(u32::from(r) * 65536 + u32::from(g) * 256 + u32::from(b)) * 0.1
    }

    /// Heights from −10000 to 9000 m in irregular steps, with fractions of all kinds.
    fn heights() -> impl Iterator<Item = f64> {
        (0..=190_000).map(|i| -10000.0 + f64::from(i) * 0.100_003_7)
    }

    #[test]
    fn terrarium_round_trips_within_a_256th() {
        for h in heights().chain([0.0, -0.001, 0.001, -1.0 / 256.0, 8848.86, -10000.0]) {
            let back = terrarium_height(terrarium(h));
            assert!(
                back <= h && h - back < 1.0 / 256.0,
                "{h} -> {back} ({:?})",
                terrarium(h)
            );
        }
        assert_eq!(terrarium(0.0), [128, 0, 0]);
        assert_eq!(terrarium(-1.0), [127, 255, 0]);
        assert_eq!(terrarium(1.5), [128, 1, 128]);
    }

    #[test]
    fn mapbox_round_trips_within_5_cm() {
        for h in heights().chain([0.0, -0.04, 0.05, 8848.86, -10000.0]) {
            let back = mapbox_height(mapbox(h));
            assert!((back - h).abs() <= 0.05 + 1e-9, "{h} -> {back}");
        }
        assert_eq!(mapbox(-10000.0), [0, 0, 0]);
        assert_eq!(mapbox(0.0), [1, 134, 160]); // 100000 = 0x0186A0
    }

    #[test]
    fn out_of_range_heights_clamp() {
        assert_eq!(terrarium(-40000.0), [0, 0, 0]);
        assert_eq!(terrarium(-32768.0), [0, 0, 0]);
        assert_eq!(terrarium(40000.0), [255, 255, 255]);
        assert_eq!(terrarium(f64::NAN), [0, 0, 0]);
        assert_eq!(mapbox(-10000.1), [0, 0, 0]);
        assert_eq!(mapbox(-1e9), [0, 0, 0]);
        assert_eq!(mapbox(1e9), [255, 255, 255]);
        assert_eq!(mapbox(f64::NAN), [0, 0, 0]);
        // The top of Terrain-RGB's range is −10000 + (2^24 − 1)·0.1 m.
        assert_eq!(mapbox(1_667_721.5), [255, 255, 255]);
    }

    #[test]
    fn encoding_from_query() {
        assert_eq!(Encoding::from_query(None).unwrap(), Encoding::Terrarium);
        assert_eq!(
            Encoding::from_query(Some("terrarium")).unwrap(),
            Encoding::Terrarium
        );
        assert_eq!(
            Encoding::from_query(Some("mapbox")).unwrap(),
            Encoding::Mapbox
        );
        let e = Encoding::from_query(Some("webp")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown encoding \"webp\": allowed values are terrarium, mapbox"
        );
    }

    /// 16 × 16 heights, every 7th pixel without data: a third of those a void
    /// with its fill height, the rest nothing (NaN).
    fn sampled(side: u32) -> (Vec<f64>, Vec<bool>) {
        (0..side * side)
            .map(|k| match (k % 7, k % 3) {
                (0, 0) => (f64::from(k) * 0.5, false),
                (0, _) => (f64::NAN, false),
                _ => (f64::from(k) * 3.25 - 40.0, true),
            })
            .unzip()
    }

    #[test]
    fn no_data_carries_a_plausible_height_and_alpha_only_when_asked() {
        let side = 16u32;
        let (heights, data) = sampled(side);
        let fill = 187.0;
        for nodata in [NoData::Opaque, NoData::Transparent] {
            let px = rgba(&heights, &data, Encoding::Terrarium, nodata, fill);
            for (k, h) in heights.iter().enumerate() {
                let p = &px[k * 4..k * 4 + 4];
                let want = if h.is_nan() { fill } else { *h };
                assert_eq!(
                    terrarium_height([p[0], p[1], p[2]]),
                    want,
                    "pixel {k}: exact in 1/256 m steps, never -32768"
                );
                let alpha = if data[k] || nodata == NoData::Opaque {
                    255
                } else {
                    0
                };
                assert_eq!(p[3], alpha, "pixel {k} {nodata:?}");
            }
        }
        let px = rgba(&heights, &data, Encoding::Mapbox, NoData::Opaque, fill);
        assert_eq!(
            [px[28], px[29], px[30]],
            mapbox(fill),
            "pixel 7 has no height: the fill"
        );
    }

    #[test]
    fn nodata_from_query() {
        assert_eq!(NoData::from_query(None).unwrap(), NoData::Opaque);
        assert_eq!(NoData::from_query(Some("opaque")).unwrap(), NoData::Opaque);
        assert_eq!(
            NoData::from_query(Some("transparent")).unwrap(),
            NoData::Transparent
        );
        let e = NoData::from_query(Some("alpha")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown nodata \"alpha\": allowed values are opaque, transparent"
        );
    }

    #[test]
    fn both_formats_decode_to_the_same_pixels() {
        let side = 16u32;
        let (heights, data) = sampled(side);
        let px = rgba(
            &heights,
            &data,
            Encoding::Terrarium,
            NoData::Transparent,
            0.0,
        );
        let png = ImageFormat::Png.encode(&px, side).unwrap();
        let mut reader = png::Decoder::new(std::io::Cursor::new(png))
            .read_info()
            .unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(info.color_type, png::ColorType::Rgba);
        assert_eq!(&buf[..info.buffer_size()], &px[..]);
        let webp = ImageFormat::Webp.encode(&px, side).unwrap();
        let mut dec = image_webp::WebPDecoder::new(std::io::Cursor::new(webp)).unwrap();
        assert_eq!(dec.dimensions(), (side, side));
        let mut back = vec![0; dec.output_buffer_size().unwrap()];
        dec.read_image(&mut back).unwrap();
        // Lossless WebP may change the colour of fully transparent pixels only.
        for (k, (a, b)) in px.chunks(4).zip(back.chunks(4)).enumerate() {
            if a[3] == 255 {
                assert_eq!(a, b, "pixel {k}");
            } else {
                assert_eq!(b[3], 0, "pixel {k}");
            }
        }
    }

    #[test]
    fn extensions() {
        assert_eq!(ImageFormat::split("12.png"), Some(("12", ImageFormat::Png)));
        assert_eq!(ImageFormat::split("3.webp"), Some(("3", ImageFormat::Webp)));
        assert_eq!(ImageFormat::split("3.jpg"), None);
    }
}

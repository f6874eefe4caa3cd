//! GeoTIFF georeferencing: the GeoKey directory, the tie points, pixel scale and
//! transformation tags, normalised to GDAL's convention (see the parent module).

use super::user_crs::{self, KeyValues};
use super::{Reader, ascii_tag};
use tessera_shared::{GeoRef, RasterType};
use tiff::decoder::Decoder;
use tiff::tags::Tag;

// GeoKey ids (GeoTIFF 1.0 §6.2).
const GT_MODEL_TYPE: u16 = 1024;
const GT_RASTER_TYPE: u16 = 1025;
const GT_CITATION: u16 = 1026;
const GEOGRAPHIC_TYPE: u16 = 2048;
const GEOG_CITATION: u16 = 2049;
const PROJECTED_CS_TYPE: u16 = 3072;
const PCS_CITATION: u16 = 3073;
/// The `TIFFTagLocation` of key values stored in GeoAsciiParamsTag.
const GEO_ASCII_PARAMS: u16 = 34737;
/// The `TIFFTagLocation` of key values stored in GeoDoubleParamsTag.
const GEO_DOUBLE_PARAMS: u16 = 34736;
/// GeoKey value meaning "user-defined" (no EPSG code).
const USER_DEFINED: u16 = 32767;

/// The GeoKeys the reader uses.
#[derive(Debug, Default)]
struct GeoKeys {
    model_type: Option<u16>,
    raster_type: Option<u16>,
    geographic_type: Option<u16>,
    projected_type: Option<u16>,
    gt_citation: Option<String>,
    geog_citation: Option<String>,
    pcs_citation: Option<String>,
    /// Every key, for a user-defined CRS ([`user_crs`]).
    values: KeyValues,
}

impl GeoKeys {
    /// Parses GeoKeyDirectoryTag: a header `[version, revision, minor, nkeys]`, then
    /// `nkeys` entries `[KeyID, TIFFTagLocation, Count, Value]`. Location 0 means the
    /// value is the short itself; location 34737 names `Count` characters of the ASCII
    /// parameters starting at `Value`.
    fn parse(dir: &[u16], ascii: Option<&str>, doubles: Option<&[f64]>) -> Self {
        let mut keys = Self::default();
        let Some(&[_, _, _, nkeys]) = dir.get(..4) else {
            tracing::warn!("ignoring a GeoKeyDirectoryTag of only {} values", dir.len());
            return keys;
        };
        for (i, entry) in dir[4..].chunks(4).take(usize::from(nkeys)).enumerate() {
            let &[id, location, count, value] = entry else {
                tracing::warn!("GeoKeyDirectoryTag is cut short after {i} of {nkeys} keys");
                break;
            };
            let text = || {
                let start = usize::from(value);
                let end = start + usize::from(count);
                ascii?.get(start..end.min(ascii?.len())).map(str::to_owned)
            };
            match location {
                0 => {
                    keys.values.shorts.insert(id, value);
                }
                GEO_DOUBLE_PARAMS => {
                    let start = usize::from(value);
                    if let Some(d) = doubles.and_then(|d| d.get(start..start + usize::from(count)))
                    {
                        keys.values.doubles.insert(id, d.to_vec());
                    }
                }
                GEO_ASCII_PARAMS => {
                    if let Some(t) = text() {
                        keys.values.ascii.insert(id, t);
                    }
                }
                _ => {}
            }
            match (id, location) {
                (GT_MODEL_TYPE, 0) => keys.model_type = Some(value),
                (GT_RASTER_TYPE, 0) => keys.raster_type = Some(value),
                (GEOGRAPHIC_TYPE, 0) => keys.geographic_type = Some(value),
                (PROJECTED_CS_TYPE, 0) => keys.projected_type = Some(value),
                (GT_CITATION, GEO_ASCII_PARAMS) => keys.gt_citation = text(),
                (GEOG_CITATION, GEO_ASCII_PARAMS) => keys.geog_citation = text(),
                (PCS_CITATION, GEO_ASCII_PARAMS) => keys.pcs_citation = text(),
                _ => {}
            }
        }
        keys
    }

    /// The EPSG code of the horizontal CRS: the projected CRS for projected models, the
    /// geographic CRS for geographic ones. 0 (undefined) and 32767 (user-defined) give none.
    fn epsg(&self) -> Option<u32> {
        let code = |c: Option<u16>| c.filter(|&c| c != 0 && c != USER_DEFINED).map(u32::from);
        match self.model_type {
            Some(1) => code(self.projected_type),
            Some(2) => code(self.geographic_type),
            None => code(self.projected_type).or_else(|| code(self.geographic_type)),
            Some(_) => None,
        }
    }

    /// A readable CRS name from the citation keys, when one is given.
    fn crs_name(&self) -> Option<String> {
        let candidates = if self.model_type == Some(2) {
            [&self.geog_citation, &self.gt_citation, &self.pcs_citation]
        } else {
            [&self.gt_citation, &self.pcs_citation, &self.geog_citation]
        };
        candidates
            .into_iter()
            .find_map(|c| clean_citation(c.as_deref()?))
    }

    fn raster_type(&self) -> RasterType {
        match self.raster_type {
            Some(2) => RasterType::PixelIsPoint,
            Some(1) | None => RasterType::PixelIsArea,
            Some(other) => {
                tracing::warn!("unknown GTRasterTypeGeoKey {other}; assuming PixelIsArea");
                RasterType::PixelIsArea
            }
        }
    }
}

/// Tidies a citation: drops the `|` terminators, ESRI's `PCS Name = ` prefixes, long
/// WKT strings and placeholders such as "unknown".
fn clean_citation(raw: &str) -> Option<String> {
    let first = raw
        .split('|')
        .next()
        .unwrap_or("")
        .trim_matches(|c: char| c == '\0' || c.is_whitespace());
    let name = first
        .strip_prefix("PCS Name = ")
        .or_else(|| first.strip_prefix("GCS Name = "))
        .unwrap_or(first)
        .trim();
    let useless = name.is_empty()
        || name.len() > 200
        || name.eq_ignore_ascii_case("unknown")
        || name.eq_ignore_ascii_case("unnamed")
        || name.starts_with("ESRI PE String");
    (!useless).then(|| name.to_owned())
}

/// Reads a tag holding doubles; a malformed value is a warning and counts as absent,
/// so bad georeferencing never stops the samples from being read.
fn f64_tag(decoder: &mut Decoder<Reader>, tag: Tag, name: &str) -> Option<Vec<f64>> {
    match decoder
        .find_tag(tag)
        .and_then(|v| v.map(tiff::decoder::ifd::Value::into_f64_vec).transpose())
    {
        Ok(v) => v,
        Err(e) => {
            tracing::warn!("ignoring unreadable {name}: {e}");
            None
        }
    }
}

/// The geotransform for the corner of pixel (0, 0) as the file states it (before any
/// PixelIsPoint shift), or `None` when the file has no usable north-up georeferencing.
fn raw_geotransform(decoder: &mut Decoder<Reader>) -> Option<[f64; 6]> {
    let transform = f64_tag(
        decoder,
        Tag::ModelTransformationTag,
        "ModelTransformationTag",
    );
    let scale = f64_tag(decoder, Tag::ModelPixelScaleTag, "ModelPixelScaleTag");
    let tiepoints = f64_tag(decoder, Tag::ModelTiepointTag, "ModelTiepointTag");
    let gt = if let Some(m) = transform {
        if m.len() < 16 {
            tracing::warn!(
                "ignoring georeferencing: ModelTransformationTag has {} values, not 16",
                m.len()
            );
            return None;
        }
        if m[1] != 0.0 || m[4] != 0.0 {
            tracing::warn!(
                "ignoring georeferencing: the ModelTransformationTag rotates or shears the raster \
                 (terms {} and {}); only north-up rasters are supported",
                m[1],
                m[4]
            );
            return None;
        }
        [m[3], m[0], m[1], m[7], m[4], m[5]]
    } else {
        match (scale, tiepoints) {
            (Some(s), Some(t)) if s.len() >= 2 && t.len() >= 6 => {
                if t.len() > 6 {
                    tracing::warn!(
                        "ModelTiepointTag holds {} tiepoints; using the first with the pixel scale",
                        t.len() / 6
                    );
                }
                let (sx, sy) = (s[0], s[1]);
                [t[3] - t[0] * sx, sx, 0.0, t[4] + t[1] * sy, 0.0, -sy]
            }
            (None, Some(t)) if t.len() >= 6 => {
                tracing::warn!(
                    "ignoring georeferencing: {} ground control points without a pixel scale \
                     are not supported",
                    t.len() / 6
                );
                return None;
            }
            (None, None) => return None,
            _ => {
                tracing::warn!(
                    "ignoring georeferencing: ModelPixelScaleTag and ModelTiepointTag are incomplete"
                );
                return None;
            }
        }
    };
    if gt.iter().any(|v| !v.is_finite()) || gt[1] == 0.0 || gt[5] == 0.0 {
        tracing::warn!("ignoring georeferencing: degenerate geotransform {gt:?}");
        return None;
    }
    Some(gt)
}

/// Reads the GeoTIFF tags into a [`GeoRef`] (GDAL's corner convention).
pub(super) fn read_georef(decoder: &mut Decoder<Reader>) -> Option<GeoRef> {
    let dir = match decoder
        .find_tag(Tag::GeoKeyDirectoryTag)
        .and_then(|v| v.map(tiff::decoder::ifd::Value::into_u16_vec).transpose())
    {
        Ok(d) => d,
        Err(e) => {
            tracing::warn!("ignoring unreadable GeoKeyDirectoryTag: {e}");
            None
        }
    };
    let ascii = match ascii_tag(decoder, Tag::GeoAsciiParamsTag) {
        Ok(a) => a,
        Err(e) => {
            tracing::warn!("ignoring unreadable GeoAsciiParamsTag: {e:#}");
            None
        }
    };
    let doubles = f64_tag(decoder, Tag::GeoDoubleParamsTag, "GeoDoubleParamsTag");
    let keys = dir
        .as_deref()
        .map(|d| GeoKeys::parse(d, ascii.as_deref(), doubles.as_deref()))
        .unwrap_or_default();
    let Some(mut gt) = raw_geotransform(decoder) else {
        if dir.is_some() {
            tracing::warn!(
                "the GeoTIFF names a CRS but has no usable geotransform; ignoring its georeferencing"
            );
        }
        return None;
    };
    let raster_type = keys.raster_type();
    if raster_type == RasterType::PixelIsPoint {
        // The tiepoint is the centre of the first sample: move to its corner, as GDAL does.
        gt[0] -= 0.5 * gt[1] + 0.5 * gt[2];
        gt[3] -= 0.5 * gt[4] + 0.5 * gt[5];
    }
    let epsg = keys.epsg();
    // No EPSG CRS code: the CRS the keys spell out, as GDAL reads it.
    let (mut proj, mut wkt) = (None, None);
    if epsg.is_none() {
        match user_crs::definition(&keys.values) {
            Ok(Some(def)) if def.starts_with('+') => proj = Some(def),
            Ok(Some(def)) => wkt = Some(def),
            Ok(None) => {}
            Err(e) => tracing::warn!("the GeoKeys' CRS cannot be read: {e}; give it with --crs"),
        }
    }
    Some(GeoRef {
        epsg,
        crs_name: keys.crs_name(),
        proj,
        wkt,
        geotransform: gt,
        raster_type,
    })
}

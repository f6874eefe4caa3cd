//! GDAL virtual rasters (`.vrt`), the subset `gdalbuildvrt` writes
//! (DECISIONS.md "Mosaics"): one `VRTRasterBand` of `SimpleSource`s and `ComplexSource`s,
//! each copying a window of a source file's band 1 (`SrcRect`) to a window of the same
//! size in the VRT (`DstRect`). Anything that would resample, rescale or look values up
//! (a `DstRect` of another size, fractional offsets, `ScaleRatio`, `LUT`, warped or
//! derived datasets, other source kinds) is refused with the element it found, rather
//! than read as something it is not.
//!
//! Parsing only describes the sources; [`super::mosaic`] opens them (lazily) and
//! places them.

use anyhow::{Context, bail};
use std::path::{Path, PathBuf};

/// A VRT larger than this is refused: the XML is parsed in memory, before the
/// build's memory plan exists (16 MiB is about 25 000 sources).
pub const MAX_VRT_BYTES: u64 = 16 << 20;

/// A window in pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub x: i64,
    pub y: i64,
    pub w: u64,
    pub h: u64,
}

/// One `SimpleSource`/`ComplexSource`.
#[derive(Clone, Debug, PartialEq)]
pub struct VrtSource {
    /// The file to read (resolved against the VRT's folder when `relativeToVRT="1"`).
    pub path: PathBuf,
    /// The window of the source to copy; `None`: the whole source.
    pub src: Option<Rect>,
    /// Where it goes in the VRT; `None`: the same place as `src` (the whole source at
    /// the origin when both are absent).
    pub dst: Option<Rect>,
    /// The `ComplexSource`'s `NODATA`: source values that are missing.
    pub nodata: Option<f64>,
}

/// What a VRT says.
#[derive(Clone, Debug, PartialEq)]
pub struct Vrt {
    pub width: u32,
    pub height: u32,
    /// The `GeoTransform` (GDAL's six coefficients, pixel corners), if any.
    pub geotransform: Option<[f64; 6]>,
    /// The CRS the `SRS` names, as PROJ reads it.
    pub srs: Option<crate::crs::Crs>,
    /// `AREA_OR_POINT` from the dataset's metadata: `Some(true)` for `Point`.
    pub pixel_is_point: Option<bool>,
    /// The band's `NoDataValue`.
    pub nodata: Option<f64>,
    pub sources: Vec<VrtSource>,
}

/// True when `path` looks like a VRT: a `.vrt` name, or XML starting with `<VRTDataset`.
pub fn is_vrt(path: &Path) -> bool {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("vrt"))
    {
        return true;
    }
    let mut head = [0u8; 256];
    // Only a regular file is peeked at: opening a FIFO would wait for a writer. What
    // else the path is, opening it as a raster says.
    let Ok((mut f, _)) = super::open_regular(path) else {
        return false;
    };
    let n = std::io::Read::read(&mut f, &mut head).unwrap_or(0);
    let text = String::from_utf8_lossy(&head[..n]);
    let text = text.trim_start_matches('\u{feff}').trim_start();
    text.starts_with("<VRTDataset") || (text.starts_with("<?xml") && text.contains("<VRTDataset"))
}

impl Vrt {
    /// Reads and parses a VRT file. Errors say what is wrong; the caller names the file.
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let base = path.parent().unwrap_or(Path::new(""));
        if let Some(url) = super::remote::url_of(path) {
            let text = super::remote::read_text(url, MAX_VRT_BYTES, "a VRT")?;
            return Self::parse(&text, base);
        }
        let (file, meta) = super::open_regular(path)?;
        let len = meta.len();
        if len > MAX_VRT_BYTES {
            bail!(
                "VRT is {len} bytes; VRTs over {} MiB are not read (list the files with --inputs instead)",
                MAX_VRT_BYTES >> 20
            );
        }
        let mut text = String::new();
        // The file is bounded above; `take` keeps it so if it grows meanwhile.
        std::io::Read::read_to_string(&mut std::io::Read::take(file, MAX_VRT_BYTES + 1), &mut text)
            .context("cannot read the VRT as UTF-8 text")?;
        Self::parse(&text, base)
    }

    /// Parses VRT text; `base` is the folder relative source names are resolved against.
    pub fn parse(text: &str, base: &Path) -> anyhow::Result<Self> {
        let doc = roxmltree::Document::parse(text).context("not well-formed XML")?;
        let root = doc.root_element();
        if root.tag_name().name() != "VRTDataset" {
            bail!(
                "not a GDAL VRT: the root element is <{}>, not <VRTDataset>",
                root.tag_name().name()
            );
        }
        if let Some(sub) = root.attribute("subClass") {
            bail!(
                "VRTDataset subClass=\"{sub}\" is not supported (only plain mosaics, as gdalbuildvrt writes)"
            );
        }
        let size = |name: &str| -> anyhow::Result<u32> {
            let v = root
                .attribute(name)
                .with_context(|| format!("<VRTDataset> has no {name}"))?;
            match v.trim().parse::<u32>() {
                Ok(n) if n > 0 => Ok(n),
                _ => bail!("<VRTDataset> {name}=\"{v}\" is not a positive whole number"),
            }
        };
        let (width, height) = (size("rasterXSize")?, size("rasterYSize")?);
        let mut geotransform = None;
        let mut srs = None;
        let mut pixel_is_point = None;
        let mut bands = Vec::new();
        for child in root.children().filter(roxmltree::Node::is_element) {
            match child.tag_name().name() {
                "GeoTransform" => geotransform = Some(parse_geotransform(text_of(child))?),
                "SRS" => srs = srs_crs(text_of(child)),
                "Metadata" if child.attribute("domain").is_none_or(str::is_empty) => {
                    for mdi in child.children().filter(|n| n.has_tag_name("MDI")) {
                        if mdi.attribute("key") == Some("AREA_OR_POINT") {
                            pixel_is_point =
                                Some(text_of(mdi).trim().eq_ignore_ascii_case("point"));
                        }
                    }
                }
                "VRTRasterBand" => bands.push(child),
                _ => {}
            }
        }
        let band = match bands.as_slice() {
            [band] => *band,
            [] => bail!("the VRT has no <VRTRasterBand>"),
            more => bail!(
                "the VRT has {} bands; a DEM mosaic reads exactly one",
                more.len()
            ),
        };
        if let Some(sub) = band.attribute("subClass") {
            bail!("VRTRasterBand subClass=\"{sub}\" is not supported (no derived or warped bands)");
        }
        let mut nodata = None;
        let mut sources = Vec::new();
        for child in band.children().filter(roxmltree::Node::is_element) {
            match child.tag_name().name() {
                "NoDataValue" => nodata = Some(parse_f64(text_of(child), "<NoDataValue>")?),
                "SimpleSource" | "ComplexSource" => {
                    let n = sources.len() + 1;
                    sources.push(
                        parse_source(child, base).with_context(|| {
                            format!("source {n} (<{}>)", child.tag_name().name())
                        })?,
                    );
                }
                other if other.ends_with("Source") => bail!(
                    "<{other}> is not supported (only <SimpleSource> and <ComplexSource> without \
                     scaling, as gdalbuildvrt writes)"
                ),
                _ => {}
            }
        }
        if sources.is_empty() {
            bail!("the VRT's band has no <SimpleSource> or <ComplexSource>");
        }
        Ok(Self {
            width,
            height,
            geotransform,
            srs,
            pixel_is_point,
            nodata,
            sources,
        })
    }
}

fn text_of<'a>(node: roxmltree::Node<'a, '_>) -> &'a str {
    node.text().unwrap_or("")
}

fn parse_f64(text: &str, what: &str) -> anyhow::Result<f64> {
    let t = text.trim();
    t.parse::<f64>()
        .or_else(|e| {
            if t.eq_ignore_ascii_case("nan") {
                Ok(f64::NAN)
            } else {
                Err(e)
            }
        })
        .with_context(|| format!("{what} {t:?} is not a number"))
}

fn parse_geotransform(text: &str) -> anyhow::Result<[f64; 6]> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| parse_f64(v, "a <GeoTransform> term"))
        .collect::<anyhow::Result<_>>()?;
    let gt: [f64; 6] = values
        .try_into()
        .map_err(|v: Vec<f64>| anyhow::anyhow!("<GeoTransform> has {} terms, not 6", v.len()))?;
    if gt[2] != 0.0 || gt[4] != 0.0 {
        bail!(
            "the <GeoTransform> rotates or shears the raster (terms {} and {}); only north-up rasters are supported",
            gt[2],
            gt[4]
        );
    }
    if !gt.iter().all(|v| v.is_finite()) || gt[1] == 0.0 || gt[5] == 0.0 {
        bail!("the <GeoTransform> {gt:?} is degenerate");
    }
    Ok(gt)
}

/// The CRS an `SRS` names (`EPSG:n`, WKT 1 or 2, a PROJ string: whatever GDAL
/// writes there), read by PROJ. An SRS PROJ cannot read is a warning and no CRS.
fn srs_crs(srs: &str) -> Option<crate::crs::Crs> {
    let t = srs.trim();
    if t.is_empty() {
        return None;
    }
    match crate::crs::Crs::from_definition(t) {
        Ok(c) => Some(c),
        Err(e) => {
            tracing::warn!("ignoring the VRT's <SRS>, which PROJ cannot read: {e:#}");
            None
        }
    }
}

fn rect(node: roxmltree::Node, what: &str) -> anyhow::Result<Rect> {
    let num = |name: &str| -> anyhow::Result<f64> {
        let v = node
            .attribute(name)
            .with_context(|| format!("<{what}> has no {name}"))?;
        parse_f64(v, &format!("<{what}> {name}"))
    };
    let (x, y, w, h) = (num("xOff")?, num("yOff")?, num("xSize")?, num("ySize")?);
    let whole = |v: f64| (v - v.round()).abs() <= 1e-6 && v.is_finite();
    if !(whole(x) && whole(y) && whole(w) && whole(h)) {
        bail!(
            "<{what}> xOff=\"{x}\" yOff=\"{y}\" xSize=\"{w}\" ySize=\"{h}\" is not in whole pixels: \
             resampling VRT sources is not supported"
        );
    }
    if w.round() < 1.0 || h.round() < 1.0 {
        bail!("<{what}> is empty ({w}×{h})");
    }
    Ok(Rect {
        x: x.round() as i64,
        y: y.round() as i64,
        w: w.round() as u64,
        h: h.round() as u64,
    })
}

fn parse_source(node: roxmltree::Node, base: &Path) -> anyhow::Result<VrtSource> {
    let mut path = None;
    let (mut src, mut dst, mut nodata) = (None, None, None);
    for child in node.children().filter(roxmltree::Node::is_element) {
        let name = child.tag_name().name();
        match name {
            "SourceFilename" => {
                let file = text_of(child).trim();
                if file.is_empty() {
                    bail!("<SourceFilename> is empty");
                }
                let url = super::remote::gdal_vsi_url(file)
                    .or_else(|| crate::storage::is_url(file).then(|| file.to_string()));
                if url.is_none() && file.starts_with("/vsi") {
                    bail!(
                        "{file}: of GDAL's virtual file systems only /vsis3/, /vsigs/, /vsiaz/ and \
                         /vsicurl/ are read (as s3://, gs://, az:// and http(s):// URLs)"
                    );
                }
                let relative = child
                    .attribute("relativeToVRT")
                    .is_some_and(|v| v.trim() == "1");
                path = Some(if let Some(url) = url {
                    PathBuf::from(url)
                } else if relative {
                    base.join(file)
                } else {
                    PathBuf::from(file)
                });
            }
            "SourceBand" => {
                let band = text_of(child).trim();
                if band != "1" {
                    bail!(
                        "<SourceBand>{band}</SourceBand>: only band 1 of a source is read (DEM inputs have one band)"
                    );
                }
            }
            "SrcRect" => src = Some(rect(child, "SrcRect")?),
            "DstRect" => dst = Some(rect(child, "DstRect")?),
            "NODATA" => nodata = Some(parse_f64(text_of(child), "<NODATA>")?),
            "ScaleOffset" | "ScaleRatio" => {
                let v = parse_f64(text_of(child), &format!("<{name}>"))?;
                let identity = if name == "ScaleOffset" { 0.0 } else { 1.0 };
                if v != identity {
                    bail!(
                        "<{name}>{v}</{name}> rescales the source: not supported (use --scale/--offset \
                         for the whole build)"
                    );
                }
            }
            "LUT"
            | "Exponent"
            | "SrcMin"
            | "SrcMax"
            | "DstMin"
            | "DstMax"
            | "ColorTableComponent" => {
                bail!("<{name}> transforms the source's values: not supported");
            }
            // SourceProperties, UseMaskBand, OpenOptions: nothing that changes values.
            _ => {}
        }
    }
    let path = path.context("no <SourceFilename>")?;
    if let (Some(s), Some(d)) = (src, dst)
        && (s.w, s.h) != (d.w, d.h)
    {
        bail!(
            "{}: SrcRect {}×{} is drawn into a DstRect of {}×{}; only 1:1 copies are supported \
             (no resampling)",
            path.display(),
            s.w,
            s.h,
            d.w,
            d.h
        );
    }
    Ok(VrtSource {
        path,
        src,
        dst,
        nodata,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What `gdalbuildvrt` 3.6 wrote for two 301² pieces of N46E008.tif.
    const BUILT: &str = r#"<VRTDataset rasterXSize="601" rasterYSize="601">
  <SRS dataAxisToSRSAxisMapping="2,1">GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AXIS["Latitude",NORTH],AXIS["Longitude",EAST],AUTHORITY["EPSG","4326"]]</SRS>
  <GeoTransform>  7.9995833333333337e+00,  8.3333333333333339e-04,  0.0000000000000000e+00,  4.7000416666666666e+01,  0.0000000000000000e+00, -8.3333333333333339e-04</GeoTransform>
  <VRTRasterBand dataType="Int16" band="1">
    <NoDataValue>-32767</NoDataValue>
    <ColorInterp>Gray</ColorInterp>
    <ComplexSource>
      <SourceFilename relativeToVRT="1">p00.tif</SourceFilename>
      <SourceBand>1</SourceBand>
      <SourceProperties RasterXSize="301" RasterYSize="301" DataType="Int16" BlockXSize="301" BlockYSize="13" />
      <SrcRect xOff="0" yOff="0" xSize="301" ySize="301" />
      <DstRect xOff="0" yOff="0" xSize="301" ySize="301" />
      <NODATA>-32767</NODATA>
    </ComplexSource>
    <SimpleSource>
      <SourceFilename relativeToVRT="0">/data/p11.tif</SourceFilename>
      <SourceBand>1</SourceBand>
      <SrcRect xOff="0" yOff="0" xSize="301" ySize="301" />
      <DstRect xOff="300" yOff="300" xSize="301" ySize="301" />
    </SimpleSource>
  </VRTRasterBand>
</VRTDataset>"#;

    #[test]
    fn reads_what_gdalbuildvrt_writes() {
        let v = Vrt::parse(BUILT, Path::new("/tiles")).unwrap();
        assert_eq!((v.width, v.height), (601, 601));
        assert_eq!(v.srs.as_ref().and_then(crate::crs::Crs::epsg), Some(4326));
        assert_eq!(v.nodata, Some(-32767.0));
        assert_eq!(v.pixel_is_point, None);
        let gt = v.geotransform.unwrap();
        assert!((gt[0] - 7.999_583_333_333_334).abs() < 1e-12 && gt[5] < 0.0);
        assert_eq!(v.sources.len(), 2);
        assert_eq!(v.sources[0].path, Path::new("/tiles/p00.tif"));
        assert_eq!(v.sources[0].nodata, Some(-32767.0));
        assert_eq!(v.sources[1].path, Path::new("/data/p11.tif"));
        assert_eq!(
            v.sources[1].dst,
            Some(Rect {
                x: 300,
                y: 300,
                w: 301,
                h: 301
            })
        );
    }

    #[test]
    fn the_srs_is_read_by_proj_in_any_form_gdal_writes() {
        let code = |srs: &str| srs_crs(srs).and_then(|c| c.epsg());
        assert_eq!(code("EPSG:32611"), Some(32611));
        // GDAL's WKT 1 and PROJ's WKT 2 of LV95 name the code at the top level.
        let lv95 = crate::crs::Crs::from_epsg(2056).unwrap();
        assert_eq!(code(lv95.wkt().unwrap()), Some(2056));
        // A user-defined WKT (no code anywhere) is still a CRS: olinda's, as GDAL writes it.
        let utm = r#"PROJCS["UTM Zone 25, Southern Hemisphere",GEOGCS["GRS 1980(IUGG, 1980)",DATUM["unknown",SPHEROID["GRS80",6378137,298.257222101],TOWGS84[0,0,0,0,0,0,0]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",-33],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",10000000],UNIT["metre",1]]"#;
        let c = srs_crs(utm).unwrap();
        let [lon, lat] = c.to_lon_lat(500_000.0, 9_000_000.0).unwrap();
        assert!(
            (lon + 33.0).abs() < 1e-9 && (lat + 9.04).abs() < 0.01,
            "{lon} {lat}"
        );
        assert!(srs_crs("+proj=longlat +datum=WGS84").is_some_and(|c| c.is_geographic()));
        assert!(srs_crs("not a CRS").is_none() && srs_crs("  ").is_none());
    }

    fn with_source(body: &str) -> String {
        format!(
            r#"<VRTDataset rasterXSize="10" rasterYSize="10"><VRTRasterBand band="1"><ComplexSource>
            <SourceFilename relativeToVRT="1">a.tif</SourceFilename>{body}</ComplexSource></VRTRasterBand></VRTDataset>"#
        )
    }

    fn error(text: &str) -> String {
        format!("{:#}", Vrt::parse(text, Path::new(".")).unwrap_err())
    }

    #[test]
    fn anything_that_resamples_or_rescales_is_refused() {
        let scaled = with_source(
            r#"<SrcRect xOff="0" yOff="0" xSize="10" ySize="10"/><DstRect xOff="0" yOff="0" xSize="5" ySize="5"/>"#,
        );
        assert!(error(&scaled).contains("only 1:1"), "{}", error(&scaled));
        let half = with_source(r#"<DstRect xOff="0.5" yOff="0" xSize="10" ySize="10"/>"#);
        assert!(error(&half).contains("whole pixels"), "{}", error(&half));
        let ratio = with_source("<ScaleRatio>2</ScaleRatio>");
        assert!(error(&ratio).contains("ScaleRatio"), "{}", error(&ratio));
        assert!(Vrt::parse(&with_source("<ScaleRatio>1</ScaleRatio>"), Path::new(".")).is_ok());
        let lut = with_source("<LUT>0:0,1:10</LUT>");
        assert!(error(&lut).contains("LUT"), "{}", error(&lut));
        let band2 = with_source("<SourceBand>2</SourceBand>");
        assert!(error(&band2).contains("band 1"), "{}", error(&band2));
        let warped = r#"<VRTDataset subClass="VRTWarpedDataset" rasterXSize="1" rasterYSize="1"/>"#;
        assert!(
            error(warped).contains("VRTWarpedDataset"),
            "{}",
            error(warped)
        );
        let averaged = r#"<VRTDataset rasterXSize="1" rasterYSize="1"><VRTRasterBand><AveragedSource/></VRTRasterBand></VRTDataset>"#;
        assert!(
            error(averaged).contains("AveragedSource"),
            "{}",
            error(averaged)
        );
        let two = r#"<VRTDataset rasterXSize="1" rasterYSize="1"><VRTRasterBand/><VRTRasterBand/></VRTDataset>"#;
        assert!(error(two).contains("2 bands"), "{}", error(two));
        assert!(error("<html/>").contains("not a GDAL VRT"));
    }
}

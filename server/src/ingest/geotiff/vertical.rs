//! What a GeoTIFF itself says about its heights' vertical datum
//! (DECISIONS.md "Real clients"), in this order: the vertical GeoKeys
//! (`VerticalCSTypeGeoKey` 4096, then `VerticalDatumGeoKey` 4098), then GDAL's metadata
//! tag (42112), where DTED-derived files keep `DTED_VerticalDatum`. The first statement
//! found is final, even one naming a datum the metadata cannot record (NAVD88, DTED's
//! "MSL"): such heights stay `unknown`, and the statement is passed on for the build's
//! warning. Only a file that states nothing falls back to its name
//! ([`super::product_name`]).

use super::{Reader, text_tag};
use crate::ingest::DatumClue;
use tessera_shared::VerticalDatum;
use tiff::decoder::Decoder;
use tiff::tags::Tag;

/// `VerticalCSTypeGeoKey` (GeoTIFF 1.1: `VerticalGeoKey`): the vertical CRS's EPSG code.
const VERTICAL_CS_TYPE: u16 = 4096;
/// `VerticalDatumGeoKey`: the vertical datum's EPSG code.
const VERTICAL_DATUM: u16 = 4098;
/// GDAL's `GDAL_METADATA` tag: an XML document of metadata items.
const GDAL_METADATA: u16 = 42112;
/// Longest GDAL metadata read (it may hold statistics and attribute tables).
const MAX_GDAL_METADATA: usize = 1 << 20;

/// The datum clue of the file's tags, or `None` when they state nothing.
pub(super) fn from_tags(decoder: &mut Decoder<Reader>) -> Option<DatumClue> {
    let dir = decoder
        .find_tag(Tag::GeoKeyDirectoryTag)
        .and_then(|v| v.map(tiff::decoder::ifd::Value::into_u16_vec).transpose())
        .ok()
        .flatten();
    if let Some(clue) = dir.as_deref().and_then(from_geokeys) {
        return Some(clue);
    }
    match text_tag(decoder, Tag::Unknown(GDAL_METADATA), MAX_GDAL_METADATA) {
        Ok(xml) => xml.as_deref().and_then(from_gdal_metadata),
        Err(e) => {
            tracing::warn!("ignoring an unreadable GDAL_METADATA tag: {e:#}");
            None
        }
    }
}

/// The vertical keys of a GeoKeyDirectoryTag (header `[version, revision, minor,
/// nkeys]`, then `[KeyID, TIFFTagLocation, Count, Value]` entries; see `georef`).
/// 0 (undefined) and 32767 (user-defined) state nothing.
fn from_geokeys(dir: &[u16]) -> Option<DatumClue> {
    let nkeys = usize::from(*dir.get(3)?);
    let key = |id: u16| {
        dir.get(4..)?
            .chunks_exact(4)
            .take(nkeys)
            .find(|e| e[0] == id && e[1] == 0)
            .map(|e| e[3])
            .filter(|&v| v != 0 && v != 32767)
    };
    let crs = key(VERTICAL_CS_TYPE).map(|code| {
        let (datum, name) = vertical_crs(code);
        (datum, describe("VerticalCSTypeGeoKey", code, name))
    });
    let datum = key(VERTICAL_DATUM).map(|code| {
        let (datum, name) = vertical_datum(code);
        (datum, describe("VerticalDatumGeoKey", code, name))
    });
    // A key naming a datum wins; else the first key, naming one we cannot record.
    let stated = [crs.clone(), datum.clone()]
        .into_iter()
        .flatten()
        .find(|(d, _)| d.is_some())
        .or(crs)
        .or(datum)?;
    Some(match stated {
        (Some(d), why) => DatumClue {
            datum: Some(d),
            why,
        },
        (None, why) => DatumClue {
            datum: None,
            why: format!("{why}, a vertical datum Tessera does not record"),
        },
    })
}

fn describe(key: &str, code: u16, name: Option<&str>) -> String {
    match name {
        Some(name) => format!("GeoTIFF {key} {code} ({name})"),
        None => format!("GeoTIFF {key} {code}"),
    }
}

/// What a vertical CRS code means: EPSG's vertical CRSs, geographic 3D CRSs (whose
/// third axis is the ellipsoidal height: GDAL writes `VerticalCSTypeGeoKey` 4979 for
/// EPSG:4979) and GeoTIFF 1.0's own codes (5001–5033 ellipsoids, 5101–5106 sea levels).
fn vertical_crs(code: u16) -> (Option<VerticalDatum>, Option<&'static str>) {
    use VerticalDatum::{Egm96, Egm2008, Ellipsoid};
    match code {
        5773 => (Some(Egm96), Some("EGM96 height")),
        3855 => (Some(Egm2008), Some("EGM2008 height")),
        4979 | 4327 | 4329 => (Some(Ellipsoid), Some("WGS 84 geographic 3D")),
        9754 => (Some(Ellipsoid), Some("WGS 84 (G2139) geographic 3D")),
        4937 => (Some(Ellipsoid), Some("ETRS89 geographic 3D")),
        7912 => (Some(Ellipsoid), Some("ITRF2014 geographic 3D")),
        6319 => (Some(Ellipsoid), Some("NAD83(2011) geographic 3D")),
        4959 => (Some(Ellipsoid), Some("NZGD2000 geographic 3D")),
        5030 => (Some(Ellipsoid), Some("GeoTIFF 1.0 WGS 84 ellipsoid")),
        5019 => (Some(Ellipsoid), Some("GeoTIFF 1.0 GRS 1980 ellipsoid")),
        5001..=5033 => (Some(Ellipsoid), Some("a GeoTIFF 1.0 ellipsoid")),
        5798 => (None, Some("EGM84 height")),
        5703 | 5103 => (None, Some("NAVD88 height")),
        5702 | 5102 => (None, Some("NGVD29 height")),
        5714 => (None, Some("MSL height")),
        5701 | 5101 => (None, Some("ODN height")),
        _ => (None, None),
    }
}

/// What a vertical datum code means (EPSG datum codes).
fn vertical_datum(code: u16) -> (Option<VerticalDatum>, Option<&'static str>) {
    match code {
        5171 => (Some(VerticalDatum::Egm96), Some("EGM96 geoid")),
        1027 => (Some(VerticalDatum::Egm2008), Some("EGM2008 geoid")),
        5203 => (None, Some("EGM84 geoid")),
        5103 => (None, Some("North American Vertical Datum 1988")),
        5215 => (None, Some("European Vertical Reference Frame 2007")),
        _ => (None, None),
    }
}

/// `DTED_VerticalDatum` in GDAL's metadata XML (`<GDALMetadata><Item
/// name="DTED_VerticalDatum">E96</Item>…`), which GDAL copies from a DTED file's
/// header: `E96` is the EGM96 geoid; `MSL` is DTED's older mean sea level, the EGM84
/// geoid, not EGM96 (metres apart), so it is reported, not mapped. Items with a
/// `role` are band properties (a description, a unit), not metadata.
fn from_gdal_metadata(xml: &str) -> Option<DatumClue> {
    let xml = xml.trim_matches(|c: char| c == '\0' || c.is_whitespace());
    let doc = match roxmltree::Document::parse(xml) {
        Ok(d) => d,
        Err(e) => {
            tracing::warn!("ignoring unparsable GDAL_METADATA XML: {e}");
            return None;
        }
    };
    let value: String = doc
        .descendants()
        .filter(|n| n.has_tag_name("Item") && n.attribute("role").is_none())
        .find(|n| {
            n.attribute("name")
                .is_some_and(|a| a.trim().eq_ignore_ascii_case("DTED_VerticalDatum"))
        })?
        .descendants()
        .filter_map(|n| n.text().filter(|_| n.is_text()))
        .collect();
    let value = value.trim();
    let why = format!("GeoTIFF GDAL metadata DTED_VerticalDatum={value}");
    Some(if value.eq_ignore_ascii_case("E96") {
        DatumClue {
            datum: Some(VerticalDatum::Egm96),
            why,
        }
    } else if value.eq_ignore_ascii_case("MSL") {
        DatumClue {
            datum: None,
            why: format!(
                "{why}: DTED's mean sea level, the EGM84 geoid, which is not EGM96 and which \
                 Tessera does not record"
            ),
        }
    } else if value.is_empty() {
        return None;
    } else {
        let shown: String = value.chars().take(40).collect();
        DatumClue {
            datum: None,
            why: format!(
                "GeoTIFF GDAL metadata DTED_VerticalDatum={shown:?}, not a DTED datum code"
            ),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::super::test_tiff::{Spec, surface};
    use super::*;
    use crate::ingest::{RowSource, SampleType};

    /// A 4×3 geographic int16 GeoTIFF with these extra GeoKeys and, if given, this
    /// GDAL metadata, opened from a file named `name`.
    fn tiff(keys: &[[u16; 4]], metadata: Option<&str>, name: &str) -> super::super::GeoTiff {
        let mut dir = vec![1, 1, 0, 2 + keys.len() as u16];
        dir.extend([1024, 0, 1, 2, 2048, 0, 1, 4326]);
        dir.extend(keys.iter().flatten());
        let mut spec = Spec::new(4, 3, SampleType::Int16, surface(4, 3, SampleType::Int16))
            .shorts(34735, &dir)
            .doubles(33550, &[0.25, 0.25, 0.0])
            .doubles(33922, &[0.0, 0.0, 0.0, 8.0, 47.0, 0.0]);
        if let Some(xml) = metadata {
            spec = spec.ascii(GDAL_METADATA, xml);
        }
        let file = spec.write(name);
        super::super::GeoTiff::open(&file.0).expect("open")
    }

    fn clue(t: &super::super::GeoTiff) -> Option<DatumClue> {
        t.datum_clue()
    }

    #[test]
    fn vertical_geokeys_name_the_datum() {
        for (keys, want, says) in [
            (
                vec![[4096, 0, 1, 5773]],
                Some(VerticalDatum::Egm96),
                "VerticalCSTypeGeoKey 5773 (EGM96 height)",
            ),
            (
                vec![[4096, 0, 1, 3855]],
                Some(VerticalDatum::Egm2008),
                "VerticalCSTypeGeoKey 3855 (EGM2008 height)",
            ),
            (
                vec![[4096, 0, 1, 4979]],
                Some(VerticalDatum::Ellipsoid),
                "4979 (WGS 84 geographic 3D)",
            ),
            (
                vec![[4096, 0, 1, 5030]],
                Some(VerticalDatum::Ellipsoid),
                "5030",
            ),
            (
                vec![[4098, 0, 1, 5171]],
                Some(VerticalDatum::Egm96),
                "VerticalDatumGeoKey 5171 (EGM96 geoid)",
            ),
            (
                vec![[4098, 0, 1, 1027]],
                Some(VerticalDatum::Egm2008),
                "VerticalDatumGeoKey 1027",
            ),
            // A user-defined CRS with an EPSG datum: the datum says it.
            (
                vec![[4096, 0, 1, 32767], [4098, 0, 1, 5171]],
                Some(VerticalDatum::Egm96),
                "5171",
            ),
            (
                vec![[4096, 0, 1, 5703]],
                None,
                "VerticalCSTypeGeoKey 5703 (NAVD88 height), a vertical datum Tessera does not record",
            ),
            (vec![[4096, 0, 1, 6360]], None, "VerticalCSTypeGeoKey 6360"),
        ] {
            let t = tiff(&keys, None, "keys.tif");
            let c = clue(&t).unwrap_or_else(|| panic!("{keys:?}: no clue"));
            assert_eq!(c.datum, want, "{keys:?}: {c:?}");
            assert!(c.why.contains(says), "{keys:?}: {c:?}");
            assert!(c.why.starts_with("GeoTIFF "), "{c:?}");
            assert_eq!(t.vertical_datum(), want);
        }
    }

    #[test]
    fn no_vertical_statement_is_no_clue() {
        for keys in [vec![], vec![[4096, 0, 1, 32767]], vec![[4096, 0, 1, 0]]] {
            let t = tiff(&keys, None, "plain.tif");
            assert_eq!(clue(&t), None, "{keys:?}");
            assert_eq!(t.vertical_datum(), None);
        }
        // Cut short: the directory claims more keys than it holds.
        assert_eq!(from_geokeys(&[1, 1, 0, 9, 4096, 0, 1]), None);
        assert_eq!(from_geokeys(&[1, 1]), None);
    }

    #[test]
    fn gdal_dted_metadata_names_the_datum() {
        let e96 = r#"<GDALMetadata>
  <Item name="DTED_Producer">USCNIMA </Item>
  <Item name="DTED_VerticalDatum">E96</Item>
  <Item name="UNITTYPE" sample="0" role="unittype">m</Item>
</GDALMetadata>
"#;
        let t = tiff(&[], Some(e96), "dted.tif");
        let c = clue(&t).expect("a clue");
        assert_eq!(c.datum, Some(VerticalDatum::Egm96));
        assert_eq!(c.why, "GeoTIFF GDAL metadata DTED_VerticalDatum=E96");

        let msl = r#"<GDALMetadata><Item name="DTED_VerticalDatum">MSL</Item></GDALMetadata>"#;
        let t = tiff(&[], Some(msl), "dted_msl.tif");
        let c = clue(&t).expect("a clue");
        assert_eq!(c.datum, None);
        assert!(c.why.contains("DTED_VerticalDatum=MSL") && c.why.contains("EGM84"));
        assert_eq!(t.vertical_datum(), None);

        // A GeoKey is stated first and wins over the metadata.
        let t = tiff(&[[4096, 0, 1, 3855]], Some(e96), "both.tif");
        assert_eq!(t.vertical_datum(), Some(VerticalDatum::Egm2008));
    }

    #[test]
    fn gdal_metadata_xml_is_read_robustly() {
        let egm96 = Some(VerticalDatum::Egm96);
        for (xml, want) in [
            // Attribute order, quotes, whitespace, a sample attribute, an entity.
            (
                "<GDALMetadata>\n\t<Item sample='0'  name = ' DTED_VerticalDatum' >\n E96 \
                 </Item></GDALMetadata>",
                egm96,
            ),
            (
                r#"<?xml version="1.0"?><GDALMetadata><Item name="X">a &amp; b</Item><Item name="dted_verticaldatum">e96</Item></GDALMetadata>"#,
                egm96,
            ),
            (
                r#"<GDALMetadata><Item name="DTED_VerticalDatum">E&#57;6</Item></GDALMetadata>"#,
                egm96,
            ),
            // A band property with the name is not the item.
            (
                r#"<GDALMetadata><Item name="DTED_VerticalDatum" sample="0" role="description">E96</Item></GDALMetadata>"#,
                None,
            ),
        ] {
            assert_eq!(from_gdal_metadata(xml).and_then(|c| c.datum), want, "{xml}");
        }
        for junk in [
            "",
            "\0\0",
            "<GDALMetadata><Item name=\"DTED_VerticalDatum\">E96",
            "not xml at all",
            "<GDALMetadata><Item name=\"DTED_VerticalDatum\"></Item></GDALMetadata>",
            "<GDALMetadata><Item name=\"STATISTICS_MAXIMUM\" sample=\"0\">547</Item></GDALMetadata>",
        ] {
            assert_eq!(from_gdal_metadata(junk), None, "{junk:?}");
        }
        let odd = from_gdal_metadata(
            "<GDALMetadata><Item name=\"DTED_VerticalDatum\">WGS</Item></GDALMetadata>",
        )
        .expect("a statement");
        assert_eq!(odd.datum, None);
        assert!(odd.why.contains("\"WGS\""), "{odd:?}");
    }
}

//! The vertical datum a GeoTIFF's file name implies, for the global DEM products
//! whose tiles keep their distributor's names and whose datum is documented
//! (DECISIONS.md "Real clients"): SRTM in its USGS, CGIAR-CSI and NASA
//! forms, NASADEM, ASTER GDEM and ALOS AW3D30 are heights above the EGM96 geoid;
//! the Copernicus DEM is above EGM2008. Such files mostly carry no vertical GeoKey.
//!
//! Only the file name counts, never its folder, and the whole name must match one
//! pattern, case aside: `n46_e008_1arc_v3.tif` is a USGS SRTM tile,
//! `n46_e008_1arc_v3_egm2008.tif` is something else and states nothing.

use crate::ingest::DatumClue;
use std::path::Path;
use tessera_shared::VerticalDatum::{self, Egm96, Egm2008};

/// Name patterns (without the `.tif`/`.tiff` extension, lower case): `#` is a digit,
/// `[abc]` one of the characters; everything else stands for itself.
const PRODUCTS: &[(&str, &str, VerticalDatum)] = &[
    // USGS EarthExplorer "SRTM 1 Arc-Second Global" / "SRTM Void Filled" GeoTIFFs.
    ("[ns]##_[ew]###_[13]arc_v[123]", "USGS SRTM GeoTIFF", Egm96),
    // CGIAR-CSI SRTM 90 m v4.1 5°×5° tiles.
    ("srtm_##_##", "CGIAR-CSI SRTM 4.1", Egm96),
    // NASA LP DAAC SRTMGL1/SRTMGL3 v3 tiles (N46E008.SRTMGL1.hgt.zip), as GeoTIFF.
    ("[ns]##[ew]###.srtmgl[13]", "NASA SRTMGL1/SRTMGL3", Egm96),
    // NASADEM (NASADEM_HGT_n46e008.zip), as GeoTIFF.
    ("nasadem_hgt_[ns]##[ew]###", "NASADEM", Egm96),
    // ASTER GDEM v3, v2 and v1.
    ("astgtmv003_[ns]##[ew]###_dem", "ASTER GDEM", Egm96),
    ("astgtm2_[ns]##[ew]###_dem", "ASTER GDEM", Egm96),
    ("astgtm_[ns]##[ew]###_dem", "ASTER GDEM", Egm96),
    // ALOS World 3D 30 m (AW3D30) v2 and later, and v1.
    ("alpsmlc30_[ns]###[ew]###_dsm", "ALOS AW3D30", Egm96),
    ("[ns]###[ew]###_ave_dsm", "ALOS AW3D30", Egm96),
    // Copernicus DEM GLO-30/GLO-90 (COG on the open buckets, and the DGED tiles).
    (
        "copernicus_dsm_cog_##_[ns]##_00_[ew]###_00_dem",
        "Copernicus DEM",
        Egm2008,
    ),
    (
        "copernicus_dsm_##_[ns]##_00_[ew]###_00_dem",
        "Copernicus DEM",
        Egm2008,
    ),
];

/// The datum `path`'s file name implies, with the product it names.
pub(super) fn datum_of(path: &Path) -> Option<DatumClue> {
    let name = path.file_name()?.to_str()?;
    let lower = name.to_ascii_lowercase();
    let stem = lower
        .strip_suffix(".tif")
        .or_else(|| lower.strip_suffix(".tiff"))?;
    let (_, product, datum) = PRODUCTS
        .iter()
        .find(|(pattern, ..)| matches(pattern.as_bytes(), stem.as_bytes()))?;
    Some(DatumClue {
        datum: Some(*datum),
        why: format!("file name {name} matches {product}"),
    })
}

/// Whether all of `name` matches `pattern` (see [`PRODUCTS`]).
fn matches(pattern: &[u8], name: &[u8]) -> bool {
    let (mut p, mut n) = (pattern, name);
    loop {
        let Some((&want, rest)) = p.split_first() else {
            return n.is_empty();
        };
        let Some((&got, tail)) = n.split_first() else {
            return false;
        };
        let (ok, rest) = match want {
            b'#' => (got.is_ascii_digit(), rest),
            b'[' => {
                let end = rest
                    .iter()
                    .position(|&c| c == b']')
                    .expect("a closed [set] in the pattern");
                (rest[..end].contains(&got), &rest[end + 1..])
            }
            c => (c == got, rest),
        };
        if !ok {
            return false;
        }
        (p, n) = (rest, tail);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn datum(name: &str) -> Option<VerticalDatum> {
        datum_of(Path::new(name)).and_then(|c| c.datum)
    }

    #[test]
    fn documented_product_names_give_their_datum() {
        for name in [
            "n46_e008_1arc_v3.tif",
            "s12_w077_3arc_v2.tif",
            "N46_E008_1ARC_V3.TIF",
            "srtm_38_03.tif",
            "N46E008.SRTMGL1.tif",
            "s12w077.srtmgl3.tiff",
            "NASADEM_HGT_n46e008.tif",
            "ASTGTMV003_N46E008_dem.tif",
            "ASTGTM2_S12W077_dem.tif",
            "ALPSMLC30_N046E008_DSM.tif",
            "N046E008_AVE_DSM.tif",
        ] {
            assert_eq!(datum(name), Some(Egm96), "{name}");
        }
        for name in [
            "Copernicus_DSM_COG_10_N46_00_E008_00_DEM.tif",
            "Copernicus_DSM_COG_30_S12_00_W077_00_DEM.tif",
            "Copernicus_DSM_10_N46_00_E008_00_DEM.tif",
        ] {
            assert_eq!(datum(name), Some(Egm2008), "{name}");
        }
        let c = datum_of(Path::new("/data/n46_e008_1arc_v3.tif")).unwrap();
        assert_eq!(
            c.why,
            "file name n46_e008_1arc_v3.tif matches USGS SRTM GeoTIFF"
        );
    }

    #[test]
    fn other_names_state_nothing() {
        for name in [
            "N46E008.tif",
            "aletsch.tif",
            "n46_e008_1arc_v3_ellipsoidal.tif",
            "my_n46_e008_1arc_v3.tif",
            "n46_e008_1arc_v3.png",
            "n46_e008_1arc_v3",
            "n4_e008_1arc_v3.tif",
            "x46_e008_1arc_v3.tif",
            "srtm_38_03_utm.tif",
            "srtm_38_3.tif",
            "Copernicus_DSM_COG_10_N46_00_E008_00_DEM_egm96.tif",
            "/srtm/data/dem.tif",
            "",
            "[.tif",
        ] {
            assert_eq!(datum(name), None, "{name}");
        }
        // The folder is not the name.
        assert_eq!(datum("n46_e008_1arc_v3.tif/dem.tif"), None);
    }
}

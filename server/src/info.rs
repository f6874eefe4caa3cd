//! `tessera-server info`: metadata and per-level statistics.

use serde::Serialize;
use std::path::Path;
use tessera_shared::reader::ReadError;
use tessera_shared::{Metadata, Pyramid};

#[derive(Debug, Serialize)]
pub struct LevelStats {
    pub level: u8,
    pub tiles_per_side: u32,
    pub tiles: u64,
    pub bytes: u64,
    /// Stored bytes per tile sample (raw 16-bit is 2).
    pub bytes_per_sample: f64,
    pub min_height: f64,
    pub max_height: f64,
    /// Largest error of any tile of this level drawn at its full resolution, in metres.
    pub max_full_res_error: f64,
    /// Samples of this level's grid that hold input data, and that were no-data and
    /// filled (format v2; `None` for v1 files, which did not count them).
    pub valid_samples: Option<u64>,
    pub filled_samples: Option<u64>,
    /// Tiles stored with a partial validity mask.
    pub partial_tiles: u64,
}

#[derive(Debug, Serialize)]
pub struct Info {
    pub file: String,
    pub file_bytes: u64,
    /// Whole file size per DEM sample.
    pub bytes_per_sample: f64,
    pub format_version: u32,
    pub crs: Option<String>,
    /// `[west, south, east, north]` of the pixel areas, when georeferenced.
    pub extent: Option<[f64; 4]>,
    pub metadata: Metadata,
    pub levels: Vec<LevelStats>,
}

pub fn info(path: &Path) -> Result<Info, ReadError> {
    let p = Pyramid::open_file(path)?;
    let m = p.metadata().clone();
    let g = *p.geometry();
    let q = m.quantization;
    let samples_per_tile = (g.tile_samples() * g.tile_samples()) as f64;
    let levels = g
        .levels()
        .map(|l| {
            let present: Vec<_> = p
                .index(l)
                .unwrap_or(&[])
                .iter()
                .filter(|e| e.is_present())
                .collect();
            let bytes: u64 = present.iter().map(|e| u64::from(e.length)).sum();
            let tiles = present.len() as u64;
            let counts = m.level_counts.get(usize::from(l.get()));
            let partial_tiles = present
                .iter()
                .filter(|e| e.flags & tessera_shared::format::FLAG_PARTIAL != 0)
                .count() as u64;
            LevelStats {
                level: l.get(),
                tiles_per_side: l.tiles_per_side(),
                tiles,
                bytes,
                bytes_per_sample: bytes as f64 / (tiles as f64 * samples_per_tile).max(1.0),
                min_height: q.height(present.iter().map(|e| e.min).min().unwrap_or(0)),
                max_height: q.height(present.iter().map(|e| e.max).max().unwrap_or(0)),
                max_full_res_error: present
                    .iter()
                    .map(|e| f64::from(e.full_res_error))
                    .fold(0.0, f64::max),
                valid_samples: counts.map(|c| c.valid),
                filled_samples: counts.map(|c| c.filled),
                partial_tiles,
            }
        })
        .collect();
    let file_bytes = std::fs::metadata(path)?.len();
    Ok(Info {
        file: path.display().to_string(),
        file_bytes,
        bytes_per_sample: file_bytes as f64 / (f64::from(m.width) * f64::from(m.height)),
        format_version: p.header().version,
        crs: m.georef.as_ref().and_then(tessera_shared::GeoRef::crs),
        extent: m.georef.as_ref().map(|g| g.extent(m.width, m.height)),
        metadata: m,
        levels,
    })
}

/// The human-readable report.
pub fn render(i: &Info) -> String {
    use std::fmt::Write;
    let m = &i.metadata;
    let q = &m.quantization;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "file        {} ({:.1} MB, format v{})",
        i.file,
        i.file_bytes as f64 / 1e6,
        i.format_version
    );
    let _ = writeln!(s, "source      {}", m.source);
    let _ = writeln!(
        s,
        "size        {} × {} samples, tiles of {} cells, {} levels",
        m.width, m.height, m.tile_size, m.levels
    );
    let _ = writeln!(
        s,
        "heights     {:.2} .. {:.2} m (h = {} + {}·q, quantization error ≤ {} m)",
        m.min_height, m.max_height, q.offset, q.scale, q.max_error
    );
    let _ = writeln!(
        s,
        "no-data     {} samples filled ({})",
        m.nodata_count, m.nodata_fill
    );
    match (&i.crs, &i.extent, &m.georef) {
        (crs, Some(e), Some(g)) => {
            let _ = writeln!(
                s,
                "georef      {} {:?}, extent west {} south {} east {} north {}",
                // A CRS known only by name (no EPSG code) is still known.
                crs.as_deref()
                    .or(g.crs_name.as_deref())
                    .unwrap_or("unknown CRS"),
                g.raster_type,
                e[0],
                e[1],
                e[2],
                e[3]
            );
        }
        _ => {
            let _ = writeln!(s, "georef      none");
        }
    }
    if let Some(g) = &m.georef
        && let Some(proj) = &g.proj
    {
        let _ = writeln!(s, "proj        {proj}");
    }
    match &m.ground_spacing {
        Some(sp) => {
            let _ = writeln!(
                s,
                "spacing     {:.3} m east–west × {:.3} m north–south at the centre",
                sp.x, sp.y
            );
        }
        None => {
            let _ = writeln!(
                s,
                "spacing     not recorded (no CRS the projection library knows)"
            );
        }
    }
    let _ = writeln!(s, "heights ref {}", m.vertical_datum.name());
    if !m.sources.is_empty() {
        let _ = writeln!(s, "sources     {} (priority order)", m.sources.len());
        for r in &m.sources {
            let spacing = r.spacing.map_or_else(
                || "spacing unknown".into(),
                |g| format!("{:.3} × {:.3} m", g.x, g.y),
            );
            let area = footprint_area_km2(&r.footprint)
                .map_or_else(String::new, |a| format!(", ≈{a:.0} km²"));
            let _ = writeln!(
                s,
                "  {}: {}, {spacing}, {}, level {}{area}",
                r.name,
                if r.crs.is_empty() { "no CRS" } else { &r.crs },
                r.vertical_datum.name(),
                r.level,
            );
        }
    }
    let _ = writeln!(s, "content     {}", m.content_hash);
    let _ = writeln!(
        s,
        "size/sample {:.3} bytes (raw 16-bit: 2)",
        i.bytes_per_sample
    );
    let _ = writeln!(
        s,
        "level  tiles partial       bytes  bytes/sample   min (m)   max (m)  full-res error (m)  valid samples  filled samples"
    );
    let count = |c: Option<u64>| c.map_or_else(|| "-".to_string(), |v| v.to_string());
    for l in &i.levels {
        let _ = writeln!(
            s,
            "{:>5} {:>6} {:>7} {:>11} {:>13.3} {:>9.1} {:>9.1} {:>19.3} {:>14} {:>15}",
            l.level,
            l.tiles,
            l.partial_tiles,
            l.bytes,
            l.bytes_per_sample,
            l.min_height,
            l.max_height,
            l.max_full_res_error,
            count(l.valid_samples),
            count(l.filled_samples)
        );
    }
    s
}

/// The area inside a longitude/latitude ring, in km², on a sphere of the Earth's mean
/// radius (a local equirectangular shoelace: within a percent for a DEM's footprint).
pub fn footprint_area_km2(ring: &[[f64; 2]]) -> Option<f64> {
    const R_KM: f64 = 6371.0;
    if ring.len() < 4 {
        return None;
    }
    let mean_lat = ring.iter().map(|p| p[1]).sum::<f64>() / ring.len() as f64;
    let k = R_KM * std::f64::consts::PI / 180.0;
    let xy = |p: &[f64; 2]| (p[0] * k * mean_lat.to_radians().cos(), p[1] * k);
    let twice: f64 = ring
        .windows(2)
        .map(|w| {
            let (a, b) = (xy(&w[0]), xy(&w[1]));
            a.0 * b.1 - b.0 * a.1
        })
        .sum();
    Some(twice.abs() / 2.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_shared::{GeoRef, RasterType};

    /// olinda_dem_utm25s.tif names its CRS ("WGS 84 / UTM zone 25S") without an EPSG
    /// code; `info` used to print "unknown CRS" for it.
    #[test]
    fn a_crs_known_by_name_only_is_named() {
        let georef = GeoRef {
            epsg: None,
            crs_name: Some("WGS 84 / UTM zone 25S".into()),
            proj: None,
            wkt: None,
            geotransform: [288_000.0, 90.0, 0.0, 9_120_000.0, 0.0, -90.0],
            raster_type: RasterType::PixelIsArea,
        };
        let metadata = Metadata {
            georef: Some(georef.clone()),
            ..tessera_shared::fixtures::metadata(111, 111, 64)
        };
        let info = Info {
            file: "olinda.tess".into(),
            file_bytes: 1,
            bytes_per_sample: 1.0,
            format_version: 1,
            crs: georef.crs(),
            extent: Some(georef.extent(111, 111)),
            metadata,
            levels: Vec::new(),
        };
        let text = render(&info);
        assert!(text.contains("georef      WGS 84 / UTM zone 25S"), "{text}");
        assert!(!text.contains("unknown CRS"), "{text}");
    }
}

//! Reading every input's header once: the grid checks that say which two files do
//! not fit together and why, and the placement of every piece on the mosaic's lattice.

use super::super::RowSource;
use super::super::vertical_shift::VerticalOptions;
use super::super::vrt::{Rect, Vrt, is_vrt};
use super::{
    Edge, Group, LATTICE_TOLERANCE, OPEN_INPUT_BYTES, Opener, Piece, crs_text, file_name,
    nodata_values, same_crs,
};
use anyhow::{Context, bail};
use std::path::Path;
use tessera_shared::{GeoRef, RasterType};

pub(super) fn piece_bytes(reader: &dyn RowSource) -> u64 {
    reader.buffer_bytes() + u64::from(reader.info().width) * 4 + OPEN_INPUT_BYTES
}

pub(super) fn file_group(
    path: &Path,
    nodata: Option<f64>,
    vertical: &VerticalOptions,
    opener: Opener,
) -> anyhow::Result<Group> {
    let name = path.display().to_string();
    let (reader, format) = opener(path).with_context(|| name.clone())?;
    let info = reader.info().clone();
    let piece = Piece {
        path: path.to_path_buf(),
        name: name.clone(),
        format,
        sample_type: info.sample_type,
        x: 0,
        y: 0,
        w: info.width,
        h: info.height,
        src_x: 0,
        src_y: 0,
        src_width: info.width,
        src_height: info.height,
        nodata: nodata_values(nodata, &[info.nodata]),
        bytes: piece_bytes(reader.as_ref()),
        datum: vertical.datum_for(path, reader.datum_clue()),
        warp: None,
        edge: Edge::Window([0, 0, info.width, info.height]),
        metres: None,
    };
    Ok(Group {
        name,
        georef: info.georef,
        width: info.width,
        height: info.height,
        pieces: vec![piece],
        is_vrt: false,
    })
}

pub(super) fn vrt_group(
    path: &Path,
    nodata: Option<f64>,
    vertical: &VerticalOptions,
    opener: Opener,
) -> anyhow::Result<Group> {
    let vrt_name = path.display().to_string();
    let vrt = Vrt::open(path).with_context(|| vrt_name.clone())?;
    let mut pieces = Vec::with_capacity(vrt.sources.len());
    let mut crs: Option<GeoRef> = None;
    for s in &vrt.sources {
        let name = s.path.display().to_string();
        if is_vrt(&s.path) {
            bail!("{vrt_name}: names {name}, another VRT: nested VRTs are not supported");
        }
        let (reader, format) = opener(&s.path)
            .with_context(|| format!("{vrt_name}: names {name}, which cannot be read"))?;
        let info = reader.info().clone();
        if crs.is_none() {
            crs.clone_from(&info.georef);
        }
        let whole = Rect {
            x: 0,
            y: 0,
            w: u64::from(info.width),
            h: u64::from(info.height),
        };
        let src = s.src.unwrap_or(whole);
        let dst = s.dst.unwrap_or(src);
        // Clip the copy to the source and to the VRT (1:1, so one shift maps both).
        let (dx, dy) = (dst.x - src.x, dst.y - src.y);
        let x0 = src.x.max(0).max(-dx);
        let y0 = src.y.max(0).max(-dy);
        let x1 = (src.x + src.w as i64)
            .min(i64::from(info.width))
            .min(i64::from(vrt.width) - dx);
        let y1 = (src.y + src.h as i64)
            .min(i64::from(info.height))
            .min(i64::from(vrt.height) - dy);
        if x1 <= x0 || y1 <= y0 {
            tracing::warn!("{vrt_name}: source {name} draws nothing inside the VRT; skipped");
            continue;
        }
        pieces.push(Piece {
            path: s.path.clone(),
            name: format!("{vrt_name}: {name}"),
            format,
            sample_type: info.sample_type,
            x: (x0 + dx) as u32,
            y: (y0 + dy) as u32,
            w: (x1 - x0) as u32,
            h: (y1 - y0) as u32,
            src_x: x0 as u32,
            src_y: y0 as u32,
            src_width: info.width,
            src_height: info.height,
            nodata: nodata_values(nodata, &[info.nodata, s.nodata, vrt.nodata]),
            bytes: piece_bytes(reader.as_ref()),
            datum: vertical.datum_for(&s.path, reader.datum_clue()),
            warp: None,
            edge: Edge::Window([0, 0, vrt.width, vrt.height]),
            metres: None,
        });
    }
    if pieces.is_empty() {
        bail!("{vrt_name}: no source draws anything inside the VRT");
    }
    // The CRS is the one our readers find in the sources; the VRT gives the grid.
    // Sources that name no CRS PROJ can read (none, or only a name) take the VRT's.
    let crs = crs
        .filter(|g| vrt.srs.is_none() || g.epsg.is_some() || g.proj.is_some() || g.wkt.is_some());
    let georef = match (vrt.geotransform, crs) {
        (Some(geotransform), Some(crs)) => {
            if let (Some(vrt_code), Some(src_code)) =
                (vrt.srs.as_ref().and_then(crate::crs::Crs::epsg), crs.epsg)
                && vrt_code != src_code
            {
                bail!(
                    "{vrt_name}: its SRS is EPSG:{vrt_code} but its source {} is EPSG:{src_code}",
                    pieces[0].name
                );
            }
            let raster_type = match vrt.pixel_is_point {
                Some(true) => RasterType::PixelIsPoint,
                Some(false) => RasterType::PixelIsArea,
                None => crs.raster_type,
            };
            Some(GeoRef {
                geotransform,
                raster_type,
                ..crs
            })
        }
        // Sources with no CRS of their own take the VRT's SRS, as GDAL reads it.
        (Some(geotransform), None) if vrt.srs.is_some() => {
            let srs = vrt.srs.as_ref().expect("checked");
            let mut g = GeoRef {
                epsg: srs.epsg(),
                crs_name: None,
                proj: None,
                wkt: None,
                geotransform,
                raster_type: if vrt.pixel_is_point == Some(true) {
                    RasterType::PixelIsPoint
                } else {
                    RasterType::PixelIsArea
                },
            };
            srs.describe(&mut g);
            Some(g)
        }
        (Some(_), None) => {
            tracing::warn!(
                "{vrt_name}: its sources carry no CRS; the pyramid will have no georeferencing"
            );
            None
        }
        (None, _) => None,
    };
    Ok(Group {
        name: vrt_name,
        georef,
        width: vrt.width,
        height: vrt.height,
        pieces,
        is_vrt: true,
    })
}

/// Checks that every group shares the first's CRS and grid, and places them: the
/// mosaic's size, georeferencing and pieces in mosaic coordinates (in input order).
pub(super) fn place(groups: &[Group]) -> anyhow::Result<(u32, u32, Option<GeoRef>, Vec<Piece>)> {
    let first = &groups[0];
    if groups.len() == 1 {
        return Ok((
            first.width,
            first.height,
            first.georef.clone(),
            first.pieces.clone(),
        ));
    }
    let georef_of = |g: &Group| -> anyhow::Result<GeoRef> {
        g.georef.clone().with_context(|| {
            format!(
                "{}: has no georeferencing, so it cannot be placed in a mosaic",
                g.name
            )
        })
    };
    let g0 = georef_of(first)?;
    let gt0 = g0.geotransform;
    let (sx, sy) = (gt0[1], gt0[5]);
    if sx <= 0.0 || sy >= 0.0 {
        bail!(
            "{}: not north-up (pixel size {sx} × {sy}); only north-up rasters can be mosaicked",
            first.name
        );
    }
    let mut offsets = Vec::with_capacity(groups.len());
    for g in groups {
        let gi = georef_of(g)?;
        let gt = gi.geotransform;
        if !same_crs(&g0, &gi) {
            bail!(
                "{} and {}: different CRS ({} vs {})",
                first.name,
                g.name,
                crs_text(&g0),
                crs_text(&gi)
            );
        }
        // Spacings agree when the drift they cause over this input stays inside the
        // lattice tolerance.
        let drift_x = (gt[1] - sx).abs() * f64::from(g.width) / sx.abs();
        let drift_y = (gt[5] - sy).abs() * f64::from(g.height) / sy.abs();
        if drift_x > LATTICE_TOLERANCE
            || drift_y > LATTICE_TOLERANCE
            || gt[2] != 0.0
            || gt[4] != 0.0
        {
            bail!(
                "{} and {}: different spacing ({} × {} vs {} × {})",
                first.name,
                g.name,
                sx,
                -sy,
                gt[1],
                -gt[5]
            );
        }
        let ox = (gt[0] - gt0[0]) / sx;
        let oy = (gt[3] - gt0[3]) / sy;
        let (fx, fy) = (ox - ox.round(), oy - oy.round());
        if fx.abs() > LATTICE_TOLERANCE || fy.abs() > LATTICE_TOLERANCE {
            bail!(
                "{} and {}: origins are not on the same lattice ({} is {fx:.6} × {fy:.6} cells off)",
                first.name,
                g.name,
                g.name
            );
        }
        offsets.push((ox.round() as i64, oy.round() as i64));
    }
    let min_x = offsets.iter().map(|o| o.0).min().unwrap_or(0);
    let min_y = offsets.iter().map(|o| o.1).min().unwrap_or(0);
    let mut width = 0i64;
    let mut height = 0i64;
    for (g, (ox, oy)) in groups.iter().zip(&offsets) {
        width = width.max(ox - min_x + i64::from(g.width));
        height = height.max(oy - min_y + i64::from(g.height));
    }
    let (Ok(width), Ok(height)) = (u32::try_from(width), u32::try_from(height)) else {
        bail!("the inputs span {width}×{height} samples, more than a pyramid can hold");
    };
    // The origin: exactly the coordinates of the inputs that lie furthest west and north.
    let west = groups[offsets.iter().position(|o| o.0 == min_x).unwrap_or(0)]
        .georef
        .as_ref()
        .map_or(gt0[0], |g| g.geotransform[0]);
    let north = groups[offsets.iter().position(|o| o.1 == min_y).unwrap_or(0)]
        .georef
        .as_ref()
        .map_or(gt0[3], |g| g.geotransform[3]);
    let georef = GeoRef {
        geotransform: [west, sx, 0.0, north, 0.0, sy],
        ..g0
    };
    let mut pieces = Vec::new();
    for (g, (ox, oy)) in groups.iter().zip(&offsets) {
        for p in &g.pieces {
            let (dx, dy) = ((ox - min_x) as u32, (oy - min_y) as u32);
            pieces.push(Piece {
                x: p.x + dx,
                y: p.y + dy,
                edge: p.edge.shifted(dx, dy),
                ..p.clone()
            });
        }
    }
    Ok((width, height, Some(georef), pieces))
}

pub(super) fn names(groups: &[Group], pieces: &[Piece]) -> (String, String) {
    let more = |n: usize| {
        if n > 1 {
            format!(" and {} more", n - 1)
        } else {
            String::new()
        }
    };
    let first_file = file_name(&pieces[0].path);
    if let [g] = groups
        && g.is_vrt
    {
        let vrt = file_name(Path::new(&g.name));
        return (
            g.name.clone(),
            format!("{vrt}: {first_file}{}", more(pieces.len())),
        );
    }
    (
        format!("mosaic of {} inputs", pieces.len()),
        format!("{first_file}{}", more(pieces.len())),
    )
}

//! Inputs on different grids (other CRSs, spacings or lattices) placed on one target
//! grid (DECISIONS.md "Mixed-grid collections"): the CRS and spacing of the finest
//! input unless `--to`/`--spacing` say otherwise, on that input's lattice, covering
//! every input's footprint. An input already on the target grid is copied as it is;
//! any other is resampled onto its window of the target grid when the row cursor
//! reaches it ([`super::super::reproject::Reprojected::onto`]), so only the inputs
//! crossing the current row are open, as in a same-grid mosaic.
//!
//! Priority where inputs overlap, `--overlap finest` (the default here): the input
//! with the finest ground spacing (the geometric mean of its two spacings at its
//! centre) wins, ties by order; where it has no data the next one shows through.

use super::super::reproject::{self, Grid, Mapping, Resampling};
use super::{Group, LATTICE_TOLERANCE, OPEN_INPUT_BYTES, Overlap, Piece, crs_text};
use crate::crs::{Crs, ground_spacing};
use anyhow::{Context, bail};
use std::path::PathBuf;
use tessera_shared::{GeoRef, GroundSpacing, RasterType};

/// What shapes the target grid of a mixed-grid mosaic.
#[derive(Clone, Debug)]
pub struct GridOptions {
    /// `--to`: the target CRS; `None`: the finest input's.
    pub to: Option<String>,
    /// `--spacing` in the target CRS's units; `None`: the finest input's.
    pub spacing: Option<[f64; 2]>,
    pub resampling: Resampling,
    /// Where resampled inputs are spooled while open.
    pub spool_dir: PathBuf,
    /// `--max-samples`: a larger target grid is refused before anything else is done.
    pub max_samples: u64,
}

/// How an input off the target grid is read: resampled onto its window.
#[derive(Clone, Debug)]
pub(super) struct Warp {
    pub map: Mapping,
    /// The raw value that marks no-data in the source (before resampling).
    pub nodata: Option<f64>,
}

/// One input of a mixed-grid mosaic, as its header describes it.
pub(super) struct Source {
    pub crs: Crs,
    pub georef: GeoRef,
    pub spacing: GroundSpacing,
}

impl Source {
    /// Metres per sample, one number: the geometric mean of the two spacings.
    pub fn fineness(&self) -> f64 {
        (self.spacing.x * self.spacing.y).sqrt()
    }

    /// Whether this input is finer than `other`: by more than a millionth, so that
    /// inputs of one resolution whose spacings differ by rounding (a piece moved by
    /// half a cell) tie, and their order decides.
    pub fn finer_than(&self, other: &Self) -> bool {
        self.fineness() < other.fineness() * (1.0 - 1e-6)
    }
}

/// Indices of `sources` finest first, ties (within a millionth) in input order.
fn by_fineness(sources: &[Source]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..sources.len()).collect();
    // Insertion sort: stable, and `finer_than` is not a total order for sort_by.
    for i in 1..order.len() {
        let mut j = i;
        while j > 0 && sources[order[j]].finer_than(&sources[order[j - 1]]) {
            order.swap(j, j - 1);
            j -= 1;
        }
    }
    order
}

/// The mosaic's size, georeferencing and pieces (in priority order for
/// [`Overlap::Finest`], else in input order), and each input's description.
pub(super) struct Placed {
    pub width: u32,
    pub height: u32,
    pub georef: GeoRef,
    pub pieces: Vec<Piece>,
    pub sources: Vec<Source>,
}

fn same_crs(a: &Crs, b: &Crs) -> bool {
    (a.epsg().is_some() && a.epsg() == b.epsg()) || a == b
}

pub(super) fn source_of(g: &Group) -> anyhow::Result<Source> {
    let georef = g.georef.clone().with_context(|| {
        format!(
            "{}: has no georeferencing, so it cannot be placed in a mosaic",
            g.name
        )
    })?;
    let gt = georef.geotransform;
    if gt[1] <= 0.0 || gt[5] >= 0.0 || gt[2] != 0.0 || gt[4] != 0.0 {
        bail!(
            "{}: not north-up (pixel size {} × {}); only north-up rasters can be mosaicked",
            g.name,
            gt[1],
            gt[5]
        );
    }
    let crs = Crs::of(&georef).with_context(|| {
        format!(
            "{}: its CRS ({}) cannot be identified, so it cannot be resampled onto the \
             others' grid; give it one PROJ reads (a .prj beside it, or a VRT with <SRS>)",
            g.name,
            crs_text(&georef)
        )
    })?;
    let spacing = ground_spacing(&georef, g.width, g.height)
        .with_context(|| format!("{}: no ground spacing", g.name))?;
    Ok(Source {
        crs,
        georef,
        spacing,
    })
}

/// Snaps `v` (in cells) down or up to a whole cell, treating values within the
/// lattice tolerance of one as on it.
fn snap(v: f64, up: bool) -> f64 {
    let r = v.round();
    if (v - r).abs() <= LATTICE_TOLERANCE {
        r
    } else if up {
        v.ceil()
    } else {
        v.floor()
    }
}

/// Places groups on different grids onto one target grid (see the module docs).
pub(super) fn place_mixed(
    groups: &[Group],
    grid: &GridOptions,
    overlap: Overlap,
) -> anyhow::Result<Placed> {
    let sources: Vec<Source> = groups
        .iter()
        .map(source_of)
        .collect::<anyhow::Result<_>>()?;
    let order = by_fineness(&sources);
    let finest = order[0];
    let fs = &sources[finest];
    let target = match &grid.to {
        Some(to) => Crs::parse(to).with_context(|| format!("--to {to}"))?,
        None => fs.crs.clone(),
    };
    let fgt = fs.georef.geotransform;
    let on_finest_crs = same_crs(&fs.crs, &target);
    let [sx, sy] = match grid.spacing {
        Some(s) => s,
        None if on_finest_crs => [fgt[1], -fgt[5]],
        None => reproject::source_step(
            &fs.crs,
            &target,
            &fgt,
            groups[finest].width as usize,
            groups[finest].height as usize,
        )?,
    };
    // The union of the footprints, then the lattice: the finest input's when the
    // target is its CRS and spacing, else the union's north-west corner.
    let mut boxes = Vec::with_capacity(groups.len());
    for (g, s) in groups.iter().zip(&sources) {
        let b = reproject::footprint(
            &s.crs,
            &target,
            &s.georef.geotransform,
            g.width as usize,
            g.height as usize,
        )
        .with_context(|| format!("{}: to {}", g.name, target.label()))?;
        boxes.push(b);
    }
    let corners: Vec<[f64; 2]> = boxes
        .iter()
        .flat_map(|b| [[b[0], b[1]], [b[2], b[3]]])
        .collect();
    let union = reproject::bounds(&corners);
    let (ox, oy) =
        if on_finest_crs && (sx - fgt[1]).abs() < 1e-12 * sx && (sy + fgt[5]).abs() < 1e-12 * sy {
            (fgt[0], fgt[3])
        } else {
            (union[0], union[3])
        };
    let west = ox + snap((union[0] - ox) / sx, false) * sx;
    let north = oy + snap((union[3] - oy) / sy, true) * sy;
    let cols = snap((union[2] - west) / sx, true);
    let rows = snap((north - union[1]) / sy, true);
    if !(cols >= 1.0 && rows >= 1.0 && cols <= f64::from(u32::MAX) && rows <= f64::from(u32::MAX)) {
        bail!(
            "the inputs' target grid would be {cols} × {rows} samples of {sx} × {sy} {} \
             units: not a size a pyramid can hold (check --spacing)",
            target.label()
        );
    }
    if cols * rows > grid.max_samples as f64 {
        bail!(
            "the inputs' common grid would be {cols} × {rows} = {:.3e} samples of {sx} × {sy} \
             ({}), more than --max-samples {}: check --spacing, or raise --max-samples",
            cols * rows,
            target.label(),
            grid.max_samples
        );
    }
    let (width, height) = (cols as u32, rows as u32);
    let mut georef = GeoRef {
        epsg: target.epsg(),
        crs_name: None,
        proj: None,
        wkt: None,
        geotransform: [west, sx, 0.0, north, 0.0, -sy],
        raster_type: RasterType::PixelIsArea,
    };
    target.describe(&mut georef);

    let mut pieces: Vec<(usize, Piece)> = Vec::new();
    for (gi, (g, s)) in groups.iter().zip(&sources).enumerate() {
        let gt = s.georef.geotransform;
        let drift_x = (gt[1] - sx).abs() * f64::from(g.width) / sx;
        let drift_y = (-gt[5] - sy).abs() * f64::from(g.height) / sy;
        let (cx, cy) = ((gt[0] - west) / sx, (north - gt[3]) / sy);
        let on_grid = same_crs(&s.crs, &target)
            && drift_x <= LATTICE_TOLERANCE
            && drift_y <= LATTICE_TOLERANCE
            && (cx - cx.round()).abs() <= LATTICE_TOLERANCE
            && (cy - cy.round()).abs() <= LATTICE_TOLERANCE;
        if on_grid {
            for p in &g.pieces {
                pieces.push((
                    gi,
                    Piece {
                        x: p.x + cx.round() as u32,
                        y: p.y + cy.round() as u32,
                        edge: p.edge.shifted(cx.round() as u32, cy.round() as u32),
                        metres: Some(s.fineness()),
                        ..p.clone()
                    },
                ));
            }
            continue;
        }
        for p in &g.pieces {
            // The file behind the piece: the group's grid shifted to the piece (a
            // VRT copies its sources 1:1).
            let src_gt = [
                gt[0] + (f64::from(p.x) - f64::from(p.src_x)) * gt[1],
                gt[1],
                0.0,
                gt[3] + (f64::from(p.y) - f64::from(p.src_y)) * gt[5],
                0.0,
                gt[5],
            ];
            let (w, h) = (p.src_width as usize, p.src_height as usize);
            let b = reproject::footprint(&s.crs, &target, &src_gt, w, h)
                .with_context(|| p.name.clone())?;
            let c0 = snap((b[0] - west) / sx, false).max(0.0);
            let c1 = snap((b[2] - west) / sx, true).min(cols);
            let r0 = snap((north - b[3]) / sy, false).max(0.0);
            let r1 = snap((north - b[1]) / sy, true).min(rows);
            if c1 <= c0 || r1 <= r0 {
                continue;
            }
            let out = Grid {
                width: (c1 - c0) as u32,
                height: (r1 - r0) as u32,
                gt: [west + c0 * sx, sx, 0.0, north - r0 * sy, 0.0, -sy],
            };
            let map = Mapping {
                source: s.crs.clone(),
                target: target.clone(),
                src_gt,
                src_w: w,
                src_h: h,
                out,
                resampling: grid.resampling,
            };
            let bytes = p.bytes + map.buffer_bytes() + u64::from(out.width) * 4 + OPEN_INPUT_BYTES;
            pieces.push((
                gi,
                Piece {
                    x: c0 as u32,
                    y: r0 as u32,
                    w: out.width,
                    h: out.height,
                    src_x: 0,
                    src_y: 0,
                    src_width: out.width,
                    src_height: out.height,
                    sample_type: match grid.resampling {
                        Resampling::Nearest => p.sample_type,
                        Resampling::Bilinear | Resampling::Cubic => super::SampleType::Float32,
                    },
                    nodata: Vec::new(),
                    bytes,
                    warp: Some(Box::new(Warp {
                        map,
                        nodata: p.nodata.first().map(|&v| f64::from(v)),
                    })),
                    edge: super::Edge::Resampled {
                        metres_per_sample: s.fineness(),
                    },
                    metres: Some(s.fineness()),
                    ..p.clone()
                },
            ));
        }
    }
    if overlap == Overlap::Finest {
        let rank: Vec<usize> = {
            let mut r = vec![0; order.len()];
            for (k, &i) in order.iter().enumerate() {
                r[i] = k;
            }
            r
        };
        // Stable: the pieces of one input keep their order.
        pieces.sort_by_key(|(gi, _)| rank[*gi]);
    }
    Ok(Placed {
        width,
        height,
        georef,
        pieces: pieces.into_iter().map(|(_, p)| p).collect(),
        sources,
    })
}

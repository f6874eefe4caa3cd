// Reference values from GDAL's command-line tools (gdal-bin), never from our server.
import { execFileSync } from 'node:child_process';

export function gdalinfo(file) {
  return JSON.parse(execFileSync('gdalinfo', ['-json', file], { encoding: 'utf8' }));
}

// The dataset's footprint in WGS84 as GDAL computes it: the polygon of `wgs84Extent` and its
// [west, south, east, north].
export function wgs84Footprint(file) {
  const ring = gdalinfo(file).wgs84Extent.coordinates[0].slice(0, -1);
  const lons = ring.map((p) => p[0]), lats = ring.map((p) => p[1]);
  return { polygon: ring, bounds: [Math.min(...lons), Math.min(...lats), Math.max(...lons), Math.max(...lats)] };
}

function locationValues(file, points, extra = []) {
  const input = points.map((p) => p.join(' ')).join('\n') + '\n';
  const out = execFileSync('gdallocationinfo', ['-valonly', ...extra, file], { input, encoding: 'utf8' });
  return out.trim().split('\n').map(Number);
}

// Heights of a geographic (EPSG:4326) DEM at [lon, lat]: `nearest` is gdallocationinfo's own
// value (the sample whose cell holds the point); `bilinear` is computed here from the 2×2 samples
// around the point with the geotransform (sample (i, j) stands at the centre of its cell, as
// GDAL's geotransform describes it); `samples` are those four (null for no-data) and `range` the
// spread of the valid ones; `range4` is the spread of the valid samples of the 4×4 block around
// the point (the samples a right Web Mercator tile can draw on there, README.md "Heights"). Where some of the four are no-data (N46E008 has SRTM voids) the
// weights of the valid ones are renormalised, as gdalwarp's bilinear kernel does. `block` is that
// 4×4 block row by row (null for no-data; the 2×2 are block[5], [6], [9], [10]), `cell` the
// sample (i, j) at the 2×2's north-west corner and `t` the point's fraction [tx, ty] of the cell.
export function heights(file, lonLats) {
  const info = gdalinfo(file);
  const [x0, dx, , y0, , dy] = info.geoTransform;
  const nodata = info.bands[0].noDataValue;
  const nearest = locationValues(file, lonLats, ['-wgs84']);
  return lonLats.map(([lon, lat], k) => {
    const fx = (lon - x0) / dx - 0.5, fy = (lat - y0) / dy - 0.5;
    const i = Math.floor(fx), j = Math.floor(fy), tx = fx - i, ty = fy - j;
    const block = []; // the 4×4 samples i-1 … i+2, j-1 … j+2, row by row
    for (let b = -1; b <= 2; b++) for (let a = -1; a <= 2; a++) block.push([i + a, j + b]);
    const s16 = locationValues(file, block).map((v) => (v === nodata ? null : v));
    const s = [s16[5], s16[6], s16[9], s16[10]];
    const valid16 = s16.filter((v) => v !== null);
    const w = [(1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty];
    let sum = 0, weight = 0;
    s.forEach((v, q) => { if (v !== null) { sum += v * w[q]; weight += w[q]; } });
    if (weight === 0) throw new Error(`only no-data around ${lon}, ${lat} in ${file}`);
    const valid = s.filter((v) => v !== null);
    return { lon, lat, nearest: nearest[k], bilinear: sum / weight, samples: s, voids: 4 - valid.length,
      range: Math.max(...valid) - Math.min(...valid), range4: Math.max(...valid16) - Math.min(...valid16),
      voids4: 16 - valid16.length, block: s16, t: [tx, ty], cell: [i, j], spacing: [dx, -dy] };
  });
}

// The lowest and highest valid sample (`gdalinfo -mm`: GDAL computes them exactly).
export function minMax(file) {
  const band = JSON.parse(execFileSync('gdalinfo', ['-json', '-mm', file], { encoding: 'utf8' })).bands[0];
  return [band.computedMin, band.computedMax];
}

// GDAL's bilinear height at many [lon, lat] points of a geographic DEM at once (one
// gdallocationinfo run): the 2×2 samples around each point, at their cells' centres, weighted by
// the point's fractions. `null` where any of the four is no-data (no renormalising here: the
// half-pixel test wants points where the value is the plain bilinear one).
export function bilinearAt(file, lonLats) {
  const info = gdalinfo(file);
  const [x0, dx, , y0, , dy] = info.geoTransform;
  const nodata = info.bands[0].noDataValue;
  const cells = lonLats.map(([lon, lat]) => {
    const fx = (lon - x0) / dx - 0.5, fy = (lat - y0) / dy - 0.5;
    const i = Math.floor(fx), j = Math.floor(fy);
    return { i, j, tx: fx - i, ty: fy - j };
  });
  const points = cells.flatMap(({ i, j }) => [[i, j], [i + 1, j], [i, j + 1], [i + 1, j + 1]]);
  const v = locationValues(file, points);
  return cells.map(({ tx, ty }, k) => {
    const s = v.slice(4 * k, 4 * k + 4);
    if (s.some((x) => x === nodata || Number.isNaN(x))) return null;
    return s[0] * (1 - tx) * (1 - ty) + s[1] * tx * (1 - ty) + s[2] * (1 - tx) * ty + s[3] * tx * ty;
  });
}

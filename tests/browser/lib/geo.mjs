// Small geometry helpers: Web Mercator tile bounds and polygon/rectangle overlap.

// [west, south, east, north] in degrees of XYZ tile z/x/y.
export function tileBounds(z, x, y) {
  const n = 2 ** z;
  const lon = (i) => (i / n) * 360 - 180;
  const lat = (j) => (Math.atan(Math.sinh(Math.PI * (1 - (2 * j) / n))) * 180) / Math.PI;
  return [lon(x), lat(y + 1), lon(x + 1), lat(y)];
}

// The XYZ tile at zoom z holding [lon, lat].
export function tileAt(z, lon, lat) {
  const n = 2 ** z, r = (lat * Math.PI) / 180;
  return { z, x: Math.floor(((lon + 180) / 360) * n),
    y: Math.floor(((1 - Math.log(Math.tan(r) + 1 / Math.cos(r)) / Math.PI) / 2) * n) };
}

// Area (in degrees², unprojected) of `polygon` clipped to the rectangle [w, s, e, n]
// (Sutherland–Hodgman; the polygon is convex here: a DEM's footprint).
export function overlapArea(polygon, [w, s, e, n]) {
  const clip = (pts, inside, cut) => {
    const out = [];
    for (let i = 0; i < pts.length; i++) {
      const a = pts[i], b = pts[(i + 1) % pts.length];
      if (inside(a)) { out.push(a); if (!inside(b)) out.push(cut(a, b)); } else if (inside(b)) out.push(cut(a, b));
    }
    return out;
  };
  const atX = (x) => (a, b) => [x, a[1] + ((b[1] - a[1]) * (x - a[0])) / (b[0] - a[0])];
  const atY = (y) => (a, b) => [a[0] + ((b[0] - a[0]) * (y - a[1])) / (b[1] - a[1]), y];
  let p = polygon;
  p = clip(p, (q) => q[0] >= w, atX(w));
  p = clip(p, (q) => q[0] <= e, atX(e));
  p = clip(p, (q) => q[1] >= s, atY(s));
  p = clip(p, (q) => q[1] <= n, atY(n));
  let a = 0;
  for (let i = 0; i < p.length; i++) { const u = p[i], v = p[(i + 1) % p.length]; a += u[0] * v[1] - v[0] * u[1]; }
  return Math.abs(a) / 2;
}

// Whether a tile lies wholly outside the footprint, to within one of its pixels: the tile shrunk
// by one pixel on every side does not overlap it. (A tile touching the data by less than a pixel
// may hold no pixel centre inside it, so a 404 for it is right too.)
export function tileOutside(polygon, { z, x, y }, tileSize) {
  const [w, s, e, n] = tileBounds(z, x, y);
  const dx = (e - w) / tileSize, dy = (n - s) / tileSize;
  return overlapArea(polygon, [w + dx, s + dy, e - dx, n - dy]) === 0;
}

// The centre of pixel (i, j) of XYZ tile z/x/y of `size` pixels, shifted by (di, dj) pixels, as
// [lon, lat]: pixel i spans [i, i + 1) of the tile's `size`, its centre at i + ½ (what MapLibre
// and GDAL both mean by a raster pixel).
export function pixelCentre(z, x, y, size, i, j, di = 0, dj = 0) {
  const n = 2 ** z * size;
  const px = x * size + i + 0.5 + di, py = y * size + j + 0.5 + dj;
  return [(px / n) * 360 - 180, (Math.atan(Math.sinh(Math.PI * (1 - (2 * py) / n))) * 180) / Math.PI];
}

// The tile and pixel of `size`-pixel XYZ tiles at zoom z holding [lon, lat].
export function pixelAt(z, size, lon, lat) {
  const n = 2 ** z * size, r = (lat * Math.PI) / 180;
  const px = ((lon + 180) / 360) * n, py = ((1 - Math.log(Math.tan(r) + 1 / Math.cos(r)) / Math.PI) / 2) * n;
  const X = Math.floor(px), Y = Math.floor(py);
  return { z, x: Math.floor(X / size), y: Math.floor(Y / size), i: X % size, j: Y % size };
}

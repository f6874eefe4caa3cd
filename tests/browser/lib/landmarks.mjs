// The landmarks of the CesiumJS tests (cesium.test.mjs: quantized-mesh, cesium3dtiles.test.mjs:
// 3D Tiles) on N46E008 and how a height CesiumJS gives there is judged against the DEM (GDAL's
// bilinear sample plus PROJ's EGM96 undulation); README.md "CesiumJS" explains the tolerance.

// Landmarks, with their height to the metre for the log (SRTM, metres above EGM96); the tests
// compare Cesium with the DEM's own bilinear sample there, not with these.
export const LANDMARKS = [
  { name: 'Urnersee', lonLat: [8.61, 46.93], approx: 431 },
  { name: 'Andermatt', lonLat: [8.5911, 46.635], approx: 1436 },
  { name: 'Lago Maggiore', lonLat: [8.70, 46.10], approx: 191 },
  { name: 'Tödi shoulder', lonLat: [8.9183, 46.8133], approx: 3543 },
  { name: 'Finsteraarhorn massif', lonLat: [8.1258, 46.5367], approx: 4173 },
];
export const FINSTERAARHORN = LANDMARKS[4].lonLat, LAGO_MAGGIORE = LANDMARKS[2].lonLat;

// Tolerance of a Cesium height against the DEM's bilinear surface plus the geoid:
//   ε + |twist| / 4 + DECODE.
// ε = levelZeroGeometricError / 2^maxzoom from layer.json's metadata: the server's bound on how far
// the deepest zoom's mesh is from the DEM's samples (RTIN, quantization included). Every
// triangle of such a mesh has its vertices at samples and its edges along grid lines or cell
// diagonals, so in the cell around the point the mesh is one plane, or one plane on each side of
// a diagonal. Where one plane f covers the cell, f − bilinear is itself bilinear (f has no
// twist), so it peaks at a corner: ≤ ε. Where a diagonal splits the cell, f on a half equals the
// linear interpolation of its three corners (each within ε), and a triangle's linear
// interpolation differs from the bilinear surface by at most |q00 + q11 − q10 − q01| / 4 (at the
// diagonal's middle): ≤ ε + |twist| / 4. The server adds the geoid per vertex; EGM96 bends by
// far less than a millimetre across a 90 m cell, so N at the point is exact enough.
// DECODE covers CesiumJS's decoding (float32 header heights, 1/32767 height steps over the tile's
// range) and its interpolation in the decoded triangle.
export const DECODE = 0.5; // m

// The DEM's bilinear surface at the point from the 2×2 samples around it (GDAL's, lib/gdal.mjs),
// and the cell's twist |q00 + q11 − q10 − q01|. SRTM voids: the pyramid fills a no-data sample
// with its nearest valid sample by a 3-4 chamfer distance (FORMAT.md), i.e. with one of its valid
// edge neighbours if it has any, else one of its valid diagonal ones. Which one on a tie is the
// build's business, so every candidate is tried: `lo`…`hi` is the range of the bilinear value and
// `twist` the largest twist over them. Without voids lo = hi = GDAL's bilinear.
export function dem(ref) {
  const at = (a, b) => ref.block[(b + 1) * 4 + (a + 1)];
  const corners = [[0, 0], [1, 0], [0, 1], [1, 1]];
  const candidates = corners.map(([a, b]) => {
    if (at(a, b) !== null) return [at(a, b)];
    const edge = [[a - 1, b], [a + 1, b], [a, b - 1], [a, b + 1]].map(([p, q]) => at(p, q)).filter((v) => v !== null);
    const diag = [[a - 1, b - 1], [a + 1, b - 1], [a - 1, b + 1], [a + 1, b + 1]].map(([p, q]) => at(p, q)).filter((v) => v !== null);
    if (edge.length + diag.length === 0) throw new Error(`void at ${ref.lon}, ${ref.lat} without a valid neighbour`);
    return edge.length ? edge : diag;
  });
  const [tx, ty] = ref.t;
  const w = [(1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty];
  let lo = Infinity, hi = -Infinity, twist = 0;
  for (const q00 of candidates[0]) for (const q10 of candidates[1]) for (const q01 of candidates[2]) for (const q11 of candidates[3]) {
    const v = w[0] * q00 + w[1] * q10 + w[2] * q01 + w[3] * q11;
    lo = Math.min(lo, v); hi = Math.max(hi, v);
    twist = Math.max(twist, Math.abs(q00 + q11 - q10 - q01));
  }
  return { lo, hi, twist, gdal: ref.bilinear };
}

// Judges `samples` ({ height, level } per landmark, from CesiumJS) against the DEM: `refs` (GDAL,
// lib/gdal.mjs `heights`), `geoid` (undulations), ε and the deepest zoom, which every sample must
// come from. Logs a table; returns the failures (empty when every height is within tolerance).
export function judgeHeights({ samples, refs, geoid, levelZeroError, maxzoom }) {
  const epsilon = levelZeroError / 2 ** maxzoom;
  const rows = [], failures = [];
  for (const [k, landmark] of LANDMARKS.entries()) {
    const r = dem(refs[k]);
    const tol = epsilon + r.twist / 4 + DECODE;
    const { height, level } = samples[k];
    const lo = r.lo + geoid[k], hi = r.hi + geoid[k];
    const diff = height < lo ? height - lo : height > hi ? height - hi : 0; // from the bilinear (range, over voids)
    rows.push({ landmark: landmark.name, approx: landmark.approx, bilinear: r, N: geoid[k], cesium: height, level, diff, tol });
    if (!(Math.abs(diff) <= tol) || level !== maxzoom) {
      failures.push(`${landmark.name}: Cesium ${height} m at level ${level}, expected ${lo.toFixed(2)}…${hi.toFixed(2)} ±${tol.toFixed(2)} m at level ${maxzoom}`);
    }
  }
  const f = (v) => v.toFixed(2);
  console.log(`# ε = levelZeroGeometricError ${f(levelZeroError)} m / 2^${maxzoom} = ${f(epsilon)} m`);
  console.log('# | landmark | approx. | DEM bilinear | +N (EGM96) | = expected | Cesium | diff | tolerance |');
  for (const r of rows) {
    const b = r.bilinear.lo === r.bilinear.hi ? f(r.bilinear.lo) : `${f(r.bilinear.lo)}…${f(r.bilinear.hi)} (void fill; GDAL ${f(r.bilinear.gdal)})`;
    const e = r.bilinear.lo === r.bilinear.hi ? f(r.bilinear.lo + r.N) : `${f(r.bilinear.lo + r.N)}…${f(r.bilinear.hi + r.N)}`;
    console.log(`# | ${r.landmark} | ~${r.approx} m | ${b} m | +${r.N.toFixed(3)} m | ${e} m | ${f(r.cesium)} m (z${r.level}) | ` +
      `${r.diff >= 0 ? '+' : ''}${f(r.diff)} m | ±${f(r.tol)} m (ε ${f(epsilon)} + twist/4 ${f(r.bilinear.twist / 4)} + ${DECODE}) |`);
  }
  return failures;
}

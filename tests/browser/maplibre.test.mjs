// Tessera's Web Mercator outputs in MapLibre GL JS, in headless Chromium (DECISIONS.md
// "Browser tests"; docs/ARCHITECTURE.md#derived-outputs). Run by ./run.sh; README.md explains the
// thresholds and tolerances.
import assert from 'node:assert/strict';
import http from 'node:http';
import path from 'node:path';
import { after, before, test } from 'node:test';
import { bilinearAt, heights, minMax, wgs84Footprint } from './lib/gdal.mjs';
import { pixelAt, pixelCentre, tileAt, tileOutside } from './lib/geo.mjs';
import { DATA, buildPyramids, launchBrowser, openPage, screenshot, startStaticServer, startTileServer } from './lib/harness.mjs';

const DATASETS = ['N46E008', 'aletsch'];
const TILE_SIZE = 512;
const VIEW = 800; // viewport, px (square)
const TERRAIN_VIEW = 400; // the terrain views: SwiftShader draws 3D terrain slowly
const PADDING = 160; // margin around the dataset in the placement views, px

// Placement thresholds (README.md "Placement"). Measured with a right implementation: inside
// ≥ 0.99 and coverage ≥ 0.9 for both datasets; a DEM stretched over the world gives inside
// ≈ the footprint's share of the screen (≤ 0.45 here), one shifted by half the dataset
// ≈ 0.5, a TMS/XYZ row flip nothing at all.
const MIN_INSIDE = 0.97;
const MIN_COVERAGE = 0.8;

// Heights (README.md "Heights" has the derivation): |MapLibre − GDAL bilinear| ≤ ABS_TOL +
// REL_TOL × (spread of the 4×4 DEM samples around the point). MapLibre interpolates bilinearly
// between Web Mercator pixels (spacing p), each of which a right server resamples from the DEM
// samples around its centre (spacing h); at maxzoom p ≤ h, so the value MapLibre gives is a
// weighted mean of the 4×4 samples around the point, mostly of the inner 2×2 ones (the
// reference's): REL_TOL bounds the weight that can move to the outer ring; ABS_TOL covers the
// Terrarium quantisation (1/256 m) and a server rounding to decimetres, with margin.
const ABS_TOL = 2; // m
const REL_TOL = 0.25;

// MapLibre 6's 3D terrain reads its DEM two zooms below the map's zoom for a 512-px source: its
// terrain tiles are the source's tile size · 2^deltaZoom = 1024 px (one zoom down), and each reads
// the DEM tile deltaZoom = 1 further down (TerrainTileManager). So the map goes to maxzoom + 2 for
// the terrain to read maxzoom tiles (at maxzoom + 1 it reads maxzoom − 1: measured, 15–25 m off
// GDAL at sharp summits, what was once taken for half a pixel: README.md "Pixel centres").
const DEM_ZOOM_OFFSET = 2;

const LANDMARKS = [
  { name: 'Urnersee', lonLat: [8.61, 46.93] },
  { name: 'Andermatt', lonLat: [8.5911, 46.635] },
  { name: 'Lago Maggiore', lonLat: [8.70, 46.10] },
  { name: 'Tödi shoulder', lonLat: [8.9183, 46.8133] },
  { name: 'Finsteraarhorn massif', lonLat: [8.1258, 46.5367] },
];

const footprints = Object.fromEntries(DATASETS.map((d) => [d, wgs84Footprint(path.join(DATA, `${d}.tif`))]));
let tiles, pages, browser;

before(async () => {
  const dir = process.env.TESSERA_TILE_SERVER ? null : buildPyramids(DATASETS);
  tiles = await startTileServer(dir);
  pages = await startStaticServer();
  browser = await launchBrowser();
});

after(async () => {
  await browser?.close();
  await pages?.stop();
  await tiles?.stop();
});

// A 404 is expected only for a tile wholly outside the dataset's true footprint (GDAL's), which
// API.md documents as absent; any other status ≥ 400, any failed request and any console error
// fails the test.
function assertNoProblems(problems, dataset) {
  const expected = (r) => r.status === 404 && r.tile && tileOutside(footprints[dataset].polygon, r.tile, TILE_SIZE);
  const unexpected = problems.responses.filter((r) => !expected(r));
  const expectedUrls = new Set(problems.responses.filter(expected).map((r) => r.url));
  const consoleErrors = problems.console.filter((m) =>
    !(m.text.startsWith('Failed to load resource: the server responded with a status of 404') && expectedUrls.has(m.url)));
  assert.deepEqual(consoleErrors, [], 'console errors');
  assert.deepEqual(problems.failed, [], 'failed requests');
  assert.deepEqual(unexpected, [], 'HTTP errors other than 404s of tiles outside the data');
}

// A request from node with the page's Origin (and, for OPTIONS, a CORS preflight's headers).
function request(url, method) {
  const headers = { Origin: pages.url, ...(method === 'OPTIONS' ? { 'Access-Control-Request-Method': 'GET' } : {}) };
  return new Promise((resolve, reject) => {
    const req = http.request(url, { method, headers }, (res) => { res.resume(); resolve(res); });
    req.on('error', reject);
    req.end();
  });
}

for (const dataset of DATASETS) {
  test(`${dataset}: TileJSON and CORS`, async () => {
    const { page, problems } = await openPage(browser, pages.url, { width: 200, height: 200 });
    // fetched from the page: a cross-origin request, so it fails without CORS headers
    const tj = await page.evaluate(async (server, name) => {
      const r = await fetch(`${server}/v1/datasets/${name}/webmercator/tilejson.json?encoding=terrarium&size=512`);
      return { status: r.status, doc: await r.json() };
    }, tiles.url, dataset);
    await page.close();
    assert.equal(tj.status, 200);
    const doc = tj.doc;
    assert.equal(doc.tilejson, '3.0.0');
    assert.equal(doc.scheme, 'xyz');
    assert.equal(doc.tileSize, TILE_SIZE);
    assert.equal(doc.encoding, 'terrarium');
    assert.ok(Array.isArray(doc.tiles) && doc.tiles.length > 0 && doc.tiles.every((t) => /\{z\}.*\{x\}.*\{y\}/.test(t)), `tiles ${doc.tiles}`);
    // With the server's default flags the templates must work from this page's origin: absolute,
    // on the tile server (MapLibre fetches relative ones from the page's origin: all 404)
    doc.tiles.forEach((t) => assert.ok(t.startsWith(`${tiles.url}/v1/datasets/${dataset}/webmercator/`), `tile template ${t} is not on ${tiles.url}`));
    assert.ok(Number.isInteger(doc.minzoom) && Number.isInteger(doc.maxzoom) && doc.minzoom <= doc.maxzoom);
    // bounds within one DEM cell of GDAL's footprint (N46E008: 0.00083°; aletsch: 200 m ≈ 0.003°)
    const cell = dataset === 'aletsch' ? 0.003 : 0.00084;
    const gdal = footprints[dataset].bounds;
    assert.equal(doc.bounds.length, 4);
    doc.bounds.forEach((v, i) => assert.ok(Math.abs(v - gdal[i]) <= cell, `bounds ${doc.bounds} vs GDAL ${gdal}`));
    assert.equal(doc.center.length >= 2, true);
    // the page cannot read Access-Control-Allow-Origin (not a safelisted header), so the
    // header and the preflight are checked from here
    const get = await request(`${tiles.url}/v1/datasets/${dataset}/webmercator/tilejson.json?encoding=terrarium&size=512`, 'GET');
    assert.equal(get.headers['access-control-allow-origin'], '*');
    // built from the request's Host, so private to the client: no shared cache hands it to another
    assert.match(get.headers['cache-control'] ?? '', /^private/, 'TileJSON from the Host must be private');
    assert.match(get.headers.vary ?? '', /host/i);
    const preflight = await request(`${tiles.url}/v1/datasets/${dataset}/webmercator/0/0/0.png?encoding=terrarium&size=512`, 'OPTIONS');
    assert.ok(preflight.statusCode >= 200 && preflight.statusCode < 300, `preflight status ${preflight.statusCode}`);
    assert.equal(preflight.headers['access-control-allow-origin'], '*');
    assertNoProblems(problems, dataset);
  });

  test(`${dataset}: hillshade lands on the dataset's footprint`, async () => {
    const { page, problems } = await openPage(browser, pages.url, { width: VIEW, height: VIEW });
    const { polygon, bounds } = footprints[dataset];
    const { zoom } = await page.evaluate((server, name, b, p) =>
      window.tessera.open({ server, dataset: name, mode: 'placement', view: { bounds: b, padding: p } }), tiles.url, dataset, bounds, PADDING);
    const file = await screenshot(page, `placement-${dataset}`);
    const m = await page.evaluate((poly) => window.tessera.placement(poly), polygon);
    await page.close();
    const drawn = m.drawnIn + m.drawnBand + m.drawnOut;
    const inside = drawn ? (m.drawnIn + m.drawnBand) / drawn : 0;
    const coverage = m.drawnIn / m.area;
    console.log(`# placement ${dataset}: zoom ${zoom.toFixed(2)}, footprint ${m.area} px of ${m.width}×${m.height}, ` +
      `drawn ${drawn} px (${m.drawnBand} within 2 px of its edge, ${m.drawnOut} beyond), inside ${inside.toFixed(4)}, coverage ${coverage.toFixed(4)} (${path.relative(process.cwd(), file)})`);
    assert.ok(inside >= MIN_INSIDE, `${dataset}: only ${(inside * 100).toFixed(1)} % of the hillshade lies on the footprint (need ${MIN_INSIDE * 100} %)`);
    assert.ok(coverage >= MIN_COVERAGE, `${dataset}: the hillshade covers only ${(coverage * 100).toFixed(1)} % of the footprint (need ${MIN_COVERAGE * 100} %)`);
    assertNoProblems(problems, dataset);
  });
}

// Two landmarks (the Tödi shoulder, the Finsteraarhorn massif) are valid samples beside SRTM
// voids. Void pixels are alpha 0, and MapLibre ignores alpha in raster-dem tiles (its canvas
// read zeroes their RGB: Terrarium −32768 m), so a bilinear lookup that touched one would sink
// into a pit. The server's maxzoom puts at least 2×2 tile pixels on every sample's own pixel
// area (server/src/web/footprint.rs), so at a sample the lookup reads that sample only: these
// landmarks are held to the same tolerance as the others (README.md "Voids").
test('N46E008: terrain heights at five landmarks match GDAL', async () => {
  const dataset = 'N46E008';
  const refs = heights(path.join(DATA, `${dataset}.tif`), LANDMARKS.map((l) => l.lonLat));
  const { page, problems } = await openPage(browser, pages.url, { width: TERRAIN_VIEW, height: TERRAIN_VIEW });
  const tj = await page.evaluate((server, name, c) => window.tessera.open({ server, dataset: name, mode: 'terrain',
    view: { center: c, zoom: 'maxzoom' } }), tiles.url, dataset, LANDMARKS[0].lonLat);
  const failures = [];
  for (const [k, landmark] of LANDMARKS.entries()) {
    const ref = refs[k];
    await page.evaluate((c, z) => window.tessera.jump(c, z), landmark.lonLat, tj.maxzoom + DEM_ZOOM_OFFSET);
    // the maxzoom tile under the landmark must have loaded and the value settled (not null, the
    // same twice 200 ms apart) before it counts; 30 s at most
    const want = tileAt(tj.maxzoom, ...landmark.lonLat);
    let value = null, demZoom = null;
    for (const start = Date.now(); Date.now() - start < 30000;) {
      const loaded = problems.tiles.some((t) => t.z === want.z && t.x === want.x && t.y === want.y && t.status === 200);
      const a = await page.evaluate((ll) => window.tessera.elevation(ll), landmark.lonLat);
      await new Promise((r) => setTimeout(r, 200));
      const b = await page.evaluate((ll) => window.tessera.elevation(ll), landmark.lonLat);
      demZoom = await page.evaluate((ll) => window.tessera.demZoom(ll), landmark.lonLat);
      if (loaded && a !== null && a === b && (demZoom === tj.maxzoom || demZoom === 'unknown')) { value = b; break; }
    }
    await screenshot(page, `terrain-${dataset}-${landmark.name.replace(/[^A-Za-z0-9]+/g, '_')}`);
    const tol = ABS_TOL + REL_TOL * ref.range4;
    const diff = value === null ? Infinity : value - ref.bilinear;
    console.log(`# ${landmark.name} (${landmark.lonLat.join(', ')}): MapLibre ${value === null ? 'null' : value.toFixed(2)} m, ` +
      `GDAL bilinear ${ref.bilinear.toFixed(2)} m, nearest ${ref.nearest} m, 2×2 ${ref.samples.map((v) => v ?? 'void').join('/')}, ` +
      `4×4 spread ${ref.range4} m (${ref.voids4} void), ` +
      `diff ${diff.toFixed(2)} m, tolerance ±${tol.toFixed(2)} m, DEM tile zoom ${demZoom} (maxzoom ${tj.maxzoom})`);
    const line = `${landmark.name}: MapLibre ${value} m, GDAL ${ref.bilinear.toFixed(2)} m (±${tol.toFixed(2)})`;
    if (!(Math.abs(diff) <= tol)) failures.push(line);
  }
  await page.close();
  assert.deepEqual(failures, [], 'heights off');
  assertNoProblems(problems, dataset);
});



// No walls (DECISIONS.md "Real clients"). Pixels without data must decode to a plausible height in
// what MapLibre reads: it ignores alpha in raster-dem tiles and reads them through a premultiplied
// canvas, so a transparent pixel decodes as Terrarium −32768 m and 3D terrain stands on walls
// 32 km deep. "Plausible": no drawn height lies more than the dataset's height range below its
// lowest sample (GDAL's). Two checks: a pitched view of the dataset's edges draped with a
// color-relief layer that is red below that line (no red pixel may be drawn), and
// queryTerrainElevation just beyond each edge (README.md "Walls").
test('N46E008: a pitched 3D view has no walls, and heights just outside the data are plausible', async () => {
  const dataset = 'N46E008';
  const [lo, hi] = minMax(path.join(DATA, `${dataset}.tif`));
  const low = lo - (hi - lo);
  const { page, problems } = await openPage(browser, pages.url, { width: TERRAIN_VIEW, height: TERRAIN_VIEW });
  const tj = await page.evaluate((server, name, l) => window.tessera.open({ server, dataset: name, mode: 'relief',
    view: { center: [8.5, 47.0], zoom: 9 }, low: l }), tiles.url, dataset, low);
  // Looking at each edge from outside the data, pitched: a wall, if any, faces the camera.
  const views = [
    { name: 'north', center: [8.5, 47.02], bearing: 180 },
    { name: 'south', center: [8.5, 45.98], bearing: 0 },
    { name: 'west', center: [7.97, 46.5], bearing: 90 },
    { name: 'east', center: [9.03, 46.5], bearing: 270 },
  ];
  const failures = [];
  for (const v of views) {
    await page.evaluate((c, o) => window.tessera.jump(c, 10, o), v.center, { pitch: 65, bearing: v.bearing });
    const file = await screenshot(page, `walls-${dataset}-${v.name}`);
    const px = await page.evaluate(() => window.tessera.reliefPixels());
    console.log(`# walls ${v.name}: ${px.low} px below ${low.toFixed(0)} m, ${px.ok} px plausible, ${px.other} other (${path.relative(process.cwd(), file)})`);
    if (px.ok < 1000) failures.push(`${v.name}: the view shows no terrain (${px.ok} px)`);
    if (px.low > 0) failures.push(`${v.name}: ${px.low} px of terrain below ${low.toFixed(0)} m`);
  }
  // Just beyond each edge (0.005°: several pixels past the apron at maxzoom), at the zoom where
  // MapLibre reads maxzoom DEM tiles.
  for (const [name, ll] of [['north', [8.5, 47.005]], ['south', [8.5, 45.995]], ['west', [7.995, 46.5]], ['east', [9.005, 46.5]]]) {
    await page.evaluate((c, z) => window.tessera.jump(c, z), ll, tj.maxzoom + DEM_ZOOM_OFFSET);
    let value = null;
    for (const start = Date.now(); Date.now() - start < 30000 && value === null;) {
      const a = await page.evaluate((p) => window.tessera.elevation(p), ll);
      await new Promise((r) => setTimeout(r, 200));
      const b = await page.evaluate((p) => window.tessera.elevation(p), ll);
      if (a !== null && a === b) value = b;
    }
    console.log(`# just outside the ${name} edge (${ll.join(', ')}): MapLibre ${value} m (lowest sample ${lo} m, limit ${low.toFixed(0)} m)`);
    if (!(value !== null && value >= low)) failures.push(`outside the ${name} edge: ${value} m`);
  }
  await page.close();
  assert.deepEqual(failures, [], 'walls');
  assertNoProblems(problems, dataset);
});

// Pixel positions (DECISIONS.md "Browser tests"). MapLibre 6 places a raster-dem pixel's value at
// the pixel's centre (DEMData.sampleBilinear with DEM_CELL_CENTER_OFFSET = −0.5, and the terrain
// shader's `+ 1.5` into its 2-px bordered texture), as GDAL does; the server computes each pixel at
// its centre. Queried exactly at maxzoom pixel centres, MapLibre must then give GDAL's bilinear
// value there to the Terrarium step, not a value half a pixel away. The points are the pixel
// centres near sharp summits where half a pixel changes the height most, so the shifted control
// (GDAL half a pixel away, what either side using the pixel's corner would give) misses by metres.
const SUMMITS = [
  { name: 'Finsteraarhorn', lonLat: [8.1261, 46.5372] },
  { name: 'Tödi', lonLat: [8.9147, 46.8111] },
  { name: 'Dammastock', lonLat: [8.4206, 46.6436] },
  { name: 'Oberalpstock', lonLat: [8.7833, 46.7] },
  { name: 'Clariden', lonLat: [8.8511, 46.8572] },
];
const PIXEL_TOL = 0.02; // m: Terrarium's 1/256 m step, the server's ≤ 4 mm to GDAL, with margin
const SHIFT_MIN = 1; // m: a control point must move at least this much at half a pixel

test('N46E008: MapLibre reads each pixel at its centre, as the server makes it (half-pixel control)', async () => {
  const dataset = 'N46E008';
  const file = path.join(DATA, `${dataset}.tif`);
  const { page, problems } = await openPage(browser, pages.url, { width: TERRAIN_VIEW, height: TERRAIN_VIEW });
  const tj = await page.evaluate((server, name, c) => window.tessera.open({ server, dataset: name, mode: 'terrain',
    view: { center: c, zoom: 'maxzoom' } }), tiles.url, dataset, SUMMITS[0].lonLat);
  const z = tj.maxzoom, size = TILE_SIZE;
  // For each summit, the pixel centre within ±4 px whose bilinear height moves most at half a
  // pixel (both diagonals), among those with no void around any of the three points.
  const picks = SUMMITS.map((s) => {
    const at = pixelAt(z, size, ...s.lonLat);
    const cands = [];
    for (let dj = -4; dj <= 4; dj++) for (let di = -4; di <= 4; di++) {
      const i = at.i + di, j = at.j + dj;
      if (i < 0 || j < 0 || i >= size || j >= size) continue;
      cands.push({ i, j, p: pixelCentre(z, at.x, at.y, size, i, j),
        minus: pixelCentre(z, at.x, at.y, size, i, j, -0.5, -0.5), plus: pixelCentre(z, at.x, at.y, size, i, j, 0.5, 0.5) });
    }
    const v = bilinearAt(file, cands.flatMap((c) => [c.p, c.minus, c.plus]));
    let best = null;
    cands.forEach((c, k) => {
      const [h, m, p] = v.slice(3 * k, 3 * k + 3);
      if (h === null || m === null || p === null) return;
      const move = Math.min(Math.abs(h - m), Math.abs(h - p));
      if (!best || move > best.move) best = { ...c, h, hMinus: m, hPlus: p, move };
    });
    return { ...s, tile: at, best };
  });
  const failures = [];
  for (const s of picks) {
    assert.ok(s.best && s.best.move >= SHIFT_MIN, `${s.name}: no pixel centre near the summit moves ${SHIFT_MIN} m at half a pixel`);
    const ll = s.best.p;
    await page.evaluate((c, zz) => window.tessera.jump(c, zz), ll, z + DEM_ZOOM_OFFSET);
    let value = null, demZoom = null;
    for (const start = Date.now(); Date.now() - start < 30000;) {
      const loaded = problems.tiles.some((t) => t.z === z && t.x === s.tile.x && t.y === s.tile.y && t.status === 200);
      const a = await page.evaluate((p) => window.tessera.elevation(p), ll);
      await new Promise((r) => setTimeout(r, 200));
      const b = await page.evaluate((p) => window.tessera.elevation(p), ll);
      demZoom = await page.evaluate((p) => window.tessera.demZoom(p), ll);
      if (loaded && a !== null && a === b && (demZoom === z || demZoom === 'unknown')) { value = b; break; }
    }
    const d = value === null ? Infinity : value - s.best.h;
    const dMinus = value === null ? Infinity : value - s.best.hMinus;
    const dPlus = value === null ? Infinity : value - s.best.hPlus;
    console.log(`# ${s.name}: pixel (${s.best.i}, ${s.best.j}) of ${z}/${s.tile.x}/${s.tile.y} at ${ll.map((v) => v.toFixed(6)).join(', ')}: ` +
      `MapLibre ${value === null ? 'null' : value.toFixed(3)} m, GDAL bilinear at the centre ${s.best.h.toFixed(3)} m (diff ${d.toFixed(3)}), ` +
      `half a pixel NW ${s.best.hMinus.toFixed(3)} (diff ${dMinus.toFixed(3)}), SE ${s.best.hPlus.toFixed(3)} (diff ${dPlus.toFixed(3)}); DEM tile zoom ${demZoom}`);
    if (!(Math.abs(d) <= PIXEL_TOL)) failures.push(`${s.name}: MapLibre ${value} m vs GDAL ${s.best.h.toFixed(3)} m at the pixel centre`);
    // the control: the same assertion against a reference half a pixel off must fail
    if (Math.abs(dMinus) <= PIXEL_TOL || Math.abs(dPlus) <= PIXEL_TOL) failures.push(`${s.name}: the half-pixel control passes too`);
  }
  await page.close();
  assert.deepEqual(failures, [], 'pixel centres');
  assertNoProblems(problems, dataset);
});

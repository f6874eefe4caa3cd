// Tessera's Cesium terrain (quantized-mesh-1.0; DECISIONS.md "Cesium terrain") in CesiumJS, in
// headless Chromium (DECISIONS.md "Browser tests"; docs/ARCHITECTURE.md#derived-outputs).
// Run by ./run.sh after maplibre.test.mjs;
// README.md "CesiumJS" explains the tolerance.
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { after, before, test } from 'node:test';
import { heights, wgs84Footprint } from './lib/gdal.mjs';
import { EGM96_GRID, undulations } from './lib/proj.mjs';
import { FINSTERAARHORN, LAGO_MAGGIORE, LANDMARKS, judgeHeights } from './lib/landmarks.mjs';
import { DATA, buildPyramids, launchBrowser, openPage, screenshot, startStaticServer, startTileServer } from './lib/harness.mjs';

const DATASET = 'N46E008'; // SRTM 3″, heights above EGM96
const VIEW = { width: 800, height: 500 };

// The water mask: the server marks heights at or below SEA_LEVEL connected to a tile's edge or to
// no-data as water (`serve --sea-level`); Urnersee (Lake Lucerne's south arm) is 431 m in this SRTM
// tile. Probes on the lake and on the slopes beside it.
const SEA_LEVEL = 431;
const LAKE_PROBES = [[8.605, 46.93], [8.60, 46.95]];
const LAND_PROBES = [[8.65, 46.93], [8.57, 46.93]];
// Mean |ΔRGB| (sum of three channels, per pixel) the water effect must make on the lake, and may
// make on land.
const MIN_WATER_EFFECT = 6, MAX_LAND_EFFECT = 1;

// Screenshot checks: the rendered terrain's heights (globe.getHeight) at the Finsteraarhorn and
// at Lago Maggiore must differ by more than this (they differ by ~3980 m; a flat globe by 0), and
// the grey levels of the centre crop must vary by more than MIN_STD (a single colour gives 0).
const MIN_RELIEF = 2000; // m
const MIN_STD = 8; // grey levels

let tiles, pages, browser, tab, problems, opened;
const footprint = wgs84Footprint(path.join(DATA, `${DATASET}.tif`));

before(async () => {
  if (!fs.existsSync(EGM96_GRID)) throw new Error(`missing the EGM96 grid ${EGM96_GRID} (Debian's proj-data)`);
  // The user's defaults (DECISIONS.md "Real clients"): no --vertical-datum (the build recognises
  // the SRTM GeoTIFF's datum, EGM96, from its DTED metadata) and no --geoid (the server finds the
  // grid PROJ uses for the reference, Debian's proj-data, by itself); layer.json must then carry no
  // warning.
  const dir = process.env.TESSERA_TILE_SERVER ? null : buildPyramids([DATASET]);
  tiles = await startTileServer(dir, { args: ['--sea-level', String(SEA_LEVEL)] });
  pages = await startStaticServer();
  browser = await launchBrowser();
  ({ page: tab, problems } = await openPage(browser, pages.url, { ...VIEW, file: 'cesium.html' }));
  opened = await tab.evaluate((server, name) => window.tessera.open({ server, dataset: name, requestWaterMask: true }), tiles.url, DATASET);
});

after(async () => {
  await tab?.close();
  await browser?.close();
  await pages?.stop();
  await tiles?.stop();
});

// The TMS tiles of EPSG:4326 zoom z (2^(z+1) × 2^z, y from the south) covering [w, s, e, n].
function covering(z, [w, s, e, n]) {
  const span = 180 / 2 ** z;
  return { startX: Math.floor((w + 180) / span), endX: Math.floor((e + 180) / span),
    startY: Math.floor((s + 90) / span), endY: Math.floor((n + 90) / span) };
}

test(`${DATASET}: layer.json as CesiumJS reads it`, async () => {
  const { layer, hasVertexNormals, hasMetadata, hasWaterMask } = opened;
  assert.equal(layer.status, 200, 'layer.json fetched cross-origin from the page');
  const doc = layer.doc;
  assert.equal(doc.format, 'quantized-mesh-1.0');
  // heights on the ellipsoid with the server's defaults: datum recognised, geoid found
  assert.equal(doc.metadata?.verticalDatum, 'egm96', `verticalDatum ${doc.metadata?.verticalDatum}`);
  assert.equal(doc.metadata?.warning, undefined, `layer.json warns: ${doc.metadata?.warning}`);
  assert.equal(doc.scheme, 'tms');
  assert.equal(doc.projection, 'EPSG:4326');
  // Normals, the water mask (the server has a water rule: --sea-level) and metadata with
  // tile-carried availability (`metadataAvailability`)
  assert.deepEqual(doc.extensions, ['octvertexnormals', 'watermask', 'metadata'], `extensions ${doc.extensions}`);
  assert.equal(doc.metadataAvailability, 10);
  assert.match(doc.tiles[0], /^\{z\}\/\{x\}\/\{y\}\.terrain\?v=[0-9A-Za-z]+$/);
  assert.ok(Number.isInteger(doc.maxzoom) && doc.maxzoom >= 12, `maxzoom ${doc.maxzoom}`);
  // zooms 0-10 listed; the deeper ones come with the tiles of zooms 10, 20
  assert.equal(doc.available.length, Math.min(doc.maxzoom, 10) + 1, '`available` for zooms 0-10');
  // both roots (CesiumJS assumes them with metadataAvailability)
  assert.deepEqual(doc.available[0], [{ startX: 0, startY: 0, endX: 1, endY: 0 }]);
  // per zoom, the tiles listed hold the data (GDAL's footprint) and nothing beyond it: they
  // include those of the sample centres' box shrunk a little, and lie within those of the
  // pixel-is-area footprint
  const [w, s, e, n] = footprint.bounds;
  const cell = 1 / 1200;
  for (let z = 1; z < doc.available.length; z++) {
    assert.equal(doc.available[z].length, 1, `zoom ${z}: one range`);
    const a = doc.available[z][0];
    const inner = covering(z, [w + cell, s + cell, e - cell, n - cell]), outer = covering(z, footprint.bounds);
    assert.ok(a.startX <= inner.startX && a.endX >= inner.endX && a.startY <= inner.startY && a.endY >= inner.endY,
      `zoom ${z}: ${JSON.stringify(a)} misses data tiles ${JSON.stringify(inner)}`);
    assert.ok(a.startX >= outer.startX && a.endX <= outer.endX && a.startY >= outer.startY && a.endY <= outer.endY,
      `zoom ${z}: ${JSON.stringify(a)} beyond the data ${JSON.stringify(outer)}`);
  }
  assert.ok(doc.metadata.levelZeroGeometricError > 0, 'metadata.levelZeroGeometricError');
  // CesiumJS took the normals, the water mask and the metadata from it
  assert.equal(hasVertexNormals, true, 'provider.hasVertexNormals');
  assert.equal(hasWaterMask, true, 'provider.hasWaterMask');
  assert.equal(hasMetadata, true, 'provider.hasMetadata');
});

test(`${DATASET}: sampleTerrainMostDetailed at five landmarks matches GDAL + PROJ`, async () => {
  const doc = opened.layer.doc;
  const refs = heights(path.join(DATA, `${DATASET}.tif`), LANDMARKS.map((l) => l.lonLat));
  const geoid = undulations(LANDMARKS.map((l) => l.lonLat));
  const samples = await tab.evaluate((ll) => window.tessera.sample(ll), LANDMARKS.map((l) => l.lonLat));
  const failures = judgeHeights({ samples, refs, geoid, levelZeroError: doc.metadata.levelZeroGeometricError, maxzoom: doc.maxzoom });
  assert.deepEqual(failures, [], 'heights off');
});

test(`${DATASET}: a view of the Alps with lit terrain`, async () => {
  // From 60 km, pitched 30° down, looking north-north-east at the middle of the Alps; the camera
  // stands over the Ticino Alps, inside the dataset.
  const target = [8.45, 46.55, 2500];
  const t0 = Date.now();
  await tab.evaluate((o) => window.tessera.fly(o), { target, range: 60000, heading: 10, pitch: -30 });
  const loaded = await tab.evaluate(() => window.tessera.tilesLoaded());
  const seconds = (Date.now() - t0) / 1000;
  const file = await screenshot(tab, 'cesium-alps');
  const v = await tab.evaluate((p) => window.tessera.view(p), [FINSTERAARHORN, LAGO_MAGGIORE]);
  const [hF, hL] = v.heights;
  console.log(`# view: camera ${v.camera.lon.toFixed(4)}° E ${v.camera.lat.toFixed(4)}° N ${(v.camera.height / 1000).toFixed(1)} km, ` +
    `heading ${v.camera.heading.toFixed(1)}°, pitch ${v.camera.pitch.toFixed(1)}°; screen centre on ` +
    (v.centre ? `${v.centre.lon.toFixed(4)}° E ${v.centre.lat.toFixed(4)}° N ${v.centre.height.toFixed(0)} m` : 'nothing') +
    `; tiles loaded ${(loaded.ms / 1000).toFixed(1)} s after the flight (${seconds.toFixed(1)} s in all); globe.getHeight Finsteraarhorn ` +
    `${hF?.toFixed(1)} m, Lago Maggiore ${hL?.toFixed(1)} m; centre crop grey std ${v.pixels.std.toFixed(1)}, ` +
    `${v.pixels.colours} colours (${path.relative(process.cwd(), file)})`);
  const [w, s, e, n] = footprint.bounds;
  const inside = (p) => p.lon > w && p.lon < e && p.lat > s && p.lat < n;
  assert.ok(inside(v.camera), `camera at ${v.camera.lon}, ${v.camera.lat}: not over the Alps of ${DATASET}`);
  assert.ok(v.camera.height > 20000 && v.camera.height < 60000, `camera height ${v.camera.height} m`);
  assert.ok(v.centre && inside(v.centre) && Math.hypot(v.centre.lon - target[0], v.centre.lat - target[1]) < 0.1,
    `screen centre on ${JSON.stringify(v.centre)}, not near ${target}`);
  assert.ok(hF !== null && hL !== null && hF - hL > MIN_RELIEF,
    `rendered terrain too flat: Finsteraarhorn ${hF} m, Lago Maggiore ${hL} m (need > ${MIN_RELIEF} m apart)`);
  assert.ok(v.pixels.std > MIN_STD && v.pixels.colours > 1, `screenshot centre nearly one colour (grey std ${v.pixels.std})`);
});

test(`${DATASET}: the water mask draws Urnersee as water, not its shores`, async () => {
  // From 12 km, pitched 45° down, looking east over the lake towards the morning sun (specular).
  await tab.evaluate((o) => window.tessera.fly(o), { target: [8.61, 46.94, 431], range: 12000, heading: 100, pitch: -45 });
  await tab.evaluate(() => window.tessera.tilesLoaded());
  const file = await screenshot(tab, 'cesium-water');
  const effect = await tab.evaluate((p) => window.tessera.waterEffect(p), [...LAKE_PROBES, ...LAND_PROBES]);
  const lake = effect.slice(0, LAKE_PROBES.length), land = effect.slice(LAKE_PROBES.length);
  const f = (e) => (e.diff === null ? 'off screen' : `${e.diff.toFixed(1)} at (${e.x}, ${e.y})`);
  console.log(`# water effect (mean |ΔRGB| with and without globe.showWaterEffect): lake ${lake.map(f).join(', ')}; ` +
    `land ${land.map(f).join(', ')} (${path.relative(process.cwd(), file)})`);
  for (const [k, e] of lake.entries()) assert.ok(e.diff !== null && e.diff >= MIN_WATER_EFFECT, `lake ${LAKE_PROBES[k]}: ${f(e)}`);
  for (const [k, e] of land.entries()) assert.ok(e.diff !== null && e.diff <= MAX_LAND_EFFECT, `land ${LAND_PROBES[k]}: ${f(e)}`);
});

// Little-endian quantized-mesh: the metadata extension's JSON, if any.
function tileMetadata(buf) {
  const v = new DataView(buf.buffer, buf.byteOffset, buf.byteLength);
  let p = 88;
  const n = v.getUint32(p, true);
  p += 4 + 6 * n;
  const width = n > 65536 ? 4 : 2;
  p = Math.ceil(p / width) * width;
  const triangles = v.getUint32(p, true);
  p += 4 + 3 * triangles * width;
  for (let k = 0; k < 4; k++) p += 4 + v.getUint32(p, true) * width;
  while (p < buf.length) {
    const id = v.getUint8(p), len = v.getUint32(p + 1, true);
    if (id === 4) return JSON.parse(new TextDecoder().decode(buf.subarray(p + 9, p + 5 + len)));
    p += 5 + len;
  }
  return null;
}

test(`${DATASET}: with metadata availability CesiumJS asks for no tile that is not available`, async () => {
  const doc = opened.layer.doc;
  const terrain = problems.all.filter((r) => /\/cesium\/\d+\/\d+\/\d+\.terrain/.test(r.url));
  const requested = [...new Set(terrain.map((r) => r.url.match(/\/cesium\/(\d+\/\d+\/\d+)\.terrain/)[1]))]
    .map((t) => t.split('/').map(Number));
  // What is available: layer.json for zooms 0-10, then each zoom-10 tile's metadata for 11-20,
  // fetched here from node as CesiumJS does
  const inRanges = (ranges, x, y) => (ranges ?? []).some((r) => x >= r.startX && x <= r.endX && y >= r.startY && y <= r.endY);
  const carried = new Map();
  const base = `${tiles.url}/v1/datasets/${DATASET}/cesium/`;
  const unavailable = [];
  for (const [z, x, y] of requested) {
    let ok;
    if (z <= 10) ok = inRanges(doc.available[z], x, y);
    else {
      const a = [10, x >> (z - 10), y >> (z - 10)].join('/');
      if (!carried.has(a)) {
        const r = await fetch(`${base}${a}.terrain`, { headers: { Accept: 'application/vnd.quantized-mesh;extensions=metadata' } });
        carried.set(a, r.status === 200 ? tileMetadata(new Uint8Array(await r.arrayBuffer()))?.available : null);
      }
      ok = inRanges(carried.get(a)?.[z - 11], x, y);
    }
    if (!ok) unavailable.push(`${z}/${x}/${y}`);
  }
  const byZoom = {};
  for (const [z] of requested) byZoom[z] = (byZoom[z] ?? 0) + 1;
  console.log(`# ${requested.length} distinct terrain tiles requested (per zoom ${JSON.stringify(byZoom)}), ` +
    `${unavailable.length} not available; ${carried.size} zoom-10 tiles' availability checked`);
  assert.deepEqual(unavailable, [], 'requests for tiles that are not available');
  assert.equal(terrain.filter((r) => r.status === 404).length, 0, '404s');
});

// Last: everything the page did, landmark sampling and the view included.
test(`${DATASET}: no console errors, no failed requests, negotiated terrain responses`, () => {
  const terrain = problems.all.filter((r) => /\/cesium\/\d+\/\d+\/\d+\.terrain/.test(r.url));
  const layers = problems.all.filter((r) => /\/cesium\/layer\.json/.test(r.url));
  const statuses = {};
  for (const r of terrain) statuses[r.status] = (statuses[r.status] ?? 0) + 1;
  const encodings = {};
  for (const r of terrain) encodings[r.headers['content-encoding'] ?? 'identity'] = (encodings[r.headers['content-encoding'] ?? 'identity'] ?? 0) + 1;
  console.log(`# ${terrain.length} terrain responses (status ${JSON.stringify(statuses)}, content-encoding ${JSON.stringify(encodings)}), ${layers.length} layer.json`);
  assert.deepEqual(problems.console, [], 'console errors');
  assert.deepEqual(problems.failed, [], 'failed requests');
  assert.deepEqual(problems.responses, [], 'HTTP errors');
  assert.ok(terrain.length > 0 && layers.length > 0);
  const bad = [...terrain, ...layers].filter((r) => r.status !== 200 && r.status !== 304);
  assert.deepEqual(bad.map((r) => `${r.status} ${r.url}`), [], 'terrain and layer.json responses other than 200/304');
  // CesiumJS asked for the normals, the water mask and the metadata and got them,
  // compressed as Chromium's Accept-Encoding allows (the server has gzip and br), cross-origin
  for (const r of terrain.filter((t) => t.status === 200)) {
    const type = r.headers['content-type'] ?? '';
    const m = type.match(/^application\/vnd\.quantized-mesh;\s*extensions=([a-z-]+)$/);
    const ext = m ? m[1].split('-') : [];
    assert.deepEqual(ext, ['octvertexnormals', 'watermask', 'metadata'], `${r.url}: Content-Type ${type}`);
    // (the server compresses bodies over 256 bytes: a flat lake tile at zoom 16 is smaller)
    const small = r.headers['content-encoding'] === undefined && Number(r.headers['content-length']) <= 256;
    assert.ok(small || ['gzip', 'br'].includes(r.headers['content-encoding']),
      `${r.url}: content-encoding ${r.headers['content-encoding']}, content-length ${r.headers['content-length']}`);
    assert.equal(r.headers['access-control-allow-origin'], '*', `${r.url}: CORS`);
  }
});

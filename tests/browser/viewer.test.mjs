// The server's built-in viewer (DECISIONS.md "Real clients") in headless Chromium: `tessera-server
// serve` with its default flags serves the landing page `/` and `/viewer/{name}` itself, with
// MapLibre GL JS and CesiumJS from its own /viewer/assets/ (prepared by server/viewer-assets.sh,
// found beside target/debug/tessera-server). Asserted: the landing page lists both datasets with
// their links; MapLibre draws the terrain at the dataset's place with GDAL's heights; the Cesium
// switch loads the quantized-mesh terrain; no console error; and no request to any host but the
// server. README.md "The built-in viewer" says why each bound is what it is.
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { after, before, test } from 'node:test';
import { heights } from './lib/gdal.mjs';
import { DATA, OUT, ROOT, buildPyramids, launchBrowser, screenshot, startTileServer } from './lib/harness.mjs';

const DATASET = 'N46E008';
const VIEW = { width: 600, height: 500 }; // small: SwiftShader draws on two cores
const ANDERMATT = [8.5911, 46.635]; // the valley floor: GDAL's 2×2 spread 1 m, 4×4 5 m
// MapLibre's terrain against GDAL's bilinear value at maxzoom + 1 (maplibre.test.mjs holds the
// same lookup to 2 m + R₄/4; here the viewer's own style is checked, so a looser bound).
const MAPLIBRE_TOLERANCE = 30; // m
// Cesium's height against GDAL's, whatever datum the build recorded for the GeoTIFF: as-is
// (unknown) or plus EGM96's ≈ 48 m at Andermatt (egm96, with the geoid grid).
const CESIUM_TOLERANCE = 100; // m
// Share of the fitted view's centre crop that must differ from the map's background colour:
// the hillshade draws nothing on flat ground (lakes, valley floors), where the background shows.
const MIN_TERRAIN = 0.6;

let tiles, browser, tab, maxzoom;
const seen = { requests: [], console: [], failed: [], errors: [] };

before(async () => {
  const dir = process.env.TESSERA_TILE_SERVER ? null : buildPyramids([DATASET, 'aletsch']);
  // Default flags. `--viewer-assets` only when the binary's own lookup (<exe dir>/../viewer-assets)
  // cannot find the prepared directory (a TESSERA_SERVER outside target/).
  const bin = path.resolve(ROOT, process.env.TESSERA_SERVER ?? 'target/debug/tessera-server');
  const beside = path.resolve(path.dirname(bin), '../viewer-assets');
  const args = fs.existsSync(path.join(beside, 'cesium/Cesium.js'))
    ? [] : ['--viewer-assets', path.join(ROOT, 'target/viewer-assets')];
  if (args.length) console.log(`# the server does not find ${beside}: ${args.join(' ')}`);
  tiles = await startTileServer(dir, { args });
  browser = await launchBrowser();
  tab = await browser.newPage();
  await tab.setViewport({ ...VIEW, deviceScaleFactor: 1 });
  tab.on('request', (r) => seen.requests.push(r.url()));
  tab.on('console', (m) => { if (m.type() === 'error') seen.console.push(m.text()); });
  tab.on('pageerror', (e) => seen.console.push(`page error: ${e.message}`));
  tab.on('requestfailed', (r) => seen.failed.push(`${r.url()}: ${r.failure()?.errorText}`));
  tab.on('response', (r) => { if (r.status() >= 400) seen.errors.push(`${r.status()} ${r.url()}`); });
  const tj = await (await fetch(`${tiles.url}/v1/datasets/${DATASET}/webmercator/tilejson.json?encoding=terrarium&size=512`)).json();
  maxzoom = tj.maxzoom;
});

after(async () => {
  await tab?.close();
  await browser?.close();
  await tiles?.stop();
});

test('the landing page lists both datasets with their links', async () => {
  const t0 = Date.now();
  await tab.goto(`${tiles.url}/`, { waitUntil: 'networkidle0' });
  const listed = await tab.evaluate(() => [...document.querySelectorAll('li.dataset')].map((li) => ({
    name: li.dataset.dataset,
    links: Object.fromEntries([...li.querySelectorAll('a[data-link]')].map((a) => [a.dataset.link, a.href])),
    preview: (() => { const img = li.querySelector('img'); return { src: img.src, ok: img.complete && img.naturalWidth > 0, w: img.naturalWidth, h: img.naturalHeight }; })(),
  })));
  fs.mkdirSync(OUT, { recursive: true });
  await tab.screenshot({ path: path.join(OUT, 'viewer-landing.png'), fullPage: true });
  assert.deepEqual(listed.map((d) => d.name), ['N46E008', 'aletsch']);
  const want = ['viewer', 'webmercator-terrarium', 'webmercator-mapbox', 'crs84-terrarium', 'crs84-mapbox', 'wmts',
    'wmts-all', 'ogcapi', 'ogcapi-collection', 'ogcapi-tilesets', 'cesium', 'pyramid', 'document', 'dataset', 'preview'];
  for (const d of listed) {
    assert.deepEqual(want.filter((k) => !d.links[k]), [], `${d.name}: links missing`);
    assert.equal(d.links.viewer, `${tiles.url}/viewer/${d.name}`);
    assert.ok(d.preview.ok && Math.max(d.preview.w, d.preview.h) === 256, `${d.name}: preview ${JSON.stringify(d.preview)}`);
    // each link answers (the pyramid: its head only)
    for (const [k, url] of Object.entries(d.links)) {
      const r = await fetch(url, { method: k === 'pyramid' ? 'HEAD' : 'GET' });
      assert.equal(r.status, 200, `${d.name} ${k}: ${url}`);
    }
  }
  console.log(`# landing: ${listed.length} datasets, ${Object.keys(listed[0].links).length} links each, all 200 (${((Date.now() - t0) / 1000).toFixed(1)} s)`);
});

test(`MapLibre shows ${DATASET}'s terrain at its place`, async () => {
  const t0 = Date.now();
  await tab.goto(`${tiles.url}/viewer/${DATASET}`, { waitUntil: 'load' });
  await tab.waitForFunction(() => window.tessera?.ready === true, { timeout: 60000 });
  await tab.evaluate(() => window.tessera.idle());
  const loaded = (Date.now() - t0) / 1000;
  const fitted = await tab.evaluate(() => {
    const m = window.tessera.map, c = m.getCenter();
    return { centre: [c.lng, c.lat], zoom: m.getZoom(), pitch: m.getPitch(), terrain: Boolean(m.getTerrain()),
      pixels: window.tessera.centrePixels(), versions: window.tessera.version() };
  });
  await screenshot(tab, 'viewer-maplibre');
  // The pointer over the middle of the view: the readout names a height in metres.
  await tab.mouse.move(VIEW.width / 2, VIEW.height / 2 + 40);
  await tab.waitForFunction(() => / m at /.test(document.getElementById('readout').textContent), { timeout: 10000 });
  const readout = await tab.$eval('#readout', (el) => el.textContent);
  console.log(`# MapLibre ${fitted.versions.maplibre}: fitted view centre ${fitted.centre.map((v) => v.toFixed(4)).join(', ')}, ` +
    `zoom ${fitted.zoom.toFixed(2)}, pitch ${fitted.pitch}°, loaded in ${loaded.toFixed(1)} s; centre crop ` +
    `${(fitted.pixels.notBackground * 100).toFixed(1)} % not background, grey std ${fitted.pixels.std.toFixed(1)}; readout "${readout}"`);
  assert.equal(fitted.versions.maplibre, '6.20.0', 'the pinned MapLibre');
  assert.ok(fitted.terrain, '3D terrain on');
  assert.ok(fitted.pitch > 0, 'tilted');
  const [lon, lat] = fitted.centre;
  assert.ok(lon > 8 && lon < 9 && lat > 46 && lat < 47, `view centre ${lon}, ${lat} is not over ${DATASET}`);
  // (the hillshade leaves flat lakes and valley floors see-through: the background shows there)
  assert.ok(fitted.pixels.notBackground > MIN_TERRAIN, `the view's centre is background (${fitted.pixels.notBackground})`);
  assert.ok(fitted.pixels.std > 8, `the view's centre is one colour (grey std ${fitted.pixels.std})`);
  // Andermatt, looked at from above at the zoom whose DEM tiles are the TileJSON's maxzoom.
  const [ref] = heights(path.join(DATA, `${DATASET}.tif`), [ANDERMATT]);
  const h = await tab.evaluate((p, z) => window.tessera.elevation(p, z), ANDERMATT, maxzoom + 1);
  await screenshot(tab, 'viewer-andermatt');
  console.log(`# Andermatt: MapLibre queryTerrainElevation ${h?.toFixed(2)} m at zoom ${maxzoom + 1}, GDAL bilinear ` +
    `${ref.bilinear.toFixed(2)} m (nearest ${ref.nearest} m): ${(h - ref.bilinear).toFixed(2)} m, tolerance ±${MAPLIBRE_TOLERANCE} m`);
  assert.ok(h !== null && Math.abs(h - ref.bilinear) <= MAPLIBRE_TOLERANCE, `Andermatt ${h} m, GDAL ${ref.bilinear} m`);
});

test('the Cesium switch loads the quantized-mesh terrain', async () => {
  const t0 = Date.now();
  await tab.click('#mode-cesium');
  await tab.waitForFunction(() => window.tessera.globeReady === true || window.tessera.errors.length > 0, { timeout: 180000 });
  assert.deepEqual(await tab.evaluate(() => window.tessera.errors), [], 'viewer errors');
  const loaded = await tab.evaluate(() => window.tessera.globeTilesLoaded());
  const seconds = (Date.now() - t0) / 1000;
  await screenshot(tab, 'viewer-cesium');
  const v = await tab.evaluate(() => {
    const { viewer, provider, Cesium } = window.tessera.globe;
    const c = viewer.camera.positionCartographic;
    return { tilesLoaded: viewer.scene.globe.tilesLoaded, provider: viewer.terrainProvider === provider,
      normals: provider.hasVertexNormals, layers: viewer.imageryLayers.length,
      camera: [Cesium.Math.toDegrees(c.longitude), Cesium.Math.toDegrees(c.latitude), c.height],
      pixels: window.tessera.centrePixels(), version: Cesium.VERSION,
      pressed: document.getElementById('mode-cesium').getAttribute('aria-pressed') };
  });
  const [ref] = heights(path.join(DATA, `${DATASET}.tif`), [ANDERMATT]);
  const [h] = await tab.evaluate((p) => window.tessera.globeSample([p]), ANDERMATT);
  console.log(`# CesiumJS ${v.version}: globe ready and every tile in view loaded ${seconds.toFixed(1)} s after the click ` +
    `(tiles ${(loaded.ms / 1000).toFixed(1)} s); camera ${v.camera[0].toFixed(3)}° E ${v.camera[1].toFixed(3)}° N ` +
    `${(v.camera[2] / 1000).toFixed(1)} km; centre crop grey std ${v.pixels.std.toFixed(1)}; Andermatt ` +
    `sampleTerrainMostDetailed ${h.toFixed(2)} m vs GDAL ${ref.bilinear.toFixed(2)} m: ${(h - ref.bilinear).toFixed(2)} m ` +
    `(tolerance ±${CESIUM_TOLERANCE} m: the build's vertical datum, as-is or + EGM96 ≈ 48 m)`);
  assert.equal(v.version, '1.145.0', 'the pinned CesiumJS');
  assert.equal(v.pressed, 'true');
  assert.ok(v.provider && v.normals, 'our terrain provider, with normals');
  assert.ok(v.tilesLoaded, 'globe.tilesLoaded');
  assert.ok(v.layers >= 1, 'Natural Earth II imagery from CesiumJS\'s own Assets');
  assert.ok(v.camera[0] > 7 && v.camera[0] < 10 && v.camera[1] > 44 && v.camera[1] < 47, `camera at ${v.camera}`);
  assert.ok(v.pixels.std > 8, `the globe's centre is one colour (grey std ${v.pixels.std})`);
  assert.ok(Math.abs(h - ref.bilinear) <= CESIUM_TOLERANCE, `Cesium ${h} m at Andermatt, GDAL ${ref.bilinear} m`);
  // And back to the map.
  await tab.click('#mode-maplibre');
  assert.equal(await tab.evaluate(() => !document.getElementById('map').hidden && document.getElementById('globe').hidden), true);
});

// Last: everything the tab did.
test('no console errors and no request to any host but the server', () => {
  const origin = new URL(tiles.url).origin;
  const foreign = seen.requests.filter((u) => !u.startsWith('data:') && !u.startsWith('blob:') && new URL(u).origin !== origin);
  const kinds = {};
  for (const u of seen.requests) {
    const k = u.startsWith('data:') || u.startsWith('blob:') ? 'data/blob'
      : /\/viewer\/assets\/cesium\//.test(u) ? 'cesium assets' : /\/viewer\/assets\//.test(u) ? 'maplibre and own assets'
        : /\/cesium\/\d+\/\d+\/\d+\.terrain/.test(u) ? 'terrain tiles' : /\/webmercator\/\d+/.test(u) ? 'web tiles' : 'other';
    kinds[k] = (kinds[k] ?? 0) + 1;
  }
  console.log(`# ${seen.requests.length} requests: ${JSON.stringify(kinds)}`);
  assert.deepEqual(foreign, [], 'requests to other hosts');
  assert.deepEqual(seen.console, [], 'console errors');
  assert.deepEqual(seen.failed, [], 'failed requests');
  assert.deepEqual(seen.errors, [], 'HTTP errors');
});

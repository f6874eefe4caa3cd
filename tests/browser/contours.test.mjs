// Contour lines in MapLibre GL JS (API.md "Contour tiles"): a page on another origin than the
// tiles, a `tessera-server serve` with its default flags, and a vector source on its contour
// TileJSON. MapLibre must draw the lines with no console errors, and the lines it decoded must lie
// where the DEM has their elevation: at sampled vertices, GDAL's bilinear height of the DEM is the
// line's `ele` within maplibre.test.mjs's tolerance (2 m + a quarter of the local 4 × 4 samples'
// spread: lines are straight between the tile grid's samples, the DEM's surface is not).
import assert from 'node:assert/strict';
import path from 'node:path';
import { after, before, test } from 'node:test';
import { heights } from './lib/gdal.mjs';
import { DATA, buildPyramids, launchBrowser, openPage, screenshot, startStaticServer, startTileServer } from './lib/harness.mjs';

const DATASET = 'N46E008';
const ANDERMATT = [8.5911, 46.635];
const ABS_TOL = 2;
const REL_TOL = 0.25;

let server, pages, browser;

before(async () => {
  server = await startTileServer(buildPyramids([DATASET]));
  pages = await startStaticServer();
  browser = await launchBrowser();
});

after(async () => {
  await browser?.close();
  await pages?.stop();
  await server?.stop();
});

test('MapLibre draws the contour tiles, and their lines lie at their elevation on the DEM', async () => {
  const tilejson = `${server.url}/v1/datasets/${DATASET}/webmercator/contours/tilejson.json`;
  const doc = await (await fetch(tilejson)).json();
  const { page, problems } = await openPage(browser, pages.url, { width: 600, height: 600, file: 'contours.html' });
  const read = await page.evaluate((url, c) => window.tessera.open({ url, center: c, zoom: 12 }), tilejson, ANDERMATT);
  console.log(`# TileJSON as MapLibre read it: ${JSON.stringify(read)}`);
  assert.deepEqual(read.vectorLayerIds, ['contours']);
  const { features, ink, rendered } = await page.evaluate(() => window.tessera.lines());
  const file = await screenshot(page, 'contours-andermatt');
  console.log(`# ${features.length} lines decoded, ${rendered} drawn, ${(ink * 100).toFixed(1)} % of the map inked; ${file}`);
  assert.ok(features.length > 50, `${features.length} lines`);
  assert.ok(rendered > 50, `${rendered} lines drawn`);
  assert.ok(ink > 0.02 && ink < 0.6, `${(ink * 100).toFixed(1)} % inked`);
  // At map zoom 12 MapLibre draws the zoom-11 tiles (the TileJSON's maxzoom), whose interval the
  // TileJSON states.
  const interval = doc.contour_intervals[String(doc.maxzoom)];
  for (const f of features) {
    assert.equal(f.ele % interval, 0, `${f.ele} m is not a multiple of ${interval} m`);
    assert.equal(f.index, f.ele % (5 * interval) === 0, `index flag of ${f.ele} m`);
  }
  // Vertices spread over the view, each against GDAL.
  const sample = [];
  const step = Math.max(1, Math.floor(features.length / 60));
  for (let i = 0; i < features.length && sample.length < 60; i += step) {
    const f = features[i];
    const [lon, lat] = f.coords[Math.min(1, f.coords.length - 1)];
    if (Math.abs(lon - ANDERMATT[0]) < 0.1 && Math.abs(lat - ANDERMATT[1]) < 0.07) sample.push({ ele: f.ele, lonLat: [lon, lat] });
  }
  assert.ok(sample.length > 20, `${sample.length} vertices in view`);
  const refs = heights(path.join(DATA, `${DATASET}.tif`), sample.map((s) => s.lonLat));
  const off = [];
  let worst = 0;
  sample.forEach((s, k) => {
    const ref = refs[k];
    if (ref.voids4 > 0) return; // beside an SRTM void the reference renormalises its weights
    const tol = ABS_TOL + REL_TOL * ref.range4;
    const d = Math.abs(ref.bilinear - s.ele);
    worst = Math.max(worst, d);
    if (!(d <= tol)) off.push(`${s.lonLat}: the ${s.ele} m line, GDAL ${ref.bilinear.toFixed(2)} m (±${tol.toFixed(2)})`);
  });
  console.log(`# ${sample.length} vertices against GDAL's bilinear DEM: worst ${worst.toFixed(2)} m`);
  await page.close();
  assert.deepEqual(off, [], 'lines off their elevation');
  assert.deepEqual(problems.console, [], 'console errors');
  assert.deepEqual(problems.failed, [], 'failed requests');
  assert.deepEqual(problems.responses, [], 'HTTP errors');
});

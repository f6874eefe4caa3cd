// A serverless map (DECISIONS.md "PMTiles export"): `tessera-server export` writes N46E008's
// Terrarium tiles (512-px lossless WebP) into one PMTiles archive; nginx serves it as a static
// file; MapLibre GL JS with the `pmtiles` npm package's protocol reads it with HTTP Range
// requests from a page on another origin, and its 3D terrain must carry the DEM's heights at the
// five landmarks of maplibre.test.mjs, held to the same tolerance (README.md "Heights", "PMTiles").
import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { after, before, test } from 'node:test';
import { heights, wgs84Footprint } from './lib/gdal.mjs';
import { DATA, SERVER, buildPyramids, launchBrowser, openPage, screenshot, startStaticServer } from './lib/harness.mjs';
import { startNginx } from './lib/nginx.mjs';

const DATASET = 'N46E008';
const VIEW = 400;
const ABS_TOL = 2; // m: maplibre.test.mjs's tolerance
const REL_TOL = 0.25;
const DEM_ZOOM_OFFSET = 2; // the map two zooms below the DEM tiles (maplibre.test.mjs)
const LANDMARKS = [
  { name: 'Urnersee', lonLat: [8.61, 46.93] },
  { name: 'Andermatt', lonLat: [8.5911, 46.635] },
  { name: 'Lago Maggiore', lonLat: [8.70, 46.10] },
  { name: 'Tödi shoulder', lonLat: [8.9183, 46.8133] },
  { name: 'Finsteraarhorn massif', lonLat: [8.1258, 46.5367] },
];

let nginx, pages, browser, archive;

before(async () => {
  const dir = buildPyramids([DATASET]);
  const host = fs.mkdtempSync(path.join(os.tmpdir(), 'tessera-pmtiles-'));
  archive = path.join(host, 'n46.pmtiles');
  execFileSync(SERVER, ['export', path.join(dir, `${DATASET}.tess`), '--pmtiles', archive,
    '--format', 'webp', '--size', '512', '--quiet'], { stdio: ['ignore', 'ignore', 'inherit'] });
  nginx = await startNginx(host);
  pages = await startStaticServer();
  browser = await launchBrowser();
});

after(async () => {
  await browser?.close();
  await pages?.stop();
  await nginx?.stop();
});

test('a PMTiles archive on nginx: MapLibre terrain carries the DEM heights at five landmarks', async () => {
  const refs = heights(path.join(DATA, `${DATASET}.tif`), LANDMARKS.map((l) => l.lonLat));
  const footprint = wgs84Footprint(path.join(DATA, `${DATASET}.tif`));
  const { page, problems } = await openPage(browser, pages.url, { width: VIEW, height: VIEW, file: 'pmtiles.html' });
  const header = await page.evaluate((url, c) => window.tessera.open({ url, center: c, zoom: 9 }),
    `${nginx.url}/n46.pmtiles`, LANDMARKS[0].lonLat);
  console.log(`# archive header as MapLibre read it: ${JSON.stringify(header)}`);
  // The place on Earth: the archive's bounds are the DEM's (GDAL's footprint) within a cell.
  const [w, s, e, n] = header.bounds;
  const g = footprint.bounds;
  for (const [got, want] of [[w, g[0]], [s, g[1]], [e, g[2]], [n, g[3]]]) {
    assert.ok(Math.abs(got - want) < 0.001, `bounds ${header.bounds} vs GDAL's ${g}`);
  }
  const failures = [];
  for (const [k, landmark] of LANDMARKS.entries()) {
    const ref = refs[k];
    const zoom = header.maxzoom + DEM_ZOOM_OFFSET;
    let value = null;
    for (const start = Date.now(); Date.now() - start < 30000;) {
      const a = await page.evaluate((ll, z) => window.tessera.freshElevation(ll, z), landmark.lonLat, zoom);
      await new Promise((r) => setTimeout(r, 200));
      const b = await page.evaluate((ll) => window.tessera.elevation(ll), landmark.lonLat);
      if (a !== null && a === b) { value = b; break; }
    }
    await screenshot(page, `pmtiles-${landmark.name.replace(/[^A-Za-z0-9]+/g, '_')}`);
    const tol = ABS_TOL + REL_TOL * ref.range4;
    const diff = value === null ? Infinity : value - ref.bilinear;
    console.log(`# ${landmark.name}: MapLibre from PMTiles ${value === null ? 'null' : value.toFixed(2)} m, GDAL bilinear ${ref.bilinear.toFixed(2)} m, diff ${diff.toFixed(2)} m, tolerance ±${tol.toFixed(2)} m`);
    if (!(Math.abs(diff) <= tol)) failures.push(`${landmark.name}: ${value} m vs GDAL ${ref.bilinear.toFixed(2)} m (±${tol.toFixed(2)})`);
  }
  await page.close();
  assert.deepEqual(failures, [], 'heights off');
  assert.deepEqual(problems.console, [], 'console errors');
  assert.deepEqual(problems.failed, [], 'failed requests');
  assert.deepEqual(problems.responses, [], 'HTTP errors');
  // Every read of the archive was a byte range: 206, or 304 when Chromium revalidated a range
  // it had cached; none fetched the archive whole.
  const reads = nginx.log().filter((r) => r.uri === '/n46.pmtiles' && r.method === 'GET');
  const size = fs.statSync(archive).size;
  const sent = reads.reduce((t, r) => t + r.bytes, 0);
  const largest = Math.max(...reads.map((r) => r.bytes));
  console.log(`# nginx: ${reads.length} range reads (${reads.filter((r) => r.status === 304).length} revalidated), ${sent} of the archive's ${size} bytes, the largest ${largest}`);
  assert.ok(reads.length > 0, 'MapLibre never read the archive');
  assert.deepEqual(reads.filter((r) => ![206, 304].includes(r.status) || !r.range), [], 'reads that were not byte ranges');
  assert.ok(largest < size / 4, `a read of ${largest} bytes of ${size}`);
});

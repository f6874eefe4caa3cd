// Tessera's Cesium terrain as 3D Tiles 1.1 (DECISIONS.md "3D Tiles terrain") in CesiumJS's
// Cesium3DTilesTerrainProvider, in headless Chromium (DECISIONS.md "Browser tests"). The same
// landmarks and tolerances as cesium.test.mjs (lib/landmarks.mjs), and the same heights as the
// quantized-mesh terrain sampled in the same page. Run by ./run.sh after cesium.test.mjs.
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { after, before, test } from 'node:test';
import { heights, wgs84Footprint } from './lib/gdal.mjs';
import { EGM96_GRID, undulations } from './lib/proj.mjs';
import { DECODE, FINSTERAARHORN, LAGO_MAGGIORE, LANDMARKS, judgeHeights } from './lib/landmarks.mjs';
import { DATA, buildPyramids, launchBrowser, openPage, screenshot, startStaticServer, startTileServer } from './lib/harness.mjs';

const DATASET = 'N46E008'; // SRTM 3″, heights above EGM96
const VIEW = { width: 800, height: 500 };
// As cesium.test.mjs: relief between the Finsteraarhorn and Lago Maggiore, grey-level spread.
const MIN_RELIEF = 2000; // m
const MIN_STD = 8; // grey levels
const TILES3D = /\/3dtiles\/([01])\/(\d+)\/(\d+)\/(\d+)\.(glb|subtree)/;

let tiles, pages, browser, tab, problems, opened, layer;
const footprint = wgs84Footprint(path.join(DATA, `${DATASET}.tif`));

before(async () => {
  if (!fs.existsSync(EGM96_GRID)) throw new Error(`missing the EGM96 grid ${EGM96_GRID} (Debian's proj-data)`);
  const dir = process.env.TESSERA_TILE_SERVER ? null : buildPyramids([DATASET]);
  tiles = await startTileServer(dir);
  pages = await startStaticServer();
  browser = await launchBrowser();
  ({ page: tab, problems } = await openPage(browser, pages.url, { ...VIEW, file: 'cesium.html' }));
  opened = await tab.evaluate((server, name) => window.tessera.open({ server, dataset: name, format: '3dtiles' }), tiles.url, DATASET);
  layer = await (await fetch(`${tiles.url}/v1/datasets/${DATASET}/cesium/layer.json`)).json();
});

after(async () => {
  await tab?.close();
  await browser?.close();
  await pages?.stop();
  await tiles?.stop();
});

test(`${DATASET}: tileset.json as Cesium3DTilesTerrainProvider reads it`, () => {
  const { tileset, hasVertexNormals } = opened;
  assert.equal(tileset.status, 200, 'tileset.json fetched cross-origin from the page');
  const doc = tileset.doc;
  assert.equal(doc.asset.version, '1.1');
  assert.equal(doc.root.children.length, 2, 'two roots: west and east of the prime meridian');
  for (const [r, child] of doc.root.children.entries()) {
    const it = child.implicitTiling;
    assert.equal(it.subdivisionScheme, 'QUADTREE');
    assert.equal(it.availableLevels, layer.maxzoom + 1, 'the quantized-mesh zooms');
    assert.match(child.content.uri, new RegExp(`^${r}/\\{level\\}/\\{x\\}/\\{y\\}\\.glb\\?v=`));
    assert.match(it.subtrees.uri, new RegExp(`^${r}/\\{level\\}/\\{x\\}/\\{y\\}\\.subtree\\?v=`));
  }
  assert.equal(hasVertexNormals, true, 'provider.hasVertexNormals');
});

test(`${DATASET}: sampleTerrainMostDetailed at five landmarks matches GDAL + PROJ and the quantized-mesh terrain`, async () => {
  const lonLats = LANDMARKS.map((l) => l.lonLat);
  const refs = heights(path.join(DATA, `${DATASET}.tif`), lonLats);
  const geoid = undulations(lonLats);
  const samples = await tab.evaluate((ll) => window.tessera.sample(ll), lonLats);
  const failures = judgeHeights({ samples, refs, geoid, levelZeroError: layer.metadata.levelZeroGeometricError, maxzoom: layer.maxzoom });
  // The same meshes: the quantized-mesh terrain's heights, sampled in the same page.
  const qm = await tab.evaluate((server, name, ll) => window.tessera.sampleQuantizedMesh({ server, dataset: name, lonLats: ll }), tiles.url, DATASET, lonLats);
  for (const [k, l] of LANDMARKS.entries()) {
    const d = samples[k].height - qm[k].height;
    console.log(`# ${l.name}: 3D Tiles ${samples[k].height.toFixed(3)} m (z${samples[k].level}), quantized-mesh ${qm[k].height.toFixed(3)} m (z${qm[k].level}), Δ ${d.toFixed(4)} m`);
    if (!(Math.abs(d) <= DECODE) || samples[k].level !== qm[k].level) {
      failures.push(`${l.name}: 3D Tiles ${samples[k].height} m at z${samples[k].level}, quantized-mesh ${qm[k].height} m at z${qm[k].level}`);
    }
  }
  assert.deepEqual(failures, [], 'heights off');
});

test(`${DATASET}: a view of the Alps drawn from 3D Tiles`, async () => {
  const target = [8.45, 46.55, 2500];
  await tab.evaluate((o) => window.tessera.fly(o), { target, range: 60000, heading: 10, pitch: -30 });
  const loaded = await tab.evaluate(() => window.tessera.tilesLoaded());
  const file = await screenshot(tab, 'cesium3dtiles-alps');
  const v = await tab.evaluate((p) => window.tessera.view(p), [FINSTERAARHORN, LAGO_MAGGIORE]);
  const [hF, hL] = v.heights;
  console.log(`# view: tiles loaded ${(loaded.ms / 1000).toFixed(1)} s after the flight; globe.getHeight Finsteraarhorn ` +
    `${hF?.toFixed(1)} m, Lago Maggiore ${hL?.toFixed(1)} m; centre crop grey std ${v.pixels.std.toFixed(1)}, ` +
    `${v.pixels.colours} colours (${path.relative(process.cwd(), file)})`);
  const [w, s, e, n] = footprint.bounds;
  const inside = (p) => p.lon > w && p.lon < e && p.lat > s && p.lat < n;
  assert.ok(v.centre && inside(v.centre) && Math.hypot(v.centre.lon - target[0], v.centre.lat - target[1]) < 0.1,
    `screen centre on ${JSON.stringify(v.centre)}, not near ${target}`);
  assert.ok(hF !== null && hL !== null && hF - hL > MIN_RELIEF,
    `rendered terrain too flat: Finsteraarhorn ${hF} m, Lago Maggiore ${hL} m (need > ${MIN_RELIEF} m apart)`);
  assert.ok(v.pixels.std > MIN_STD && v.pixels.colours > 1, `screenshot centre nearly one colour (grey std ${v.pixels.std})`);
});

// Last: everything the page did.
test(`${DATASET}: no console errors, no failed requests, only available tiles asked for`, () => {
  const ours = problems.all.filter((r) => TILES3D.test(r.url));
  const count = { glb: 0, subtree: 0 };
  const levels = {};
  for (const r of ours) {
    const [, , z, , , kind] = r.url.match(TILES3D);
    count[kind]++;
    levels[z] = (levels[z] ?? 0) + 1;
  }
  const statuses = {};
  for (const r of ours) statuses[r.status] = (statuses[r.status] ?? 0) + 1;
  console.log(`# ${count.glb} GLB and ${count.subtree} subtree responses (status ${JSON.stringify(statuses)}; per level ${JSON.stringify(levels)})`);
  assert.deepEqual(problems.console, [], 'console errors');
  assert.deepEqual(problems.failed, [], 'failed requests');
  assert.deepEqual(problems.responses, [], 'HTTP errors (a 404 is a tile or subtree asked for outside availability)');
  assert.ok(count.glb > 0 && count.subtree > 0, 'GLBs and subtrees were fetched');
  for (const r of ours) assert.equal(r.headers['access-control-allow-origin'], '*', `${r.url}: CORS`);
});

// Drives CesiumJS for cesium.test.mjs, through its public API only. Cesium.js (the IIFE build)
// is loaded by cesium.html with CESIUM_BASE_URL = /cesium/, where its Workers/ and Assets/ are.
const { Cesium } = window;

let widget, provider;

// A CesiumWidget (the Viewer's globe without its UI widgets) on Tessera's terrain, with no
// Cesium ion anywhere: no base imagery layer (`baseLayer: false`; the globe draws its plain
// `baseColor`), no sky box, sun or moon textures (`skyBox: false`); the terrain provider comes
// from our layer.json with both extensions. Lighting is on so the octvertexnormals shade the
// slopes: the sun stands where it does over the Alps on a June morning (the clock is stopped).
async function open({ server, dataset, requestWaterMask = false, format = 'quantized-mesh' }) {
  const root = `${server}/v1/datasets/${encodeURIComponent(dataset)}`;
  let layer, tileset;
  if (format === '3dtiles') {
    // 3D Tiles 1.1 (cesium3dtiles.test.mjs): fromUrl takes tileset.json itself
    const url = `${root}/3dtiles/tileset.json`;
    const response = await fetch(url);
    tileset = { status: response.status, doc: await response.json() };
    provider = await Cesium.Cesium3DTilesTerrainProvider.fromUrl(url, { requestVertexNormals: true });
  } else {
    // fromUrl takes the terrain's directory and reads `layer.json` in it (it appends a slash and
    // the name: given …/layer.json itself it would ask for …/layer.json/layer.json, and on that 404
    // fall back silently to a default layer)
    const base = `${root}/cesium/`;
    // the document as the page gets it (a cross-origin fetch: fails without CORS)
    const response = await fetch(`${base}layer.json`);
    layer = { status: response.status, doc: await response.json() };
    provider = await Cesium.CesiumTerrainProvider.fromUrl(base, { requestVertexNormals: true, requestMetadata: true, requestWaterMask });
  }
  provider.errorEvent.addEventListener((e) => console.error(`terrain provider error: ${e.message}`));
  const time = Cesium.JulianDate.fromIso8601('2026-06-21T08:00:00Z');
  widget = new Cesium.CesiumWidget('globe', {
    terrainProvider: provider, baseLayer: false, skyBox: false, shadows: false,
    clock: new Cesium.Clock({ startTime: time, currentTime: time, shouldAnimate: false }),
    contextOptions: { webgl: { preserveDrawingBuffer: true, antialias: false } }, msaaSamples: 1,
    useBrowserRecommendedResolution: true,
  });
  const globe = widget.scene.globe;
  globe.baseColor = Cesium.Color.fromCssColorString('#b8b8a8');
  globe.enableLighting = true;
  globe.depthTestAgainstTerrain = true;
  return { layer, tileset, hasVertexNormals: provider.hasVertexNormals, hasMetadata: provider.hasMetadata,
    hasWaterMask: provider.hasWaterMask, availability: Boolean(provider.availability) };
}

// sampleTerrainMostDetailed at [lon, lat] degrees: heights (m above the ellipsoid) from the
// deepest tile layer.json lists there, and that level.
async function sample(lonLats) {
  const positions = lonLats.map(([lon, lat]) => Cesium.Cartographic.fromDegrees(lon, lat));
  const done = await Cesium.sampleTerrainMostDetailed(provider, positions, true);
  // With metadata availability the provider learns the deeper zooms from the tiles it loaded:
  // the level is known after sampling.
  const levels = positions.map((p) => provider.availability.computeMaximumLevelAtPosition(p));
  return done.map((p, k) => ({ height: p.height, level: levels[k] }));
}

// sampleTerrainMostDetailed at [lon, lat] degrees from the server's quantized-mesh terrain,
// whatever the globe draws: the reference the 3D Tiles terrain is compared with.
async function sampleQuantizedMesh({ server, dataset, lonLats }) {
  const qm = await Cesium.CesiumTerrainProvider.fromUrl(`${server}/v1/datasets/${encodeURIComponent(dataset)}/cesium/`, { requestMetadata: true });
  const positions = lonLats.map(([lon, lat]) => Cesium.Cartographic.fromDegrees(lon, lat));
  const done = await Cesium.sampleTerrainMostDetailed(qm, positions, true);
  const levels = positions.map((p) => qm.availability.computeMaximumLevelAtPosition(p));
  return done.map((p, k) => ({ height: p.height, level: levels[k] }));
}

// Waits for `n` rendered frames.
function frames(n) {
  const scene = widget.scene;
  return new Promise((resolve) => {
    let k = 0;
    const remove = scene.postRender.addEventListener(() => { if (++k >= n) { remove(); resolve(); } });
    scene.requestRender();
  });
}

// The canvas's RGB pixels (the drawing buffer is preserved).
function pixels() {
  const canvas = widget.canvas;
  const c2 = document.createElement('canvas');
  c2.width = canvas.width; c2.height = canvas.height;
  const ctx = c2.getContext('2d');
  ctx.drawImage(canvas, 0, 0);
  return ctx.getImageData(0, 0, canvas.width, canvas.height).data;
}

// How much the globe's water effect changes the picture around each probe [lon, lat]: the mean
// absolute RGB difference over a 9 × 9 pixel box at the probe's screen position between a frame
// with `globe.showWaterEffect` and one without (tiles and camera unchanged), and the probe's
// screen position. Where the water mask says land, nothing changes.
async function waterEffect(probes) {
  const scene = widget.scene, globe = scene.globe, canvas = widget.canvas;
  const scale = canvas.width / canvas.clientWidth;
  const at = probes.map(([lon, lat]) => {
    const h = globe.getHeight(Cesium.Cartographic.fromDegrees(lon, lat)) ?? 0;
    const p = Cesium.SceneTransforms.worldToWindowCoordinates(scene, Cesium.Cartesian3.fromDegrees(lon, lat, h));
    return p && { x: Math.round(p.x * scale), y: Math.round(p.y * scale) };
  });
  globe.showWaterEffect = true;
  await frames(10);
  const wet = pixels();
  globe.showWaterEffect = false;
  await frames(10);
  const dry = pixels();
  globe.showWaterEffect = true;
  await frames(10);
  return at.map((p) => {
    if (!p) return { diff: null };
    let sum = 0, n = 0;
    for (let dy = -4; dy <= 4; dy++) for (let dx = -4; dx <= 4; dx++) {
      const x = p.x + dx, y = p.y + dy;
      if (x < 0 || y < 0 || x >= canvas.width || y >= canvas.height) continue;
      const k = 4 * (y * canvas.width + x);
      sum += Math.abs(wet[k] - dry[k]) + Math.abs(wet[k + 1] - dry[k + 1]) + Math.abs(wet[k + 2] - dry[k + 2]);
      n++;
    }
    return { x: p.x, y: p.y, diff: n ? sum / n : null };
  });
}

// Flies (2 s) to look at `target` [lon, lat, h] from `range` m at `heading`/`pitch` degrees.
function fly({ target, range, heading, pitch, duration = 2 }) {
  const centre = Cesium.Cartesian3.fromDegrees(...target);
  return new Promise((resolve, reject) => {
    widget.camera.flyToBoundingSphere(new Cesium.BoundingSphere(centre, 0), {
      offset: new Cesium.HeadingPitchRange(Cesium.Math.toRadians(heading), Cesium.Math.toRadians(pitch), range),
      duration, complete: resolve, cancel: () => reject(new Error('flight cancelled')),
    });
  });
}

// Resolves once the globe reports every tile in view loaded (`globe.tilesLoaded`) on `frames`
// consecutive rendered frames, with no terrain request pending; rejects after `timeoutMs`.
function tilesLoaded({ frames = 10, timeoutMs = 180000 } = {}) {
  const scene = widget.scene;
  return new Promise((resolve, reject) => {
    let n = 0;
    const t0 = performance.now();
    const remove = scene.postRender.addEventListener(() => {
      n = scene.globe.tilesLoaded ? n + 1 : 0;
      if (n >= frames) { remove(); clearTimeout(timer); resolve({ ms: performance.now() - t0 }); }
    });
    const timer = setTimeout(() => { remove(); reject(new Error(`globe.tilesLoaded not reached in ${timeoutMs / 1000} s`)); }, timeoutMs);
    scene.requestRender();
  });
}

// What the view shows: the camera's position (degrees, m above the ellipsoid), the globe point at
// the screen's centre, the rendered globe's heights (`globe.getHeight`, from the tiles it has
// loaded) at `probes`, and grey-level statistics of the canvas's centre crop (half its size).
function view(probes) {
  const scene = widget.scene, camera = widget.camera, canvas = widget.canvas;
  const c = camera.positionCartographic;
  const deg = Cesium.Math.toDegrees;
  const ray = camera.getPickRay(new Cesium.Cartesian2(canvas.clientWidth / 2, canvas.clientHeight / 2));
  const hit = ray && scene.globe.pick(ray, scene);
  const centre = hit ? Cesium.Cartographic.fromCartesian(hit) : null;
  const heights = probes.map(([lon, lat]) => scene.globe.getHeight(Cesium.Cartographic.fromDegrees(lon, lat)) ?? null);
  // pixels (the drawing buffer is preserved, so the last frame is still there)
  const w = canvas.width, h = canvas.height;
  const c2 = document.createElement('canvas');
  c2.width = w; c2.height = h;
  const ctx = c2.getContext('2d');
  ctx.drawImage(canvas, 0, 0);
  const px = ctx.getImageData(Math.floor(w / 4), Math.floor(h / 4), Math.floor(w / 2), Math.floor(h / 2)).data;
  let n = 0, sum = 0, sum2 = 0;
  const colours = new Set();
  for (let k = 0; k < px.length; k += 4) {
    const g = 0.299 * px[k] + 0.587 * px[k + 1] + 0.114 * px[k + 2];
    n++; sum += g; sum2 += g * g;
    colours.add((px[k] << 16) | (px[k + 1] << 8) | px[k + 2]);
  }
  const mean = sum / n;
  return {
    camera: { lon: deg(c.longitude), lat: deg(c.latitude), height: c.height,
      heading: deg(camera.heading), pitch: deg(camera.pitch) },
    centre: centre && { lon: deg(centre.longitude), lat: deg(centre.latitude), height: centre.height },
    heights, pixels: { n, mean, std: Math.sqrt(Math.max(0, sum2 / n - mean * mean)), colours: colours.size, width: w, height: h },
  };
}

window.tessera = { open, sample, sampleQuantizedMesh, fly, tilesLoaded, view, waterEffect, version: Cesium.VERSION, ready: true };

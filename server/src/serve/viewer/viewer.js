// Tessera's viewer of one dataset (server/src/serve/viewer/page.rs makes the page). MapLibre
// GL JS shows the dataset's Web Mercator height tiles as 3D terrain with a hillshade; the
// "Globe" button loads CesiumJS on the dataset's quantized-mesh terrain. Both libraries are
// served by this server (/viewer/assets/…): nothing is fetched from another host, no Cesium
// ion. Every URL is relative to the page. `window.tessera` exposes hooks for the browser test
// (tests/browser/viewer.test.mjs) and the console.
const config = JSON.parse(document.getElementById('tessera-config').textContent);
const abs = (url) => new URL(url, document.baseURI).href;
const $ = (id) => document.getElementById(id);
const BACKGROUND = '#dfe5ea';

const api = { ready: false, mode: 'maplibre', config, errors: [], globeReady: false };
window.tessera = api;

function status(text) {
  const el = $('status');
  el.textContent = text ?? '';
  el.hidden = !text;
}

function fail(where, e) {
  const message = `${where}: ${e?.message ?? e}`;
  api.errors.push(message);
  console.error(message);
  status(message);
}

function lonLatText(lon, lat) {
  const f = (v, pos, neg) => `${Math.abs(v).toFixed(4)}° ${v < 0 ? neg : pos}`;
  return `${f(lat, 'N', 'S')}, ${f(lon, 'E', 'W')}`;
}

function readout(lon, lat, height, via) {
  $('readout').textContent = height === null || height === undefined || Number.isNaN(height)
    ? `${lonLatText(lon, lat)}: no terrain here`
    : `${height.toFixed(1)} m at ${lonLatText(lon, lat)} (${via})`;
}

// ---- MapLibre GL JS ----------------------------------------------------------------------

let maplibregl, map;

// Resolves once every tile in view is loaded and nothing moves (with 3D terrain MapLibre may
// keep redrawing, so polling backs up the 'idle' event); rejects after `ms`.
function idle(ms = 120000) {
  return new Promise((resolve, reject) => {
    let rendered = false;
    const onRender = () => { rendered = true; };
    const done = (f) => { clearTimeout(timer); clearInterval(poll); map.off('render', onRender); map.off('idle', onIdle); f(); };
    const onIdle = () => done(resolve);
    const timer = setTimeout(() => done(() => reject(new Error(`map not idle after ${ms / 1000} s`))), ms);
    const poll = setInterval(() => {
      if (rendered && map.loaded() && map.areTilesLoaded() && !map.isMoving()) done(resolve);
    }, 250);
    map.on('render', onRender);
    map.on('idle', onIdle);
    map.triggerRepaint();
  });
}

async function openMap() {
  maplibregl = await import(abs(`${config.assets.maplibre}maplibre-gl.mjs`));
  // `url`: MapLibre reads the TileJSON itself and keeps to its `bounds` and zooms.
  const dem = () => ({ type: 'raster-dem', url: abs(config.tilejson), tileSize: 512, encoding: 'terrarium' });
  const [w, s, e, n] = config.bounds;
  map = new maplibregl.Map({
    container: 'map',
    style: {
      version: 8,
      sources: { terrain: dem(), hillshade: dem() },
      layers: [
        { id: 'background', type: 'background', paint: { 'background-color': BACKGROUND } },
        { id: 'hillshade', type: 'hillshade', source: 'hillshade',
          paint: { 'hillshade-shadow-color': '#2f3b46', 'hillshade-highlight-color': '#ffffff',
            'hillshade-accent-color': '#4b5a68', 'hillshade-exaggeration': 0.7 } },
      ],
      terrain: { source: 'terrain', exaggeration: 1 },
    },
    bounds: [[w, s], [e, n]],
    fitBoundsOptions: { padding: 24 },
    maxPitch: 85,
    attributionControl: { compact: true },
    canvasContextAttributes: { preserveDrawingBuffer: true },
  });
  map.on('error', (ev) => fail('map', ev.error ?? ev));
  map.addControl(new maplibregl.NavigationControl({ visualizePitch: true }), 'top-right');
  map.addControl(new maplibregl.TerrainControl({ source: 'terrain', exaggeration: 1 }), 'top-right');
  map.addControl(new maplibregl.ScaleControl(), 'bottom-left');
  // Fitted to the dataset, then tilted.
  map.fitBounds([[w, s], [e, n]], { padding: 24, pitch: 50, duration: 0 });
  map.on('mousemove', (ev) => {
    readout(ev.lngLat.lng, ev.lngLat.lat, map.queryTerrainElevation(ev.lngLat), 'MapLibre terrain');
  });
  map.once('load', () => status(''));
}

// The terrain height at [lon, lat] as MapLibre has it, looked at from straight above at
// `zoom`: the value once it is the same twice 200 ms apart after the view is loaded.
async function elevation(lonLat, zoom) {
  map.jumpTo({ center: lonLat, zoom, pitch: 0, bearing: 0 });
  await idle();
  let last = null;
  for (let k = 0; k < 150; k++) {
    const h = map.queryTerrainElevation(lonLat);
    if (h !== null && h === last) return h;
    last = h;
    await new Promise((r) => setTimeout(r, 200));
  }
  return last;
}

// ---- CesiumJS ----------------------------------------------------------------------------

let globe = null; // { Cesium, viewer, provider, ellipsoid }

function loadScript(src) {
  return new Promise((resolve, reject) => {
    const el = document.createElement('script');
    el.src = src;
    el.onload = resolve;
    el.onerror = () => reject(new Error(`cannot load ${src}`));
    document.head.append(el);
  });
}

function addStyle(href) {
  const el = document.createElement('link');
  el.rel = 'stylesheet';
  el.href = href;
  document.head.append(el);
}

async function openGlobe() {
  const base = abs(config.assets.cesium);
  window.CESIUM_BASE_URL = base;
  addStyle(`${base}Widgets/widgets.css`);
  await loadScript(`${base}Cesium.js`);
  const { Cesium } = window;
  let ellipsoid = Cesium.Ellipsoid.WGS84;
  if (!config.earth && config.radii) {
    // Another body (the Moon): its own ellipsoid for the globe and the terrain.
    ellipsoid = new Cesium.Ellipsoid(...config.radii);
    Cesium.Ellipsoid.default = ellipsoid;
  }
  // fromUrl takes the terrain's directory and reads layer.json in it.
  const provider = await Cesium.CesiumTerrainProvider.fromUrl(abs(config.cesium), { requestVertexNormals: true, ellipsoid });
  provider.errorEvent.addEventListener((e) => fail('terrain', e.message));
  // No Cesium ion: the Earth gets the Natural Earth II imagery CesiumJS ships in its own
  // Assets (served here); another body a plain globe.
  const baseLayer = config.earth
    ? Cesium.ImageryLayer.fromProviderAsync(Cesium.TileMapServiceImageryProvider.fromUrl(
      Cesium.buildModuleUrl('Assets/Textures/NaturalEarthII')))
    : false;
  const [w, s, e, n] = config.bounds;
  const lon = (w + e) / 2, lat = (s + n) / 2;
  // Lit as at 10:00 local solar time on 21 June, so the terrain's normals shade the slopes.
  const time = Cesium.JulianDate.fromDate(new Date(Date.UTC(2026, 5, 21, 10) - (lon / 15) * 3600e3));
  const viewer = new Cesium.Viewer('globe', {
    terrainProvider: provider, baseLayer, ellipsoid,
    baseLayerPicker: false, geocoder: false, animation: false, timeline: false, homeButton: false,
    sceneModePicker: false, navigationHelpButton: false, fullscreenButton: false, infoBox: false,
    selectionIndicator: false, skyBox: false, ...(config.earth ? {} : { skyAtmosphere: false }),
    shadows: false, msaaSamples: 1, useBrowserRecommendedResolution: true,
    clockViewModel: new Cesium.ClockViewModel(new Cesium.Clock({ startTime: time, currentTime: time, shouldAnimate: false })),
    contextOptions: { webgl: { preserveDrawingBuffer: true } },
  });
  const scene = viewer.scene;
  scene.globe.enableLighting = true;
  scene.globe.depthTestAgainstTerrain = true;
  scene.globe.baseColor = Cesium.Color.fromCssColorString('#b8b8a8');
  const handler = new Cesium.ScreenSpaceEventHandler(scene.canvas);
  handler.setInputAction((m) => {
    const ray = viewer.camera.getPickRay(m.endPosition);
    const hit = ray && scene.globe.pick(ray, scene);
    if (!hit) { $('readout').textContent = 'Point at the terrain for its height'; return; }
    const c = Cesium.Cartographic.fromCartesian(hit, ellipsoid);
    readout(Cesium.Math.toDegrees(c.longitude), Cesium.Math.toDegrees(c.latitude), c.height, 'Cesium terrain, above the ellipsoid');
  }, Cesium.ScreenSpaceEventType.MOUSE_MOVE);
  globe = { Cesium, viewer, provider, ellipsoid };
  // Fly to the dataset: its middle, seen from the south, pitched down, near enough for the
  // relief to show.
  const r = ellipsoid.maximumRadius;
  const rad = Math.PI / 180;
  const across = Math.hypot((e - w) * rad * r * Math.cos(lat * rad), (n - s) * rad * r);
  const centre = Cesium.Cartesian3.fromDegrees(lon, lat, (config.minHeight + config.maxHeight) / 2, ellipsoid);
  await new Promise((resolve) => {
    viewer.camera.flyToBoundingSphere(new Cesium.BoundingSphere(centre, across / 2), {
      offset: new Cesium.HeadingPitchRange(0, -40 * rad, Math.max(across * 0.75, 2000)),
      duration: 1.5, complete: resolve, cancel: resolve,
    });
  });
}

// Resolves once the globe reports every tile in view loaded on `frames` rendered frames in a
// row; rejects after `ms`.
function globeTilesLoaded(frames = 10, ms = 240000) {
  const scene = globe.viewer.scene;
  return new Promise((resolve, reject) => {
    let k = 0;
    const t0 = performance.now();
    const remove = scene.postRender.addEventListener(() => {
      k = scene.globe.tilesLoaded ? k + 1 : 0;
      if (k >= frames) { remove(); clearTimeout(timer); resolve({ ms: performance.now() - t0 }); }
    });
    const timer = setTimeout(() => { remove(); reject(new Error(`globe.tilesLoaded not reached in ${ms / 1000} s`)); }, ms);
    scene.requestRender();
  });
}

// The terrain's height (metres above the ellipsoid) at each [lon, lat], from the deepest
// tiles layer.json lists there.
async function globeSample(lonLats) {
  const { Cesium, provider } = globe;
  const positions = lonLats.map(([lon, lat]) => Cesium.Cartographic.fromDegrees(lon, lat));
  const done = await Cesium.sampleTerrainMostDetailed(provider, positions, true);
  return done.map((p) => p.height);
}

// ---- both ----------------------------------------------------------------------------------

// Grey-level statistics of the centre crop (half its size) of the view on screen, and the
// share of its pixels that differ from the map's background colour.
function centrePixels() {
  const canvas = api.mode === 'cesium' ? globe.viewer.scene.canvas : map.getCanvas();
  const c2 = document.createElement('canvas');
  c2.width = canvas.width; c2.height = canvas.height;
  const ctx = c2.getContext('2d');
  ctx.drawImage(canvas, 0, 0);
  const px = ctx.getImageData(Math.floor(c2.width / 4), Math.floor(c2.height / 4),
    Math.floor(c2.width / 2), Math.floor(c2.height / 2)).data;
  const bg = [0xdf, 0xe5, 0xea];
  let n = 0, sum = 0, sum2 = 0, other = 0;
  for (let k = 0; k < px.length; k += 4) {
    const g = 0.299 * px[k] + 0.587 * px[k + 1] + 0.114 * px[k + 2];
    n++; sum += g; sum2 += g * g;
    if (Math.hypot(px[k] - bg[0], px[k + 1] - bg[1], px[k + 2] - bg[2]) > 12) other++;
  }
  const mean = sum / n;
  return { n, mean, std: Math.sqrt(Math.max(0, sum2 / n - mean * mean)), notBackground: other / n };
}

async function setMode(mode) {
  if (mode === api.mode && (mode === 'maplibre' || api.globeReady)) return;
  api.mode = mode;
  $('mode-maplibre').setAttribute('aria-pressed', String(mode === 'maplibre'));
  $('mode-cesium').setAttribute('aria-pressed', String(mode === 'cesium'));
  $('map').hidden = mode !== 'maplibre';
  $('globe').hidden = mode !== 'cesium';
  $('readout').textContent = 'Point at the terrain for its height';
  if (mode === 'cesium') {
    if (!globe) {
      status('Loading CesiumJS…');
      try {
        await openGlobe();
      } catch (e) {
        fail('CesiumJS', e);
        return;
      }
      status('');
    }
    globe.viewer.useDefaultRenderLoop = true;
    api.globeReady = true;
  } else {
    if (globe) globe.viewer.useDefaultRenderLoop = false;
    map.resize();
  }
}

$('mode-maplibre').addEventListener('click', () => setMode('maplibre'));
$('mode-cesium').addEventListener('click', () => setMode('cesium'));
window.addEventListener('unhandledrejection', (ev) => fail('unexpected', ev.reason));

Object.assign(api, {
  idle, elevation, centrePixels, setMode, globeTilesLoaded, globeSample,
  version: () => ({ maplibre: maplibregl?.getVersion?.() ?? null, cesium: window.Cesium?.VERSION ?? null }),
});
// (getters: Object.assign would copy their values of now)
Object.defineProperties(api, {
  map: { get: () => map },
  globe: { get: () => globe },
});

try {
  await openMap();
  api.ready = true;
} catch (e) {
  fail('MapLibre', e);
}

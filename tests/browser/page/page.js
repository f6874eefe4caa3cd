// Drives MapLibre for maplibre.test.mjs. Everything here uses MapLibre's public API only.
import * as maplibregl from '/maplibre/maplibre-gl.mjs';

const BACKGROUND = [255, 0, 255]; // magenta: no hillshade colour comes near it

// The standard-grid TileJSON's URL, and the document as the page fetches it (cross-origin: it
// fails without CORS). The server's defaults must give `tiles` that work from this page's origin
// (absolute, on the tile server): the map below takes them exactly as MapLibre does, from the
// TileJSON `url`, with nothing resolved or rewritten here.
async function tileJSON(server, dataset, size) {
  const url = `${server}/v1/datasets/${encodeURIComponent(dataset)}/webmercator/tilejson.json?encoding=terrarium&size=${size}`;
  const response = await fetch(url);
  if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
  return { url, doc: await response.json() };
}

// A raster-dem source on the TileJSON `url`, as a MapLibre user writes it: MapLibre reads
// `tiles`, `bounds`, `minzoom` and `maxzoom` from the document (so it asks only for tiles within
// the bounds); `tileSize` and `encoding` are the source's own options (MapLibre does not take
// them from TileJSON).
function demSource({ url, doc }) {
  return { type: 'raster-dem', url, tileSize: doc.tileSize, encoding: doc.encoding };
}

// Resolves at the next 'idle' (every tile in view loaded, nothing moving), or once polling sees
// the map loaded with all its tiles after a frame has been drawn (with 3D terrain MapLibre can
// keep redrawing, so 'idle' may be long in coming); rejects after 90 s.
function idle(map) {
  return new Promise((resolve, reject) => {
    let rendered = false;
    const onRender = () => { rendered = true; };
    const done = (f) => { clearTimeout(timer); clearInterval(poll); map.off('render', onRender); map.off('idle', onIdle); f(); };
    const onIdle = () => done(resolve);
    const timer = setTimeout(() => done(() => reject(new Error('map not idle after 90 s'))), 90000);
    const poll = setInterval(() => {
      if (rendered && map.loaded() && map.areTilesLoaded() && !map.isMoving()) done(resolve);
    }, 250);
    map.on('render', onRender);
    map.on('idle', onIdle);
    map.triggerRepaint();
  });
}

let map;

const RELIEF_LOW = [255, 0, 0]; // color-relief below the plausible range: pure red
const RELIEF_OK = [96, 96, 96];

// mode 'placement': hillshade only, flat map, no basemap, over a plain background.
// mode 'terrain': hillshade plus 3D terrain with exaggeration 1 (two sources, as MapLibre advises).
// mode 'relief': 3D terrain draped with a color-relief layer that is pure red below `low` metres
// and grey from there up (the walls test: a height below `low` anywhere MapLibre draws is red).
// view: { bounds: [w, s, e, n], padding } or { center, zoom } (zoom may be 'maxzoom'): where
// the map starts.
async function open({ server, dataset, mode, view, size = 512, low = -1e6 }) {
  const tj = await tileJSON(server, dataset, size);
  const style = {
    version: 8,
    sources: { dem: demSource(tj) },
    layers: [
      { id: 'background', type: 'background', paint: { 'background-color': `rgb(${BACKGROUND.join(',')})` } },
    ],
  };
  if (mode === 'relief') {
    style.layers.push({ id: 'relief', type: 'color-relief', source: 'dem',
      paint: { 'color-relief-color': ['interpolate', ['linear'], ['elevation'],
        low - 0.01, `rgb(${RELIEF_LOW.join(',')})`, low, `rgb(${RELIEF_OK.join(',')})`] } });
  } else {
    style.layers.push({ id: 'hillshade', type: 'hillshade', source: 'dem',
      paint: { 'hillshade-exaggeration': 1, 'hillshade-shadow-color': '#000000',
        'hillshade-highlight-color': '#ffffff', 'hillshade-accent-color': '#000000' } });
  }
  if (mode === 'terrain' || mode === 'relief') {
    style.sources.terrain = demSource(tj);
    style.terrain = { source: 'terrain', exaggeration: 1 };
  }
  const doc = tj.doc;
  map = new maplibregl.Map({
    container: 'map', style, ...(view.bounds
      ? { bounds: [[view.bounds[0], view.bounds[1]], [view.bounds[2], view.bounds[3]]], fitBoundsOptions: { padding: view.padding } }
      : { center: view.center, zoom: view.zoom === 'maxzoom' ? doc.maxzoom : view.zoom }),
    attributionControl: false, fadeDuration: 0, pitch: 0,
    canvasContextAttributes: { preserveDrawingBuffer: true, antialias: false },
  });
  map.on('error', (e) => console.error(`maplibre error: ${e.error?.message ?? e.error ?? e}`));
  await idle(map);
  return { ...doc, zoom: map.getZoom() };
}

// Fits [w, s, e, n] with `padding` px of margin; waits until every tile in view has loaded.
async function fit(bounds, padding) {
  map.fitBounds([[bounds[0], bounds[1]], [bounds[2], bounds[3]]], { padding, animate: false });
  await idle(map);
  return map.getZoom();
}

// Counts drawn pixels (anything not the background) inside `polygon` ([[lon, lat]…], projected to
// the screen with map.project), within `band` px outside its edge (MapLibre's hillshade takes
// its slope from the neighbouring DEM pixels, so the drop at the data's edge shades a pixel or
// two beyond it), and farther out.
function placement(polygon, band = 2) {
  const canvas = map.getCanvas();
  const w = canvas.width, h = canvas.height;
  const ratio = w / canvas.clientWidth;
  const c2 = document.createElement('canvas');
  c2.width = w; c2.height = h;
  const ctx = c2.getContext('2d');
  ctx.drawImage(canvas, 0, 0);
  const px = ctx.getImageData(0, 0, w, h).data;
  const poly = polygon.map((p) => { const q = map.project(p); return [q.x * ratio, q.y * ratio]; });
  const inside = (x, y) => { // even-odd rule
    let r = false;
    for (let i = 0, j = poly.length - 1; i < poly.length; j = i++) {
      const [xi, yi] = poly[i], [xj, yj] = poly[j];
      if ((yi > y) !== (yj > y) && x < ((xj - xi) * (y - yi)) / (yj - yi) + xi) r = !r;
    }
    return r;
  };
  const nearEdge = (x, y) => poly.some(([xi, yi], i) => {
    const [xj, yj] = poly[(i + 1) % poly.length];
    const dx = xj - xi, dy = yj - yi;
    const t = Math.max(0, Math.min(1, ((x - xi) * dx + (y - yi) * dy) / (dx * dx + dy * dy)));
    return Math.hypot(x - xi - t * dx, y - yi - t * dy) <= band;
  });
  let drawnIn = 0, drawnBand = 0, drawnOut = 0, area = 0;
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      const k = (y * w + x) * 4;
      const d = Math.abs(px[k] - BACKGROUND[0]) + Math.abs(px[k + 1] - BACKGROUND[1]) + Math.abs(px[k + 2] - BACKGROUND[2]);
      const drawn = d > 12;
      const isIn = inside(x + 0.5, y + 0.5);
      if (isIn) area++;
      if (drawn) { if (isIn) drawnIn++; else if (nearEdge(x + 0.5, y + 0.5)) drawnBand++; else drawnOut++; }
    }
  }
  return { drawnIn, drawnBand, drawnOut, area, width: w, height: h, polygonOnScreen: poly };
}

async function jump(center, zoom, { pitch = 0, bearing = 0 } = {}) {
  map.jumpTo({ center, zoom, pitch, bearing });
  await idle(map);
  return { zoom: map.getZoom() };
}

// Counts the pixels the color-relief layer paints red (a height below its `low`), the grey
// ones (a plausible height) and the rest (background, sky).
function reliefPixels() {
  const canvas = map.getCanvas();
  const c2 = document.createElement('canvas');
  c2.width = canvas.width; c2.height = canvas.height;
  const ctx = c2.getContext('2d');
  ctx.drawImage(canvas, 0, 0);
  const px = ctx.getImageData(0, 0, c2.width, c2.height).data;
  const near = (k, c) => Math.abs(px[k] - c[0]) + Math.abs(px[k + 1] - c[1]) + Math.abs(px[k + 2] - c[2]) <= 24;
  let low = 0, ok = 0, other = 0;
  for (let k = 0; k < px.length; k += 4) {
    if (near(k, RELIEF_LOW)) low++; else if (near(k, RELIEF_OK)) ok++; else other++;
  }
  return { low, ok, other };
}

function elevation(lngLat) {
  return map.queryTerrainElevation(lngLat);
}

// The zoom of the DEM tile the terrain samples at lngLat, or null once loaded data is not found.
// Diagnostic only, through MapLibre 6 internals (Terrain, its tile manager), so any error gives
// 'unknown' rather than failing the test.
function demZoom(lngLat) {
  try {
    const terrain = map.terrain;
    // the terrain's tiles are tileSize · 2^deltaZoom px (1024 for a 512-px source), so at tile
    // zoom T they are zoom T − 1; getSourceTile goes deltaZoom further down for the DEM
    const zoom = map._camera.projectedCamera.tileZoom - Math.log2(terrain.tileManager.tileSize / 512);
    const { tileID } = terrain._getOverscaledTileIDFromLngLatZoom(maplibregl.LngLat.convert(lngLat), zoom);
    const source = terrain.tileManager.getSourceTile(tileID, true);
    return source?.dem ? source.tileID.canonical.z : null;
  } catch {
    return 'unknown';
  }
}

// queryTerrainElevation once MapLibre's CPU elevation index reads the DEM tiles loaded now.
// MapLibre 6.20 builds that index (TerrainCoverage) when first asked and keeps each tile's
// sampler until the set of rendered tiles changes, even when the sampler was made from a loaded
// parent's DEM (one zoom coarser) while the tile's own was loading: queryTerrainElevation then
// answers from the coarser DEM although the terrain is drawn from the fine one. A jump out one
// zoom and back changes the rendered set, which drops the index; public API only.
async function freshElevation(lngLat, zoom) {
  await jump(lngLat, zoom - 1);
  await jump(lngLat, zoom);
  return map.queryTerrainElevation(lngLat);
}

window.tessera = { open, fit, placement, jump, elevation, freshElevation, demZoom, reliefPixels, ready: true };

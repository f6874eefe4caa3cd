// Drives MapLibre for maplibre.test.mjs. Everything here uses MapLibre's public API only.
import * as maplibregl from '/maplibre/maplibre-gl.mjs';

const BACKGROUND = [255, 0, 255]; // magenta: no hillshade colour comes near it

// The TileJSON with its tile URL templates made absolute. The server gives them relative to
// itself when it has no --public-url (API.md); TileJSON says they resolve against the document's
// URL, but MapLibre 6 uses `tiles` as given (loadTileJson copies them), so a relative template
// would be fetched from this page's origin. Resolving here keeps the test to the contract.
async function tileJSON(server, dataset, size) {
  const url = `${server}/v1/datasets/${encodeURIComponent(dataset)}/webmercator/tilejson.json?encoding=terrarium&size=${size}`;
  const response = await fetch(url);
  if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
  const doc = await response.json();
  // (URL percent-encodes the braces of {z}/{x}/{y}; they are put back)
  const resolve = (t) => new URL(t, url).href.replace(/%7B(z|x|y)%7D/gi, '{$1}');
  return { ...doc, tiles: doc.tiles.map(resolve) };
}

// A raster-dem source from the TileJSON. `bounds` is left out on purpose: with it MapLibre would
// request only tiles inside the bounds the server states, which could hide tiles drawn in the
// wrong place; without it every tile in view is asked for and the server's 404s for tiles
// outside the data are expected (see maplibre.test.mjs, expected404).
function demSource(tj) {
  return { type: 'raster-dem', tiles: tj.tiles, tileSize: tj.tileSize, minzoom: tj.minzoom,
    maxzoom: tj.maxzoom, encoding: tj.encoding }; // scheme: MapLibre 6's raster-dem has none (xyz)
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

// mode 'placement': hillshade only, flat map, no basemap, over a plain background.
// mode 'terrain': hillshade plus 3D terrain with exaggeration 1 (two sources, as MapLibre advises).
// view: { bounds: [w, s, e, n], padding } or { center, zoom } (zoom may be 'maxzoom'): where
// the map starts.
async function open({ server, dataset, mode, view, size = 512 }) {
  const tj = await tileJSON(server, dataset, size);
  const style = {
    version: 8,
    sources: { hillshade: demSource(tj) },
    layers: [
      { id: 'background', type: 'background', paint: { 'background-color': `rgb(${BACKGROUND.join(',')})` } },
      { id: 'hillshade', type: 'hillshade', source: 'hillshade',
        paint: { 'hillshade-exaggeration': 1, 'hillshade-shadow-color': '#000000',
          'hillshade-highlight-color': '#ffffff', 'hillshade-accent-color': '#000000' } },
    ],
  };
  if (mode === 'terrain') {
    style.sources.terrain = demSource(tj);
    style.terrain = { source: 'terrain', exaggeration: 1 };
  }
  map = new maplibregl.Map({
    container: 'map', style, ...(view.bounds
      ? { bounds: [[view.bounds[0], view.bounds[1]], [view.bounds[2], view.bounds[3]]], fitBoundsOptions: { padding: view.padding } }
      : { center: view.center, zoom: view.zoom === 'maxzoom' ? tj.maxzoom : view.zoom }),
    attributionControl: false, fadeDuration: 0, pitch: 0,
    canvasContextAttributes: { preserveDrawingBuffer: true, antialias: false },
  });
  map.on('error', (e) => console.error(`maplibre error: ${e.error?.message ?? e.error ?? e}`));
  await idle(map);
  return { ...tj, zoom: map.getZoom() };
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

async function jump(center, zoom) {
  map.jumpTo({ center, zoom, pitch: 0, bearing: 0 });
  await idle(map);
  return { zoom: map.getZoom() };
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
    const zoom = Math.min(map._camera.projectedCamera.tileZoom, terrain.tileManager.maxzoom);
    const { tileID } = terrain._getOverscaledTileIDFromLngLatZoom(maplibregl.LngLat.convert(lngLat), zoom);
    const source = terrain.tileManager.getSourceTile(tileID, true);
    return source?.dem ? source.tileID.canonical.z : null;
  } catch {
    return 'unknown';
  }
}

window.tessera = { open, fit, placement, jump, elevation, demZoom, ready: true };

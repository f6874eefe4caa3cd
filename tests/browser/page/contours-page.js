// Drives MapLibre for contours.test.mjs: a vector source on the server's contour TileJSON and a
// line layer on its `contours` source layer, index contours drawn thicker. Public API only.
import * as maplibregl from '/maplibre/maplibre-gl.mjs';
import { idle } from '/map-idle.js';

let map;

// The contours of TileJSON `url` centred on `center` at `zoom`; resolves to what MapLibre read
// from the TileJSON.
async function open({ url, center, zoom }) {
  map = new maplibregl.Map({
    container: 'map',
    style: {
      version: 8,
      sources: { contours: { type: 'vector', url } },
      layers: [
        { id: 'background', type: 'background', paint: { 'background-color': '#ffffff' } },
        {
          id: 'contours', type: 'line', source: 'contours', 'source-layer': 'contours',
          paint: { 'line-color': '#8a4b0f', 'line-width': ['case', ['get', 'index'], 1.6, 0.6] },
        },
      ],
    },
    center, zoom, attributionControl: false, fadeDuration: 0,
    canvasContextAttributes: { preserveDrawingBuffer: true, antialias: false },
  });
  map.on('error', (e) => console.error(`maplibre error: ${e.error?.message ?? e.error ?? e}`));
  await idle(map);
  const source = map.getSource('contours');
  return { minzoom: source.minzoom, maxzoom: source.maxzoom, vectorLayerIds: source.vectorLayerIds ?? null };
}

// The lines MapLibre decoded: elevation, index flag and the first vertices, as longitude and
// latitude; and the share of the canvas the lines inked.
function lines() {
  const features = map.querySourceFeatures('contours', { sourceLayer: 'contours' }).map((f) => {
    const g = f.geometry;
    const coords = g.type === 'LineString' ? g.coordinates : g.coordinates.flat();
    return { ele: f.properties.ele, index: f.properties.index, coords: coords.slice(0, 3) };
  });
  const canvas = map.getCanvas();
  const copy = document.createElement('canvas');
  copy.width = canvas.width; copy.height = canvas.height;
  const ctx = copy.getContext('2d');
  ctx.drawImage(canvas, 0, 0);
  const px = ctx.getImageData(0, 0, copy.width, copy.height).data;
  let ink = 0;
  for (let i = 0; i < px.length; i += 4) if (px[i] < 235 || px[i + 1] < 235 || px[i + 2] < 235) ink++;
  return { features, ink: ink / (px.length / 4), rendered: map.queryRenderedFeatures({ layers: ['contours'] }).length };
}

window.tessera = { open, lines, ready: true };

// Drives MapLibre for pmtiles.test.mjs: the pmtiles protocol (the `pmtiles` npm package's own
// Protocol, as its README tells MapLibre users), a raster-dem source on `pmtiles://URL`, 3D
// terrain and a hillshade from it. Public API only.
import * as maplibregl from '/maplibre/maplibre-gl.mjs';
import { idle } from '/map-idle.js';

/* global pmtiles */
const protocol = new pmtiles.Protocol();
maplibregl.addProtocol('pmtiles', protocol.tile);

let map;

// The archive at `url` as terrain (and a hillshade), centred on `center` at `zoom`; resolves to
// what MapLibre read from the archive's header (through the protocol's TileJSON).
async function open({ url, center, zoom }) {
  const dem = { type: 'raster-dem', url: `pmtiles://${url}`, tileSize: 512, encoding: 'terrarium' };
  map = new maplibregl.Map({
    container: 'map',
    style: {
      version: 8,
      sources: { dem, terrain: { ...dem } },
      layers: [
        { id: 'background', type: 'background', paint: { 'background-color': '#ff00ff' } },
        { id: 'hillshade', type: 'hillshade', source: 'dem' },
      ],
      terrain: { source: 'terrain', exaggeration: 1 },
    },
    center, zoom, attributionControl: false, fadeDuration: 0,
    canvasContextAttributes: { preserveDrawingBuffer: true, antialias: false },
  });
  map.on('error', (e) => console.error(`maplibre error: ${e.error?.message ?? e.error ?? e}`));
  await idle(map);
  const source = map.getSource('terrain');
  return { minzoom: source.minzoom, maxzoom: source.maxzoom, bounds: source.bounds ?? null };
}

async function jump(center, zoom) {
  map.jumpTo({ center, zoom });
  await idle(map);
}

// queryTerrainElevation after the elevation index has been rebuilt for the tiles loaded now
// (see page.js freshElevation: a jump out one zoom and back).
async function freshElevation(lngLat, zoom) {
  await jump(lngLat, zoom - 1);
  await jump(lngLat, zoom);
  return map.queryTerrainElevation(lngLat);
}

window.tessera = { open, jump, freshElevation, elevation: (ll) => map.queryTerrainElevation(ll), ready: true };

// The harness of the browser tests: pyramids built with the server binary, `tessera-server
// serve` on a random port, a second tiny HTTP server for the test pages, MapLibre and CesiumJS
// (another origin, so CORS is exercised), and headless Chromium driven by puppeteer-core.
import { spawn, execFileSync } from 'node:child_process';
import fs from 'node:fs';
import http from 'node:http';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import puppeteer from 'puppeteer-core';

export const HERE = path.dirname(path.dirname(fileURLToPath(import.meta.url)));
export const ROOT = path.resolve(HERE, '../..');
export const DATA = path.resolve(ROOT, process.env.TESSERA_DATA ?? '../shared/data/dem');
export const OUT = path.resolve(ROOT, process.env.TESSERA_BROWSER_OUT ?? 'out/browser');
const SERVER_BIN = path.resolve(ROOT, process.env.TESSERA_SERVER ?? 'target/debug/tessera-server');
const CHROMIUM = process.env.CHROMIUM ?? '/usr/bin/chromium';

// Builds DATA/NAME.tif into DIR/NAME.tess for each name, with `args` added to each
// `tessera-server build` (e.g. ['--vertical-datum', 'egm96']); returns DIR (a fresh temp dir).
export const SERVER = SERVER_BIN;

export function buildPyramids(names, { args = [] } = {}) {
  const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'tessera-browser-'));
  for (const name of names) {
    const input = path.join(DATA, `${name}.tif`);
    if (!fs.existsSync(input)) throw new Error(`missing test DEM ${input}`);
    execFileSync(SERVER_BIN, ['build', input, '-o', path.join(dir, `${name}.tess`), '--quiet', ...args],
      { stdio: ['ignore', 'ignore', 'inherit'] });
  }
  return dir;
}

// `tessera-server serve DIR --listen 127.0.0.1:0 ARGS…`; resolves to { url, stop } once it prints
// `listening on http://ADDR`. TESSERA_TILE_SERVER=URL uses an already running server instead.
export async function startTileServer(dir, { args = [] } = {}) {
  if (process.env.TESSERA_TILE_SERVER) return { url: process.env.TESSERA_TILE_SERVER, stop: async () => {}, log: () => '' };
  const child = spawn(SERVER_BIN, ['serve', dir, '--listen', '127.0.0.1:0', ...args], { stdio: ['ignore', 'pipe', 'pipe'] });
  let stdout = '', stderr = '';
  child.stderr.on('data', (d) => { stderr += d; });
  const url = await new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error(`server did not start in 20 s:\n${stderr}`)), 20000);
    child.stdout.on('data', (d) => {
      stdout += d;
      const m = stdout.match(/^listening on (http:\/\/\S+)$/m);
      if (m) { clearTimeout(timer); resolve(m[1]); }
    });
    child.on('exit', (code) => { clearTimeout(timer); reject(new Error(`server exited (${code}):\n${stderr}`)); });
  });
  child.removeAllListeners('exit');
  const stop = () => new Promise((resolve) => {
    if (child.exitCode !== null) return resolve();
    child.once('exit', resolve);
    child.kill('SIGTERM');
  });
  return { url, stop, log: () => stderr };
}

const TYPES = { '.html': 'text/html', '.js': 'text/javascript', '.mjs': 'text/javascript',
  '.css': 'text/css', '.map': 'application/json', '.json': 'application/json', '.wasm': 'application/wasm',
  '.png': 'image/png', '.jpg': 'image/jpeg', '.svg': 'image/svg+xml', '.ktx2': 'image/ktx2', '.glb': 'model/gltf-binary' };

// Serves page/ at /, maplibre-gl's dist/ at /maplibre/, the pmtiles package's dist/ at /pmtiles/,
// and CesiumJS's built package
// (cesium's Build/Cesium: Cesium.js, Workers/, Assets/, Widgets/, ThirdParty/) at /cesium/ on
// 127.0.0.1, another port; straight from node_modules, nothing copied.
export async function startStaticServer() {
  const roots = { '/maplibre/': path.join(HERE, 'node_modules/maplibre-gl/dist'),
    '/pmtiles/': path.join(HERE, 'node_modules/pmtiles/dist'),
    '/cesium/': path.join(HERE, 'node_modules/cesium/Build/Cesium'), '/': path.join(HERE, 'page') };
  const server = http.createServer((req, res) => {
    const p = decodeURIComponent(new URL(req.url, 'http://x').pathname);
    const prefix = Object.keys(roots).find((r) => p.startsWith(r));
    let file = path.join(roots[prefix], p.slice(prefix.length) || 'index.html');
    if (!file.startsWith(roots[prefix]) || !fs.existsSync(file) || !fs.statSync(file).isFile()) {
      res.writeHead(404); return res.end('not found');
    }
    res.writeHead(200, { 'Content-Type': TYPES[path.extname(file)] ?? 'application/octet-stream' });
    fs.createReadStream(file).pipe(res);
  });
  await new Promise((resolve) => server.listen(0, '127.0.0.1', resolve));
  return { url: `http://127.0.0.1:${server.address().port}`, stop: () => new Promise((r) => server.close(r)) };
}

// Chromium headless with WebGL on SwiftShader (PLATFORM.md).
export async function launchBrowser() {
  return puppeteer.launch({
    executablePath: CHROMIUM, headless: true,
    args: ['--no-sandbox', '--use-gl=angle', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
      '--ignore-gpu-blocklist', '--disable-dev-shm-usage'],
  });
}

// A tab on test page `file` (page/index.html: MapLibre; page/cesium.html: CesiumJS), with every
// console error, page error, failed request and HTTP error response recorded in `problems` (the
// test decides which 404s are expected), and every response's URL, status and headers in
// `problems.all`.
export async function openPage(browser, staticUrl, { width = 800, height = 800, file = 'index.html' } = {}) {
  const page = await browser.newPage();
  await page.setViewport({ width, height, deviceScaleFactor: 1 });
  const problems = { console: [], failed: [], aborted: [], responses: [], tiles: [], all: [] };
  // Chromium logs "Failed to load resource" for every status >= 400: those carry the URL, so
  // the test can match them with the responses it expects
  page.on('console', (m) => { if (m.type() === 'error') problems.console.push({ text: m.text(), url: m.location()?.url ?? '' }); });
  page.on('pageerror', (e) => problems.console.push({ text: `page error: ${e.message}`, url: '' }));
  // A request the page cancelled itself (MapLibre aborts the tiles of a view it has left:
  // net::ERR_ABORTED) is the client's choice, not a failure; a slow machine makes more of them.
  // A server that drops or cuts a response shows as another error (ERR_EMPTY_RESPONSE,
  // ERR_CONNECTION_RESET, ERR_INCOMPLETE_CHUNKED_ENCODING …), which fails the test.
  page.on('requestfailed', (r) => {
    const why = r.failure()?.errorText;
    (why === 'net::ERR_ABORTED' ? problems.aborted : problems.failed).push(`${r.url()}: ${why}`);
  });
  page.on('response', (r) => {
    problems.all.push({ url: r.url(), status: r.status(), headers: r.headers() });
    const m = r.url().match(/\/webmercator\/(\d+)\/(\d+)\/(\d+)\.png/);
    if (m) problems.tiles.push({ z: +m[1], x: +m[2], y: +m[3], status: r.status() });
    if (r.status() >= 400) problems.responses.push({ url: r.url(), status: r.status(), tile: m ? { z: +m[1], x: +m[2], y: +m[3] } : null });
  });
  await page.goto(`${staticUrl}/${file}`, { waitUntil: 'load' });
  await page.waitForFunction(() => window.tessera?.ready === true, { timeout: 30000 });
  return { page, problems };
}

export function screenshot(page, name) {
  fs.mkdirSync(OUT, { recursive: true });
  const file = path.join(OUT, `${name}.png`);
  return page.screenshot({ path: file }).then(() => file);
}

// nginx serving a folder's files on a free loopback port, as a static host or CDN would: byte
// ranges (nginx's own, for static files), CORS for another origin's page, and an access log of
// every request's method, status, Range header and bytes sent (pmtiles.test.mjs).
import { spawn } from 'node:child_process';
import fs from 'node:fs';
import net from 'node:net';
import os from 'node:os';
import path from 'node:path';

const NGINX = process.env.TESSERA_NGINX ?? '/usr/sbin/nginx';

function freePort() {
  return new Promise((resolve, reject) => {
    const s = net.createServer();
    s.on('error', reject);
    s.listen(0, '127.0.0.1', () => { const { port } = s.address(); s.close(() => resolve(port)); });
  });
}

// Resolves to { url, log(), stop() } once nginx accepts connections.
export async function startNginx(root) {
  const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'tessera-nginx-'));
  for (const d of ['logs', 'tmp']) fs.mkdirSync(path.join(dir, d));
  const port = await freePort();
  const conf = path.join(dir, 'nginx.conf');
  fs.writeFileSync(conf, `daemon off;
master_process off;
worker_processes 1;
pid ${dir}/nginx.pid;
error_log ${dir}/logs/error.log warn;
events { worker_connections 256; }
http {
  log_format tessera '$request_method $uri $status "$http_range" $body_bytes_sent';
  access_log ${dir}/logs/access.log tessera;
  client_body_temp_path ${dir}/tmp/client_body;
  proxy_temp_path ${dir}/tmp/proxy;
  fastcgi_temp_path ${dir}/tmp/fastcgi;
  uwsgi_temp_path ${dir}/tmp/uwsgi;
  scgi_temp_path ${dir}/tmp/scgi;
  types { application/octet-stream pmtiles; }
  default_type application/octet-stream;
  server {
    listen 127.0.0.1:${port};
    root ${root};
    location / {
      if ($request_method = OPTIONS) {
        add_header Access-Control-Allow-Origin * always;
        add_header Access-Control-Allow-Headers "Range, If-Match" always;
        return 204;
      }
      add_header Access-Control-Allow-Origin * always;
      add_header Access-Control-Expose-Headers "Content-Range, Content-Length, ETag" always;
    }
  }
}
`);
  const child = spawn(NGINX, ['-p', dir, '-c', conf], { stdio: ['ignore', 'ignore', 'pipe'] });
  let stderr = '';
  child.stderr.on('data', (d) => { stderr += d; });
  const url = `http://127.0.0.1:${port}`;
  for (const start = Date.now(); ; await new Promise((r) => setTimeout(r, 50))) {
    if (child.exitCode !== null) throw new Error(`nginx exited (${child.exitCode}): ${stderr}`);
    const up = await new Promise((resolve) => {
      const c = net.connect(port, '127.0.0.1', () => { c.end(); resolve(true); });
      c.on('error', () => resolve(false));
    });
    if (up) break;
    if (Date.now() - start > 10000) throw new Error(`nginx did not start in 10 s: ${stderr}`);
  }
  const log = () => fs.readFileSync(path.join(dir, 'logs/access.log'), 'utf8').trim().split('\n').filter(Boolean)
    .map((l) => { const m = l.match(/^(\S+) (\S+) (\d+) "([^"]*)" (\d+)$/); return m && { method: m[1], uri: m[2], status: +m[3], range: m[4] === '-' ? null : m[4], bytes: +m[5] }; })
    .filter(Boolean);
  const stop = () => new Promise((resolve) => {
    if (child.exitCode !== null) return resolve();
    child.once('exit', resolve);
    child.kill('SIGTERM');
  });
  return { url, log, stop };
}

#!/usr/bin/env bash
# The browser tests (README.md here): MapLibre GL JS, then CesiumJS, in headless Chromium
# against `tessera-server serve`. Called by `./run test` after cargo test; runs alone too:
#   tests/browser/run.sh          (TESSERA_SERVER=path/to/tessera-server, default target/debug/)
# Needs node/npm and /usr/bin/chromium (./run installs chromium nodejs npm), gdal-bin, and
# proj-bin (cs2cs) with proj-data (the EGM96 grid) for the Cesium heights.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
export TESSERA_SERVER="${TESSERA_SERVER:-$root/target/debug/tessera-server}"
start=$(date +%s.%N)
elapsed() { awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }'; }
if [ ! -x "$TESSERA_SERVER" ]; then
  echo "tests/browser: no server binary at $TESSERA_SERVER (cargo build -p tessera-server)" >&2
  exit 1
fi
# npm ci only when package-lock.json changed since the last install (a stamp in
# node_modules), from a cache outside the clone so a clean clone installs offline and fast.
cd "$here"
if ! cmp -s package-lock.json node_modules/.tessera-installed 2>/dev/null; then
  echo "== npm ci (tests/browser)" >&2
  npm ci --cache "${XDG_CACHE_HOME:-$HOME/.cache}/tessera/npm" --prefer-offline --no-audit --no-fund --loglevel=error >&2
  cp package-lock.json node_modules/.tessera-installed
fi
echo "== browser tests (node --test, headless Chromium)" >&2
rc=0
node --test maplibre.test.mjs || rc=$?
echo "== CesiumJS terrain (cesium.test.mjs, $(elapsed) s so far)" >&2
node --test cesium.test.mjs || rc=$?
echo "browser tests took $(elapsed) s, npm ci included (screenshots in out/browser/)" >&2
exit "$rc"

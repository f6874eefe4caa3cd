#!/usr/bin/env bash
# The browser tests (README.md here): MapLibre GL JS, then CesiumJS, a PMTiles archive from nginx, contours,
# then the server's built-in viewer, in headless Chromium against `tessera-server serve`. Called by `./run test` after
# cargo test; runs alone too:
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
# npm ci only when package-lock.json changed since the last install (npm-install.sh, shared
# with server/viewer-assets.sh).
"$here/npm-install.sh"
# The built-in viewer's MapLibre GL JS and CesiumJS (viewer.test.mjs), from the same
# node_modules into target/viewer-assets, where target/debug/tessera-server finds them.
"$root/server/viewer-assets.sh"
cd "$here"
echo "== browser tests (node --test, headless Chromium)" >&2
rc=0
node --test maplibre.test.mjs || rc=$?
echo "== CesiumJS terrain (cesium.test.mjs, $(elapsed) s so far)" >&2
node --test cesium.test.mjs || rc=$?
echo "== CesiumJS 3D Tiles terrain (cesium3dtiles.test.mjs, $(elapsed) s so far)" >&2
node --test cesium3dtiles.test.mjs || rc=$?
echo "== a PMTiles archive from nginx (pmtiles.test.mjs, $(elapsed) s so far)" >&2
node --test pmtiles.test.mjs || rc=$?
echo "== contour lines in MapLibre (contours.test.mjs, $(elapsed) s so far)" >&2
node --test contours.test.mjs || rc=$?
echo "== the built-in viewer (viewer.test.mjs, $(elapsed) s so far)" >&2
node --test viewer.test.mjs || rc=$?
echo "browser tests took $(elapsed) s, npm ci included (screenshots in out/browser/)" >&2
exit "$rc"

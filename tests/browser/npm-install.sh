#!/usr/bin/env bash
# Installs tests/browser/node_modules exactly from package-lock.json (npm ci), only when the
# lock changed since the last install (a stamp in node_modules), from a cache outside the clone
# so a clean clone installs offline and fast once the cache holds the packages. Shared by
# tests/browser/run.sh (the browser tests) and server/viewer-assets.sh (the viewer's MapLibre GL
# JS and CesiumJS, the same pinned versions).
set -euo pipefail
cd "$(dirname "$0")"
if ! command -v npm >/dev/null; then
  echo "tests/browser/npm-install.sh: npm is not installed (Debian: apt-get install nodejs npm; ./run test installs them)" >&2
  exit 1
fi
if ! cmp -s package-lock.json node_modules/.tessera-installed 2>/dev/null; then
  echo "== npm ci (tests/browser)" >&2
  npm ci --cache "${XDG_CACHE_HOME:-$HOME/.cache}/tessera/npm" --prefer-offline --no-audit --no-fund --loglevel=error >&2
  cp package-lock.json node_modules/.tessera-installed
fi

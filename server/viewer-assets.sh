#!/usr/bin/env bash
# Prepares the built-in viewer's third-party files (DECISIONS.md "Real clients"):
# MapLibre GL JS and CesiumJS at exactly the versions the browser tests pin
# (tests/browser/package-lock.json), copied (hard-linked where the file system allows) out of
# tests/browser/node_modules into a directory `tessera-server serve` serves under
# /viewer/assets/. Only what loads in a browser without a bundler:
#   maplibre/  maplibre-gl.mjs, maplibre-gl-shared.mjs, maplibre-gl-worker.mjs, maplibre-gl.css,
#              LICENSE.txt
#   cesium/    Build/Cesium's Cesium.js, Workers/, Assets/, ThirdParty/, Widgets/; LICENSE.md
#   versions.txt
#
#   server/viewer-assets.sh [DIR]     (default: ${CARGO_TARGET_DIR:-target}/viewer-assets)
#
# The server looks beside its executable by default: <exe dir>/../viewer-assets (so
# target/debug/ and target/release/tessera-server find target/viewer-assets), then
# <exe dir>/../share/tessera/viewer-assets; else `serve --viewer-assets DIR`.
# Cheap when DIR is already prepared from the same lock file (a stamp in DIR). Needs npm.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
out="${1:-${CARGO_TARGET_DIR:-$root/target}/viewer-assets}"
case "$out" in /*) ;; *) out="$PWD/$out" ;; esac
lock="$root/tests/browser/package-lock.json"
stamp_want="$(cat "$lock" "$0" | sha256sum | cut -d' ' -f1)"   # contents only, not paths
if [ "$(cat "$out/.tessera-assets" 2>/dev/null)" = "$stamp_want" ]; then
  exit 0
fi
"$root/tests/browser/npm-install.sh"
nm="$root/tests/browser/node_modules"
echo "== viewer assets: MapLibre GL JS and CesiumJS into $out" >&2
mkdir -p "$(dirname "$out")"
stage=$(mktemp -d "$(dirname "$out")/.viewer-assets.XXXXXX")
trap 'rm -rf "$stage"' EXIT
# Hard links where node_modules and DIR share a file system (no copy of CesiumJS's 14 MB),
# plain copies elsewhere.
copy() { cp -R -l "$@" 2>/dev/null || cp -R "$@"; }
mkdir -p "$stage/maplibre" "$stage/cesium"
for f in maplibre-gl.mjs maplibre-gl-shared.mjs maplibre-gl-worker.mjs maplibre-gl.css; do
  copy "$nm/maplibre-gl/dist/$f" "$stage/maplibre/"
done
copy "$nm/maplibre-gl/LICENSE.txt" "$stage/maplibre/"
for f in Cesium.js Workers Assets ThirdParty Widgets; do
  copy "$nm/cesium/Build/Cesium/$f" "$stage/cesium/"
done
copy "$nm/cesium/LICENSE.md" "$stage/cesium/"
(cd "$nm" && node -p "'maplibre-gl ' + require('./maplibre-gl/package.json').version + '\ncesium ' + require('./cesium/package.json').version") > "$stage/versions.txt"
chmod -R a+rX "$stage"
echo "$stamp_want" > "$stage/.tessera-assets"
rm -rf "$out"
mv "$stage" "$out"
trap - EXIT
echo "== viewer assets ready: $out ($(tr '\n' ' ' < "$out/versions.txt" | sed 's/ $//'))" >&2

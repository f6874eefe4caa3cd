#!/usr/bin/env bash
# Rendered terrain tiles (DECISIONS.md "Rendered terrain tiles") and PMTiles export
# (DECISIONS.md "PMTiles export"): Tessera's Web Mercator 256-px hillshade PNG tiles against
# TiTiler's hillshade algorithm on the same DEM as a Cloud-Optimized GeoTIFF, one after the
# other in the same run, on loopback; then `tessera-server export` throughput.
#
# Dataset: N46E008.tif (SRTM 1201², EPSG:4326), zooms 8 to the hillshade TileJSON's maxzoom;
# the tile list is every tile of those zooms in the TileJSON bounds that Tessera answers
# with 200, the same list for both servers. TiTiler: `algorithm=hillshade` with
# azimuth 315, altitude 45 and its default 3-pixel buffer (its numpy.gradient takes heights
# per pixel, not per metre of ground: a different picture, the same work per tile).
#
# Modes (64 connections; wrk 2 threads cycling through the list; a "pass" is curl -Z
# --parallel-max 64 requesting each tile once):
#   tessera cold         a fresh server, one pass;
#   tessera warm         that server afterwards, made tiles cached, wrk;
#   tessera source-warm  a fresh server with --tile-cache-mib 1 after one unmeasured pass:
#                        every tile rendered and PNG-encoded per request, wrk;
#   titiler cold         a fresh TiTiler (nproc uvicorn workers), one pass;  titiler warm: wrk.
# Contour rows (DECISIONS.md "Contour tiles"): Tessera's contour vector tiles (interval auto,
# 512-sample grid) of the same zooms up to the contour TileJSON's maxzoom, cold, warm and
# source-warm as above; no peer serves contour vector tiles from a DEM, so the rows stand beside
# Tessera's own hillshade on the same ground.
# Export rows: `export --pmtiles` of N46E008 as Terrarium 512-px WebP (zooms 0 to maxzoom),
# exact and --precision auto, as a 256-px hillshade PNG archive and as contour lines (MVT);
# tiles/s, MB/s and sizes.
# Appends to $RESULTS/rendered.jsonl. RENDERED_SECONDS per wrk row (default 20; QUICK=1: 5).
# BENCHMARKS.md's "Rendered terrain tiles, contour tiles and PMTiles export" is a hand section from these rows.
SERVER_ONLY=1
source "$(dirname "$0")/common.sh"
secs=${RENDERED_SECONDS:-20}
[ "$QUICK" = 1 ] && secs=${RENDERED_SECONDS:-5}
conns=64
workers=$(nproc)
px=256
ulimit -n 65536 2>/dev/null || ulimit -n "$(ulimit -Hn)"
source "$(dirname "$0")/tile_servers.sh"

# row SERVER MODE RUN CLIENT JSON RSS: one record.
row() {
  record rendered "$(jq -c --arg server "$1" --arg mode "$2" --argjson run "$3" --arg client "$4" \
    --argjson tiles "$ntiles" --argjson c "$conns" --argjson mean "$mean_bytes" --argjson rss "$6" \
    --argjson workers "$workers" --arg titiler "$titiler_version" --arg commit "$commit" \
    --arg measured "$(date -u +%Y-%m-%dT%H:%M:%SZ)" --argjson load "$(cut -d' ' -f1 /proc/loadavg)" \
    --arg section "$section" \
    '{section: $section, server: $server, mode: $mode, run: $run, client: $client,
      measured: $measured, commit: $commit, loadavg_1m: $load, tiles: $tiles, connections: $c,
      mean_tile_bytes: $mean, rss_mib: $rss, titiler_workers: $workers,
      titiler_version: $titiler} + .' <<< "$5")"
}

# tessera_rows RUN LIST: Tessera cold then warm on a fresh server caching every made tile, then
# source-warm (--tile-cache-mib 1) after one unmeasured pass; $section names the rows.
tessera_rows() {
  log "rendered run $1 of $RUNS: Tessera $section cold, then warm (${secs}s)"
  start_tessera "$WORK/$name.tess" --tile-cache-mib "$cache_mib"
  row tessera cold "$1" "curl -Z" "$(pass_json "$TESSERA_URL" "$2")" "$(rss_mib "$TESSERA_PID")"
  row tessera warm "$1" wrk "$(wrk_json "$TESSERA_URL" "$2")" "$(rss_mib "$TESSERA_PID")"
  stop "$TESSERA_PID"
  log "rendered run $1 of $RUNS: Tessera $section source-warm (--tile-cache-mib 1, ${secs}s)"
  start_tessera "$WORK/$name.tess" --tile-cache-mib 1
  pass_json "$TESSERA_URL" "$2" > /dev/null
  row tessera source-warm "$1" wrk "$(wrk_json "$TESSERA_URL" "$2")" "$(rss_mib "$TESSERA_PID")"
  stop "$TESSERA_PID"
}

section=hillshade
name=srtm
log "rendered: pyramid and COG"
"$SERVER_BIN" build "$DEM/N46E008.tif" -o "$WORK/$name.tess" --quiet > /dev/null
gdal_translate -q -of COG -co COMPRESS=DEFLATE -co PREDICTOR=2 "$DEM/N46E008.tif" "$WORK/$name.cog.tif"

start_tessera "$WORK/$name.tess"
tj=$(curl -sf "$TESSERA_URL/v1/datasets/$name/webmercator/hillshade/tilejson.json?size=$px")
maxzoom=$(jq .maxzoom <<< "$tj")
jq -r '.bounds | @tsv' <<< "$tj" | python3 -c '
import math, sys
w, s, e, n = map(float, sys.stdin.read().split())
lo, hi = int(sys.argv[1]), int(sys.argv[2])
eps = 1e-9
def tx(lon, z): return int(math.floor((lon + 180) / 360 * 2**z))
def ty(lat, z):
    r = math.radians(lat)
    return int(math.floor((1 - math.log(math.tan(r) + 1 / math.cos(r)) / math.pi) / 2 * 2**z))
for z in range(lo, hi + 1):
    for x in range(tx(w + eps, z), tx(e - eps, z) + 1):
        for y in range(ty(n - eps, z), ty(s + eps, z) + 1):
            print(f"{z} {x} {y}")
' 8 "$maxzoom" > "$WORK/$name.zxy"
: > "$WORK/tessera.list"
: > "$WORK/titiler.list"
params=$(python3 -c 'import urllib.parse; print(urllib.parse.quote("{\"azimuth\":315,\"angle_altitude\":45}"))')
total=0 ntiles=0
while read -r z x y; do
  p="/v1/datasets/$name/webmercator/hillshade/$z/$x/$y.png?size=$px"
  got=$(curl -s -o /dev/null -w '%{http_code} %{size_download}' "$TESSERA_URL$p")
  [ "${got%% *}" = 200 ] || continue
  total=$((total + ${got#* })) ntiles=$((ntiles + 1))
  echo "$p" >> "$WORK/tessera.list"
  echo "/cog/tiles/WebMercatorQuad/$z/$x/$y.png?url=$WORK/$name.cog.tif&algorithm=hillshade&algorithm_params=$params&tilesize=$px" >> "$WORK/titiler.list"
done < "$WORK/$name.zxy"
mean_bytes=$((total / ntiles))
stop "$TESSERA_PID"
log "rendered: $ntiles hillshade tiles at zooms 8-$maxzoom, mean $mean_bytes bytes"
cache_mib=$(( total * 5 / 4 / 1048576 + 64 ))

for run in $(seq "$RUNS"); do
  tessera_rows "$run" "$WORK/tessera.list"

  log "rendered run $run of $RUNS: TiTiler ($workers workers) cold, then ${secs}s"
  start_titiler
  row titiler cold "$run" "curl -Z" "$(pass_json "$TITILER_URL" "$WORK/titiler.list")" "$(rss_mib "$TITILER_PID")"
  row titiler warm "$run" wrk "$(wrk_json "$TITILER_URL" "$WORK/titiler.list")" "$(rss_mib "$TITILER_PID")"
  stop "$TITILER_PID"
done

# Contour tiles: the zooms of the hillshade list up to the contour TileJSON's maxzoom.
section=contours
start_tessera "$WORK/$name.tess"
cmax=$(curl -sf "$TESSERA_URL/v1/datasets/$name/webmercator/contours/tilejson.json" | jq .maxzoom)
: > "$WORK/contours.list"
total=0 ntiles=0
while read -r z x y; do
  [ "$z" -le "$cmax" ] || continue
  p="/v1/datasets/$name/webmercator/contours/$z/$x/$y.mvt"
  got=$(curl -s -o /dev/null -w '%{http_code} %{size_download}' "$TESSERA_URL$p")
  [ "${got%% *}" = 200 ] || continue
  total=$((total + ${got#* })) ntiles=$((ntiles + 1))
  echo "$p" >> "$WORK/contours.list"
done < "$WORK/$name.zxy"
mean_bytes=$((total / ntiles))
stop "$TESSERA_PID"
log "rendered: $ntiles contour tiles at zooms 8-$cmax, mean $mean_bytes bytes"
cache_mib=$(( total * 5 / 4 / 1048576 + 64 ))
for run in $(seq "$RUNS"); do
  tessera_rows "$run" "$WORK/contours.list"
done

# export_row WHAT RUN ARGS...: one timed export (release build, all cores) as a record.
export_row() {
  local what=$1 run=$2
  shift 2
  rm -f "$WORK/x.pmtiles"
  local t0 t1
  t0=$(date +%s.%N)
  "$SERVER_BIN" export "$WORK/$name.tess" --pmtiles "$WORK/x.pmtiles" --quiet "$@" 2> "$WORK/export.log"
  t1=$(date +%s.%N)
  local line
  line=$(tail -n1 "$WORK/export.log")
  log "rendered: export $what: $line"
  record rendered "$(jq -nc --arg what "$what" --argjson run "$run" --arg line "$line" --arg commit "$commit" \
    --argjson secs "$(awk -v a="$t0" -v b="$t1" 'BEGIN { print b - a }')" \
    --argjson bytes "$(stat -c %s "$WORK/x.pmtiles")" --argjson cores "$workers" \
    --arg measured "$(date -u +%Y-%m-%dT%H:%M:%SZ)" \
    '{section: "export", what: $what, run: $run, wall_s: $secs, archive_bytes: $bytes,
      summary: $line, cores: $cores, commit: $commit, measured: $measured}')"
}
for run in $(seq "$RUNS"); do
  export_row "terrarium webp 512 exact" "$run" --format webp --size 512
  export_row "terrarium webp 512 precision auto" "$run" --format webp --size 512 --precision auto
  export_row "terrarium png 256 exact" "$run"
  export_row "terrarium png 256 precision auto" "$run" --precision auto
  export_row "hillshade png 256" "$run" --layer hillshade
  export_row "contours mvt (interval auto)" "$run" --layer contours
done
log "rendered: done ($RESULTS/rendered.jsonl)"

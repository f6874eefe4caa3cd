#!/usr/bin/env bash
# Standard-grid web tiles (DECISIONS.md "Standard-grid web tiles"): Web Mercator 512 px
# Terrarium PNG tiles from Tessera (resampled per request from the pyramid) against
# TiTiler (a dynamic tiler on rasterio/GDAL, reading the same DEM as a Cloud-Optimized
# GeoTIFF), one after the other in the same run, on loopback.
#
# Datasets: N46E008.tif (SRTM 1201², EPSG:4326) at zooms 8 to the TileJSON maxzoom,
# and the moon 8192² written as an Int16 GeoTIFF (elevation = value − 10000) with a
# made-up EPSG:4326 georeferencing of its lat/lon grid (43–75°E, 1–33°N), zooms 6 to
# maxzoom: the larger tile set. The tile list is every tile of those zooms covering
# the TileJSON bounds that Tessera answers with 200 (a throwaway server checks), the
# same list for both servers.
#
# Modes (64 connections; wrk 2 threads cycling through the list, --latency; a "pass"
# is curl -Z --parallel-max 64 requesting each tile once, its tiles/s = tiles ÷ wall):
#   tessera cold         a fresh server (both caches empty), one pass;
#   tessera warm         that same server afterwards, made tiles cached
#                        (--tile-cache-mib sized for every tile of the list, with
#                        slack: the whole list in bytes × 1.25 + 64 MiB), wrk;
#   tessera source-warm  a fresh server with --tile-cache-mib 1, one unmeasured pass
#                        (decoded source tiles cached), then wrk: every tile resampled
#                        and PNG-encoded per request (the /metrics tile-cache hits say
#                        how many were not);
#   titiler cold         a fresh TiTiler, one pass;  titiler  then wrk.
# TiTiler: titiler.application under uvicorn with as many workers as cores (nproc),
# no access log, GDAL_DISABLE_READDIR_ON_OPEN=EMPTY_DIR, in a virtualenv under
# $TITILER_VENV (default ${XDG_CACHE_HOME:-~/.cache}/tessera/titiler-venv; made once).
# Peak RSS is VmHWM from /proc (TiTiler: the master and its workers summed).
# Appends to $RESULTS/webtiles.jsonl {dataset, server, mode, run, client, tiles,
# connections, duration_s, requests, non2xx, errors, p50_ms, p99_ms, mean_tile_bytes,
# rss_mib, tile_cache_hits, tile_cache_misses, titiler_workers, titiler_version, measured,
# commit, loadavg_1m (the machine's at the row's end: others may share it)} and to
# $RESULTS/webtiles_check.jsonl the landmark heights both servers' tiles decode to.
#   WEBTILES_SECONDS (default 20; QUICK=1: 5) per wrk row: wrk counts only requests
#   that complete within the row, and at 64 connections a server answering in L
#   seconds completes nothing for about its first L, so a row of T seconds
#   understates its tiles/s by about L/T (TiTiler's L is seconds here).
#   WEBTILES_MOON=0 leaves the moon out; WEBTILES_SRTM=0 leaves N46E008 out (to rerun
#   one dataset's rows).
source "$(dirname "$0")/common.sh"
secs=${WEBTILES_SECONDS:-20}
[ "$QUICK" = 1 ] && secs=${WEBTILES_SECONDS:-5}
conns=64
workers=$(nproc)
px=512
ulimit -n 65536 2>/dev/null || ulimit -n "$(ulimit -Hn)"

source "$(dirname "$0")/tile_servers.sh"

# row DATASET SERVER MODE RUN CLIENT JSON RSS HITS MISSES: one record.
row() {
  record webtiles "$(jq -c --arg dataset "$1" --arg server "$2" --arg mode "$3" --argjson run "$4" \
    --arg client "$5" --argjson tiles "$ntiles" --argjson c "$conns" --argjson mean "$mean_bytes" \
    --argjson rss "$7" --argjson hits "${8:-null}" --argjson misses "${9:-null}" \
    --argjson workers "$workers" --arg titiler "$titiler_version" --arg commit "$commit" \
    --arg measured "$(date -u +%Y-%m-%dT%H:%M:%SZ)" --argjson load "$(cut -d' ' -f1 /proc/loadavg)" \
    '{dataset: $dataset, server: $server, mode: $mode, run: $run, client: $client,
      measured: $measured, commit: $commit, loadavg_1m: $load,
      tiles: $tiles, connections: $c, mean_tile_bytes: $mean, rss_mib: $rss,
      tile_cache_hits: $hits, tile_cache_misses: $misses, titiler_workers: $workers,
      titiler_version: $titiler} + .' <<< "$6")"
}

# terrarium_at PNG PX PY: the Terrarium height of one pixel ("nodata" where alpha is 0).
terrarium_at() {
  local v
  v=$(for b in 1 2 3 4; do gdallocationinfo -valonly -b "$b" "$1" "$2" "$3" 2> /dev/null; done | tr '\n' ' ')
  awk -v v="$v" 'BEGIN { split(v, c, " "); if (c[4] == 0) print "null"; else printf "%.1f\n", c[1] * 256 + c[2] + c[3] / 256 - 32768 }'
}

# dataset NAME SOURCE MINZOOM: the pyramid, the COG, the tile list, then every mode.
dataset() {
  local name=$1 src=$2 minzoom=$3
  log "webtiles: $name: pyramid and COG"
  "$SERVER_BIN" build "$src" -o "$WORK/$name.tess" --quiet > /dev/null
  gdal_translate -q -of COG -co COMPRESS=DEFLATE -co PREDICTOR=2 "$src" "$WORK/$name.cog.tif"

  # The tile list, from the TileJSON's bounds and maxzoom, checked on a throwaway server.
  start_tessera "$WORK/$name.tess"
  local tj maxzoom
  tj=$(curl -sf "$TESSERA_URL/v1/datasets/$name/webmercator/tilejson.json?encoding=terrarium&size=$px")
  maxzoom=$(jq .maxzoom <<< "$tj")
  jq -r '.bounds | @tsv' <<< "$tj" | python3 -c '
import math, sys
w, s, e, n = map(float, sys.stdin.read().split())
lo, hi, name, px = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
eps = 1e-9
def tx(lon, z): return int(math.floor((lon + 180) / 360 * 2**z))
def ty(lat, z):
    r = math.radians(lat)
    return int(math.floor((1 - math.log(math.tan(r) + 1 / math.cos(r)) / math.pi) / 2 * 2**z))
for z in range(lo, hi + 1):
    for x in range(tx(w + eps, z), tx(e - eps, z) + 1):
        for y in range(ty(n - eps, z), ty(s + eps, z) + 1):
            print(f"{z} {x} {y}")
' "$minzoom" "$maxzoom" "$name" "$px" > "$WORK/$name.zxy"
  : > "$WORK/$name.tessera"
  : > "$WORK/$name.titiler"
  local z x y bytes total=0 n=0
  while read -r z x y; do
    local p="/v1/datasets/$name/webmercator/$z/$x/$y.png?encoding=terrarium&size=$px"
    bytes=$(curl -s -o /dev/null -w '%{http_code} %{size_download}' "$TESSERA_URL$p")
    [ "${bytes%% *}" = 200 ] || continue
    total=$((total + ${bytes#* })) n=$((n + 1))
    echo "$p" >> "$WORK/$name.tessera"
    echo "/cog/tiles/WebMercatorQuad/$z/$x/$y.png?url=$WORK/$name.cog.tif&algorithm=terrarium&tilesize=$px" >> "$WORK/$name.titiler"
  done < "$WORK/$name.zxy"
  ntiles=$n
  [ "$ntiles" -gt 0 ] || { echo "$name: no tiles with data" >&2; exit 1; }
  mean_bytes=$((total / n))
  log "webtiles: $name: $ntiles tiles at zooms $minzoom-$maxzoom (of $(wc -l < "$WORK/$name.zxy") covering the bounds), mean $mean_bytes bytes"
  stop "$TESSERA_PID"

  # The made-tile cache must hold the whole list for "warm" to mean warm.
  local cache_mib=$(( total * 5 / 4 / 1048576 + 64 ))
  for run in $(seq "$RUNS"); do
    log "webtiles: $name run $run of $RUNS: Tessera cold, then warm (${secs}s, --tile-cache-mib $cache_mib)"
    start_tessera "$WORK/$name.tess" --tile-cache-mib "$cache_mib"
    local h0 m0 j
    j=$(pass_json "$TESSERA_URL" "$WORK/$name.tessera")
    local h1 m1
    h1=$(tile_cache hit "$TESSERA_URL") m1=$(tile_cache miss "$TESSERA_URL")
    row "$name" tessera cold "$run" "curl -Z" "$j" "$(rss_mib "$TESSERA_PID")" "$h1" "$m1"
    j=$(wrk_json "$TESSERA_URL" "$WORK/$name.tessera")
    h0=$(tile_cache hit "$TESSERA_URL") m0=$(tile_cache miss "$TESSERA_URL")
    row "$name" tessera warm "$run" wrk "$j" "$(rss_mib "$TESSERA_PID")" $((h0 - h1)) $((m0 - m1))
    stop "$TESSERA_PID"

    log "webtiles: $name run $run of $RUNS: Tessera source-warm (--tile-cache-mib 1, ${secs}s)"
    start_tessera "$WORK/$name.tess" --tile-cache-mib 1
    pass_json "$TESSERA_URL" "$WORK/$name.tessera" > /dev/null
    h1=$(tile_cache hit "$TESSERA_URL") m1=$(tile_cache miss "$TESSERA_URL")
    j=$(wrk_json "$TESSERA_URL" "$WORK/$name.tessera")
    h0=$(tile_cache hit "$TESSERA_URL") m0=$(tile_cache miss "$TESSERA_URL")
    row "$name" tessera source-warm "$run" wrk "$j" "$(rss_mib "$TESSERA_PID")" $((h0 - h1)) $((m0 - m1))
    stop "$TESSERA_PID"

    log "webtiles: $name run $run of $RUNS: TiTiler ($workers workers) cold, then ${secs}s"
    start_titiler
    j=$(pass_json "$TITILER_URL" "$WORK/$name.titiler")
    row "$name" titiler cold "$run" "curl -Z" "$j" "$(rss_mib "$TITILER_PID")"
    j=$(wrk_json "$TITILER_URL" "$WORK/$name.titiler")
    row "$name" titiler warm "$run" wrk "$j" "$(rss_mib "$TITILER_PID")"
    if [ "$run" = 1 ]; then check_landmark "$name"; fi
    stop "$TITILER_PID"
  done
}

# check_landmark NAME: one pixel of one tile from both servers, decoded (TiTiler is
# still running; a fresh Tessera is started).
check_landmark() {
  local name=$1 lon lat label
  case "$name" in
    srtm) lon=8.5911 lat=46.6350 label="Andermatt" ;;
    *) return 0 ;;
  esac
  local zxy
  zxy=$(python3 -c '
import math, sys
lon, lat, z, px = float(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
fx = (lon + 180) / 360 * 2**z
r = math.radians(lat)
fy = (1 - math.log(math.tan(r) + 1 / math.cos(r)) / math.pi) / 2 * 2**z
print(z, int(fx), int(fy), int((fx % 1) * px), int((fy % 1) * px))
' "$lon" "$lat" 10 "$px")
  read -r z x y i j <<< "$zxy"
  start_tessera "$WORK/$name.tess"
  curl -sf -o "$WORK/t.png" "$TESSERA_URL/v1/datasets/$name/webmercator/$z/$x/$y.png?encoding=terrarium&size=$px"
  curl -sf -o "$WORK/g.png" "$TITILER_URL/cog/tiles/WebMercatorQuad/$z/$x/$y.png?url=$WORK/$name.cog.tif&algorithm=terrarium&tilesize=$px"
  stop "$TESSERA_PID"
  local ht hg dims
  ht=$(terrarium_at "$WORK/t.png" "$i" "$j") hg=$(terrarium_at "$WORK/g.png" "$i" "$j")
  dims=$(gdalinfo "$WORK/g.png" | sed -n 's/^Size is //p')
  log "webtiles: $label ($lon, $lat) z$z/$x/$y pixel ($i, $j): Tessera $ht m, TiTiler $hg m (TiTiler tile $dims)"
  record webtiles_check "$(jq -n --arg name "$name" --arg lm "$label" --argjson lon "$lon" \
    --argjson lat "$lat" --arg tile "$z/$x/$y" --argjson i "$i" --argjson j "$j" --argjson t "$ht" \
    --argjson g "$hg" --arg dims "$dims" \
    '{dataset: $name, landmark: $lm, lon: $lon, lat: $lat, tile: $tile, pixel: [$i, $j],
      tessera_m: $t, titiler_m: $g, titiler_size: $dims, run: 1}')"
}

# Only srtm writes the landmark check: keep it when only the moon is rerun.
if [ "${WEBTILES_SRTM:-1}" = 1 ]; then rm -f "$RESULTS/webtiles_check.jsonl"; fi
[ "${WEBTILES_SRTM:-1}" = 1 ] && dataset srtm "$DEM/N46E008.tif" 8
if [ "${WEBTILES_MOON:-1}" = 1 ]; then
  gdal_translate -q -ot Int16 -scale 0 65535 -10000 55535 -a_srs EPSG:4326 -a_ullr 43 33 75 1 \
    "$DEM/moon_crisium_gld100_8192.png" "$WORK/moon8k.tif"
  dataset moon8k "$WORK/moon8k.tif" 6
fi

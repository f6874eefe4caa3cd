#!/usr/bin/env bash
# Cesium terrain (DECISIONS.md "Cesium terrain"): quantized-mesh tiles meshed per request
# from the pyramid and its error tables (`/v1/datasets/NAME/cesium/{z}/{x}/{y}.terrain`).
#
# Pyramids (built here, in $WORK):
#   N46E008  ../shared/data/dem/N46E008.tif (SRTM 3", 1201²) with --vertical-datum egm96,
#            so tiles get the EGM96 geoid (Debian's proj-data egm96_15.gtx);
#   moon     ../shared/data/dem/moon_crisium_gld100_8192.png (elevation = value − 10000)
#            on the Moon's sphere (+proj=longlat +R=1737400), --vertical-datum ellipsoid.
#            Its sidecar moon_crisium_gld100_8192.json gives the upper-left corner as
#            lon 43.0, lat 32.9921875 with 1/256° pixels (0.00390625°): 8192 px = 32°, so
#            the pixel edges are W 43, S 0.9921875, E 75, N 32.9921875. (The 4096 crop's
#            corner, lon 51.0 lat 24.9921875, is 2048 px = 8° in from it on both axes,
#            the same lattice.)
#
# 1. Mesh timing and quality (TERRAIN_MESH=1): the measuring tool
#    tests/examples/terrain_mesh.rs (built here: cargo build --release -p tessera-e2e
#    --example terrain_mesh; TERRAIN_BUILD=0 skips the build) on N46E008 zooms 10 (tiles
#    of ~211² finest samples, the nearest to a 257² tile), 12 (~53²) and 14 (~13²), and
#    the moon zooms 7 (~360²) and 8 (~180²): $TERRAIN_TILES distinct tiles per zoom (default 40; QUICK=1:
#    10), a seeded draw (seed 1; the tool draws with replacement, so it is asked for 5×
#    as many and the first distinct ones are kept, each measured the first time it was
#    drawn, so cold_us is that tile's first mesh). One line per tile is appended to
#    $RESULTS/terrain_mesh.jsonl: the tool's fields (cold_us, mesh_us: median of 5,
#    encode_us, bytes, vertices, triangles, error_m, geometric_error_m, samples,
#    regular_triangles, regular_error_m, at_regular_triangles, at_regular_error_m) plus
#    {dataset, zoom, seed, run: 1, measured, commit, loadavg_1m}. One run: every tile's
#    time is already a median of 5.
#
# 1b. The peers (part of 1): every measured tile wholly inside the data has its window of
#    finest samples written by the tool (TERRAIN_WINDOWS) and meshed by bench/mesh_peers.py
#    with pydelatin and pymartini (PyPI, in $MESH_PEERS_VENV, default
#    ${XDG_CACHE_HOME:-~/.cache}/tessera/mesh-venv, made once) at the tile's own true
#    worst error (Martini's threshold bisected until its true error is within it), one line per
#    tile to $RESULTS/terrain_peers.jsonl: triangles and µs (median of 5) for each.
#
# 2. Serving (TERRAIN_SERVE=1): `tessera-server serve` on both pyramids, the CesiumJS
#    request headers (Accept: application/vnd.quantized-mesh;extensions=… with the
#    extensions CesiumJS asks for among those layer.json lists, octvertexnormals and
#    metadata, as `accept` in the records; Accept-Encoding: gzip), 64 connections, N46E008 zoom 12
#    and the moon zoom 9. The tile list is the zoom's tiles over layer.json's `bounds`,
#    at most $TERRAIN_SERVE_TILES (default 600) of them (the ones nearest the middle),
#    in rows, with the `?v=` pin of layer.json's template; a throwaway server checks that
#    every one answers 200. For each run of $RUNS, a fresh server (--tile-cache-mib sized
#    for the whole list, as the throwaway server's /metrics measured it, × 1.25 + 64 MiB):
#      cold  each tile of the list once, `curl -Z --parallel-max 64` (tiles/s = tiles ÷
#            wall; p50/p99 from curl's per-transfer times): every tile meshed, encoded
#            and gzipped, its sources decoded;
#      warm  then wrk (2 threads, --latency) cycling through the same list for
#            $TERRAIN_SECONDS (default 20; QUICK=1: 5): made tiles come from the cache
#            (the server gzips each response again: the cache holds the raw tile).
#    Appends to $RESULTS/terrain_serve.jsonl {dataset, zoom, mode, run, client, tiles,
#    connections, accept, duration_s, requests, errors, non2xx, p50_ms, p99_ms, mean_tile_bytes
#    (gzipped, as sent), mean_raw_bytes, content_encoding, rss_mib, tile_cache_hits,
#    tile_cache_misses (the terrain cache's lookups during the row), cores (nproc),
#    server_cpus (the server's Cpus_allowed_list), measured, commit, loadavg_1m}.
source "$(dirname "$0")/common.sh"
mesh_tiles=${TERRAIN_TILES:-40}
secs=${TERRAIN_SECONDS:-20}
if [ "$QUICK" = 1 ]; then
  mesh_tiles=${TERRAIN_TILES:-10}
  secs=${TERRAIN_SECONDS:-5}
fi
serve_tiles=${TERRAIN_SERVE_TILES:-600}
conns=64
MESH_BIN=$ROOT/target/release/examples/terrain_mesh
# The Accept header as CesiumJS builds it (requestVertexNormals: true, requestMetadata
# left at its default, true): the extensions it asks for among those layer.json lists,
# octvertexnormals before metadata; set per dataset by serve_case.
ACCEPT=
GZIP='Accept-Encoding: gzip'
ulimit -n 65536 2> /dev/null || ulimit -n "$(ulimit -Hn)"

# The commit measured, "+dirty" when tracked files differ from it.
commit=$(git rev-parse --short HEAD 2> /dev/null || echo unknown)
[ -z "$(git status --porcelain --untracked-files=no 2> /dev/null)" ] || commit="$commit+dirty"

now() { date -u +%Y-%m-%dT%H:%M:%SZ; }
load1() { cut -d' ' -f1 /proc/loadavg; }

log "terrain: pyramids"
"$SERVER_BIN" build "$DEM/N46E008.tif" --vertical-datum egm96 -o "$WORK/N46E008.tess" --quiet > /dev/null
"$SERVER_BIN" build "$DEM/moon_crisium_gld100_8192.png" --offset -10000 \
  --crs '+proj=longlat +R=1737400 +no_defs' --bounds 43,0.9921875,75,32.9921875 \
  --vertical-datum ellipsoid -o "$WORK/moon.tess" --quiet > /dev/null

# --- 1. Mesh timing and quality

# mesh_case NAME ZOOM: $mesh_tiles distinct seeded tiles of one zoom.
mesh_case() {
  local name=$1 zoom=$2 seed=1
  log "terrain: meshing $mesh_tiles tiles of $name zoom $zoom"
  mkdir -p "$WORK/windows"
  TERRAIN_WINDOWS=$WORK/windows \
    "$MESH_BIN" "$WORK/$name.tess" "$zoom" $((mesh_tiles * 5)) "$seed" > "$WORK/mesh.jsonl" \
    2> "$WORK/mesh.err" || { cat "$WORK/mesh.err" >&2; exit 1; }
  jq -c -s --argjson n "$mesh_tiles" --arg name "$name" --argjson zoom "$zoom" \
    --argjson seed "$seed" --arg commit "$commit" --arg measured "$(now)" \
    --argjson load "$(load1)" '
    reduce .[] as $r ([]; if length >= $n or any(.[]; .tile == $r.tile) then . else . + [$r] end)
    | .[] | . + {dataset: $name, zoom: $zoom, seed: $seed, run: 1, measured: $measured,
                 commit: $commit, loadavg_1m: $load}' "$WORK/mesh.jsonl" \
    >> "$RESULTS/terrain_mesh.jsonl"
  # 1b. The peers on the same windows (the tiles wholly inside the data).
  jq -c --arg name "$name" 'select(.dataset == $name and .window != null)' \
    "$RESULTS/terrain_mesh.jsonl" | jq -c --argjson zoom "$zoom" 'select(.zoom == $zoom)' \
    | "$PEERS_VENV/bin/python" bench/mesh_peers.py \
    | jq -c --arg commit "$commit" --arg measured "$(now)" --argjson load "$(load1)" \
      '. + {measured: $measured, commit: $commit, loadavg_1m: $load}' \
    >> "$RESULTS/terrain_peers.jsonl"
  rm -rf "$WORK/windows"
}

if [ "${TERRAIN_MESH:-1}" = 1 ]; then
  if [ "${TERRAIN_BUILD:-1}" = 1 ]; then
    log "terrain: building the measuring tool (terrain_mesh)"
    cargo build --release --locked -q -p tessera-e2e --example terrain_mesh
  fi
  [ -x "$MESH_BIN" ] || { echo "no $MESH_BIN (cargo build --release -p tessera-e2e --example terrain_mesh)" >&2; exit 1; }
  # pydelatin and pymartini (PyPI wheels) in a venv of their own, made once.
  PEERS_VENV=${MESH_PEERS_VENV:-${XDG_CACHE_HOME:-$HOME/.cache}/tessera/mesh-venv}
  if ! "$PEERS_VENV/bin/python" -c 'import pydelatin, pymartini, numpy' 2> /dev/null; then
    log "terrain: installing pydelatin and pymartini into $PEERS_VENV"
    python3 -m venv "$PEERS_VENV"
    "$PEERS_VENV/bin/pip" install -q pydelatin pymartini numpy
  fi
  rm -f "$RESULTS/terrain_mesh.jsonl" "$RESULTS/terrain_peers.jsonl"
  mesh_case N46E008 10
  mesh_case N46E008 12
  mesh_case N46E008 14
  mesh_case moon 7
  mesh_case moon 8
fi

# --- 2. Serving

# rss_mib PID: VmHWM of PID in MiB.
rss_mib() {
  sed -n 's/^VmHWM:\s*\([0-9]*\) kB/\1/p' "/proc/$1/status" | awk '{printf "%.1f", $1 / 1024}'
}

# metric URL NAME LABELS...: the value of one /metrics sample whose line has every LABEL.
metric() {
  local url=$1 name=$2
  shift 2
  curl -sf "$url/metrics" | awk -v n="$name" -v labels="$*" '
    index($0, n "{") == 1 {
      k = split(labels, l, " "); ok = 1
      for (i = 1; i <= k; i++) if (index($0, l[i]) == 0) ok = 0
      if (ok) { print $NF; exit }
    }'
}
cache_lookups() { metric "$2" tessera_web_cache_requests_total 'cache="terrain"' "result=\"$1\""; }

stop() { kill -TERM "$1" 2> /dev/null || true; wait "$1" 2> /dev/null || true; }

# start_tessera ARGS...: a fresh server on both pyramids; sets TESSERA_URL and TESSERA_PID.
start_tessera() {
  local n=${#BENCH_PIDS[@]}
  spawn "$WORK/serve$n.out" "$WORK/serve$n.log" "$SERVER_BIN" serve \
    "$WORK/N46E008.tess" "$WORK/moon.tess" --listen 127.0.0.1:0 "$@"
  TESSERA_PID=${BENCH_PIDS[-1]}
  TESSERA_URL=$(wait_listening "$WORK/serve$n.out")
}

# wrk cycling through $TILE_LIST (each thread from its own offset), JSON from done().
cat > "$WORK/cycle.lua" << 'LUA'
local paths = {}
for line in io.lines(os.getenv("TILE_LIST")) do paths[#paths + 1] = line end
local threads = 0
function setup(thread)
  thread:set("offset", threads)
  threads = threads + 1
end
local i = 0
function init(args)
  i = (tonumber(offset) or 0) * math.floor(#paths / 2)
end
function request()
  i = i % #paths + 1
  return wrk.format("GET", paths[i])
end
function done(summary, latency, requests)
  local e = summary.errors
  io.write(string.format(
    '{"duration_s":%.6f,"requests":%d,"errors":%d,"non2xx":%d,"p50_ms":%.3f,"p99_ms":%.3f}\n',
    summary.duration / 1e6, summary.requests, e.connect + e.read + e.write + e.timeout,
    e.status, latency:percentile(50) / 1e3, latency:percentile(99) / 1e3))
end
LUA

# wrk_json BASE LIST: one wrk row of $secs at $conns connections, CesiumJS's headers.
wrk_json() {
  TILE_LIST=$2 wrk -t2 -c"$conns" -d"${secs}s" --timeout 60s --latency -H "$ACCEPT" -H "$GZIP" \
    -s "$WORK/cycle.lua" "$1" > "$WORK/wrk.out" 2> "$WORK/wrk.err" \
    || { cat "$WORK/wrk.out" "$WORK/wrk.err" >&2; exit 1; }
  tail -n1 "$WORK/wrk.out"
}

# pass_json BASE LIST: each path of LIST once, $conns at a time (curl -Z), CesiumJS's
# headers (gzip not decoded); prints {duration_s, requests, errors, non2xx, p50_ms,
# p99_ms, mean_tile_bytes}.
pass_json() {
  local base=$1 list=$2 t0 t1
  sed "s|.*|url = \"$base&\"\noutput = \"/dev/null\"|" "$list" > "$WORK/pass.curl"
  t0=$(date +%s.%N)
  curl -s --no-progress-meter -Z --parallel-max "$conns" --parallel-immediate -H "$ACCEPT" -H "$GZIP" \
    -K "$WORK/pass.curl" -w '%{http_code} %{time_total} %{exitcode} %{size_download}\n' \
    > "$WORK/pass.out" || true
  t1=$(date +%s.%N)
  sort -k2,2g "$WORK/pass.out" | awk -v t0="$t0" -v t1="$t1" '
    { t[NR] = $2; if ($3 != 0) err++; else if ($1 < 200 || $1 > 299) bad++; else { ok++; bytes += $4 } }
    END {
      p50 = t[int((NR - 1) * 0.50) + 1]; p99 = t[int((NR - 1) * 0.99) + 1]
      printf "{\"duration_s\":%.6f,\"requests\":%d,\"errors\":%d,\"non2xx\":%d,\"p50_ms\":%.3f,\"p99_ms\":%.3f,\"mean_tile_bytes\":%.1f}\n",
        t1 - t0, NR - err, err, bad, p50 * 1000, p99 * 1000, (ok > 0 ? bytes / ok : 0) }'
}

# serve_case NAME ZOOM: the tile list, then cold and warm for every run.
serve_case() {
  local name=$1 zoom=$2
  start_tessera
  local layer
  layer=$(curl -sf "$TESSERA_URL/v1/datasets/$name/cesium/layer.json")
  local template
  template=$(jq -r '.tiles[0]' <<< "$layer")
  ACCEPT="Accept: application/vnd.quantized-mesh;extensions=$(jq -r '[.extensions[]
    | select(. == "octvertexnormals" or . == "metadata")] | sort_by(. != "octvertexnormals")
    | join("-")' <<< "$layer"),application/octet-stream;q=0.9,*/*;q=0.01"
  # The tiles over the data's bounds (layer.json lists availability only down to its
  # metadataAvailability zoom; deeper tiles carry it), every one checked below.
  jq -c '.bounds' <<< "$layer" | python3 -c '
import json, math, sys
(w, s, e, n), most, name, template = json.load(sys.stdin), int(sys.argv[1]), sys.argv[2], sys.argv[3]
z = sys.argv[4]
span = 180 / 2 ** int(z)
# A tile meets the open box when its open interior overlaps it.
x0, x1 = math.floor((w + 180) / span), math.ceil((e + 180) / span) - 1
y0, y1 = math.floor((s + 90) / span), math.ceil((n + 90) / span) - 1
tiles = sorted((x, y) for x in range(x0, x1 + 1) for y in range(y0, y1 + 1))
if not tiles:
    sys.exit(f"{name}: no available tiles at zoom {z}")
if len(tiles) > most:
    cx = (min(t[0] for t in tiles) + max(t[0] for t in tiles)) / 2
    cy = (min(t[1] for t in tiles) + max(t[1] for t in tiles)) / 2
    tiles = sorted(tiles, key=lambda t: ((t[0] - cx) ** 2 + (t[1] - cy) ** 2, t[1], t[0]))[:most]
for x, y in sorted(tiles, key=lambda t: (t[1], t[0])):
    path = template.replace("{z}", z).replace("{x}", str(x)).replace("{y}", str(y))
    print(f"/v1/datasets/{name}/cesium/{path}")
' "$serve_tiles" "$name" "$template" "$zoom" > "$WORK/$name.list"
  ntiles=$(wc -l < "$WORK/$name.list")
  # The check: every tile 200 on the throwaway server; what the cache then holds.
  local check
  check=$(pass_json "$TESSERA_URL" "$WORK/$name.list")
  [ "$(jq '.errors + .non2xx' <<< "$check")" = 0 ] || {
    echo "$name zoom $zoom: not every listed tile answered 200: $check" >&2
    exit 1
  }
  local held encoding
  held=$(metric "$TESSERA_URL" tessera_web_cache_bytes 'cache="terrain"')
  mean_raw=$(( held / ntiles - 64 ))
  encoding=$(curl -sf -o /dev/null -D - -H "$ACCEPT" -H "$GZIP" "$TESSERA_URL$(head -n1 "$WORK/$name.list")" \
    | tr -d '\r' | sed -n 's/^content-encoding: //Ip' | head -n1)
  content_encoding=${encoding:-identity}
  stop "$TESSERA_PID"
  local cache_mib=$(( held * 5 / 4 / 1048576 + 64 ))
  log "terrain: $name zoom $zoom: $ntiles tiles, mean $mean_raw bytes raw ($content_encoding on the wire), --tile-cache-mib $cache_mib"

  local run j h0 m0 h1 m1
  for run in $(seq "$RUNS"); do
    log "terrain: $name zoom $zoom run $run of $RUNS: cold pass, then warm (${secs}s)"
    start_tessera --tile-cache-mib "$cache_mib"
    h0=$(cache_lookups hit "$TESSERA_URL") m0=$(cache_lookups miss "$TESSERA_URL")
    j=$(pass_json "$TESSERA_URL" "$WORK/$name.list")
    h1=$(cache_lookups hit "$TESSERA_URL") m1=$(cache_lookups miss "$TESSERA_URL")
    row "$name" "$zoom" cold "$run" "curl -Z" "$j" $((h1 - h0)) $((m1 - m0))
    j=$(wrk_json "$TESSERA_URL" "$WORK/$name.list")
    h0=$(cache_lookups hit "$TESSERA_URL") m0=$(cache_lookups miss "$TESSERA_URL")
    j=$(jq -c --argjson b "$(jq .mean_tile_bytes <<< "$check")" '. + {mean_tile_bytes: $b}' <<< "$j")
    row "$name" "$zoom" warm "$run" wrk "$j" $((h0 - h1)) $((m0 - m1))
    stop "$TESSERA_PID"
  done
}

# row NAME ZOOM MODE RUN CLIENT JSON HITS MISSES: one record of terrain_serve.jsonl.
row() {
  record terrain_serve "$(jq -c --arg dataset "$1" --argjson zoom "$2" --arg mode "$3" \
    --argjson run "$4" --arg client "$5" --argjson tiles "$ntiles" --argjson c "$conns" \
    --argjson raw "$mean_raw" --arg enc "$content_encoding" --arg accept "${ACCEPT#Accept: }" --argjson rss "$(rss_mib "$TESSERA_PID")" \
    --argjson hits "$7" --argjson misses "$8" --argjson cores "$(nproc)" \
    --arg cpus "$(sed -n 's/^Cpus_allowed_list:\s*//p' "/proc/$TESSERA_PID/status")" \
    --arg commit "$commit" --arg measured "$(now)" --argjson load "$(load1)" \
    '{dataset: $dataset, zoom: $zoom, mode: $mode, run: $run, client: $client,
      measured: $measured, commit: $commit, loadavg_1m: $load, tiles: $tiles,
      connections: $c, accept: $accept, mean_raw_bytes: $raw, content_encoding: $enc, rss_mib: $rss,
      tile_cache_hits: $hits, tile_cache_misses: $misses, cores: $cores,
      server_cpus: $cpus} + .' <<< "$6")"
}

if [ "${TERRAIN_SERVE:-1}" = 1 ]; then
  rm -f "$RESULTS/terrain_serve.jsonl"
  serve_case N46E008 12
  serve_case moon 9
fi

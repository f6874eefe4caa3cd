# Shared by the bench/*.sh section scripts (sourced, not run). Each section script
# measures one comparison (docs/ARCHITECTURE.md#measuring, DECISIONS.md "Benchmarks") and
# appends one JSON object per run to $RESULTS/<section>.jsonl; `tessera-bench report`
# turns those into BENCHMARKS.md.
#
# Environment:
#   RESULTS  where the .jsonl files go (default target/bench/results)
#   RUNS     repeats of every timed measurement (default 3)
#   QUICK=1  a short smoke run (fewer frames, shorter rows); the report says so
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ROOT=$PWD
DEM=${TESSERA_DEM_DIR:-$ROOT/../shared/data/dem}
RESULTS=${RESULTS:-$ROOT/target/bench/results}
RUNS=${RUNS:-3}
QUICK=${QUICK:-0}
# SERVER_BIN: another server binary to measure (e.g. an older build, side by side).
SERVER_BIN=${SERVER_BIN:-$ROOT/target/release/tessera-server}
CLIENT_BIN=$ROOT/target/release/tessera
# The latency proxy of bench/stream.sh (which checks for it).
PROXY_BIN=$ROOT/target/release/tessera-proxy
mkdir -p "$RESULTS"
# Headless: no Mesa device-select layer (see ./run), and say so when the CPU
# Vulkan driver is missing, since the renderer would then measure GL instead
# (`./run bench` installs it).
if [ -z "${DISPLAY:-}" ] && [ -z "${WAYLAND_DISPLAY:-}" ]; then
  export NODEVICE_SELECT="${NODEVICE_SELECT:-1}"
fi
if command -v dpkg-query >/dev/null &&
  ! dpkg-query -W -f='${Status}' mesa-vulkan-drivers 2>/dev/null | grep -q "install ok installed"; then
  echo "warning: mesa-vulkan-drivers is not installed, so the renderer will draw through GL;" \
    "run ./run bench (as root it installs it) or: sudo apt-get install -y mesa-vulkan-drivers" >&2
fi
# SERVER_ONLY=1: a section that measures the server alone (rendered.sh) needs no client build.
[ -x "$SERVER_BIN" ] && { [ "${SERVER_ONLY:-0}" = 1 ] || [ -x "$CLIENT_BIN" ]; } || {
  echo "build first: cargo build --release --locked -p tessera-server -p tessera-client" >&2
  exit 1
}

# A scratch directory removed on exit, with every background process started
# through `spawn` killed first.
WORK=$(mktemp -d "${TMPDIR:-/tmp}/tessera-bench.XXXXXX")
BENCH_PIDS=()
bench_cleanup() {
  # Processes spawned in command substitutions ($(serve …)) are known only by the
  # pid file: the subshell's BENCH_PIDS does not reach this one.
  for p in "${BENCH_PIDS[@]}" $(cat "$WORK/pids" 2>/dev/null); do kill -TERM "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  rm -rf "$WORK"
}
trap bench_cleanup EXIT

log() { echo "[bench $(date +%H:%M:%S)] $*" >&2; }

# spawn OUT ERR COMMAND...: runs COMMAND in the background, stdout to OUT, stderr to ERR.
spawn() {
  local out=$1 err=$2
  shift 2
  "$@" > "$out" 2> "$err" &
  BENCH_PIDS+=($!)
  echo "$!" >> "$WORK/pids"
}

# wait_listening FILE: waits for "listening on URL" in FILE and prints the URL.
wait_listening() {
  for _ in $(seq 400); do
    if grep -q "^listening on " "$1" 2>/dev/null; then
      sed -n 's/^listening on //p' "$1" | head -n1
      return 0
    fi
    sleep 0.05
  done
  echo "no 'listening on' line in $1" >&2
  cat "$1" "${1%.out}.log" >&2 2>/dev/null || true
  return 1
}

# serve FILE...: starts `tessera-server serve` on a free loopback port; prints its URL.
serve() {
  # A fresh name: called in $(…), BENCH_PIDS does not count this subshell's spawns.
  local out
  out=$(mktemp "$WORK/serve.XXXXXX.out")
  spawn "$out" "${out%.out}.log" "$SERVER_BIN" serve "$@" --listen 127.0.0.1:0
  wait_listening "$out"
}

# build_moon N OUT: the moon N² mosaic as a pyramid (elevation = value − 10000).
build_moon() {
  "$SERVER_BIN" build "$DEM/moon_crisium_gld100_$1.png" --offset -10000 -o "$2" --quiet > /dev/null
}

# The moon's sample spacing in metres (GLD100 at 512 px/degree, ../shared/data/dem/README).
MOON_SPACING=118.45

# record SECTION JSON: appends one compact JSON object to $RESULTS/SECTION.jsonl.
record() {
  jq -c . <<< "$2" >> "$RESULTS/$1.jsonl"
}

# fly_record SECTION FIELDS_JSON SUMMARY_FILE [STATS_FILE]: a record holding the
# flight's parameters, its summary and (with STATS_FILE) every frame's statistics.
fly_record() {
  local frames='[]'
  [ $# -ge 4 ] && frames=$(jq -s -c . "$4")
  record "$1" "$(jq -c --argjson p "$2" --argjson f "$frames" '$p + {summary: ., frames: $f}' "$3")"
}

# fly_quality SECTION FIELDS_JSON FLY_ARGS...: one settled quality flight (1280×720,
# 30 fps, every 10th frame against the cached full-resolution reference) recorded
# with every frame's statistics. FLY_ARGS add the server, dataset, path, frames and
# the setting under test.
fly_quality() {
  local section=$1 fields=$2
  shift 2
  rm -rf "$WORK/run"
  "$CLIENT_BIN" fly --fps 30 --viewport 1280x720 --spacing "$MOON_SPACING" --budget-ms 50 \
    --quality --quality-every 10 --settle --reference-cache "$RESULTS/reference-cache" --no-frames \
    --out "$WORK/run" "$@" > "$WORK/run.json" 2> "$WORK/run.log" || { cat "$WORK/run.log" >&2; exit 1; }
  fly_record "$section" "$fields" "$WORK/run.json" "$WORK/run/stats.jsonl"
}

# Shared by bench/webtiles.sh and bench/rendered.sh (sourced after common.sh, with $secs,
# $conns and $workers set): TiTiler in its own virtualenv, Tessera and TiTiler servers started on
# free ports, peak RSS of a process tree, the made-tile cache counters, a wrk row cycling
# through a tile list and a curl pass over it, both as JSON.

# --- TiTiler in its own virtualenv (outside the repository)
venv=${TITILER_VENV:-${XDG_CACHE_HOME:-$HOME/.cache}/tessera/titiler-venv}
if ! "$venv/bin/python" -c 'import titiler.application, uvicorn' 2> /dev/null; then
  log "webtiles: installing TiTiler into $venv"
  python3 -m venv "$venv"
  "$venv/bin/pip" install -q --upgrade pip
  "$venv/bin/pip" install -q titiler.application uvicorn
fi
titiler_version=$("$venv/bin/python" -c 'import importlib.metadata as m; print(m.version("titiler.application"))')

# The commit measured, "+dirty" when tracked files differ from it.
commit=$(git rev-parse --short HEAD 2> /dev/null || echo unknown)
[ -z "$(git status --porcelain --untracked-files=no 2> /dev/null)" ] || commit="$commit+dirty"

free_port() {
  python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# rss_mib PID: VmHWM of PID and all its descendants, in MiB.
rss_mib() {
  local pids=("$1") kids
  kids=$(pgrep -P "$1" || true)
  for k in $kids; do pids+=("$k" $(pgrep -P "$k" || true)); done
  for p in "${pids[@]}"; do sed -n 's/^VmHWM:\s*\([0-9]*\) kB/\1/p' "/proc/$p/status" 2> /dev/null; done \
    | awk '{s += $1} END {printf "%.1f", s / 1024}'
}

# tile_cache RESULT URL: tessera_web_cache_requests_total{cache="tile",result=RESULT}.
tile_cache() {
  curl -sf "$2/metrics" | awk -v r="$1" '/^tessera_web_cache_requests_total\{/ && /cache="tile"/ && $0 ~ "result=\"" r "\"" {print $NF}' | head -n1
}

# stop PID: SIGTERM and wait (a server started through spawn).
stop() { kill -TERM "$1" 2> /dev/null || true; wait "$1" 2> /dev/null || true; }

# start_tessera PYRAMID ARGS...: a fresh server; sets TESSERA_URL and TESSERA_PID.
start_tessera() {
  local n=${#BENCH_PIDS[@]}
  spawn "$WORK/serve$n.out" "$WORK/serve$n.log" "$SERVER_BIN" serve "$@" --listen 127.0.0.1:0
  TESSERA_PID=${BENCH_PIDS[-1]}
  TESSERA_URL=$(wait_listening "$WORK/serve$n.out")
}

# start_titiler: a fresh TiTiler; sets TITILER_URL and TITILER_PID.
start_titiler() {
  local port n=${#BENCH_PIDS[@]}
  port=$(free_port)
  GDAL_DISABLE_READDIR_ON_OPEN=EMPTY_DIR spawn "$WORK/titiler$n.out" "$WORK/titiler$n.log" \
    "$venv/bin/uvicorn" titiler.application.main:app --host 127.0.0.1 --port "$port" \
    --workers "$workers" --no-access-log --log-level warning
  TITILER_PID=${BENCH_PIDS[-1]}
  TITILER_URL=http://127.0.0.1:$port
  for _ in $(seq 600); do
    curl -sf -o /dev/null "$TITILER_URL/healthz" && return 0
    sleep 0.1
  done
  echo "TiTiler did not start" >&2
  cat "$WORK/titiler$n.log" >&2
  exit 1
}

# wrk: a request generator cycling through $TILE_LIST (each thread from its own
# offset), and a done() printing JSON.
cat > "$WORK/cycle.lua" <<'LUA'
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

# wrk_json BASE LIST: one wrk row of $secs at $conns connections; prints its JSON.
wrk_json() {
  TILE_LIST=$2 wrk -t2 -c"$conns" -d"${secs}s" --timeout 60s --latency -s "$WORK/cycle.lua" "$1" \
    > "$WORK/wrk.out" 2> "$WORK/wrk.err" || { cat "$WORK/wrk.out" "$WORK/wrk.err" >&2; exit 1; }
  tail -n1 "$WORK/wrk.out"
}

# pass_json BASE LIST: each path of LIST requested once, $conns at a time (curl -Z);
# prints {duration_s, requests, errors, non2xx, p50_ms, p99_ms}.
pass_json() {
  local base=$1 list=$2 t0 t1
  sed "s|.*|url = \"$base&\"\noutput = \"/dev/null\"|" "$list" > "$WORK/pass.curl"
  t0=$(date +%s.%N)
  curl -s --no-progress-meter -Z --parallel-max "$conns" --parallel-immediate -K "$WORK/pass.curl" \
    -w '%{http_code} %{time_total} %{exitcode}\n' > "$WORK/pass.out" || true
  t1=$(date +%s.%N)
  sort -k2,2g "$WORK/pass.out" | awk -v t0="$t0" -v t1="$t1" '
    { code[NR] = $1; t[NR] = $2; if ($3 != 0) err++; else if ($1 < 200 || $1 > 299) bad++ }
    END {
      p50 = t[int((NR - 1) * 0.50) + 1]; p99 = t[int((NR - 1) * 0.99) + 1]
      printf "{\"duration_s\":%.6f,\"requests\":%d,\"errors\":%d,\"non2xx\":%d,\"p50_ms\":%.3f,\"p99_ms\":%.3f}\n",
        t1 - t0, NR - err, err, bad, p50 * 1000, p99 * 1000 }'
}


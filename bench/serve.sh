#!/usr/bin/env bash
# Serving (DECISIONS.md "Benchmarks"): the finest level of the moon 8192² pyramid
# (512-cell tiles: level 4, 16×16 tiles) on loopback, wrk with 2 threads at 64, 256 and
# 1024 connections:
#   (a) Tessera Morton-range batches of 4, 16 and 64 consecutive tiles from a random
#       batch-aligned start (one Z-order quadtree block);
#   (b) Tessera one tile per request (`/v1/datasets/NAME/tiles/L/X/Y`), a random tile;
#   (c) nginx serving the same records as static files `L/X/Y.bin`, exported through
#       (b)'s route so they are byte for byte what (b) sends; a random file.
# nginx: 2 workers, sendfile, tcp_nopush, no access log, keep-alive without a request
# limit (nginx's default closes a connection after 1000 requests; Tessera never does).
# Then the real request pattern: `tessera load --clients 64` in both request modes.
# wrk, nginx, the clients and the server share the machine's cores.
# CPU per row (DECISIONS.md "Object storage", serving efficiency): user + system seconds
# of the server's processes (Tessera's one; nginx's master and workers) from
# /proc/PID/stat before and after the wrk run, wrk's own (GNU time), and every CPU's busy
# seconds (/proc/stat), so that CPU per payload byte is compared in the same run and other
# load shows. Appends to $RESULTS/serve.jsonl {server, request, tiles_per_request,
# connections, run, duration_s, requests, errors, p50_ms, p99_ms, mean_tile_bytes,
# wrk_bytes, server_cpu_s, wrk_cpu_s, machine_cpu_s} and to $RESULTS/load.jsonl {mode,
# run, …`tessera load --json`}.
#   ROW_SECONDS (default 4) per wrk row, LOAD_SECONDS (default 10) per load run.
source "$(dirname "$0")/common.sh"
row=${ROW_SECONDS:-4}
load_s=${LOAD_SECONDS:-10}
conns=(64 256 1024)
if [ "$QUICK" = 1 ]; then row=2; load_s=4; conns=(64); fi
nginx_bin=$(command -v nginx || echo /usr/sbin/nginx)
ulimit -n 65536 2>/dev/null || ulimit -n "$(ulimit -Hn)"

ds=moon8k level=4 side=16
build_moon 8192 "$WORK/$ds.tess"
# Not `url=$(serve …)`: in a subshell the server's PID would not reach BENCH_PIDS.
serve "$WORK/$ds.tess" > "$WORK/url"
url=$(cat "$WORK/url")
tessera_pid=${BENCH_PIDS[-1]}

# Export every finest tile through the single-tile route, one curl over one connection.
static=$WORK/static
for x in $(seq 0 $((side - 1))); do
  for y in $(seq 0 $((side - 1))); do
    printf 'url = "%s/v1/datasets/%s/tiles/%s/%s/%s"\noutput = "%s/%s/%s/%s.bin"\n' \
      "$url" "$ds" "$level" "$x" "$y" "$static" "$level" "$x" "$y"
  done
done > "$WORK/export.curl"
curl -sS --fail --create-dirs -K "$WORK/export.curl"
ntiles=$(find "$static" -name '*.bin' | wc -l)
[ "$ntiles" -eq $((side * side)) ] || { echo "exported $ntiles tiles, expected $((side * side))" >&2; exit 1; }
mean_bytes=$(find "$static" -name '*.bin' -printf '%s\n' | awk '{s += $1} END {printf "%.0f", s / NR}')

port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
mkdir -p "$WORK/nginx"
{
  [ "$(id -u)" -eq 0 ] && echo "user root;"
  cat <<CONF
worker_processes 2;
worker_rlimit_nofile 65536;
pid $WORK/nginx/nginx.pid;
error_log $WORK/nginx/error.log warn;
events { worker_connections 4096; }
http {
  access_log off;
  sendfile on;
  tcp_nopush on;
  keepalive_requests 1000000;
  keepalive_timeout 75s;
  default_type application/octet-stream;
  client_body_temp_path $WORK/nginx/body;
  proxy_temp_path $WORK/nginx/proxy;
  fastcgi_temp_path $WORK/nginx/fastcgi;
  uwsgi_temp_path $WORK/nginx/uwsgi;
  scgi_temp_path $WORK/nginx/scgi;
  server {
    listen 127.0.0.1:$port;
    root $static;
  }
}
CONF
} > "$WORK/nginx.conf"
spawn "$WORK/nginx.out" "$WORK/nginx/error.log" "$nginx_bin" -p "$WORK/nginx" -e "$WORK/nginx/error.log" \
  -c "$WORK/nginx.conf" -g 'daemon off;'
nginx_pid=${BENCH_PIDS[-1]}
for _ in $(seq 200); do curl -sf -o /dev/null "http://127.0.0.1:$port/$level/0/0.bin" && break; sleep 0.05; done
cmp -s <(curl -sf "http://127.0.0.1:$port/$level/3/5.bin") <(curl -sf "$url/v1/datasets/$ds/tiles/$level/3/5") \
  || { echo "nginx does not serve the exported tiles" >&2; cat "$WORK/nginx/error.log" >&2; exit 1; }

# wrk scripts: a request generator each, and one shared done() printing JSON.
cat > "$WORK/report.lua" <<'LUA'
done = function(summary, latency, requests)
  local e = summary.errors
  io.write(string.format(
    '{"duration_s":%.6f,"requests":%d,"wrk_bytes":%d,"errors":%d,"p50_ms":%.3f,"p99_ms":%.3f}\n',
    summary.duration / 1e6, summary.requests, summary.bytes,
    e.connect + e.read + e.write + e.status + e.timeout,
    latency:percentile(50) / 1e3, latency:percentile(99) / 1e3))
end
LUA
seed='math.randomseed(os.time() + tonumber(tostring({}):sub(8), 16))'
cat > "$WORK/batch.lua" <<LUA
local ds, level, side, batch = os.getenv("DS"), os.getenv("LEVEL"), tonumber(os.getenv("SIDE")), tonumber(os.getenv("BATCH"))
$seed
request = function()
  local s = batch * math.random(0, side * side / batch - 1)
  return wrk.format("GET", "/v1/datasets/" .. ds .. "/levels/" .. level .. "/tiles?ranges=" .. s .. "-" .. (s + batch - 1))
end
LUA
cat > "$WORK/single.lua" <<LUA
local ds, level, side = os.getenv("DS"), os.getenv("LEVEL"), tonumber(os.getenv("SIDE"))
$seed
request = function()
  return wrk.format("GET", "/v1/datasets/" .. ds .. "/tiles/" .. level .. "/" .. math.random(0, side - 1) .. "/" .. math.random(0, side - 1))
end
LUA
cat > "$WORK/static.lua" <<LUA
local level, side = os.getenv("LEVEL"), tonumber(os.getenv("SIDE"))
$seed
request = function()
  return wrk.format("GET", "/" .. level .. "/" .. math.random(0, side - 1) .. "/" .. math.random(0, side - 1) .. ".bin")
end
LUA
for s in batch single static; do cat "$WORK/report.lua" >> "$WORK/$s.lua"; done
export DS=$ds LEVEL=$level SIDE=$side

hz=$(getconf CLK_TCK)
# cpu_ticks PID...: user + system clock ticks the processes have used so far (fields
# 14 and 15 of /proc/PID/stat, counted after the parenthesised command name).
cpu_ticks() {
  local t=0 p f
  for p in "$@"; do
    f=$(cat "/proc/$p/stat")
    f=${f##*) }
    t=$((t + $(awk '{print $12 + $13}' <<< "$f")))
  done
  echo "$t"
}
# machine_ticks: busy clock ticks of all CPUs (user nice system irq softirq steal).
machine_ticks() { awk '/^cpu / {print $2 + $3 + $4 + $7 + $8 + $9}' /proc/stat; }
# server_pids SERVER: the processes whose CPU a row counts.
server_pids() {
  case "$1" in
    tessera) echo "$tessera_pid" ;;
    nginx) echo "$nginx_pid" $(cat /proc/"$nginx_pid"/task/*/children) ;;
  esac
}

# wrk_row SERVER REQUEST TILES CONNECTIONS RUN BASE_URL: one wrk run, one record.
wrk_row() {
  local server=$1 request=$2 tiles=$3 c=$4 run=$5 base=$6
  local pids s0 s1 m0 m1
  pids=$(server_pids "$server")
  # shellcheck disable=SC2086 # one PID per word
  s0=$(cpu_ticks $pids)
  m0=$(machine_ticks)
  BATCH=$tiles /usr/bin/time -f '%U %S' -o "$WORK/wrk.time" \
    wrk -t2 -c"$c" -d"${row}s" --timeout 60s -s "$WORK/$request.lua" "$base" > "$WORK/wrk.out"
  # shellcheck disable=SC2086
  s1=$(cpu_ticks $pids)
  m1=$(machine_ticks)
  local non2xx
  non2xx=$(awk '/Non-2xx/ {print $NF}' "$WORK/wrk.out")
  record serve "$(tail -n1 "$WORK/wrk.out" | jq -c --arg server "$server" --arg request "$request" \
    --argjson tiles "$tiles" --argjson c "$c" --argjson run "$run" --argjson mean "$mean_bytes" \
    --argjson non2xx "${non2xx:-0}" \
    --argjson server_cpu "$(awk -v t=$((s1 - s0)) -v hz="$hz" 'BEGIN {print t / hz}')" \
    --argjson machine_cpu "$(awk -v t=$((m1 - m0)) -v hz="$hz" 'BEGIN {print t / hz}')" \
    --argjson wrk_cpu "$(awk '{print $1 + $2}' "$WORK/wrk.time")" \
    '{server: $server, request: $request, tiles_per_request: $tiles, connections: $c, run: $run,
      mean_tile_bytes: $mean} + . + {errors: (.errors + $non2xx), server_cpu_s: $server_cpu,
      wrk_cpu_s: $wrk_cpu, machine_cpu_s: $machine_cpu}')"
}

for run in $(seq "$RUNS"); do
  for c in "${conns[@]}"; do
    log "serve: run $run of $RUNS, $c connections, ${row}s per row"
    for b in 4 16 64; do wrk_row tessera batch "$b" "$c" "$run" "$url"; done
    wrk_row tessera single 1 "$c" "$run" "$url"
    wrk_row nginx static 1 "$c" "$run" "http://127.0.0.1:$port"
  done
done

for run in $(seq "$RUNS"); do
  for mode in ranges single; do
    log "load: run $run of $RUNS, 64 clients, $mode, ${load_s}s"
    "$CLIENT_BIN" load --server "$url" --dataset "$ds" --clients 64 --duration "${load_s}s" \
      --mode "$mode" --spacing "$MOON_SPACING" --json > "$WORK/load.json" 2> "$WORK/load.log" \
      || { cat "$WORK/load.log" >&2; exit 1; }
    record load "$(jq -c --arg mode "$mode" --argjson run "$run" '{mode: $mode, run: $run} + .' "$WORK/load.json")"
  done
done

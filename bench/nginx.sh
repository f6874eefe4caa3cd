#!/usr/bin/env bash
# Serving against nginx (issue 6 item 3, DESIGN §7): the finest level of the moon
# 8192² pyramid (512-cell tiles: level 4, 16×16 = 256 tiles), at each connection count,
# with wrk (2 threads, --latency) on loopback:
#   (a) Tessera Morton-range batches of 4, 16 and 64 consecutive tiles, random aligned start;
#   (b) Tessera one tile per request (`/v1/datasets/NAME/tiles/L/X/Y`), random tile;
#   (c) nginx serving the same tile records as static files `L/X/Y.bin` (exported
#       through (b)'s route, so byte for byte what (b) sends), random tile.
#   bench/nginx.sh [DURATION] [CONNECTIONS...]     (defaults: 15s, 64 256 1024)
# nginx: 2 workers, sendfile, tcp_nopush, no access log, keep-alive without a request
# limit (nginx's default closes a connection after 1000 requests; Tessera never does).
# Payload MB/s is tiles/s × the mean stored tile size (10^6 bytes); wrk MiB/s is wrk's
# own transfer rate (bodies, headers and frame headers). wrk, nginx and the server
# share the machine's cores. Prints a Markdown table, then the issue's two ratios per
# connection count. Needs wrk, nginx and curl (Debian packages of those names).
set -euo pipefail
cd "$(dirname "$0")/.."
duration=${1:-15s}
shift || true
conns=("$@")
[ ${#conns[@]} -gt 0 ] || conns=(64 256 1024)
need=()
for p in wrk nginx curl; do command -v "$p" >/dev/null || [ -x "/usr/sbin/$p" ] || need+=("$p"); done
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" -eq 0 ]; then
    apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
  else
    echo "install: sudo apt-get install --no-install-recommends ${need[*]}" >&2; exit 1
  fi
fi
nginx_bin=$(command -v nginx || echo /usr/sbin/nginx)
cargo build --release --locked -q -p tessera-server
bin=$PWD/target/release/tessera-server
work=$(mktemp -d "${TMPDIR:-/tmp}/tessera-nginx-bench.XXXXXX")
server_pid=
nginx_pid=
cleanup() {
  [ -n "$server_pid" ] && kill -TERM "$server_pid" 2>/dev/null
  [ -n "$nginx_pid" ] && kill -TERM "$nginx_pid" 2>/dev/null
  wait 2>/dev/null
  rm -rf "$work"
}
trap cleanup EXIT
ulimit -n 65536 2>/dev/null || ulimit -n "$(ulimit -Hn)"

ds=moon8k level=4 side=16
"$bin" build ../shared/data/dem/moon_crisium_gld100_8192.png --offset -10000 -o "$work/$ds.tess" --quiet >/dev/null
"$bin" serve "$work/$ds.tess" --listen 127.0.0.1:0 > "$work/serve.out" 2> "$work/serve.log" &
server_pid=$!
for _ in $(seq 200); do grep -q "listening on" "$work/serve.out" 2>/dev/null && break; sleep 0.05; done
url=$(sed -n 's/^listening on //p' "$work/serve.out")
[ -n "$url" ] || { cat "$work/serve.log" >&2; exit 1; }

# Export every finest tile through the single-tile route, one curl over one connection.
root=$work/static
for x in $(seq 0 $((side - 1))); do
  for y in $(seq 0 $((side - 1))); do
    printf 'url = "%s/v1/datasets/%s/tiles/%s/%s/%s"\noutput = "%s/%s/%s/%s.bin"\n' \
      "$url" "$ds" "$level" "$x" "$y" "$root" "$level" "$x" "$y"
  done
done > "$work/export.curl"
curl -sS --fail --create-dirs -K "$work/export.curl"
ntiles=$(find "$root" -name '*.bin' | wc -l)
[ "$ntiles" -eq $((side * side)) ] || { echo "exported $ntiles tiles, expected $((side * side))" >&2; exit 1; }
mean_bytes=$(find "$root" -name '*.bin' -printf '%s\n' | awk '{s += $1} END {printf "%.0f", s / NR}')

port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
mkdir -p "$work/nginx"
{
  [ "$(id -u)" -eq 0 ] && echo "user root;"
  cat <<CONF
worker_processes 2;
worker_rlimit_nofile 65536;
pid $work/nginx/nginx.pid;
error_log $work/nginx/error.log warn;
events { worker_connections 4096; }
http {
  access_log off;
  sendfile on;
  tcp_nopush on;
  keepalive_requests 1000000;
  keepalive_timeout 75s;
  default_type application/octet-stream;
  client_body_temp_path $work/nginx/body;
  proxy_temp_path $work/nginx/proxy;
  fastcgi_temp_path $work/nginx/fastcgi;
  uwsgi_temp_path $work/nginx/uwsgi;
  scgi_temp_path $work/nginx/scgi;
  server {
    listen 127.0.0.1:$port;
    root $root;
  }
}
CONF
} > "$work/nginx.conf"
"$nginx_bin" -p "$work/nginx" -e "$work/nginx/error.log" -c "$work/nginx.conf" -g 'daemon off;' 2>> "$work/nginx/error.log" &
nginx_pid=$!
for _ in $(seq 200); do curl -sf -o /dev/null "http://127.0.0.1:$port/$level/0/0.bin" && break; sleep 0.05; done
cmp -s <(curl -sf "http://127.0.0.1:$port/$level/3/5.bin") <(curl -sf "$url/v1/datasets/$ds/tiles/$level/3/5") \
  || { echo "nginx does not serve the exported tiles" >&2; cat "$work/nginx/error.log" >&2; exit 1; }

cat > "$work/ranges.lua" <<'LUA'
-- BATCH consecutive finest-level tiles from a random BATCH-aligned Morton start.
local ds, level, side, batch = os.getenv("DS"), os.getenv("LEVEL"), tonumber(os.getenv("SIDE")), tonumber(os.getenv("BATCH"))
math.randomseed(os.time() + tonumber(tostring({}):sub(8), 16))
request = function()
  local s = batch * math.random(0, side * side / batch - 1)
  return wrk.format("GET", "/v1/datasets/" .. ds .. "/levels/" .. level .. "/tiles?ranges=" .. s .. "-" .. (s + batch - 1))
end
LUA
cat > "$work/single.lua" <<'LUA'
local ds, level, side = os.getenv("DS"), os.getenv("LEVEL"), tonumber(os.getenv("SIDE"))
math.randomseed(os.time() + tonumber(tostring({}):sub(8), 16))
request = function()
  return wrk.format("GET", "/v1/datasets/" .. ds .. "/tiles/" .. level .. "/" .. math.random(0, side - 1) .. "/" .. math.random(0, side - 1))
end
LUA
cat > "$work/static.lua" <<'LUA'
local level, side = os.getenv("LEVEL"), tonumber(os.getenv("SIDE"))
math.randomseed(os.time() + tonumber(tostring({}):sub(8), 16))
request = function()
  return wrk.format("GET", "/" .. level .. "/" .. math.random(0, side - 1) .. "/" .. math.random(0, side - 1) .. ".bin")
end
LUA
export DS=$ds LEVEL=$level SIDE=$side

# run KEY LABEL CONNECTIONS BASE_URL SCRIPT TILES_PER_REQUEST: one wrk run, one table
# row; "KEY CONNECTIONS tiles/s payload_MB/s" goes to $work/results for the ratios.
run() {
  local key=$1 label=$2 c=$3 out=$work/$1-$3.txt
  BATCH=$6 wrk -t2 -c"$c" -d"$duration" --timeout 60s --latency -s "$work/$5" "$4" > "$out"
  local rps tps pay mibs p50 p99 errs
  rps=$(awk '/^Requests\/sec/ {print $2}' "$out")
  tps=$(awk -v r="$rps" -v t="$6" 'BEGIN {printf "%.0f", r * t}')
  pay=$(awk -v t="$tps" -v b="$mean_bytes" 'BEGIN {printf "%.0f", t * b / 1e6}')
  mibs=$(awk '/^Transfer\/sec/ {v=$2; if (v ~ /GB$/) {sub(/GB/,"",v); v*=1024} else if (v ~ /MB$/) {sub(/MB/,"",v)} else if (v ~ /KB$/) {sub(/KB/,"",v); v/=1024}; printf "%.0f", v}' "$out")
  p50=$(awk '$1=="50%" {print $2}' "$out")
  p99=$(awk '$1=="99%" {print $2}' "$out")
  errs=$(awk '/Non-2xx|Socket errors/ {print}' "$out" | tr '\n' ' ' | sed 's/ *$//')
  echo "$key $c $tps $pay" >> "$work/results"
  printf "| %s | %s | %.0f | %s | %s | %s | %s | %s | %s |\n" "$label" "$c" "$rps" "$tps" "$pay" "$mibs" "$p50" "$p99" "${errs:-none}"
}

: > "$work/results"
echo "Mean stored tile: $mean_bytes bytes ($ntiles tiles, level $level of $ds, 512-cell tiles). wrk $duration per row."
echo
echo "| server and request | connections | requests/s | tiles/s | payload MB/s | wrk MiB/s | p50 | p99 | errors |"
echo "|---|---|---|---|---|---|---|---|---|"
for c in "${conns[@]}"; do
  for b in 4 16 64; do
    run "batch$b" "Tessera: Morton batch of $b tiles" "$c" "$url" ranges.lua "$b"
  done
  run single "Tessera: one tile per request" "$c" "$url" single.lua 1
  run nginx "nginx: one static tile file per request" "$c" "http://127.0.0.1:$port" static.lua 1
done
echo
echo "| connections | batch-16 payload MB/s ÷ nginx (aim ≥ 1) | batch-16 tiles/s ÷ Tessera single (aim ≥ 3) | Tessera single ÷ nginx tiles/s |"
echo "|---|---|---|---|"
for c in "${conns[@]}"; do
  awk -v c="$c" '$2 == c {t[$1] = $3; p[$1] = $4}
    END {printf "| %s | %.2f | %.2f | %.2f |\n", c, p["batch16"] / p["nginx"], t["batch16"] / t["single"], t["single"] / t["nginx"]}' "$work/results"
done

#!/usr/bin/env bash
# Serving benchmark: wrk against `tessera-server serve` on the moon 8192² pyramid,
# finest level, built with 512-cell tiles (256 tiles of ~230 KB) and with 128-cell
# tiles (4096 tiles of ~15 KB):
#   (a) Morton-range requests of 16 consecutive tiles, random aligned start;
#   (b) one tile per request, random tile.
#   bench/serve.sh [DURATION] [CONNECTIONS]     (defaults: 30s 64)
# Prints a Markdown table: requests/s, tiles/s, MB/s (wrk's transfer rate, headers
# included), p50/p99 latency. wrk comes from Debian's `wrk` package.
set -euo pipefail
cd "$(dirname "$0")/.."
duration=${1:-30s}
conns=${2:-64}
if ! command -v wrk >/dev/null; then
  if [ "$(id -u)" -eq 0 ]; then apt-get install -y -qq wrk >/dev/null; else echo "install wrk: sudo apt-get install wrk" >&2; exit 1; fi
fi
cargo build --release --locked -q -p tessera-server
bin=$PWD/target/release/tessera-server
work=$(mktemp -d "${TMPDIR:-/tmp}/tessera-serve-bench.XXXXXX")
server_pid=
cleanup() { [ -n "$server_pid" ] && kill -TERM "$server_pid" 2>/dev/null; wait 2>/dev/null; rm -rf "$work"; }
trap cleanup EXIT

"$bin" build ../shared/data/dem/moon_crisium_gld100_8192.png --offset -10000 -o "$work/moon8k.tess" --quiet >/dev/null
"$bin" build ../shared/data/dem/moon_crisium_gld100_8192.png --offset -10000 --tile-size 128 -o "$work/moon8k128.tess" --quiet >/dev/null
"$bin" serve "$work/moon8k.tess" "$work/moon8k128.tess" --listen 127.0.0.1:0 > "$work/serve.out" 2> "$work/serve.log" &
server_pid=$!
for _ in $(seq 100); do grep -q "listening on" "$work/serve.out" 2>/dev/null && break; sleep 0.05; done
url=$(sed -n 's/^listening on //p' "$work/serve.out")

cat > "$work/ranges.lua" <<'LUA'
-- 16 consecutive finest-level tiles from a random 16-aligned Morton start.
local ds, level, side = os.getenv("DS"), os.getenv("LEVEL"), tonumber(os.getenv("SIDE"))
math.randomseed(os.time() + tonumber(tostring({}):sub(8), 16))
request = function()
  local s = 16 * math.random(0, side * side / 16 - 1)
  return wrk.format("GET", "/v1/datasets/" .. ds .. "/levels/" .. level .. "/tiles?ranges=" .. s .. "-" .. (s + 15))
end
LUA
cat > "$work/single.lua" <<'LUA'
local ds, level, side = os.getenv("DS"), os.getenv("LEVEL"), tonumber(os.getenv("SIDE"))
math.randomseed(os.time() + tonumber(tostring({}):sub(8), 16))
request = function()
  return wrk.format("GET", "/v1/datasets/" .. ds .. "/tiles/" .. level .. "/" .. math.random(0, side - 1) .. "/" .. math.random(0, side - 1))
end
LUA

run() { # name script tiles_per_request
  wrk -t2 -c"$conns" -d"$duration" --latency -s "$work/$2" "$url" > "$work/run.txt"
  mv "$work/run.txt" "$work/$(echo "$1" | tr -c 'A-Za-z0-9\n' _).txt"
  local out="$work/$(echo "$1" | tr -c 'A-Za-z0-9\n' _).txt"
  local rps mbs p50 p99 errs
  rps=$(awk '/^Requests\/sec/ {print $2}' "$out")
  mbs=$(awk '/^Transfer\/sec/ {v=$2; if (v ~ /GB$/) {sub(/GB/,"",v); v*=1024} else if (v ~ /MB$/) {sub(/MB/,"",v)} else if (v ~ /KB$/) {sub(/KB/,"",v); v/=1024}; printf "%.0f", v}' "$out")
  p50=$(awk '$1=="50%" {print $2}' "$out")
  p99=$(awk '$1=="99%" {print $2}' "$out")
  errs=$(awk '/Non-2xx|Socket errors/ {print}' "$out" | tr '\n' ' ')
  printf "| %s | %s | %.0f | %s | %s | %s | %s | %s |\n" "$1" "$conns" "$rps" "$(awk -v r="$rps" -v t="$3" 'BEGIN {printf "%.0f", r * t}')" "$mbs" "$p50" "$p99" "${errs:-none}"
}
echo "| request | connections | requests/s | tiles/s | MiB/s | p50 | p99 | errors |"
echo "|---|---|---|---|---|---|---|---|"
export DS=moon8k LEVEL=4 SIDE=16
run "T=512: ranges of 16 tiles" ranges.lua 16
run "T=512: single tile" single.lua 1
export DS=moon8k128 LEVEL=6 SIDE=64
run "T=128: ranges of 16 tiles" ranges.lua 16
run "T=128: single tile" single.lua 1

#!/usr/bin/env bash
# Streaming under latency: `tessera fly --no-render --path pass` over the moon 8192²
# pyramid, at 0 and 150 ms added latency (bench/delay_proxy.py holds each response
# that long), prefetch on and off. Prints a Markdown table.
#   bench/stream.sh [FRAMES] [TAU]     (defaults: 600 frames at 60 fps, τ = 1)
set -euo pipefail
cd "$(dirname "$0")/.."
frames=${1:-600}
tau=${2:-1}
cargo build --release --locked -q -p tessera-server -p tessera-client
server_bin=$PWD/target/release/tessera-server
fly_bin=$PWD/target/release/tessera
work=$(mktemp -d "${TMPDIR:-/tmp}/tessera-stream-bench.XXXXXX")
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; rm -rf "$work"; }
trap cleanup EXIT

"$server_bin" build ../shared/data/dem/moon_crisium_gld100_8192.png --offset -10000 -o "$work/moon8k.tess" --quiet >/dev/null
"$server_bin" serve "$work/moon8k.tess" --listen 127.0.0.1:0 > "$work/serve.out" 2> "$work/serve.log" &
pids+=($!)
wait_line() { for _ in $(seq 200); do grep -q "listening on" "$1" 2>/dev/null && return 0; sleep 0.05; done; return 1; }
wait_line "$work/serve.out"
direct=$(sed -n 's/^listening on //p' "$work/serve.out")
python3 bench/delay_proxy.py 0 "${direct#http://}" 150 > "$work/proxy.out" 2>&1 &
pids+=($!)
wait_line "$work/proxy.out"
delayed="http://$(sed -n 's/^listening on //p' "$work/proxy.out")"

echo "| added latency | prefetch | frames ≤ τ | frames ≤ 2τ | warm-up frames | after warm-up ≤ τ | after warm-up ≤ 2τ | p99 streaming work | max streaming work | bytes fetched | requests |"
echo "|---|---|---|---|---|---|---|---|---|---|---|"
for latency in 0 150; do
  url=$direct; [ "$latency" = 150 ] && url=$delayed
  for prefetch in on off; do
    flag=""; [ "$prefetch" = off ] && flag="--no-prefetch"
    # shellcheck disable=SC2086
    "$fly_bin" fly --server "$url" --dataset moon8k --path pass --frames "$frames" --tau "$tau" \
      --spacing 118.45 --no-render $flag > "$work/summary.json"
    python3 - "$work/summary.json" "$latency" "$prefetch" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
st = s["stream"]
print(f"| {sys.argv[2]} ms | {sys.argv[3]} | {100*s['within_tau']:.1f}% | {100*s['within_2tau']:.1f}% "
      f"| {s['warmup_frames']} | {100*s['steady_within_tau']:.1f}% | {100*s['steady_within_2tau']:.1f}% "
      f"| {s['p99_stream_us']:.0f} µs | {s['max_stream_us']:.0f} µs | {st['bytes']/1e6:.1f} MB | {st['requests']} |")
PY
  done
done

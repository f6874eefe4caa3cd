#!/usr/bin/env bash
# Selection policy at equal image quality (issue 6, DESIGN §7): screen-space error
# (τ in pixels of error) against the distance-only baseline (τ bounds a cell's size
# on screen), on the moon 4096², `pass` path, 1280×720, 60 frames; PSNR against the
# full-resolution reference every 10th frame, over frames that draw what the policy
# asks for. Prints a Markdown table.
#   bench/policy.sh ["SCREEN_TAUS"] ["DISTANCE_TAUS"]   (defaults: "1 2", "2 4 8 16 32")
set -euo pipefail
cd "$(dirname "$0")/.."
screen=${1:-1 2}
distance=${2:-2 4 8 16 32}
cargo build --release --locked -q -p tessera-server -p tessera-client
server_bin=$PWD/target/release/tessera-server
fly_bin=$PWD/target/release/tessera
work=$(mktemp -d "${TMPDIR:-/tmp}/tessera-policy-bench.XXXXXX")
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; rm -rf "$work"; }
trap cleanup EXIT
"$server_bin" build ../shared/data/dem/moon_crisium_gld100_4096.png --offset -10000 -o "$work/moon4096.tess" --quiet >/dev/null
"$server_bin" serve "$work/moon4096.tess" --listen 127.0.0.1:0 > "$work/serve.out" 2> "$work/serve.log" &
pids+=($!)
for _ in $(seq 200); do grep -q "listening on" "$work/serve.out" 2>/dev/null && break; sleep 0.05; done
url=$(sed -n 's/^listening on //p' "$work/serve.out")
echo "| policy | τ | median triangles | max draw calls | measured frames | median PSNR | median MSE |"
echo "|---|---|---|---|---|---|---|"
run() {
  "$fly_bin" fly --server "$url" --dataset moon4096 --path pass --frames 60 --fps 30 \
    --viewport 1280x720 --spacing 118.45 --pool-tiles 2048 --gpu-tiles 400 --quality \
    --quality-every 10 --no-frames --out "$work/run" --policy "$1" --tau "$2" > "$work/run.json"
  python3 - "$work/run.json" "$1" "$2" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))["render"]
print(f"| {sys.argv[2]} | {sys.argv[3]} | {r['median_triangles']} | {r['max_draw_calls']} "
      f"| {r['quality_frames']} | {r['median_psnr']:.2f} dB | {r['median_mse']:.3f} |")
PY
}
for t in $screen; do run screen-error "$t"; done
for t in $distance; do run distance "$t"; done

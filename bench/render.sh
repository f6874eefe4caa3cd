#!/usr/bin/env bash
# Rendering figures (issue 5), headless with `tessera fly --out`:
#  1. the moon 8192² pyramid, `canyon` path, W×H, τ = 1, with --quality: triangles,
#     draw calls, crack pixels, PSNR against the full-resolution reference, CPU ms
#     for selection and upload;
#  2. the González table on the moon 4096²: MSE against the reference for parallax
#     none/offset/iterative/binary at τ = 1, 2, 4.
#   bench/render.sh [FRAMES] [WIDTHxHEIGHT]     (defaults: 120 frames, 1280x720)
# Frames run at 30 fps of simulated time. The reference (every sample in view a
# vertex, fetched in full first) is drawn every 20th (canyon) or 10th (González)
# frame, and quality is summarized over those frames that are within τ.
set -euo pipefail
cd "$(dirname "$0")/.."
frames=${1:-120}
size=${2:-1280x720}
cargo build --release --locked -q -p tessera-server -p tessera-client
server_bin=$PWD/target/release/tessera-server
fly_bin=$PWD/target/release/tessera
work=$(mktemp -d "${TMPDIR:-/tmp}/tessera-render-bench.XXXXXX")
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; rm -rf "$work"; }
trap cleanup EXIT

for n in 8192 4096; do
  "$server_bin" build "../shared/data/dem/moon_crisium_gld100_$n.png" --offset -10000 -o "$work/moon$n.tess" --quiet >/dev/null
done
"$server_bin" serve "$work/moon8192.tess" "$work/moon4096.tess" --listen 127.0.0.1:0 > "$work/serve.out" 2> "$work/serve.log" &
pids+=($!)
for _ in $(seq 200); do grep -q "listening on" "$work/serve.out" 2>/dev/null && break; sleep 0.05; done
url=$(sed -n 's/^listening on //p' "$work/serve.out")

summary() {
  python3 - "$1" "$2" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); r = s["render"]
rows = [json.loads(l) for l in open(sys.argv[2])]
tris = sorted(x["triangles"] for x in rows)
ref = sorted(x.get("reference_triangles", 0) for x in rows)
cpu = sorted(x["select_us"] / 1e3 + x["upload_ms"] for x in rows)
mid = lambda v: v[len(v) // 2]
ref = [x for x in ref if x] or [0]
print(f"| {r['gpu']} | {mid(tris)} | {mid(ref)} | {r['max_draw_calls']} | {r['total_crack_pixels']} in {r['quality_frames']} frames "
      f"| {r['median_psnr']:.2f} dB | {r['median_mse']:.2f} | {mid(cpu):.2f} ms | {r['median_render_ms']:.0f} ms |")
PY
}

echo "### moon 8192², canyon, $size, τ = 1, $frames frames"
echo "| renderer | median triangles | median reference triangles | max draw calls | crack pixels (all frames) | median PSNR | median MSE | median CPU selection + upload | median render |"
echo "|---|---|---|---|---|---|---|---|---|"
"$fly_bin" fly --server "$url" --dataset moon8192 --path canyon --frames "$frames" --fps 30 \
  --viewport "$size" --spacing 118.45 --pool-tiles 2048 --gpu-tiles 640 --quality --quality-every 20 --no-frames \
  --out "$work/canyon" > "$work/canyon.json"
summary "$work/canyon.json" "$work/canyon/stats.jsonl"

echo
echo "### González table: moon 4096², pass path, $size, median MSE against the full-resolution reference"
echo "| τ | median triangles | none | offset | iterative | binary |"
echo "|---|---|---|---|---|---|"
for tau in 1 2 4; do
  row="| $tau |"
  tris=""
  for mode in none offset iterative binary; do
    "$fly_bin" fly --server "$url" --dataset moon4096 --path pass --frames "$frames" --fps 30 --tau "$tau" \
      --viewport "$size" --spacing 118.45 --pool-tiles 2048 --gpu-tiles 640 --quality --quality-every 10 --no-frames \
      --parallax "$mode" --out "$work/g-$tau-$mode" > "$work/g.json"
    mse=$(python3 -c "import json,sys; print(f\"{json.load(open('$work/g.json'))['render']['median_mse']:.3f}\")")
    [ -z "$tris" ] && tris=$(python3 -c "import json; print(json.load(open('$work/g.json'))['render']['median_triangles'])")
    row="$row $mse |"
  done
  echo "| $tau | $tris |${row#| $tau |}"
done

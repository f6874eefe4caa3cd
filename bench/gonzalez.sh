#!/usr/bin/env bash
# The González table (issue 6 item 5): on the moon 4096², `pass` path, 1280×720,
# 30 fps, for τ = 1, 2, 4 px and each parallax mode (none, offset limiting,
# iterative, binary search + secant; González Figs. 7, 9, 10): MSE against the
# full-resolution reference drawn without parallax (every 10th frame, settled, cached
# across runs), and the frame time (GPU render per frame; lavapipe where there is no
# GPU). Appends to $RESULTS/gonzalez.jsonl {dataset, path, tau, parallax, run, summary,
# frames}.
source "$(dirname "$0")/common.sh"
frames=31
taus=(1 2 4)
[ "$QUICK" = 1 ] && { frames=11; taus=(1 4); }
build_moon 4096 "$WORK/moon4096.tess"
url=$(serve "$WORK/moon4096.tess")
for run in $(seq "$RUNS"); do
  for tau in "${taus[@]}"; do
    for mode in none offset iterative binary; do
      log "gonzalez: run $run of $RUNS, τ = $tau, parallax $mode"
      rm -rf "$WORK/run"
      "$CLIENT_BIN" fly --server "$url" --dataset moon4096 --path pass --frames "$frames" --fps 30 \
        --tau "$tau" --viewport 1280x720 --spacing "$MOON_SPACING" --pool-tiles 2048 --gpu-tiles 640 \
        --budget-ms 50 --quality --quality-every 10 --settle --reference-cache "$RESULTS/reference-cache" \
        --no-frames --parallax "$mode" --out "$WORK/run" > "$WORK/run.json" 2> "$WORK/run.log" \
        || { cat "$WORK/run.log" >&2; exit 1; }
      fly_record gonzalez "$(jq -n -c --argjson tau "$tau" --arg mode "$mode" --argjson run "$run" \
        '{dataset: "moon4096", path: "pass", tau: $tau, parallax: $mode, run: $run}')" \
        "$WORK/run.json" "$WORK/run/stats.jsonl"
    done
  done
done

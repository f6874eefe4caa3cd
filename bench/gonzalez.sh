#!/usr/bin/env bash
# The González table (DECISIONS.md "Benchmarks"): on the moon 4096², `pass` path,
# 1280×720, 30 fps, for τ = 1, 2, 4 px and each parallax mode (none, offset limiting,
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
      fly_quality gonzalez "$(jq -n -c --argjson tau "$tau" --arg mode "$mode" --argjson run "$run" \
        '{dataset: "moon4096", path: "pass", tau: $tau, parallax: $mode, run: $run}')" \
        --server "$url" --dataset moon4096 --path pass --frames "$frames" --pool-tiles 2048 \
        --gpu-tiles 640 --tau "$tau" --parallax "$mode"
    done
  done
done

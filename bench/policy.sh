#!/usr/bin/env bash
# Selection policy at equal quality (DECISIONS.md "Benchmarks"): the screen-space error
# policy (τ in pixels of error) against the distance-only baseline (τ bounds a cell's size
# on screen, González Fig. 2), on the moon 8192², `canyon` and `pass` paths, 1280×720,
# 30 fps, lavapipe where there is no GPU. Every 10th frame is measured against the
# full-resolution reference after settling (`--settle`: the selection has everything
# it asks for, the eye on the finest ground), so every policy is judged on the same
# cameras; references are cached across runs (`--reference-cache`). A converged
# frame's triangles and image do not depend on timing, so each setting flies once.
# Appends to $RESULTS/policy.jsonl {dataset, path, policy, tau, run, summary, frames}.
source "$(dirname "$0")/common.sh"
frames=31
screen=(1 2)
distance=(2 4 8 16 32)
paths=(canyon pass)
if [ "$QUICK" = 1 ]; then frames=11; distance=(4 16); paths=(pass); fi
build_moon 8192 "$WORK/moon8192.tess"
url=$(serve "$WORK/moon8192.tess")
for path in "${paths[@]}"; do
  for setting in "${screen[@]/#/screen-error:}" "${distance[@]/#/distance:}"; do
    policy=${setting%%:*} tau=${setting#*:}
    log "policy: $path, $policy, τ = $tau"
    fly_quality policy "$(jq -n -c --arg path "$path" --arg policy "$policy" --argjson tau "$tau" \
      '{dataset: "moon8192", path: $path, policy: $policy, tau: $tau, run: 1}')" \
      --server "$url" --dataset moon8192 --path "$path" --frames "$frames" --pool-tiles 4096 \
      --gpu-tiles 800 --policy "$policy" --tau "$tau"
  done
done

#!/usr/bin/env bash
# Tile uploads with normal maps built on the CPU against the GPU's compute pass
# (DECISIONS.md "Normal maps on the GPU"): the plain (unsettled) `canyon` flight over the
# moon 8192², rendered headless (lavapipe where there is no GPU), 1920×1080, τ = 1 px, 60
# fps, the default 4 ms per-frame upload budget, `--normals cpu` and `--normals gpu`
# alternating in each of $RUNS runs (side by side in one session). Appends to
# $RESULTS/upload.jsonl per flight {dataset, path, normals, run, frames, upload_frames,
# tiles_uploaded, median_upload_ms_per_tile (over frames that uploaded: the frame's
# upload_ms ÷ its uploads), median_upload_ms (all frames), median_render_ms, warmup_frames
# (frames before the first within τ), longest_unconverged_frames (after the warm-up: the
# longest run of frames whose selection still wanted tiles), longest_outside_tau_frames
# (likewise for frames not within τ), steady_within_tau, summary}.
#   UPLOAD_FRAMES  frames per flight (default 600 = 10 s; QUICK=1: 240)
source "$(dirname "$0")/common.sh"
frames=${UPLOAD_FRAMES:-600}
[ "$QUICK" = 1 ] && frames=${UPLOAD_FRAMES:-240}
build_moon 8192 "$WORK/moon8192.tess"
url=$(serve "$WORK/moon8192.tess")
for run in $(seq "$RUNS"); do
  for normals in cpu gpu; do
    log "upload: run $run of $RUNS, --normals $normals, $frames frames"
    rm -rf "$WORK/run"
    "$CLIENT_BIN" fly --server "$url" --dataset moon8192 --path canyon --frames "$frames" \
      --fps 60 --tau 1 --viewport 1920x1080 --spacing "$MOON_SPACING" --normals "$normals" \
      --no-frames --out "$WORK/run" > "$WORK/run.json" 2> "$WORK/run.log" \
      || { cat "$WORK/run.log" >&2; exit 1; }
    jq -s -c --arg normals "$normals" --argjson run "$run" --slurpfile summary "$WORK/run.json" '
      def median: sort | if length == 0 then null else .[(length - 1) / 2 | floor] end;
      # The longest run of consecutive frames (after the warm-up) where f is true.
      def longest(f): reduce .[] as $r ({cur: 0, best: 0};
          if ($r | f) then .cur += 1 | .best = ([.best, .cur] | max) else .cur = 0 end) | .best;
      ($summary[0].warmup_frames) as $w
      | (map(select(.uploads > 0))) as $up
      | {dataset: "moon8192", path: "canyon", normals: $normals, run: $run, frames: length,
         upload_frames: ($up | length), tiles_uploaded: (map(.uploads) | add),
         median_upload_ms_per_tile: ($up | map(.upload_ms / .uploads) | median),
         median_upload_ms: (map(.upload_ms) | median),
         median_render_ms: (map(.render_ms) | median),
         warmup_frames: $w,
         longest_unconverged_frames: (.[$w:] | longest(.converged | not)),
         longest_outside_tau_frames: (.[$w:] | longest((.tiles > 0 and .deficit != null and .deficit <= 1) | not)),
         steady_within_tau: $summary[0].steady_within_tau,
         summary: $summary[0]}' "$WORK/run/stats.jsonl" >> "$RESULTS/upload.jsonl"
    tail -n1 "$RESULTS/upload.jsonl" | jq -c 'del(.summary)' >&2
  done
done

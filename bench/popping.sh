#!/usr/bin/env bash
# Popping (DECISIONS.md "Geomorphing over time"): on the moon 8192², a descent
# (bench/paths/popping.json: 12 km down to 1.5 km above the ground in 6 s, the height
# falling by the same fraction every frame, so that the camera's own motion changes the
# picture at a steady pace), settled at every frame (everything the selection asks for
# resident, so only the level of detail changes the picture), in five modes: geomorphing
# over time with shading fades (the default, transitions held within τ), the same
# without that limit (`--morph-error-limit inf`), with CDLOD's distance band as well
# (`--morph-by-distance`), the distance band alone (`--morph-seconds 0
# --morph-by-distance`), and none (`--no-morph`); at τ = 8 px (at τ = 1 a pop moves
# the surface by about a pixel and is lost in the camera's motion). Figures: the mean and
# p99 per-pixel change between consecutive frames where the selection changed and
# where it did not, and the same camera drawn with this frame's patches and the
# previous frame's (the pop alone). Then PSNR against the full-resolution reference
# and crack pixels on the `pass` path at τ = 1 in each mode (every 10th frame,
# settled). Appends to $RESULTS/popping.jsonl
# {dataset, path, measure: "popping"|"quality", mode, run, summary}.
source "$(dirname "$0")/common.sh"
frames=121
[ "$QUICK" = 1 ] && frames=41
build_moon 8192 "$WORK/moon8192.tess"
url=$(serve "$WORK/moon8192.tess")
path=$ROOT/bench/paths/popping.json
for run in $(seq "$RUNS"); do
  for mode in time time-unlimited time+distance distance none; do
    case $mode in
      time) flag=() ;;
      time-unlimited) flag=(--morph-error-limit inf) ;;
      time+distance) flag=(--morph-by-distance) ;;
      distance) flag=(--morph-seconds 0 --morph-by-distance) ;;
      none) flag=(--no-morph) ;;
    esac
    log "popping: run $run of $RUNS, morph $mode"
    rm -rf "$WORK/run"
    "$CLIENT_BIN" fly --server "$url" --dataset moon8192 --path "$path" --frames "$frames" \
      --fps 20 --viewport 960x540 --spacing "$MOON_SPACING" --tau 8 --pool-tiles 4096 \
      --gpu-tiles 1024 --popping --no-frames --out "$WORK/run" "${flag[@]}" \
      > "$WORK/run.json" 2> "$WORK/run.log" || { cat "$WORK/run.log" >&2; exit 1; }
    fly_record popping "$(jq -n -c --arg mode "$mode" --argjson run "$run" \
      '{dataset: "moon8192", path: "popping.json", measure: "popping", mode: $mode, run: $run}')" \
      "$WORK/run.json"
    log "quality: run $run of $RUNS, morph $mode"
    fly_quality popping "$(jq -n -c --arg mode "$mode" --argjson run "$run" \
      '{dataset: "moon8192", path: "pass", measure: "quality", mode: $mode, run: $run}')" \
      --server "$url" --dataset moon8192 --path pass --frames 31 --pool-tiles 4096 \
      --gpu-tiles 1024 --tau 1 "${flag[@]}"
  done
done
# The table for BENCHMARKS.md ("Popping"): medians over the runs.
jq -s -r '
  def med: sort | if length == 0 then null else .[(length - 1) / 2 | floor] end;
  def r2: if . == null then "–" else (. * 100 | round / 100 | tostring) end;
  def r3: if . == null then "–" else (. * 1000 | round / 1000 | tostring) end;
  (map(select(.measure == "popping")) | group_by(.mode)[] |
    (map(.summary.render.popping)) as $p |
    "popping \(.[0].mode): changed pairs \($p | map(.changed_pairs) | med), unchanged \($p | map(.unchanged_pairs) | med); changed mean \($p | map(.changed_mean) | med | r3) p99 \($p | map(.changed_p99) | med | r3); unchanged mean \($p | map(.unchanged_mean) | med | r3) p99 \($p | map(.unchanged_p99) | med | r3); excess \($p | map(.excess_mean) | med | r3); same camera: changed \($p | map(.same_camera_changed_mean) | med | r3) (excess over the drift \($p | map(.same_camera_changed_mean - .same_camera_unchanged_mean) | med | r3)) p99 \($p | map(.same_camera_changed_p99) | med | r3), unchanged \($p | map(.same_camera_unchanged_mean) | med | r3) p99 \($p | map(.same_camera_unchanged_p99) | med | r3), LOD only (\($p | map(.lod_only_pairs) | med) pairs) \($p | map(.same_camera_lod_only_mean) | med | r3) p99 \($p | map(.same_camera_lod_only_p99) | med | r3)"),
  (map(select(.measure == "quality")) | group_by(.mode)[] |
    "quality \(.[0].mode): median PSNR \(map(.summary.render.median_psnr) | med | r2) dB, crack pixels \(map(.summary.render.total_crack_pixels) | max), median triangles \(map(.summary.render.median_triangles) | med)")
' "$RESULTS/popping.jsonl" >&2

#!/usr/bin/env bash
# Selection time (DECISIONS.md "Benchmarks"): `tessera bench-select --json` (every error
# table resident, one core, the selector's own clock) on the moon 8192² (118.45 m) and
# synthetic:65537 (30 m), `pass` and `canyon` paths run forward and back at 60 fps,
# 1920×1080, τ = 1 px, 2000 timed frames. SYNTH names a built synthetic:65537 pyramid
# to reuse (bench/build.sh leaves one when asked); else it is built here (~95 s).
# Appends to $RESULTS/select.jsonl {dataset, path, run, …bench-select's JSON}.
source "$(dirname "$0")/common.sh"
frames=2000
[ "$QUICK" = 1 ] && frames=300
build_moon 8192 "$WORK/moon8192.tess"
synth=${SYNTH:-}
synth_name=${SYNTH_NAME:-synthetic:65537}
if [ -z "$synth" ] || [ ! -f "$synth" ]; then
  [ "$QUICK" = 1 ] && synth_name=synthetic:16385
  log "select: building $synth_name"
  synth=$WORK/synth.tess
  "$SERVER_BIN" build "$synth_name" -o "$synth" --quiet > /dev/null
fi
names=(moon8192 "$synth_name")
files=("$WORK/moon8192.tess" "$synth")
spacings=("$MOON_SPACING" 30)
for run in $(seq "$RUNS"); do
  for i in 0 1; do
    for path in pass canyon; do
      log "select: run $run of $RUNS, ${names[$i]}, $path"
      "$CLIENT_BIN" bench-select "${files[$i]}" --spacing "${spacings[$i]}" --path "$path" --frames "$frames" \
        --json > "$WORK/sel.json" 2> "$WORK/sel.log" || { cat "$WORK/sel.log" >&2; exit 1; }
      record select "$(jq -c --arg ds "${names[$i]}" --arg path "$path" --argjson run "$run" \
        '{dataset: $ds, path: $path, run: $run} + .' "$WORK/sel.json")"
    done
  done
done

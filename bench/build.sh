#!/usr/bin/env bash
# Build (DECISIONS.md "Benchmarks"): `tessera-server build` against GDAL's
#   gdal_translate -of GTiff -co TILED=YES -co COMPRESS=LZW -co PREDICTOR=2 IN out.tif
#   gdaladdo -r nearest out.tif 2 4 8 16
# on the moon 8192² mosaic (the two alternate within each run, after one untimed read
# of the PNG into the page cache), and Tessera alone on synthetic:16385 and
# synthetic:65537. Wall and CPU (user + sys) seconds and peak RSS from GNU time;
# GDAL's wall and CPU add its two commands, its RSS is the larger. Appends to
# $RESULTS/build.jsonl: {tool, input, run, wall_s, cpu_s, rss_mib, bytes, samples}.
source "$(dirname "$0")/common.sh"

# timed TOOL INPUT SAMPLES RUN OUTPUT COMMAND...: one timed build, one record.
timed() {
  local tool=$1 input=$2 samples=$3 run=$4 output=$5
  shift 5
  /usr/bin/time -f "%e %U %S %M" -o "$WORK/time" "$@" > "$WORK/log" 2>&1 || { cat "$WORK/log" >&2; exit 1; }
  read -r wall user sys rss < "$WORK/time"
  echo "$wall $user $sys $rss" >> "$WORK/times"
}

# emit TOOL INPUT SAMPLES RUN OUTPUT: sums $WORK/times (wall, CPU; RSS is the max).
emit() {
  local t
  t=$(awk '{w += $1; c += $2 + $3; if ($4 > r) r = $4} END {printf "{\"wall_s\":%.3f,\"cpu_s\":%.3f,\"rss_mib\":%.1f}", w, c, r / 1024}' "$WORK/times")
  record build "$(jq -c -n --argjson t "$t" --arg tool "$1" --arg input "$2" --argjson samples "$3" \
    --argjson run "$4" --argjson bytes "$(stat -c %s "$5")" \
    '{tool: $tool, input: $input, run: $run, samples: $samples, bytes: $bytes} + $t')"
  : > "$WORK/times"
}

moon=$DEM/moon_crisium_gld100_8192.png
cat "$moon" > /dev/null
: > "$WORK/times"
for run in $(seq "$RUNS"); do
  log "build: moon 8192², run $run of $RUNS (Tessera, then GDAL)"
  rm -f "$WORK/moon.tess"
  timed tessera "$(basename "$moon")" 67108864 "$run" "$WORK/moon.tess" \
    "$SERVER_BIN" build "$moon" --offset -10000 -o "$WORK/moon.tess" --quiet
  emit tessera "$(basename "$moon")" 67108864 "$run" "$WORK/moon.tess"
  rm -f "$WORK/out.tif"
  timed gdal "$(basename "$moon")" 67108864 "$run" "$WORK/out.tif" \
    gdal_translate -q -of GTiff -co TILED=YES -co COMPRESS=LZW -co PREDICTOR=2 "$moon" "$WORK/out.tif"
  timed gdal "$(basename "$moon")" 67108864 "$run" "$WORK/out.tif" \
    gdaladdo -q -r nearest "$WORK/out.tif" 2 4 8 16
  emit gdal "$(basename "$moon")" 67108864 "$run" "$WORK/out.tif"
done
rm -f "$WORK/moon.tess" "$WORK/out.tif"

sizes=(16385 65537)
[ "$QUICK" = 1 ] && sizes=(4097 16385)
for n in "${sizes[@]}"; do
  for run in $(seq "$RUNS"); do
    log "build: synthetic:$n, run $run of $RUNS"
    rm -f "$WORK/synth.tess"
    timed tessera "synthetic:$n" $((n * n)) "$run" "$WORK/synth.tess" \
      "$SERVER_BIN" build "synthetic:$n" -o "$WORK/synth.tess" --quiet
    emit tessera "synthetic:$n" $((n * n)) "$run" "$WORK/synth.tess"
  done
  # The selection benchmark reuses the largest synthetic pyramid.
  [ -n "${KEEP_SYNTH:-}" ] && mv "$WORK/synth.tess" "$KEEP_SYNTH"
  rm -f "$WORK/synth.tess"
done

#!/usr/bin/env bash
# Real datasets (DECISIONS.md "Mosaics", "Coordinate systems"): what many inputs and
# reprojection cost.
#
# 1. Mosaic: the moon 8192² mosaic written by GDAL as one GeoTIFF, and cut by
#    `gdal_translate -srcwin` into 64 GeoTIFFs (8 × 8, 1025² with shared borders, as
#    SRTM tiles are); `tessera-server build` of the one file and of the 64 (a
#    directory), alternating within each run. Both get the same made-up projected
#    georeferencing (EPSG:32632, 100 m), which costs nothing to either.
# 2. Reprojection: bigtujunga (EPSG:32611) resampled ×4 by GDAL (4788 × 2572 int16),
#    reprojected to EPSG:4326 by `gdalwarp -r bilinear` (its default approximate
#    transformer, as users run it) and by `tessera-server build --to EPSG:4326`; the
#    build of gdalwarp's output without --to is timed too, so the reprojection's own
#    share of the build can be told apart.
#
# Wall and CPU seconds and peak RSS from GNU time. Appends to $RESULTS/ingest.jsonl:
#   {case, tool, run, wall_s, cpu_s, rss_mib, samples}
source "$(dirname "$0")/common.sh"

# timed CASE TOOL RUN SAMPLES COMMAND...: one timed command, one record.
timed() {
  local case=$1 tool=$2 run=$3 samples=$4
  shift 4
  /usr/bin/time -f "%e %U %S %M" -o "$WORK/time" "$@" > "$WORK/log" 2>&1 || { cat "$WORK/log" >&2; exit 1; }
  read -r wall user sys rss < "$WORK/time"
  record ingest "$(jq -n --arg case "$case" --arg tool "$tool" --argjson run "$run" \
    --argjson samples "$samples" --argjson wall "$wall" --argjson user "$user" \
    --argjson sys "$sys" --argjson rss "$rss" \
    '{case: $case, tool: $tool, run: $run, samples: $samples, wall_s: $wall,
      cpu_s: ($user + $sys), rss_mib: ($rss / 1024)}')"
}

# --- 1. one file against a 64-file mosaic of the same samples
moon=$DEM/moon_crisium_gld100_8192.png
n=8192 step=1024
srs=(-a_srs EPSG:32632 -a_ullr 500000 $((5000000 + n * 100)) $((500000 + n * 100)) 5000000)
gdal_translate -q -of GTiff "${srs[@]}" "$moon" "$WORK/one.tif"
mkdir -p "$WORK/pieces"
for r in $(seq 0 7); do
  for c in $(seq 0 7); do
    x=$((c * step)) y=$((r * step))
    w=$((n - x < step + 1 ? n - x : step + 1)) h=$((n - y < step + 1 ? n - y : step + 1))
    gdal_translate -q -of GTiff -srcwin "$x" "$y" "$w" "$h" "$WORK/one.tif" "$WORK/pieces/r${r}c${c}.tif"
  done
done
cat "$WORK/one.tif" "$WORK"/pieces/*.tif > /dev/null
for run in $(seq "$RUNS"); do
  log "ingest: moon 8192², one GeoTIFF then 64 pieces, run $run of $RUNS"
  rm -f "$WORK/one.tess" "$WORK/mosaic.tess"
  timed mosaic "one file" "$run" $((n * n)) \
    "$SERVER_BIN" build "$WORK/one.tif" --offset -10000 -o "$WORK/one.tess" --quiet
  timed mosaic "64-file mosaic" "$run" $((n * n)) \
    "$SERVER_BIN" build "$WORK/pieces/" --offset -10000 -o "$WORK/mosaic.tess" --quiet
done
# The two pyramids hold the same samples (the mosaic's metadata names its pieces,
# so the files differ only there): the per-level byte counts must agree.
diff <("$SERVER_BIN" info "$WORK/one.tess" | sed -n '/^level/,$p') \
     <("$SERVER_BIN" info "$WORK/mosaic.tess" | sed -n '/^level/,$p') >&2 \
  || { echo "the mosaic's pyramid differs from the one file's" >&2; exit 1; }
rm -rf "$WORK/pieces" "$WORK/one.tif" "$WORK/one.tess" "$WORK/mosaic.tess"

# --- 2. reprojection to EPSG:4326
gdal_translate -q -outsize 400% 400% -r bilinear "$DEM/bigtujunga.tif" "$WORK/big.tif"
read -r bw bh < <(gdalinfo "$WORK/big.tif" | sed -n 's/^Size is \([0-9]*\), \([0-9]*\)/\1 \2/p')
cat "$WORK/big.tif" > /dev/null
for run in $(seq "$RUNS"); do
  log "ingest: reprojection of ${bw}×${bh} to EPSG:4326, run $run of $RUNS"
  rm -f "$WORK/gdal.tif" "$WORK/to.tess" "$WORK/plain.tess"
  timed reproject "gdalwarp -r bilinear" "$run" $((bw * bh)) \
    gdalwarp -q -t_srs EPSG:4326 -r bilinear "$WORK/big.tif" "$WORK/gdal.tif"
  timed reproject "tessera build --to" "$run" $((bw * bh)) \
    "$SERVER_BIN" build "$WORK/big.tif" --to EPSG:4326 -o "$WORK/to.tess" --quiet
  timed reproject "tessera build (no --to)" "$run" $((bw * bh)) \
    "$SERVER_BIN" build "$WORK/gdal.tif" -o "$WORK/plain.tess" --quiet
done

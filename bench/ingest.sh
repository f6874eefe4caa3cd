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
# 3. Mixed grids (DECISIONS.md "Mixed-grid collections"): N46E008 (SRTM 3″, 1201²,
#    EPSG:4326) cut by `gdal_translate -srcwin` into 64 pieces (8 × 8, 151² with shared
#    borders); by diagonals, a third stay in EPSG:4326 at 3″ (the finest, so the target
#    grid), a third are warped by GDAL to EPSG:32632 at 90 m and a third to EPSG:2056
#    at 100 m (`gdalwarp -r bilinear`). Timed, alternating within each run: `build` of
#    the 64 (a directory) with `--memory 256MiB`; `gdalwarp -r bilinear` of the 64
#    onto the same grid (the pyramid's CRS, extent and spacing from `info`; coarsest
#    first, so that the finest wins where they overlap, as in the build) into one
#    GeoTIFF; `build` of that GeoTIFF with `--memory 256MiB`.
#
# INGEST_CASES picks the cases (default "mosaic reproject mixed").
#
# Wall and CPU seconds and peak RSS from GNU time. Appends to $RESULTS/ingest.jsonl:
#   {case, tool, run, wall_s, cpu_s, rss_mib, samples[, memory_mib]}
# (memory_mib: the build's --memory budget, where the case sets one).
source "$(dirname "$0")/common.sh"
CASES=" ${INGEST_CASES:-mosaic reproject mixed} "
for c in $CASES; do
  case "$c" in mosaic | reproject | mixed) ;; *) echo "unknown ingest case '$c' (mosaic reproject mixed)" >&2; exit 2 ;; esac
done
# wanted CASE: whether INGEST_CASES has CASE.
wanted() { [[ $CASES == *" $1 "* ]]; }

# timed CASE TOOL RUN SAMPLES COMMAND...: one timed command, one record (with the
# fields of the JSON object $TIMED_EXTRA added, when set).
timed() {
  local case=$1 tool=$2 run=$3 samples=$4 extra='{}'
  [ -z "${TIMED_EXTRA:-}" ] || extra=$TIMED_EXTRA
  shift 4
  /usr/bin/time -f "%e %U %S %M" -o "$WORK/time" "$@" > "$WORK/log" 2>&1 || { cat "$WORK/log" >&2; exit 1; }
  read -r wall user sys rss < "$WORK/time"
  record ingest "$(jq -n --arg case "$case" --arg tool "$tool" --argjson run "$run" \
    --argjson samples "$samples" --argjson wall "$wall" --argjson user "$user" \
    --argjson sys "$sys" --argjson rss "$rss" --argjson extra "$extra" \
    '{case: $case, tool: $tool, run: $run, samples: $samples, wall_s: $wall,
      cpu_s: ($user + $sys), rss_mib: ($rss / 1024)} + $extra')"
}

# --- 1. one file against a 64-file mosaic of the same samples
if wanted mosaic; then
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
fi

# --- 2. reprojection to EPSG:4326
if wanted reproject; then
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
rm -f "$WORK/big.tif" "$WORK/gdal.tif" "$WORK/to.tess" "$WORK/plain.tess"
fi

# --- 3. mixed grids: 64 pieces in 3 CRSs against gdalwarp + a single-grid build
if wanted mixed; then
srtm=$DEM/N46E008.tif
mixed=$WORK/mixed
mkdir -p "$mixed/pieces"
# The pieces in gdalwarp's order, coarsest CRS first (where inputs overlap gdalwarp
# keeps the last, the build the finest).
lv95=() utm=() wgs84=()
for r in $(seq 0 7); do
  for c in $(seq 0 7); do
    piece=$mixed/pieces/r${r}c${c}.tif
    cut=(-q -of GTiff -srcwin $((c * 150)) $((r * 150)) 151 151 "$srtm")
    case $(((r + c) % 3)) in
      0) gdal_translate "${cut[@]}" "$piece"; wgs84+=("$piece") ;;
      1) gdal_translate "${cut[@]}" "$mixed/cut.tif"
         gdalwarp -q -t_srs EPSG:32632 -tr 90 90 -r bilinear "$mixed/cut.tif" "$piece"
         utm+=("$piece") ;;
      2) gdal_translate "${cut[@]}" "$mixed/cut.tif"
         gdalwarp -q -t_srs EPSG:2056 -tr 100 100 -r bilinear "$mixed/cut.tif" "$piece"
         lv95+=("$piece") ;;
    esac
    rm -f "$mixed/cut.tif"
  done
done
order=("${lv95[@]}" "${utm[@]}" "${wgs84[@]}")
# The input samples: the 64 pieces' sizes.
pieces_samples=0
for p in "${order[@]}"; do
  read -r pw ph < <(gdalinfo "$p" | sed -n 's/^Size is \([0-9]*\), \([0-9]*\)/\1 \2/p')
  pieces_samples=$((pieces_samples + pw * ph))
done
cat "${order[@]}" > /dev/null
# The target grid as the build chose it (an untimed build first): CRS, extent and
# size from `info`, the spacing from them.
"$SERVER_BIN" build "$mixed/pieces/" -o "$mixed/mixed.tess" --memory 256MiB --quiet > /dev/null
grid() { "$SERVER_BIN" info "$1" | sed -n 's/^size *\([0-9]*\) × \([0-9]*\) samples.*/\1 \2/p; s/^georef *\([^ ]*\) [A-Za-z]*, extent west \([^ ]*\) south \([^ ]*\) east \([^ ]*\) north \([^ ]*\)$/\1 \2 \3 \4 \5/p' | paste -sd' '; }
read -r gw gh crs west south east north < <(grid "$mixed/mixed.tess")
read -r trx try < <(awk -v w="$west" -v s="$south" -v e="$east" -v n="$north" -v gw="$gw" -v gh="$gh" \
  'BEGIN { printf "%.17g %.17g\n", (e - w) / gw, (n - s) / gh }')
log "ingest: mixed grids, 64 pieces (${#wgs84[@]} EPSG:4326, ${#utm[@]} EPSG:32632, ${#lv95[@]} EPSG:2056) onto ${gw}×${gh} $crs"
for run in $(seq "$RUNS"); do
  log "ingest: mixed grids, 64 pieces in 3 CRSs, then gdalwarp and a single build, run $run of $RUNS"
  rm -f "$mixed/mixed.tess" "$mixed/warped.tif" "$mixed/single.tess"
  TIMED_EXTRA='{"memory_mib": 256}' timed mixed "64 pieces in 3 CRSs" "$run" "$pieces_samples" \
    "$SERVER_BIN" build "$mixed/pieces/" -o "$mixed/mixed.tess" --memory 256MiB --quiet
  timed mixed "gdalwarp -r bilinear (64 pieces)" "$run" "$pieces_samples" \
    gdalwarp -q -r bilinear -t_srs "$crs" -te "$west" "$south" "$east" "$north" -tr "$trx" "$try" \
    "${order[@]}" "$mixed/warped.tif"
  TIMED_EXTRA='{"memory_mib": 256}' timed mixed "tessera build (gdalwarp's output)" "$run" "$pieces_samples" \
    "$SERVER_BIN" build "$mixed/warped.tif" -o "$mixed/single.tess" --memory 256MiB --quiet
done
# Both pyramids on one grid: the same size, the same extent (to a millionth of a sample).
read -r sw sh scrs swest ssouth seast snorth < <(grid "$mixed/single.tess")
awk -v a="$gw $gh $west $south $east $north" -v b="$sw $sh $swest $ssouth $seast $snorth" -v t="$trx" 'BEGIN {
  split(a, x, " "); split(b, y, " ")
  for (i = 1; i <= 6; i++) if ((i <= 2 && x[i] != y[i]) || (i > 2 && (x[i] - y[i])^2 > (t * 1e-6)^2)) exit 1
}' && [ "$crs" = "$scrs" ] || {
  echo "the mixed pyramid's grid ($gw×$gh $crs $west $south $east $north) differs from gdalwarp's ($sw×$sh $scrs $swest $ssouth $seast $snorth)" >&2
  exit 1
}
rm -rf "$mixed"
fi

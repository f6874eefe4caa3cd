#!/usr/bin/env bash
# Build against GDAL (issue 6 item 2, DESIGN §7): on the moon 8192² mosaic
# (elevation = value − 10000), `tessera-server build INPUT --offset -10000` against
#   gdal_translate -of GTiff -co TILED=YES -co COMPRESS=LZW -co PREDICTOR=2 INPUT out.tif
#   gdaladdo -r nearest out.tif 2 4 8 16
# Wall s, CPU s (user + sys), peak RSS MiB (GNU time's maximum resident set size) and
# bytes per sample (output file / 8192²), median (min–max) of RUNS runs; the two tools
# alternate within each run, after one untimed read of the input into the page cache.
# GDAL's row adds both commands' wall and CPU; its RSS is the larger of the two.
# Note that Tessera does more than GDAL here: besides the levels, it computes the exact
# per-tile error tables (every finest sample against every mesh spacing covering it),
# stores per-record checksums and verifies the file before renaming it into place.
# GDAL keeps the raw PNG values (no offset applied); that changes no byte count.
#   bench/gdal.sh [RUNS]     (default 3)
# Prints a Markdown table. Needs GNU time (Debian `time`) and GDAL (Debian `gdal-bin`).
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-3}
input=../shared/data/dem/moon_crisium_gld100_8192.png
samples=$((8192 * 8192))
need=()
[ -x /usr/bin/time ] || need+=(time)
command -v gdal_translate >/dev/null && command -v gdaladdo >/dev/null || need+=(gdal-bin)
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" -eq 0 ]; then
    apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
  else
    echo "install: sudo apt-get install --no-install-recommends ${need[*]}" >&2; exit 1
  fi
fi
cargo build --release --locked -q -p tessera-server
bin=$PWD/target/release/tessera-server
work=$(mktemp -d "${TMPDIR:-/tmp}/tessera-gdal-bench.XXXXXX")
trap 'rm -rf "$work"' EXIT

median() { sort -g | awk '{a[NR]=$1} END {m=(NR%2)?a[(NR+1)/2]:(a[NR/2]+a[NR/2+1])/2; printf "%s (%s–%s)", m, a[1], a[NR]}'; }
med() { sort -g | awk '{a[NR]=$1} END {print (NR%2)?a[(NR+1)/2]:(a[NR/2]+a[NR/2+1])/2}'; }
# timed TAG COMMAND...: runs COMMAND under GNU time, appends "wall cpu rss_kib" to $work/TAG
timed() {
  local tag=$1; shift
  /usr/bin/time -f "%e %U %S %M" -o "$work/time" "$@" > "$work/log" 2>&1 || { cat "$work/log" >&2; exit 1; }
  awk '{printf "%s %.2f %s\n", $1, $2 + $3, $4}' "$work/time" >> "$work/$tag"
}

cat "$input" > /dev/null
for tool in tessera gdal; do : > "$work/$tool.runs"; done
for _ in $(seq "$runs"); do
  rm -f "$work/moon8k.tess"
  : > "$work/t"; timed t "$bin" build "$input" --offset -10000 -o "$work/moon8k.tess" --quiet
  read -r wall cpu rss < "$work/t"
  echo "$wall $cpu $rss $(stat -c %s "$work/moon8k.tess")" >> "$work/tessera.runs"

  rm -f "$work/out.tif"
  : > "$work/g"
  timed g gdal_translate -q -of GTiff -co TILED=YES -co COMPRESS=LZW -co PREDICTOR=2 "$input" "$work/out.tif"
  timed g gdaladdo -q -r nearest "$work/out.tif" 2 4 8 16
  awk -v size="$(stat -c %s "$work/out.tif")" \
    '{w += $1; c += $2; if ($3 > r) r = $3} END {printf "%.2f %.2f %s %s\n", w, c, r, size}' "$work/g" >> "$work/gdal.runs"
done

echo "| tool | runs | wall s | CPU s | peak RSS MiB | bytes/sample |"
echo "|---|---|---|---|---|---|"
row() { # label tool
  local f=$work/$2.runs
  printf "| %s | %s | %s | %s | %s | %s |\n" "$1" "$runs" \
    "$(awk '{print $1}' "$f" | median)" "$(awk '{print $2}' "$f" | median)" \
    "$(awk '{printf "%.0f\n", $3 / 1024}' "$f" | median)" \
    "$(awk -v n="$samples" '{printf "%.3f\n", $4 / n}' "$f" | median)"
}
row "Tessera \`build --offset -10000\` (levels 0–4 + error tables)" tessera
row "GDAL \`gdal_translate\` (tiled, LZW, predictor 2) + \`gdaladdo -r nearest 2 4 8 16\`" gdal
ratio() { # column: ratio of the medians
  awk -v t="$(awk -v c="$1" '{print $c}' "$work/tessera.runs" | med)" \
      -v g="$(awk -v c="$1" '{print $c}' "$work/gdal.runs" | med)" 'BEGIN {printf "%.2f×", t / g}'
}
printf "| ratio Tessera / GDAL (medians) | | %s | %s | %s | %s |\n" "$(ratio 1)" "$(ratio 2)" "$(ratio 3)" "$(ratio 4)"

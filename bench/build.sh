#!/usr/bin/env bash
# Build benchmark: wall time, CPU time, peak RSS and bytes per sample of
# `tessera-server build`, median (min–max) of N runs per input.
#   bench/build.sh [RUNS] [INPUT[=FLAGS]]...
# Defaults: the moon 8192² mosaic, synthetic:16385 and synthetic:65537 (1 run).
# Prints a Markdown table. Needs GNU time (/usr/bin/time, Debian package `time`).
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-3}; shift || true
dem=../shared/data/dem
inputs=("$@")
if [ ${#inputs[@]} -eq 0 ]; then
  inputs=("$dem/moon_crisium_gld100_8192.png=--offset -10000" "synthetic:16385" "synthetic:65537@1")
fi
if [ ! -x /usr/bin/time ]; then
  if [ "$(id -u)" -eq 0 ]; then apt-get install -y -qq time >/dev/null; else echo "install GNU time: sudo apt-get install time" >&2; exit 1; fi
fi
cargo build --release --locked -q -p tessera-server
bin=target/release/tessera-server
work=$(mktemp -d "${TMPDIR:-/tmp}/tessera-bench.XXXXXX")
trap 'rm -rf "$work"' EXIT

median() { sort -g | awk '{a[NR]=$1} END {m=(NR%2)?a[(NR+1)/2]:(a[NR/2]+a[NR/2+1])/2; printf "%s (%s–%s)", m, a[1], a[NR]}'; }

echo "| input | samples | runs | wall s | CPU s | M samples/s | peak RSS MiB | bytes/sample |"
echo "|---|---|---|---|---|---|---|---|"
for spec in "${inputs[@]}"; do
  n=$runs
  case "$spec" in *@*) n=${spec##*@}; spec=${spec%@*} ;; esac
  input=${spec%%=*}; flags=""
  [ "$input" != "$spec" ] && flags=${spec#*=}
  : > "$work/wall"; : > "$work/cpu"; : > "$work/rss"; : > "$work/rate"
  for _ in $(seq "$n"); do
    rm -f "$work/out.tess"
    # shellcheck disable=SC2086
    /usr/bin/time -f "%e %U %S %M" -o "$work/time" "$bin" build "$input" -o "$work/out.tess" --quiet $flags > "$work/log"
    read -r wall user sys rss < "$work/time"
    echo "$wall" >> "$work/wall"
    echo "$user $sys" | awk '{print $1+$2}' >> "$work/cpu"
    echo "$rss" | awk '{printf "%.0f\n", $1/1024}' >> "$work/rss"
    samples=$("$bin" info "$work/out.tess" --json | awk -F'[:,]' '/"width"/{w=$2} /"height"/{h=$2} END{printf "%.0f", w*h}')
    echo "$samples $wall" | awk '{printf "%.1f\n", $1/$2/1e6}' >> "$work/rate"
  done
  bps=$("$bin" info "$work/out.tess" --json | awk -F'[:,]' '/"bytes_per_sample"/{print $2; exit}' | awk '{printf "%.3f", $1}')
  echo "| \`$(basename "$input")\` $flags | $samples | $n | $(median < "$work/wall") | $(median < "$work/cpu") | $(median < "$work/rate") | $(median < "$work/rss") | $bps |"
done

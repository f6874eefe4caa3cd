#!/usr/bin/env bash
# Every benchmark (DECISIONS.md "Benchmarks") in one run (`./run bench` calls this), then
# `tessera-bench report`, which rewrites BENCHMARKS.md and bench/plots/*.png from the
# results. Expects the release binaries built and the tools installed (./run does both).
#   bench/all.sh [SECTION...]   (default: build select serve load stream policy gonzalez ingest webtiles rendered terrain elevation upload popping)
# RESULTS (default target/bench/results) is emptied first, unless KEEP_RESULTS=1 (to
# rerun one section and regenerate the report from old results of the others).
set -euo pipefail
cd "$(dirname "$0")/.."
export RESULTS=${RESULTS:-$PWD/target/bench/results}
export RUNS=${RUNS:-3} QUICK=${QUICK:-0}
sections=("$@")
[ ${#sections[@]} -gt 0 ] || sections=(build select serve load stream policy gonzalez ingest webtiles rendered terrain elevation upload popping)
[ "${KEEP_RESULTS:-0}" = 1 ] || rm -rf "$RESULTS"
mkdir -p "$RESULTS"
keep=$(mktemp -d "${TMPDIR:-/tmp}/tessera-bench-keep.XXXXXX")
trap 'rm -rf "$keep"' EXIT

started=$(date -u +%Y-%m-%dT%H:%M:%SZ)
t0=$(date +%s)
for s in "${sections[@]}"; do
  echo "== bench: $s" >&2
  # (load's results are loadreplay.jsonl: load.jsonl is serve's full-client runs.)
  [ "$s" = load ] || rm -f "$RESULTS/$s.jsonl"
  case "$s" in
    build) KEEP_SYNTH=$keep/synth.tess bench/build.sh ;;
    select)
      if [ "$QUICK" = 1 ]; then name=synthetic:16385; else name=synthetic:65537; fi
      SYNTH=$keep/synth.tess SYNTH_NAME=$name bench/select.sh
      rm -f "$keep/synth.tess" ;;
    serve) rm -f "$RESULTS/load.jsonl"; bench/serve.sh ;;
    # tessera load --record, then --replay against wrk and oha (DECISIONS.md "Load
    # testing: the proof").
    load) rm -f "$RESULTS"/loadreplay{.jsonl,_record.json,_trace.jsonl}; bench/load.sh ;;
    # terrain writes terrain_mesh.jsonl and terrain_serve.jsonl, each replaced only by
    # the part that runs (TERRAIN_MESH=0 or TERRAIN_SERVE=0 keeps the other's).
    # elevation's and rendered's figures are hand sections of BENCHMARKS.md ("Elevation queries",
    # "Rendered terrain tiles, contour tiles and PMTiles export"):
    # the script prints its tables.
    stream | policy | gonzalez | ingest | webtiles | rendered | terrain | elevation | upload | popping) "bench/$s.sh" ;;
    *) echo "unknown section '$s' (build select serve load stream policy gonzalez ingest webtiles rendered terrain elevation upload popping)" >&2; exit 2 ;;
  esac
done
rm -rf "$RESULTS/reference-cache"

version() { "$@" 2>&1 | head -n1 || true; }
oha_bin=${OHA:-$(command -v oha || echo "${XDG_CACHE_HOME:-$HOME/.cache}/tessera/oha/bin/oha")}
renderer=$(jq -r '.summary.render.gpu // empty' "$RESULTS/gonzalez.jsonl" 2>/dev/null | head -n1 || true)
jq -n \
  --arg started "$started" --arg finished "$(date -u +%Y-%m-%dT%H:%M:%SZ)" \
  --argjson seconds $(($(date +%s) - t0)) \
  --arg commit "$(git rev-parse --short HEAD 2>/dev/null || echo unknown)" \
  --argjson dirty "$([ -n "$(git status --porcelain --untracked-files=no 2>/dev/null)" ] && echo true || echo false)" \
  --arg cpu "$(sed -n 's/^model name\s*: //p' /proc/cpuinfo | head -n1)" \
  --argjson cores "$(nproc)" \
  --argjson memory "$(awk '/MemTotal/ {printf "%.1f", $2 / 1048576}' /proc/meminfo)" \
  --arg os "$(. /etc/os-release 2>/dev/null && echo "$PRETTY_NAME")" \
  --arg rustc "$(version rustc --version)" \
  --arg gdal "$(version gdal_translate --version)" \
  --arg nginx "$(version "$(command -v nginx || echo /usr/sbin/nginx)" -v)" \
  --arg wrk "$(version wrk -v)" \
  --arg oha "$([ -x "$oha_bin" ] && version "$oha_bin" --version)" \
  --arg renderer "$renderer" \
  --argjson runs "$RUNS" --argjson quick "$([ "$QUICK" = 1 ] && echo true || echo false)" \
  --arg sections "${sections[*]}" \
  '{started: $started, finished: $finished, seconds: $seconds, commit: $commit, dirty: $dirty,
    cpu: $cpu, cores: $cores, memory_gib: $memory, os: $os, rustc: $rustc, gdal: $gdal,
    nginx: $nginx, wrk: $wrk, oha: $oha, renderer: $renderer, runs: $runs, quick: $quick,
    sections: ($sections | split(" "))}' > "$RESULTS/meta.json"

echo "== bench: report" >&2
target/release/tessera-bench report --results "$RESULTS" --template bench/BENCHMARKS.md.in \
  --out BENCHMARKS.md --plots bench/plots
echo "BENCHMARKS.md and bench/plots/ rewritten from $RESULTS ($(($(date +%s) - t0)) s)" >&2

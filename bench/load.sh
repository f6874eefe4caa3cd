#!/usr/bin/env bash
# Load replay against the peers (DECISIONS.md "Load testing: the proof"): does `tessera
# load --replay` measure the server, not itself? The moon 8192² (512-cell tiles) on the
# release server; 64 real clients fly once with `tessera load --record` (RECORD_SECONDS,
# default 20) and the requests they got a 200 for are replayed, the same list by every
# tool, cycling:
#   (a) saturation, SAT_SECONDS (default 10) each, closed loops over CONNECTIONS
#       (default 64), each load generator pinned to one core (`taskset -c $LOAD_CPU`,
#       default 1; the server is not pinned):
#       `tessera load --replay --rate max`, `wrk -t1` with a Lua script cycling
#       through the targets, `oha --urls-from-file` (random picks among them);
#   (b) at half of this run's Tessera saturation requests/s, HALF_SECONDS (default
#       20) each: `tessera load --replay --rate R` and `oha -q R --latency-correction`
#       (both measure latency from the scheduled start). wrk2 is not in Debian.
# wrk and oha do not parse the tile stream: their tiles/s is their 200 answers per
# second × the replayed requests' mean recorded tiles. Tessera verifies each frame's
# checksum and the recorded digests, and counts what it verified.
# Appends to $RESULTS/loadreplay.jsonl {tool, phase, run, connections, seconds,
# requests_per_s, tiles_per_s, latency_ms_p50, latency_ms_p99, latency_ms_p999,
# latency_from, target_rate, rate_held, errors, tool_cpu_s, trace_requests,
# trace_mean_tiles}; the recording clients' report goes to
# $RESULTS/loadreplay_record.json and the replayed requests to loadreplay_trace.jsonl.
# oha: $OHA, else `oha` on PATH, else ~/.cache/tessera/oha/bin/oha (`./run bench`
# installs it); without it the oha rows are skipped (the report says so).
source "$(dirname "$0")/common.sh"
record_s=${RECORD_SECONDS:-20}
sat_s=${SAT_SECONDS:-10}
half_s=${HALF_SECONDS:-20}
conns=${CONNECTIONS:-64}
cpu=${LOAD_CPU:-1}
if [ "$QUICK" = 1 ]; then record_s=8; sat_s=4; half_s=6; fi
ulimit -n 65536 2>/dev/null || ulimit -n "$(ulimit -Hn)"
oha=${OHA:-$(command -v oha || echo "${XDG_CACHE_HOME:-$HOME/.cache}/tessera/oha/bin/oha")}
[ -x "$oha" ] || { log "load: no oha ($oha): its rows are skipped (./run bench installs it)"; oha=; }
# pin COMMAND...: runs COMMAND on core $cpu (when the machine has it) under GNU time,
# which writes its user + system seconds to $WORK/tool.time.
pin=()
if [ "$(nproc)" -gt "$cpu" ] && command -v taskset > /dev/null; then pin=(taskset -c "$cpu"); fi
pin() { "${pin[@]}" /usr/bin/time -f '%U %S' -o "$WORK/tool.time" "$@"; }
tool_cpu() { awk '{print $1 + $2}' "$WORK/tool.time"; }

ds=moon8k
build_moon 8192 "$WORK/$ds.tess"
serve "$WORK/$ds.tess" > "$WORK/url"
url=$(cat "$WORK/url")

log "load: recording $record_s s of 64 clients"
"$CLIENT_BIN" load --server "$url" --dataset "$ds" --clients 64 --duration "${record_s}s" \
  --spacing "$MOON_SPACING" --record "$WORK/trace.jsonl" --json > "$WORK/record.json" 2> "$WORK/record.log" \
  || { cat "$WORK/record.log" >&2; exit 1; }
cp "$WORK/record.json" "$RESULTS/loadreplay_record.json"
# The replayed list: the header, then the requests answered 200 when recorded (all
# three tools send exactly these; a 404 or an unanswered request has no tiles to count).
{
  head -n1 "$WORK/trace.jsonl"
  tail -n +2 "$WORK/trace.jsonl" | jq -c 'select(.expect != null and .expect.status == 200)'
} > "$WORK/replay.jsonl"
cp "$WORK/replay.jsonl" "$RESULTS/loadreplay_trace.jsonl"
tail -n +2 "$WORK/replay.jsonl" | jq -r .target > "$WORK/targets.txt"
sed "s|^|$url|" "$WORK/targets.txt" > "$WORK/urls.txt"
n=$(wc -l < "$WORK/targets.txt")
[ "$n" -gt 0 ] || { echo "the recording has no request answered 200" >&2; exit 1; }
mean_tiles=$(tail -n +2 "$WORK/replay.jsonl" | jq -s 'map(.expect.tiles) | add / length')
log "load: $n requests to replay, $mean_tiles tiles per request on average"

cat > "$WORK/replay.lua" <<'LUA'
-- The trace's targets in order, cycling (one thread: one sequence, as Tessera's).
local targets = {}
for line in io.lines(os.getenv("TARGETS")) do targets[#targets + 1] = line end
local i = 0
request = function()
  i = i % #targets + 1
  return wrk.format("GET", targets[i])
end
done = function(summary, latency, requests)
  local e = summary.errors
  io.write(string.format(
    '{"duration_s":%.6f,"requests":%d,"errors":%d,"non2xx":%d,"p50_ms":%.3f,"p99_ms":%.3f,"p999_ms":%.3f}\n',
    summary.duration / 1e6, summary.requests, e.connect + e.read + e.write + e.timeout, e.status,
    latency:percentile(50) / 1e3, latency:percentile(99) / 1e3, latency:percentile(99.9) / 1e3))
end
LUA
export TARGETS=$WORK/targets.txt

# row JSON: one record, with what every row shares.
row() {
  record loadreplay "$(jq -c --argjson n "$n" --argjson mean "$mean_tiles" --argjson c "$conns" \
    '{connections: $c, trace_requests: $n, trace_mean_tiles: $mean} + .' <<< "$1")"
}

# tessera_row PHASE RUN REPORT: a row from a `tessera load --replay --json` report.
tessera_row() {
  row "$(jq -c --arg phase "$1" --argjson run "$2" --argjson cpu "$(tool_cpu)" \
    '{tool: "tessera", phase: $phase, run: $run, seconds, requests_per_s, tiles_per_s,
      latency_ms_p50: .latency_ms.p50, latency_ms_p99: .latency_ms.p99, latency_ms_p999: .latency_ms.p999,
      latency_from: (if .latency_from == "scheduled" then "scheduled" else "closed loop" end),
      target_rate, rate_held, errors: (.errors | add), tool_cpu_s: $cpu}' "$3")"
}

# oha_row PHASE RUN OUT [TARGET_RATE]: a row from oha's JSON (times in seconds); its
# requests/s counts the 200 answers over the run.
oha_row() {
  row "$(jq -c --arg phase "$1" --argjson run "$2" --argjson cpu "$(tool_cpu)" --argjson mean "$mean_tiles" \
    --argjson target "${4:-null}" --arg from "$([ -n "${4:-}" ] && echo scheduled || echo "closed loop")" '
    (.statusCodeDistribution["200"] // 0) as $ok
    | ((.statusCodeDistribution | add // 0) - $ok + (.errorDistribution | add // 0)) as $errors
    | (.summary.total) as $s
    | {tool: "oha", phase: $phase, run: $run, seconds: $s, requests_per_s: ($ok / $s),
       tiles_per_s: ($ok / $s * $mean), latency_ms_p50: (.latencyPercentiles.p50 * 1000),
       latency_ms_p99: (.latencyPercentiles.p99 * 1000), latency_ms_p999: (.latencyPercentiles["p99.9"] * 1000),
       latency_from: $from, target_rate: $target,
       rate_held: (if $target == null then null else ($ok / $s >= 0.95 * $target) end),
       errors: $errors, tool_cpu_s: $cpu}' "$3")"
}

# sat_tessera / sat_wrk / sat_oha RUN: one saturation row each.
sat_tessera() {
  pin "$CLIENT_BIN" load --replay "$WORK/replay.jsonl" --server "$url" --rate max --duration "${sat_s}s" \
    --connections "$conns" --json > "$WORK/tessera.json" 2> "$WORK/tessera.log" \
    || { cat "$WORK/tessera.log" >&2; exit 1; }
  tessera_row saturation "$1" "$WORK/tessera.json"
  sat_rps=$(jq .requests_per_s "$WORK/tessera.json")
}
sat_wrk() {
  pin wrk -t1 -c"$conns" -d"${sat_s}s" --timeout 10s -s "$WORK/replay.lua" "$url" > "$WORK/wrk.out"
  row "$(tail -n1 "$WORK/wrk.out" | jq -c --argjson run "$1" --argjson cpu "$(tool_cpu)" --argjson mean "$mean_tiles" '
    ((.requests - .non2xx) / .duration_s) as $ok
    | {tool: "wrk", phase: "saturation", run: $run, seconds: .duration_s, requests_per_s: $ok,
       tiles_per_s: ($ok * $mean), latency_ms_p50: .p50_ms, latency_ms_p99: .p99_ms, latency_ms_p999: .p999_ms,
       latency_from: "closed loop", target_rate: null, rate_held: null, errors: (.errors + .non2xx),
       tool_cpu_s: $cpu}')"
}
sat_oha() {
  [ -n "$oha" ] || return 0
  pin "$oha" --no-tui --output-format json -z "${sat_s}s" -w -c "$conns" --urls-from-file "$WORK/urls.txt" \
    > "$WORK/oha.json" 2> "$WORK/oha.log" || { cat "$WORK/oha.log" >&2; exit 1; }
  oha_row saturation "$1" "$WORK/oha.json"
}

# half_tessera / half_oha RUN RATE: one row each at RATE requests/s.
half_tessera() {
  pin "$CLIENT_BIN" load --replay "$WORK/replay.jsonl" --server "$url" --rate "$2" --duration "${half_s}s" \
    --connections "$conns" --json > "$WORK/tessera.json" 2> "$WORK/tessera.log" \
    || { cat "$WORK/tessera.log" >&2; exit 1; }
  tessera_row half "$1" "$WORK/tessera.json"
}
half_oha() {
  [ -n "$oha" ] || return 0
  pin "$oha" --no-tui --output-format json -z "${half_s}s" -w -c "$conns" -q "$2" --latency-correction \
    --urls-from-file "$WORK/urls.txt" > "$WORK/oha.json" 2> "$WORK/oha.log" || { cat "$WORK/oha.log" >&2; exit 1; }
  oha_row half "$1" "$WORK/oha.json" "$2"
}

tools=(tessera wrk oha)
for run in $(seq "$RUNS"); do
  # The order rotates from run to run, so that no tool always comes first (or right
  # after another one's load).
  order=("${tools[@]:$(((run - 1) % 3))}" "${tools[@]:0:$(((run - 1) % 3))}")
  log "load: run $run of $RUNS, saturation (${order[*]}), $conns connections, ${sat_s}s each, on core $cpu"
  for t in "${order[@]}"; do "sat_$t" "$run"; done

  rate=$(awk -v r="$sat_rps" 'BEGIN {printf "%.1f", r / 2}')
  log "load: run $run of $RUNS, $rate requests/s (half of Tessera's saturation in this run), ${half_s}s each"
  if [ $((run % 2)) = 1 ]; then half=(tessera oha); else half=(oha tessera); fi
  for t in "${half[@]}"; do "half_$t" "$run" "$rate"; done
done

#!/usr/bin/env bash
# Streaming under latency (DECISIONS.md "Benchmarks"): `tessera fly --no-render` over the
# moon 8192² on loopback, `pass` and `canyon` paths, 1920×1080, τ = 1 px, 60 fps in real
# time, 4 ms streaming budget per frame, at 0, 50 and 150 ms added latency
# (`tessera-proxy --delay-ms`, proxy/, holds each response that long before its first
# byte), prefetch on and off. Appends to $RESULTS/stream.jsonl {dataset, path,
# latency_ms, prefetch, run, summary}.
#
# Then (DECISIONS.md "The first view in one round trip") three opens side by side in the
# same run at 150 ms, prefetch on: the bootstrap focused on the path's start (the default:
# document, the coarsest levels' records, the next levels' error tables, and the records
# around the start at every finer level), the bootstrap every client shares
# (`--no-focus`), and the old open (`--no-bootstrap`: the document, then the root and each
# level as frames ask). Appends to $RESULTS/stream_bootstrap.jsonl {dataset, path,
# latency_ms, open (focus|no-focus|no-bootstrap), bootstrap, run, frame0_tiles,
# frame0_coarsest_level, first_drawn, summary (with open_bytes)}, and prints a table of
# medians.
#
# The proxy delays by watching a connection for silence (proxy/src/delay.rs), which
# is honest for HTTP/1.1, where each response in flight has a connection of its own;
# under HTTP/2 responses share one connection and those that overlap would not be
# held, so the client runs HTTP/1.1 here (its default; `--http2` is not measured).
source "$(dirname "$0")/common.sh"
[ -x "$PROXY_BIN" ] || { echo "build first: cargo build --release --locked -p tessera-proxy" >&2; exit 1; }
frames=300
latencies=(0 50 150)
paths=(pass canyon)
[ "$QUICK" = 1 ] && { frames=120; latencies=(0 150); paths=(pass); }
build_moon 8192 "$WORK/moon8192.tess"
direct=$(serve "$WORK/moon8192.tess")
declare -A via
for latency in "${latencies[@]}"; do
  if [ "$latency" = 0 ]; then via[$latency]=$direct; continue; fi
  spawn "$WORK/proxy$latency.out" "$WORK/proxy$latency.log" \
    "$PROXY_BIN" --upstream "${direct#http://}" --delay-ms "$latency"
  via[$latency]="http://$(wait_listening "$WORK/proxy$latency.out")"
done
for run in $(seq "$RUNS"); do
  for path in "${paths[@]}"; do
    for latency in "${latencies[@]}"; do
      for prefetch in true false; do
        log "stream: run $run of $RUNS, $path, +$latency ms, prefetch $prefetch"
        flag=()
        [ "$prefetch" = false ] && flag=(--no-prefetch)
        "$CLIENT_BIN" fly --server "${via[$latency]}" --dataset moon8192 --path "$path" --frames "$frames" \
          --fps 60 --tau 1 --spacing "$MOON_SPACING" --no-render "${flag[@]}" > "$WORK/run.json" 2> "$WORK/run.log" \
          || { cat "$WORK/run.log" >&2; exit 1; }
        fly_record stream "$(jq -n -c --arg path "$path" --argjson latency "$latency" --argjson prefetch "$prefetch" \
          --argjson run "$run" '{dataset: "moon8192", path: $path, latency_ms: $latency, prefetch: $prefetch, run: $run}')" \
          "$WORK/run.json"
      done
    done
  done
done
for run in $(seq "$RUNS"); do
  for path in "${paths[@]}"; do
    for open in focus no-focus no-bootstrap; do
      log "stream: run $run of $RUNS, $path, +150 ms, $open"
      flag=()
      [ "$open" = no-focus ] && flag=(--no-focus)
      [ "$open" = no-bootstrap ] && flag=(--no-bootstrap)
      "$CLIENT_BIN" fly --server "${via[150]}" --dataset moon8192 --path "$path" --frames "$frames" \
        --fps 60 --tau 1 --spacing "$MOON_SPACING" --no-render --stats "$WORK/frames.jsonl" "${flag[@]}" \
        > "$WORK/run.json" 2> "$WORK/run.log" || { cat "$WORK/run.log" >&2; exit 1; }
      first=$(jq -s -c '{frame0_tiles: .[0].tiles, frame0_coarsest_level: .[0].coarsest_level,
        first_drawn: (map(select(.tiles > 0)) | first | .frame)}' "$WORK/frames.jsonl")
      record stream_bootstrap "$(jq -c --arg path "$path" --argjson run "$run" --argjson first "$first" \
        --arg open "$open" --argjson bootstrap "$([ "$open" = no-bootstrap ] && echo false || echo true)" \
        '{dataset: "moon8192", path: $path, latency_ms: 150, open: $open, bootstrap: $bootstrap, run: $run} + $first + {summary: .}' \
        "$WORK/run.json")"
    done
  done
done
# The table for BENCHMARKS.md ("One round trip to the first frame"): medians (range).
jq -s -r '
  def med: sort | .[(length - 1) / 2 | floor];
  def pct: . * 1000 | round / 10 | tostring + "%";
  def rng(f): (map(f) | min | pct) + "–" + (map(f) | max | pct);
  group_by([.path, .open])[] |
  "\(.[0].path) \(.[0].open): ≤2τ \(map(.summary.within_2tau) | med | pct) (\(rng(.summary.within_2tau))), ≤τ \(map(.summary.within_tau) | med | pct) (\(rng(.summary.within_tau))), frame 0 tiles \(map(.frame0_tiles) | med), first drawn \(map(.first_drawn) | med), open MB \(map(.summary.open_bytes / 1e6 * 100 | round / 100) | med), tile requests \(map(.summary.stream.requests) | med), tile MB \(map(.summary.stream.bytes / 1e6 * 10 | round / 10) | med)"
' "$RESULTS/stream_bootstrap.jsonl" >&2

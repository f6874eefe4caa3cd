#!/usr/bin/env bash
# Streaming under latency (issue 6 item 6): `tessera fly --no-render` over the moon
# 8192² on loopback, `pass` and `canyon` paths, 1920×1080, τ = 1 px, 60 fps in real
# time, 4 ms streaming budget per frame, at 0, 50 and 150 ms added latency
# (`tessera-proxy --delay-ms`, proxy/, holds each response that long before its first
# byte), prefetch on and off. Appends to $RESULTS/stream.jsonl {dataset, path,
# latency_ms, prefetch, run, summary}.
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

#!/usr/bin/env bash
# Scale-out (docs/ARCHITECTURE.md#scale-out): the same flight over the moon 8192² pyramid
# from four places, side by side in one run — `tessera fly --no-render` (1920×1080, τ = 1
# px, 60 fps in real time, the default 4 ms budget), `pass` and `canyon` paths, at LATENCY
# ms added before every response (default 50, through `tessera-proxy`):
#   local      tessera-server serve FILE.tess
#   s3         tessera-server serve s3://tessera/moon8192.tess (moto_server on loopback;
#              the object uploaded by `tessera-server build -o s3://…`)
#   nginx      no server: tessera fly --pyramid http://nginx/moon8192.tess (HTTP Range)
#   moto       no server: tessera fly --pyramid http://moto/tessera/moon8192.tess
# The proxy sits in front of the client's first hop (the server, nginx or moto), so a
# serverless client pays the latency per Range request as a server's client pays it per
# range stream. Appends to $RESULTS/scaleout.jsonl {source, path, latency_ms, run,
# summary} and prints a Markdown table of medians to stdout.
source "$(dirname "$0")/common.sh"
[ -x "$PROXY_BIN" ] || { echo "build first: cargo build --release --locked -p tessera-proxy" >&2; exit 1; }
frames=${FRAMES:-300}
latency=${LATENCY:-50}
paths=(pass canyon)
[ "$QUICK" = 1 ] && { frames=120; paths=(pass); }
venv=${XDG_CACHE_HOME:-$HOME/.cache}/tessera/deploy-venv
[ -x "$venv/bin/moto_server" ] || deploy/check.sh --tools-only
nginx_bin=$(command -v nginx || echo /usr/sbin/nginx)
free_port() { python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }

ds=moon8192
build_moon 8192 "$WORK/$ds.tess"

# The S3 server, its bucket and the object, uploaded by the build itself.
moto_port=$(free_port)
spawn "$WORK/moto.out" "$WORK/moto.log" "$venv/bin/moto_server" -H 127.0.0.1 -p "$moto_port"
for _ in $(seq 200); do curl -fs "http://127.0.0.1:$moto_port/" > /dev/null && break; sleep 0.05; done
export AWS_ENDPOINT_URL=http://127.0.0.1:$moto_port AWS_ALLOW_HTTP=true AWS_REGION=us-east-1 \
  AWS_ACCESS_KEY_ID=bench AWS_SECRET_ACCESS_KEY=bench
"$venv/bin/python" -c "import boto3; boto3.client('s3', endpoint_url='$AWS_ENDPOINT_URL').create_bucket(Bucket='tessera')"
"$SERVER_BIN" build "$DEM/moon_crisium_gld100_8192.png" --offset -10000 -o "s3://tessera/$ds.tess" --quiet > /dev/null
cmp <(curl -fsS "http://127.0.0.1:$moto_port/tessera/$ds.tess") "$WORK/$ds.tess" \
  || { echo "the uploaded object differs from the local build" >&2; exit 1; }

# nginx serving the file as a static host (Range is built in).
nginx_port=$(free_port)
mkdir -p "$WORK/nginx" "$WORK/www"
ln "$WORK/$ds.tess" "$WORK/www/$ds.tess"
{
  [ "$(id -u)" -eq 0 ] && echo "user root;"
  cat <<CONF
worker_processes 2;
pid $WORK/nginx/nginx.pid;
error_log $WORK/nginx/error.log warn;
events { worker_connections 1024; }
http {
  access_log $WORK/nginx/access.log;
  sendfile on;
  default_type application/octet-stream;
  client_body_temp_path $WORK/nginx/body;
  proxy_temp_path $WORK/nginx/proxy;
  fastcgi_temp_path $WORK/nginx/fastcgi;
  uwsgi_temp_path $WORK/nginx/uwsgi;
  scgi_temp_path $WORK/nginx/scgi;
  server { listen 127.0.0.1:$nginx_port; root $WORK/www; }
}
CONF
} > "$WORK/nginx/nginx.conf"
spawn "$WORK/nginx.out" "$WORK/nginx.log" "$nginx_bin" -c "$WORK/nginx/nginx.conf" -e "$WORK/nginx/error.log" -g 'daemon off;'

local_url=$(serve "$WORK/$ds.tess")
s3_url=$(serve "s3://tessera/$ds.tess")

# proxied HOST:PORT: a latency proxy in front of HOST:PORT; prints its address.
proxied() {
  if [ "$latency" = 0 ]; then echo "$1"; return; fi
  local out
  out=$(mktemp "$WORK/proxy.XXXXXX.out")
  spawn "$out" "${out%.out}.log" "$PROXY_BIN" --upstream "$1" --delay-ms "$latency"
  wait_listening "$out" | sed 's|^http://||'
}
declare -A target
target[local]="--server http://$(proxied "${local_url#http://}") --dataset $ds"
target[s3]="--server http://$(proxied "${s3_url#http://}") --dataset $ds"
target[nginx]="--pyramid http://$(proxied "127.0.0.1:$nginx_port")/$ds.tess"
target[moto]="--pyramid http://$(proxied "127.0.0.1:$moto_port")/tessera/$ds.tess"
sources=(local s3 nginx moto)

for run in $(seq "$RUNS"); do
  for path in "${paths[@]}"; do
    for src in "${sources[@]}"; do
      log "scaleout: run $run of $RUNS, $path, $src, +$latency ms"
      # shellcheck disable=SC2086 # target[] holds flags
      "$CLIENT_BIN" fly ${target[$src]} --path "$path" --frames "$frames" --fps 60 --tau 1 \
        --spacing "$MOON_SPACING" --no-render > "$WORK/run.json" 2> "$WORK/run.log" \
        || { cat "$WORK/run.log" >&2; exit 1; }
      fly_record scaleout "$(jq -n -c --arg src "$src" --arg path "$path" --argjson latency "$latency" \
        --argjson run "$run" '{source: $src, path: $path, latency_ms: $latency, run: $run}')" "$WORK/run.json"
    done
  done
done
s3_gets=$(curl -fsS "$s3_url/metrics" | awk '$1 ~ /^tessera_store_requests_total\{op="get",outcome="ok"\}/ {print $2}')
log "scaleout: the S3-backed server made ${s3_gets:-0} GETs to the store over all its flights"

# A table of medians over the runs, one row per path and source.
jq -s -r --argjson latency "$latency" '
  def median: sort | if length % 2 == 1 then .[length / 2 | floor] else (.[length / 2 - 1] + .[length / 2]) / 2 end;
  map(select(.latency_ms == $latency)) | group_by(.path)[] | group_by(.source)[] |
  "| \(.[0].path) | \(.[0].source) | \(length) | \(map(.summary.within_tau * 100) | median | . * 10 | round / 10) % | \(map(.summary.within_2tau * 100) | median | . * 10 | round / 10) % | \(map(.summary.warmup_frames) | median) | \(map(.summary.stream.requests) | median) | \(map(.summary.stream.tiles) | median) | \(map(.summary.stream.bytes / 1e6) | median | . * 10 | round / 10) | \(map(.summary.stream.failures) | add) |"
' "$RESULTS/scaleout.jsonl" | sed '1i | path | source | runs | frames within τ | within 2τ | warm-up frames | requests | tiles | MB | failures |\n|---|---|---|---|---|---|---|---|---|---|'

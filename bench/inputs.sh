#!/usr/bin/env bash
# Build inputs at collection scale (DECISIONS.md "Inputs in object storage"):
#  1. the moon 8192² mosaic cut by GDAL into 64 Cloud-Optimized GeoTIFF pieces of
#     1024² (512² tiles, deflate, with overviews), built from a local folder and from
#     s3://bench/pieces/ (moto_server on loopback), alternating, RUNS times: wall time,
#     bytes fetched against the pieces' full-resolution tile bytes, and `cmp` of the two
#     pyramids;
#  2. how the build scales with cores: `synthetic:16385` and the local pieces at
#     RAYON_NUM_THREADS=1 and 2, alternating, RUNS times.
#  3. parts that read only their share: the s3:// pieces as 4 and 16 parts;
#  4. an update after 4 of the 64 pieces changed, against the whole build.
# Prints Markdown tables of every run and the medians; the commands are the ones shown.
# SCALING=0 skips part 2.
source "$(dirname "$0")/common.sh"
runs=${RUNS:-3}
venv=${XDG_CACHE_HOME:-$HOME/.cache}/tessera/deploy-venv
[ -x "$venv/bin/moto_server" ] || deploy/check.sh --tools-only
free_port() { python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }

# UPSAMPLE=K (default 1): the mosaic upsampled K times by GDAL (bilinear) before it is
# cut, for a collection K² times larger (pieces of 1024·K²; K = 4: 32768², 1.07 × 10⁹
# samples): parts' footprints then span more COG tiles.
up=${UPSAMPLE:-1}
side=$((1024 * up))
pieces=$WORK/inputs/pieces
mkdir -p "$pieces"
if [ ! -s "$pieces/p77.tif" ]; then
  whole=$WORK/inputs/moon.tif
  # 118.45 m samples (the data README); any georeferencing on one grid will do.
  gdal_translate -q -a_ullr 0 970342.4 970342.4 0 "$DEM/moon_crisium_gld100_8192.png" "$whole"
  if [ "$up" != 1 ]; then
    gdal_translate -q -of VRT -r bilinear -outsize $((8192 * up)) $((8192 * up)) "$whole" "$whole.vrt"
    whole=$whole.vrt
  fi
  for r in $(seq 0 7); do
    for c in $(seq 0 7); do
      gdal_translate -q -of COG -co BLOCKSIZE=512 -co COMPRESS=DEFLATE \
        -srcwin $((c * side)) $((r * side)) $side $side "$whole" "$pieces/p$r$c.tif"
    done
  done
  rm -f "$WORK/inputs/moon.tif" "$WORK/inputs/moon.tif.vrt"
fi
# The full-resolution tiles' stored bytes (first image's TileByteCounts), overviews and
# headers left out.
tile_bytes=$(python3 - "$pieces" <<'PY'
import os, struct, sys
total = 0
for name in sorted(os.listdir(sys.argv[1])):
    b = open(os.path.join(sys.argv[1], name), 'rb').read()
    e = '<' if b[:2] == b'II' else '>'
    off = struct.unpack_from(e + 'I', b, 4)[0]
    n = struct.unpack_from(e + 'H', b, off)[0]
    for i in range(n):
        tag, typ, cnt, val = struct.unpack_from(e + 'HHII', b, off + 2 + 12 * i)
        if tag == 325:
            fmt = 'I' if typ == 4 else 'H'
            total += sum(struct.unpack_from(e + fmt * cnt, b, val)) if cnt > 1 else val
print(total)
PY
)

moto_port=$(free_port)
spawn "$WORK/moto.out" "$WORK/moto.log" "$venv/bin/moto_server" -H 127.0.0.1 -p "$moto_port"
for _ in $(seq 200); do curl -fs "http://127.0.0.1:$moto_port/" > /dev/null && break; sleep 0.05; done
export AWS_ENDPOINT_URL=http://127.0.0.1:$moto_port AWS_ALLOW_HTTP=true AWS_REGION=us-east-1 \
  AWS_ACCESS_KEY_ID=bench AWS_SECRET_ACCESS_KEY=bench
"$venv/bin/python" - "$pieces" <<PY
import boto3, os, sys
s3 = boto3.client('s3', endpoint_url='$AWS_ENDPOINT_URL')
s3.create_bucket(Bucket='bench')
for n in sorted(os.listdir(sys.argv[1])):
    s3.upload_file(os.path.join(sys.argv[1], n), 'bench', 'pieces/' + n)
PY

timed() { # label, command...: prints "label wall cpu rss"
  local label=$1; shift
  /usr/bin/time -f "$label %e %U %S %M" "$@" 2>&1 > "$WORK/inputs/stdout" | tail -1
}
echo "| build | run | wall s | CPU s | peak RSS MiB |"
echo "|---|---|---|---|---|"
rows=()
for run in $(seq "$runs"); do
  for src in local s3; do
    input="$pieces/"; [ $src = s3 ] && input=s3://bench/pieces/
    read -r _ wall user sys rss < <(timed $src "$SERVER_BIN" build "$input" -o "$WORK/inputs/$src.tess" --quiet)
    echo "| 64 COG pieces from $src | $run | $wall | $(echo "$user + $sys" | bc) | $((rss / 1024)) |"
    rows+=("$src $wall")
    [ $src = s3 ] && fetched=$(grep '^read ' "$WORK/inputs/stdout")
  done
  cmp "$WORK/inputs/local.tess" "$WORK/inputs/s3.tess" || { echo "the pyramids differ" >&2; exit 1; }
done
median() { sort -n | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }
ml=$(printf '%s\n' "${rows[@]}" | awk '$1=="local"{print $2}' | median)
ms=$(printf '%s\n' "${rows[@]}" | awk '$1=="s3"{print $2}' | median)
echo
echo "medians: local $ml s, s3 $ms s ($(echo "scale=2; $ms / $ml" | bc)×); pyramids identical"
echo "s3: $fetched; full-resolution tile bytes $tile_bytes"

# 3. Parts that read only their share: the pieces from s3:// as N = 4 and 16 parts, one
#    after another; bytes fetched by all parts against the whole build's, the slowest
#    part's wall time, and `cmp` of the assembled pyramid with the whole build's.
echo
echo "| parts | bytes fetched, all parts | ÷ whole build's | slowest part wall s | median part wall s |"
echo "|---|---|---|---|---|"
whole_bytes=$(echo "$fetched" | awk '{print $2}')
for n in 4 16; do
  dir=$WORK/inputs/parts$n
  rm -rf "$dir"
  sum=0
  walls=()
  for k in $(seq 0 $((n - 1))); do
    read -r _ wall _ _ _ < <(timed part "$SERVER_BIN" build s3://bench/pieces/ --part "$k/$n" -o "$dir" --quiet)
    grep -q '^read its share' "$WORK/inputs/stdout" || { cat "$WORK/inputs/stdout" >&2; exit 1; }
    sum=$((sum + $(awk '/^read [0-9]+ bytes/ {print $2}' "$WORK/inputs/stdout")))
    walls+=("$wall")
  done
  "$SERVER_BIN" build --assemble "$dir" -o "$WORK/inputs/assembled.tess" --quiet > /dev/null
  cmp "$WORK/inputs/s3.tess" "$WORK/inputs/assembled.tess" || { echo "assembled $n parts differ" >&2; exit 1; }
  slowest=$(printf '%s\n' "${walls[@]}" | sort -n | tail -1)
  mid=$(printf '%s\n' "${walls[@]}" | median)
  echo "| $n | $sum | $(echo "scale=3; $sum / $whole_bytes" | bc) | $slowest | $mid |"
done
echo "(whole build from s3: $whole_bytes bytes; assembled pyramids identical to it)"

# 4. Updates: the pieces built with --state, locally and from s3://; four pieces (p11,
#    p26, p52, p67: 1/16 of the samples) resurveyed (heights rescaled by GDAL), in the
#    folder and uploaded over their objects; then, RUNS times alternating, the whole
#    build and `--update` of the old pyramid: wall time, bytes fetched, `cmp`.
echo
for src in local s3; do
  input="$pieces/"; [ $src = s3 ] && input=s3://bench/pieces/
  "$SERVER_BIN" build "$input" --state -o "$WORK/inputs/old-$src.tess" --quiet > /dev/null
done
for p in p11 p26 p52 p67; do
  gdal_translate -q -of COG -co BLOCKSIZE=512 -co COMPRESS=DEFLATE -ot UInt16 \
    -scale 0 65535 0 60000 "$pieces/$p.tif" "$WORK/inputs/$p.tif"
  mv "$WORK/inputs/$p.tif" "$pieces/$p.tif"
  "$venv/bin/python" - "$pieces/$p.tif" "$p" <<PY
import boto3, sys
boto3.client('s3', endpoint_url='$AWS_ENDPOINT_URL').upload_file(sys.argv[1], 'bench', 'pieces/' + sys.argv[2] + '.tif')
PY
done
echo "| build after 4 of 64 pieces changed | inputs | run | wall s | bytes fetched |"
echo "|---|---|---|---|---|"
urows=()
for run in $(seq "$runs"); do
  for src in local s3; do
    input="$pieces/"; [ $src = s3 ] && input=s3://bench/pieces/
    for how in whole update; do
      flags=(); [ $how = update ] && flags=(--update "$WORK/inputs/old-$src.tess")
      read -r _ wall _ _ _ < <(timed $how "$SERVER_BIN" build "$input" "${flags[@]}" -o "$WORK/inputs/$how.tess" --quiet)
      b=$(awk '/^read [0-9]+ bytes/ {print $2}' "$WORK/inputs/stdout")
      echo "| $how | $src | $run | $wall | ${b:--} |"
      urows+=("$src-$how $wall")
      [ $how = update ] && line=$(grep '^updated ' "$WORK/inputs/stdout")
    done
    cmp "$WORK/inputs/whole.tess" "$WORK/inputs/update.tess" || { echo "the update differs from the whole build" >&2; exit 1; }
  done
done
echo
for src in local s3; do
  mw=$(printf '%s\n' "${urows[@]}" | awk -v k="$src-whole" '$1==k{print $2}' | median)
  mu=$(printf '%s\n' "${urows[@]}" | awk -v k="$src-update" '$1==k{print $2}' | median)
  echo "$src medians: whole $mw s, update $mu s ($(echo "scale=3; $mu / $mw" | bc)×); identical"
done
echo "$line"
echo "pyramid $(stat -c %s "$WORK/inputs/old-s3.tess") bytes, its state $(stat -c %s "$WORK/inputs/old-s3.tess.state") bytes"

[ "${SCALING:-1}" = 0 ] && exit 0
echo
echo "| build | threads | run | wall s | CPU s |"
echo "|---|---|---|---|---|"
srows=()
for run in $(seq "$runs"); do
  for t in 1 2; do
    for input in synthetic:16385 "$pieces/"; do
      name=$input; [ "$input" = "$pieces/" ] && name="64 pieces"
      read -r _ wall user sys _ < <(timed x env RAYON_NUM_THREADS=$t "$SERVER_BIN" build "$input" -o "$WORK/inputs/t.tess" --quiet)
      echo "| $name | $t | $run | $wall | $(echo "$user + $sys" | bc) |"
      srows+=("$name|$t|$wall")
    done
  done
done
echo
for name in synthetic:16385 "64 pieces"; do
  one=$(printf '%s\n' "${srows[@]}" | awk -F'|' -v n="$name" '$1==n && $2==1 {print $3}' | median)
  two=$(printf '%s\n' "${srows[@]}" | awk -F'|' -v n="$name" '$1==n && $2==2 {print $3}' | median)
  echo "$name: 1 thread $one s, 2 threads $two s, speedup $(echo "scale=2; $one / $two" | bc)×"
done

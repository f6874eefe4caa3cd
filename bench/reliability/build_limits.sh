#!/usr/bin/env bash
# Usage: bench/reliability/build_limits.sh BIN WORKDIR
# Reproduces the build defects RELIABILITY.md lists (lying headers, damaged PNG, memory
# budget, signals, full disk) with the tessera-server binary BIN; run it with an old and a
# new binary side by side. Figures: RELIABILITY.md.
BIN=$(realpath "$1"); W=$2
export DEM_DIR; DEM_DIR=$(realpath "$(dirname "$0")/../../../shared/data/dem")
rm -rf "$W"; mkdir -p "$W"; cd "$W"
python3 - <<'PY'
import zlib, struct
def chunk(t, d): return struct.pack('>I', len(d)) + t + d + struct.pack('>I', zlib.crc32(t + d) & 0xffffffff)
w, h = 120, 4000
raw = b''.join(b'\0' + b''.join(struct.pack('>H', 1000 + (x + y) % 3000) for x in range(w)) for y in range(h))
idat = zlib.compress(raw, 9)
def png(hh): return b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', struct.pack('>IIBBBBB', w, hh, 16, 0, 0, 0, 0)) + chunk(b'IDAT', idat) + chunk(b'IEND', b'')
open('liar.png', 'wb').write(png(16777215))
open('liar4m.png', 'wb').write(png(4194304))
PY
ls -l liar.png | awk '{print "liar.png bytes:", $5}'
peak() { # command... ; prints exit code and peak RSS
  /usr/bin/time -f "%x %M" -o t.txt "$@" > out.txt 2> err.txt; read code kb < <(tail -1 t.txt)
  echo "exit=$code peak_rss=$((kb/1024))MiB err=$(grep -v '^Command' err.txt | tail -1 | cut -c1-220)"
  echo "  leftovers: $(ls -a | grep -c 'partial') partial, $(ls | grep -c '\.tess$') .tess"; rm -f .*.partial-* *.tess; }
echo "== 1 lying header 120x16777215";  peak "$BIN" build liar.png -o liar.tess --memory 256MiB --quiet
echo "== 1 lying header 120x4194304";  peak "$BIN" build liar4m.png -o liar.tess --memory 256MiB --quiet
echo "== 2 damaged PNG (bit flip in IDAT)"
python3 - <<'PY'
import os
b = bytearray(open(os.environ['DEM_DIR'] + '/jacksboro_fault_dem.png', 'rb').read())
at = 8; last = None
while at + 12 <= len(b):
    n = int.from_bytes(b[at:at+4], 'big'); t = bytes(b[at+4:at+8])
    if t == b'IDAT': last = (at, n)
    at += 12 + n
a, n = last; b[a + 8 + n // 2] ^= 0x10
open('flipped.png', 'wb').write(b)
PY
"$BIN" build flipped.png -o flipped.tess --quiet > out.txt 2> err.txt; echo "exit=$? $(tail -1 err.txt | cut -c1-200)"
[ -f flipped.tess ] && "$BIN" info flipped.tess | grep heights; rm -f flipped.tess
echo "== 3 memory: build --memory 256MiB --tile-size 64 synthetic:262145 (sampled 40 s)"
"$BIN" build synthetic:262145 --tile-size 64 --memory 256MiB --quiet -o big.tess > out.txt 2> err.txt & pid=$!
for i in $(seq 40); do sleep 1; kill -0 $pid 2>/dev/null || break; done
hwm=$(grep VmHWM /proc/$pid/status 2>/dev/null | awk '{print int($2/1024)}'); kill -TERM $pid 2>/dev/null; wait $pid; code=$?
echo "VmHWM=${hwm}MiB exit after SIGTERM=$code err=$(tail -1 err.txt | cut -c1-200)"
echo "  leftovers after SIGTERM: $(ls -a | grep partial | xargs -r du -ch 2>/dev/null | tail -1)"; rm -f .*.partial-* big.tess
echo "== 4 SIGINT after 2 s of synthetic:32769"
env --default-signal=INT "$BIN" build synthetic:32769 --quiet -o x.tess > out.txt 2> err.txt & pid=$!; sleep 2; kill -INT $pid; wait $pid; echo "exit=$? $(tail -1 err.txt)"
echo "  leftovers: $(ls -a | grep partial | xargs -r du -ch | tail -1)"; rm -f .*.partial-*
echo "== 4 ulimit -f 4096 (4 MiB)"
(ulimit -f 4096; "$BIN" build synthetic:4097 --quiet -o f.tess > out.txt 2> err.txt; echo "exit=$? $(tail -1 err.txt | cut -c1-200)")
echo "  leftovers: $(ls -a | grep -c partial) partial, $(ls | grep -c '\.tess$') .tess"; rm -f .*.partial-* *.tess

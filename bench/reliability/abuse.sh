#!/usr/bin/env bash
# Usage: bench/reliability/abuse.sh BIN — the reliability campaign (RELIABILITY.md): 1024
# keep-alive connections with wrk on one tile (non-2xx, server RSS before/after) and a
# slowloris of 100 sockets against a 5 s header timeout. Needs wrk and python3. Figures:
# RELIABILITY.md.
BIN=$(realpath "$1"); W=${2:-/tmp/tessera-abuse}; rm -rf $W; mkdir -p $W; cd $W
"$BIN" build synthetic:4097 --quiet -o synth.tess >/dev/null
ulimit -n 4096
"$BIN" serve synth.tess --listen 127.0.0.1:0 --header-timeout-secs 5 > serve.out 2> serve.err & pid=$!
for i in $(seq 100); do url=$(sed -n 's/^listening on //p' serve.out); [ -n "$url" ] && break; sleep 0.1; done
echo "server $url pid $pid"
rss() { awk '/VmRSS/{print int($2/1024)}' /proc/$pid/status; }
echo "RSS before: $(rss) MiB"
cat > count.lua <<'LUA'
done = function(summary, latency, requests)
  io.write(string.format("requests=%d non2xx=%d errors_connect=%d read=%d write=%d timeout=%d p50_ms=%.2f p99_ms=%.2f\n",
    summary.requests, summary.errors.status, summary.errors.connect, summary.errors.read, summary.errors.write,
    summary.errors.timeout, latency:percentile(50)/1000, latency:percentile(99)/1000))
end
LUA
wrk -c 1024 -t 2 -d 20s -s count.lua "$url/v1/datasets/synth/tiles/3/2/5" | tail -1
echo "RSS after wrk: $(rss) MiB (peak VmHWM $(awk '/VmHWM/{print int($2/1024)}' /proc/$pid/status) MiB)"
python3 - "$url" <<'PY'
import socket, sys, time, threading, urllib.request
url = sys.argv[1]; host, port = url.split('//')[1].split(':'); port = int(port)
socks = []
for i in range(100):
    s = socket.create_connection((host, port)); s.settimeout(0.05); socks.append(s)
start = time.time(); closed = {}
ok = []
def normal():
    time.sleep(1.0)
    with urllib.request.urlopen(url + '/v1/datasets/synth', timeout=10) as r: ok.append(r.status)
t = threading.Thread(target=normal); t.start()
req = b"GET /v1/datasets/synth HTTP/1.1\r\nHost: x\r\nX-Slow: " 
k = 0
while len(closed) < 100 and time.time() - start < 60:
    for i, s in enumerate(socks):
        if i in closed: continue
        try:
            s.send(req[k % len(req):k % len(req) + 1] if k < len(req) else b"a")
            try:
                if s.recv(1) == b'': closed[i] = time.time() - start
            except socket.timeout: pass
        except OSError:
            closed[i] = time.time() - start
    k += 1; time.sleep(1.0)
t.join()
c = sorted(closed.values())
print(f"slowloris: {len(c)}/100 closed; first {c[0]:.1f} s, last {c[-1]:.1f} s (header timeout 5 s); normal request during the attack: {ok}")
PY
echo "RSS at the end: $(rss) MiB"
kill -TERM $pid; wait $pid; echo "server exit $?"

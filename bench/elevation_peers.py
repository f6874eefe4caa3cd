#!/usr/bin/env python3
"""Point elevations timed two ways for bench/elevation.sh, one JSON line per batch size.

    elevation_peers.py rasterio FILE.tif POINTS.json SIZES RUNS
    elevation_peers.py tessera URL PID POINTS.json SIZES RUNS

POINTS.json is a list of [lat, lon]; SIZES is comma-separated batch sizes (1,100,100000).
Each batch takes the next points of the list, wrapping around it.

- rasterio: what opentopodata does for a request (backend.py, `_get_elevation_from_path`):
  open the file with rasterio, find each point's fractional row and column
  (`rowcol` without rounding), shift them half a pixel, and read a 1 x 1 window at that fractional offset
  with `resampling=bilinear` (GDAL's resampled RasterIO), masked, as floats. The file is
  EPSG:4326, so no reprojection (opentopodata skips it then too).
- tessera: POSTs the batch as JSON to the elevation API over one keep-alive connection.

"cold" is the first batch of a size in a fresh process (rasterio: this process, GDAL's
block cache empty; tessera: the caller starts a fresh server per size); "warm" the median
of RUNS more, each repeating the batch for about half a second. Per core: CPU seconds of the process doing the work (rasterio: this
process; tessera: the server, PID, from /proc), so the figures are points per CPU-second
whatever the machine's cores.
"""
import http.client
import json
import statistics
import sys
import time
import urllib.parse


def server_cpu(pid):
    """User + system CPU seconds of process `pid`."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    ticks = int(fields[11]) + int(fields[12])
    import os

    return ticks / os.sysconf("SC_CLK_TCK")


def rasterio_batch(path, pts):
    import numpy as np
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.windows import Window

    lats = np.array([p[0] for p in pts])
    lons = np.array([p[1] for p in pts])
    out = []
    with rasterio.open(path) as f:
        # `f.index(xs, ys, op=_noop)` in opentopodata; rasterio 1.4's `index` casts to
        # int, so its `rowcol` with the same no-op rounding.
        rows, cols = rasterio.transform.rowcol(f.transform, lons, lats, op=lambda v: v)
        rows = np.atleast_1d(np.array(rows, dtype=float)) - 0.5
        cols = np.atleast_1d(np.array(cols, dtype=float)) - 0.5
        rows = rows.clip(0, f.height - 1)
        cols = cols.clip(0, f.width - 1)
        for row, col in zip(rows, cols):
            z = f.read(
                indexes=1,
                window=Window(col, row, 1, 1),
                resampling=Resampling.bilinear,
                out_dtype=float,
                boundless=True,
                masked=True,
                fill_value=np.nan,
            )
            out.append(float(np.ma.filled(z, np.nan)[0][0]))
    return out


def main():
    mode = sys.argv[1]
    if mode == "rasterio":
        _, _, path, points, sizes, runs = sys.argv
        pid = None
    else:
        _, _, url, pid, points, sizes, runs = sys.argv
    pts = json.load(open(points))
    sizes = [int(s) for s in sizes.split(",")]
    runs = int(runs)
    at = 0

    def take(n):
        # The next n points, wrapping around the list (POSTs are never cached, and
        # every tile is decoded and cached after the cold batch anyway).
        nonlocal at
        batch = [pts[(at + i) % len(pts)] for i in range(n)]
        at += n
        return batch

    if mode == "rasterio":
        import rasterio  # noqa: F401  (imported before timing)

        def work(batch):
            return rasterio_batch(path, batch)

        def cpu():
            return time.process_time()

    else:
        u = urllib.parse.urlparse(url)
        conn = http.client.HTTPConnection(u.hostname, u.port)

        def work(batch):
            body = json.dumps({"locations": batch}).encode()
            conn.request("POST", u.path, body, {"Content-Type": "application/json"})
            r = conn.getresponse()
            data = r.read()
            assert r.status == 200, (r.status, data[:200])
            return data

        def cpu():
            return server_cpu(pid)

    for n in sizes:
        batch = take(n)
        t, c = time.perf_counter(), cpu()
        work(batch)
        cold_s, cold_cpu = time.perf_counter() - t, cpu() - c
        # Each run repeats the batch for about half a second (CPU time is counted in
        # ticks of 10 ms), judged by one more batch.
        t = time.perf_counter()
        work(take(n))
        reps = max(1, min(5000, int(0.5 / max(time.perf_counter() - t, 1e-6))))
        walls, cpus = [], []
        for _ in range(runs):
            batches = [take(n) for _ in range(reps)]
            t, c = time.perf_counter(), cpu()
            for b in batches:
                work(b)
            walls.append((time.perf_counter() - t) / reps)
            cpus.append((cpu() - c) / reps)
        print(
            json.dumps(
                {
                    "peer": mode,
                    "points": n,
                    "cold_s": cold_s,
                    "cold_cpu_s": cold_cpu,
                    "warm_s": statistics.median(walls),
                    "warm_cpu_s": statistics.median(cpus),
                    "reps": reps,
                    "runs": runs,
                }
            ),
            flush=True,
        )
        if mode == "tessera":
            # The caller starts a fresh server for the next size's cold batch.
            return


if __name__ == "__main__":
    main()

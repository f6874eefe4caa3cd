#!/usr/bin/env python3
"""The peer meshers on Tessera's tile windows (bench/terrain.sh part 1b).

Reads terrain_mesh's JSON lines (stdin) and, for each tile with a `window` (its finest
samples, little-endian f32, row-major from the north-west), meshes the same samples with:

- pydelatin (Delatin: greedy insertion into a Delaunay triangulation) at
  max_error = the tile's measured worst error (`error_m`, against the same samples),
  so both meshes keep the same maximum error;
- pymartini (Martini: RTIN, which needs a (2^k + 1)² grid: the window padded by
  repeating its last row and column, which adds flat area that costs Martini few
  triangles) at the same max_error.

Prints one JSON line per tile: the input line's dataset/zoom/tile/samples/triangles/
mesh_us and delatin_triangles, delatin_error_m, delatin_us, martini_triangles,
martini_error_m, martini_us (times: the median of 5 runs, each run meshing from the
array; Martini's includes building its error tree, as a server meshing a tile must).
"""
import json
import statistics
import sys
import time

import numpy as np
from pydelatin import Delatin
from pymartini import Martini


def timed(f, runs=5):
    times, out = [], None
    for _ in range(runs):
        t = time.perf_counter()
        out = f()
        times.append((time.perf_counter() - t) * 1e6)
    return statistics.median(times), out


def main():
    for line in sys.stdin:
        r = json.loads(line)
        if not r.get("window"):
            continue
        w, h = r["window_size"]
        a = np.fromfile(r["window"], dtype="<f4").reshape(h, w).astype(np.float32)
        tol = r["error_m"]
        d_us, d = timed(lambda: Delatin(a, width=w, height=h, max_error=tol))
        n = 1
        while n + 1 < max(w, h):
            n *= 2
        padded = np.pad(a, ((0, n + 1 - h), (0, n + 1 - w)), mode="edge")
        martini = Martini(n + 1)

        def run_martini():
            tile = martini.create_tile(padded)
            return tile.get_mesh(tol)

        m_us, (_, m_tris) = timed(run_martini)
        out = {k: r[k] for k in ("dataset", "zoom", "tile", "samples", "triangles",
                                  "mesh_us", "error_m", "level") if k in r}
        out.update(
            window_size=[w, h],
            delatin_triangles=int(len(d.triangles)),
            delatin_error_m=float(d.error),
            delatin_us=d_us,
            martini_triangles=int(len(m_tris) // 3),
            martini_grid=n + 1,
            martini_us=m_us,
        )
        print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()

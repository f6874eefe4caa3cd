#!/usr/bin/env python3
"""The peer meshers on Tessera's tile windows (bench/terrain.sh part 1b).

Reads terrain_mesh's JSON lines (stdin) and, for each tile with a `window` (its finest
samples, little-endian f32, row-major from the north-west), meshes the same samples with:

- pydelatin (Delatin: greedy insertion into a Delaunay triangulation) at
  max_error = the tile's measured worst error (`error_m`, against the same samples),
  so both meshes keep the same maximum error;
- pymartini (Martini: RTIN, which needs a (2^k + 1)² grid: the window padded by
  repeating its last row and column, which adds flat area that costs Martini few
  triangles). Martini's max_error is not a bound (it measures each vertex's own
  midpoint error, not its children's), so its threshold is bisected (8 steps) to
  the largest whose true worst error over the window's samples is within
  `error_m`; `martini_param` is that threshold.

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


def true_error(grid, vertices, triangles, w, h):
    """The worst |mesh − sample| over the window's samples (the padding excluded)."""
    v = vertices.reshape(-1, 2).astype(np.float64)
    worst = 0.0
    for tri in triangles.reshape(-1, 3):
        p = v[tri]
        z = grid[p[:, 1].astype(int), p[:, 0].astype(int)].astype(np.float64)
        x0, x1 = int(p[:, 0].min()), min(int(p[:, 0].max()), w - 1)
        y0, y1 = int(p[:, 1].min()), min(int(p[:, 1].max()), h - 1)
        if x0 > x1 or y0 > y1:
            continue
        xs, ys = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1))
        (ax, ay), (bx, by), (cx, cy) = p
        d = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
        l0 = ((by - cy) * (xs - cx) + (cx - bx) * (ys - cy)) / d
        l1 = ((cy - ay) * (xs - cx) + (ax - cx) * (ys - cy)) / d
        l2 = 1 - l0 - l1
        inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
        if inside.any():
            e = np.abs(l0 * z[0] + l1 * z[1] + l2 * z[2] - grid[ys, xs])[inside]
            worst = max(worst, float(e.max()))
    return worst


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

        martini_tile = martini.create_tile(padded)
        lo, hi = 0.0, tol
        for _ in range(8):
            mid = (lo + hi) / 2
            v, t = martini_tile.get_mesh(mid)
            if true_error(padded, v, t, w, h) <= tol:
                lo = mid
            else:
                hi = mid
        param = lo

        def run_martini():
            tile = martini.create_tile(padded)
            return tile.get_mesh(param)

        m_us, (m_v, m_tris) = timed(run_martini)
        m_err = true_error(padded, m_v, m_tris, w, h)
        out = {k: r[k] for k in ("dataset", "zoom", "tile", "samples", "triangles",
                                  "mesh_us", "error_m", "level") if k in r}
        out.update(
            window_size=[w, h],
            delatin_triangles=int(len(d.triangles)),
            delatin_error_m=float(d.error),
            delatin_us=d_us,
            martini_triangles=int(len(m_tris) // 3),
            martini_grid=n + 1,
            martini_param=param,
            martini_error_m=m_err,
            martini_us=m_us,
        )
        print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()

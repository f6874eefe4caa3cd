"""Reads a PMTiles archive with the `pmtiles` package from PyPI (the reference
reader of the format's authors): prints its header and metadata as JSON and writes
every tile to OUT/z/x/y.bin. Used by server/tests/export_pmtiles.rs."""
import json
import os
import sys

from pmtiles.reader import MmapSource, Reader, all_tiles

path, out = sys.argv[1], sys.argv[2]
with open(path, "r+b") as f:
    source = MmapSource(f)
    reader = Reader(source)
    header = {k: getattr(v, "name", v) for k, v in reader.header().items()}
    n = 0
    for (z, x, y), data in all_tiles(source):
        d = os.path.join(out, str(z), str(x))
        os.makedirs(d, exist_ok=True)
        with open(os.path.join(d, f"{y}.bin"), "wb") as t:
            t.write(data)
        # Each tile once more through the reader's own lookup by z/x/y.
        assert reader.get(z, x, y) == data, (z, x, y)
        n += 1
    print(json.dumps({"header": header, "metadata": reader.metadata(), "tiles": n}))

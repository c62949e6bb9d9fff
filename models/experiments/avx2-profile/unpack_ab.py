"""Decode of a 1,024-plane chunk: the code before the stop of 2026-11-29 (one unpackbits, flip, contiguous copy,
fresh arrays) against ``unpack_planes`` into a reused array, alternated 7 times; medians of ms a plane.
Run from the repository root: python models/experiments/avx2-profile/unpack_ab.py
"""

import statistics
import time
import numpy as np
from rmbvideo.io.dat import DatGeometry, unpack_planes

def before(packed, g):
    bits = np.unpackbits(packed, axis=1, bitorder="little").reshape(len(packed), g.height, g.width)
    if g.flip:
        bits = bits[:, ::-1]
    return np.ascontiguousarray(bits[:, :, : g.image_width])

g = DatGeometry()
packed = np.random.default_rng(0).integers(0, 256, (1024, g.plane_bytes), dtype=np.uint8)
out = np.empty((1024, g.height, g.image_width), np.uint8)
assert np.array_equal(before(packed, g), unpack_planes(packed, g, out))
t = {"before": [], "reused": []}
for _ in range(7):
    s = time.perf_counter(); before(packed, g); t["before"].append(time.perf_counter() - s)
    s = time.perf_counter(); unpack_planes(packed, g, out); t["reused"].append(time.perf_counter() - s)
for k, v in t.items():
    print(k, f"{statistics.median(v) * 1e3 / 1024:.4f} ms/plane", [f"{x*1e3/1024:.3f}" for x in v])

"""TFI's central spike counts summed in uint16 (``Tfi._count``) against the int64 sum before: TFI-16 at reach 200
over a held-out 400x250 capture, the two alternated in one process (ABBA), the median milliseconds a frame, and
whether every frame is the same. Run from the repository root (a minute with the held-out cache):

    python models/experiments/run-views/tfi_counts.py [ROUNDS]
"""

import statistics
import sys
import time

import numpy as np

from rmbvideo.evaluate.heldout import load_heldout
from rmbvideo.recon.classical import Tfi


def main(rounds: int = 6) -> None:
    chunks = list(load_heldout(False)[0].chunks(128))
    counts = {"uint16": Tfi.__dict__["_count"],
              "int64": staticmethod(lambda planes: planes.sum(axis=0, dtype=np.int64))}
    times: dict = {name: [] for name in counts}
    frames = {}
    for r in range(rounds):
        for name in (("int64", "uint16") if r % 2 else ("uint16", "int64")):
            Tfi._count = counts[name]
            tfi, out = Tfi(step=20, window=16, max_reach=200), []
            began = time.perf_counter()
            for chunk in chunks:
                out += tfi.push(chunk)
            out += tfi.flush()
            times[name].append(time.perf_counter() - began)
            frames[name] = out
    Tfi._count = counts["uint16"]
    n = len(frames["uint16"])
    same = all(np.array_equal(a.image, b.image) for a, b in zip(frames["int64"], frames["uint16"]))
    print(", ".join(f"{name} {1e3 * statistics.median(t) / n:.2f} ms a frame" for name, t in times.items()),
          f"({n} frames); the same frames: {same}")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:2]))

"""Byte planes counted in uint16 against the int64 sums before, alternated in one process (ABBA) over a held-out
400x250 capture: TFI's central spike counts (``Tfi._count``; TFI-16 at reach 200), or with ``tfp`` the window sums of
unpacked planes (``_DenseTotals.add``; TFP-80). Prints the median milliseconds and whether every frame is the same.
Run from the repository root (a minute with the held-out cache):

    python models/experiments/run-views/tfi_counts.py [ROUNDS] [tfp]
"""

import statistics
import sys
import time

import numpy as np

from rmbvideo.evaluate.heldout import load_heldout
import rmbvideo.recon.classical as classical
from rmbvideo.recon.classical import Tfi, Tfp


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


def window_sums(rounds: int = 6) -> None:
    """TFP-80 on unpacked planes with the uint16 window sums against int64 ones."""
    chunks = list(load_heldout(False)[0].chunks(128))

    def int64_add(self, channels, a, b):
        for total, channel in zip(self._total, channels):
            total += channel[a:b].sum(axis=0, dtype=total.dtype)

    adds = {"uint16": classical._DenseTotals.add, "int64": int64_add}
    times: dict = {name: [] for name in adds}
    frames = {}
    for r in range(rounds):
        for name in (("int64", "uint16") if r % 2 else ("uint16", "int64")):
            classical._DenseTotals.add = adds[name]
            tfp, out = Tfp(window=80, step=20), []
            began = time.perf_counter()
            for chunk in chunks:
                out += tfp.push(chunk)
            out += tfp.flush()
            times[name].append(time.perf_counter() - began)
            frames[name] = out
    classical._DenseTotals.add = adds["uint16"]
    same = all(np.array_equal(a.image, b.image) for a, b in zip(frames["int64"], frames["uint16"]))
    print(", ".join(f"{name} {1e3 * statistics.median(t):.1f} ms" for name, t in times.items()),
          f"(TFP-80, {len(frames['uint16'])} frames); the same frames: {same}")


if __name__ == "__main__":
    run = window_sums if "tfp" in sys.argv[1:] else main
    run(*(int(a) for a in sys.argv[1:] if a.isdigit()))

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


def _int64_add(self, channels, a, b):
    """``_DenseTotals.add`` as it was: every channel summed in its total's dtype (int64 for byte planes)."""
    for total, channel in zip(self._total, channels):
        total += channel[a:b].sum(axis=0, dtype=total.dtype)


#: what is measured -> (the class and attribute swapped, {variant: its value}, the method run over the capture)
CASES = {
    "tfi": (Tfi, "_count", {"uint16": Tfi.__dict__["_count"],
                            "int64": staticmethod(lambda planes: planes.sum(axis=0, dtype=np.int64))},
            lambda: Tfi(step=20, window=16, max_reach=200)),
    "tfp": (classical._DenseTotals, "add", {"uint16": classical._DenseTotals.add, "int64": _int64_add},
            lambda: Tfp(window=80, step=20)),
}


def main(case: str = "tfi", rounds: int = 6) -> None:
    """Both variants of ``case`` alternated over the capture; the median ms a frame and whether the frames agree."""
    owner, attribute, variants, method = CASES[case]
    chunks = list(load_heldout(False)[0].chunks(128))
    times: dict = {name: [] for name in variants}
    frames = {}
    for r in range(rounds):
        for name in (("int64", "uint16") if r % 2 else ("uint16", "int64")):
            setattr(owner, attribute, variants[name])
            made, out = method(), []
            began = time.perf_counter()
            for chunk in chunks:
                out += made.push(chunk)
            out += made.flush()
            times[name].append(time.perf_counter() - began)
            frames[name] = out
    setattr(owner, attribute, variants["uint16"])
    n = len(frames["uint16"])
    same = all(np.array_equal(a.image, b.image) for a, b in zip(frames["int64"], frames["uint16"]))
    print(f"{case}: " + ", ".join(f"{name} {1e3 * statistics.median(t) / n:.2f} ms a frame" for name, t in times.items())
          + f" ({n} frames); the same frames: {same}")


if __name__ == "__main__":
    main("tfp" if "tfp" in sys.argv[1:] else "tfi", *(int(a) for a in sys.argv[1:] if a.isdigit()))

"""How long the first frame's state is primed (frames run backwards before frame 0) against its edge figures, on
the development video sequences (never the held-out ones). Run from the repository root (minutes on one core):

    python models/experiments/first-window/prime.py 3 6 12 24

Prints, per sequence and prime, the first frame's drop below the clip's median, its time offset and its edge cost
(the middle frame scored mid-clip minus scored as a clip's first frame; ``video_checks.edge_report``).
"""

import sys

import numpy as np

from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.video_checks import edge_report


def main(primes: list[int]) -> None:
    print("| sequence | prime | first: dB below median | first: offset ms | middle offset ms | edge cost as first (dB) |")
    print("|---|---:|---:|---:|---:|---:|")
    costs: dict[int, list[float]] = {p: [] for p in primes}
    for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
        for prime in primes:
            r = edge_report(seq, "rmbnet", {"threads": 1, "prime": prime})
            costs[prime].append(r.first_edge_cost_db)
            print(f"| {seq.name} | {prime} | {r.first_drop_db:.2f} | {r.first_offset_ms:+.2f} | "
                  f"{r.middle_offset_ms:+.2f} | {r.first_edge_cost_db:.2f} |", flush=True)
    for prime in primes:
        print(f"prime {prime}: mean edge cost as first frame {np.mean(costs[prime]):.3f} dB")


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]])

"""Are the real-video streams' spike intervals more regular than a simulated camera's? Per capture, the fraction of
a pixel's consecutive inter-spike intervals that differ by more than one plane (first 200 planes): near 0 for a
noise-free integrate-and-fire pixel under steady light, large under shot noise or changing light. Real streams and
the held-out synthetic sequences (both pixels). Run from the repository root (about a minute):

    python models/experiments/tfi-detail/regularity.py ../shared/data/spikezoo-base
"""

import sys
from pathlib import Path

import numpy as np

from rmbvideo.evaluate.heldout import load_heldout, load_video_heldout
from rmbvideo.evaluate.real_video import find_streams
from rmbvideo.io.dat import DatReader


def irregular(planes: np.ndarray) -> tuple[float, int]:
    """The fraction of consecutive interval pairs of a pixel that differ by more than one plane, and the pairs."""
    T = len(planes); flat = planes.reshape(T, -1)
    last = np.full(flat.shape[1], -1); prev_iv = np.zeros(flat.shape[1], int)
    jumps = pairs = 0
    for t in range(T):
        s = flat[t].astype(bool)
        has = s & (last >= 0)
        iv = t - last
        both = has & (prev_iv > 0)
        pairs += int(both.sum()); jumps += int((np.abs(iv - prev_iv) > 1)[both].sum())
        prev_iv = np.where(has, iv, prev_iv)
        last = np.where(s, t, last)
    return jumps / max(pairs, 1), pairs


def main(streams: str) -> None:
    for st in find_streams(Path(streams)):
        p = np.concatenate([c.planes for c in DatReader(st.capture, st.geometry).chunks(1024)])[:200]
        print(st.name, "%.4f %d" % irregular(p))
    for reset in ("zero", "subtract"):
        for seq in (load_heldout(False, reset=reset) + load_video_heldout(False, reset=reset)):
            bits = np.unpackbits(seq.raw_packed, axis=-1, bitorder="little")[:200]
            print(reset, seq.name, "%.4f %d" % irregular(bits))


if __name__ == "__main__":
    main(sys.argv[1])

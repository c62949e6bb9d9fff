"""The tabulated reset-to-zero inverse (``rmbvideo.net.blend.reset_to_zero_intensity``) against its earlier form
(the same lookups by tensor indexing, below), alternated in one process at one thread. Run from the repository root:

    python models/experiments/inverse-lookup/time_inverse.py candidates       # a frame's 7 candidates at 200x125
    python models/experiments/inverse-lookup/time_inverse.py engine FILE.dat  # the engine end to end, 6 pairs

FILE.dat: a capture ``rmbvideo simulate`` made (its sidecar selects the tabulated response), e.g.
``rmbvideo simulate fast-motion -o fm5.dat --duration 0.5``.
"""

import statistics
import sys
import time

import torch

import rmbvideo.net.blend as blend
from rmbvideo.net.blend import _LOOKUP_CELLS, RESET_TO_ZERO_RATES, RESET_TO_ZERO_STEP, _inverse_lookup
from rmbvideo.recon.run import reconstruct_frames


def indexed(rate: torch.Tensor) -> torch.Tensor:
    """The inverse as it was before this change: the same lookups by tensor indexing."""
    table, segment = _inverse_lookup(rate.device)
    last = len(RESET_TO_ZERO_RATES) - 2
    r = rate.float().clamp(0.0, RESET_TO_ZERO_RATES[-1])
    cell = (r * (_LOOKUP_CELLS / RESET_TO_ZERO_RATES[-1])).long().clamp(0, _LOOKUP_CELLS - 1)
    j = segment[cell]
    j = (j + (r >= table[(j + 1).clamp(max=last + 1)]).long() - (r < table[j]).long()).clamp(0, last)
    low, high = table[j], table[j + 1]
    return (j.float() + (r - low) / (high - low)) * RESET_TO_ZERO_STEP


def alternate(pairs: int, measure) -> dict[str, list[float]]:
    """``measure(function)`` for the earlier and the current inverse, alternating which goes first."""
    variants = {"tensor indexing": indexed, "index_select": blend.reset_to_zero_intensity}
    results: dict[str, list[float]] = {name: [] for name in variants}
    for rep in range(pairs):
        for name in (list(variants) if rep % 2 == 0 else list(variants)[::-1]):
            results[name].append(measure(variants[name]))
    return results


def main(mode: str, path: str | None = None) -> None:
    torch.set_num_threads(1)
    if mode == "candidates":
        g = torch.Generator().manual_seed(0)
        candidates = [torch.rand(1, 1, 125, 200, generator=g) * 0.9 for _ in range(7)]
        assert all(torch.equal(indexed(c), blend.reset_to_zero_intensity(c)) for c in candidates)

        def measure(function) -> float:
            began = time.perf_counter()
            for c in candidates:
                function(c)
            return 1e3 * (time.perf_counter() - began)

        for name, ms in alternate(300, measure).items():
            print(f"{name}: {statistics.median(ms):.2f} ms a frame (7 candidates, median of 300)")
    elif mode == "engine" and path:
        current = blend.reset_to_zero_intensity

        def measure(function) -> float:
            blend.reset_to_zero_intensity = function
            began = time.perf_counter()
            count = sum(1 for _ in reconstruct_frames(path, "rmbnet", resolution="binned", threads=1, precision="fp32"))
            blend.reset_to_zero_intensity = current
            return count / (time.perf_counter() - began)

        fps = alternate(6, measure)
        ratios = [b / a for a, b in zip(*fps.values())]
        print("frames/s:", {name: [round(v, 2) for v in values] for name, values in fps.items()})
        print(f"index_select / tensor indexing, per pair: {[round(r, 3) for r in ratios]}; "
              f"median {statistics.median(ratios):.3f}")
    else:
        raise SystemExit("usage: time_inverse.py candidates | engine FILE.dat")


if __name__ == "__main__":
    main(*sys.argv[1:])

"""Pareto front of accuracy against time: the configurations no other one beats on both."""

from __future__ import annotations

import math
from collections.abc import Sequence


def pareto_front(points: Sequence[tuple[float | None, float | None]], resolution: float = 0.0) -> list[bool]:
    """For (seconds per frame, accuracy) points, True where no other point is at least as fast and
    at least as accurate and strictly better in one. Accuracies are compared rounded to ``resolution``
    (e.g. the 0.01 dB a table shows, so float noise in equal outputs does not put a slower row on the
    front). Points with a missing or non-finite value are never on the front (nor do they dominate)."""
    valid = [p[0] is not None and p[1] is not None and math.isfinite(p[0]) and math.isfinite(p[1])
             for p in points]
    if resolution > 0:
        points = [(t, round(a / resolution) if ok else a) for (t, a), ok in zip(points, valid)]
    front = []
    for i, (t, a) in enumerate(points):
        if not valid[i]:
            front.append(False)
            continue
        dominated = any(
            valid[j] and points[j][0] <= t and points[j][1] >= a and (points[j][0] < t or points[j][1] > a)
            for j in range(len(points)) if j != i
        )
        front.append(not dominated)
    return front

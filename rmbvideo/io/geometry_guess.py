"""Guess the plane geometry of a ``.dat`` capture from its data (the file does not record it).

Candidates are the (width, height) pairs whose plane of ``W*H/8`` bytes divides the file size
(sides 64..4096, aspect ratio at most 4:1), plus the common camera geometries in any case. Each is
scored on a sample from the start of the file decoded with that geometry:

- row correlation: neighbouring rows of the time-averaged image are alike only at the true width
  (a wrong width shears rows against each other);
- plane correlation: consecutive planes, pooled over 8x8 blocks, show the same scene only at the
  true plane size (a wrong height cuts planes in the wrong places).

The score is their mean. Plane sizes that are whole multiples of an about as good one (two true
planes read as one) are ranked below it, and the common geometries get a small bonus. The
vertical orientation (``flip``) cannot be told from correlations; the camera's default is assumed.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rmbvideo.errors import InputError
from rmbvideo.io.dat import COMMON_GEOMETRIES, DatGeometry, foreign_format

MIN_SIDE, MAX_SIDE = 64, 4096
MAX_ASPECT = 4.0
SAMPLE_BYTES = 1024 * 1024
# first pass: every candidate scored on this much data; the best FINALISTS are scored on SAMPLE_BYTES
SCREEN_BYTES = 128 * 1024
FINALISTS = 12
POOL = 8
COMMON_BONUS = 0.02
MULTIPLE_TOLERANCE = 0.05
# below this score no candidate looks like images (e.g. random bytes)
CONVINCING_SCORE = 0.2
# candidates within this score of the best are not told apart by the data: a scene whose rows are all alike (no
# structure down its columns) fits every height that divides the file about equally well
TIE_SCORE = 0.01
# ``better_geometry`` names another geometry only when it scores at least this and this much above the one assumed
# (a sideways 250x400 capture read as 400x250: 0.86 against 0.50; real 400x250 captures: their best other geometry
# 0.18-0.48 below theirs; random spikes: every geometry ~0)
BETTER_CONVINCING = 0.5
BETTER_BY = 0.2


@dataclass(frozen=True)
class GeometryGuess:
    """One candidate geometry, its score (higher is likelier; ~0 for noise) and what it implies."""

    geometry: DatGeometry
    score: float
    row_correlation: float
    plane_correlation: float
    planes: int
    trailing_bytes: int

    @property
    def options(self) -> str:
        """The command-line options selecting this geometry."""
        g = self.geometry
        header = f" --header-cols {g.header_cols}" if g.header_cols else ""
        return f"--width {g.width} --height {g.height}{header}"


def candidate_geometries(size: int) -> list[DatGeometry]:
    """Geometries whose plane divides ``size`` bytes at least twice, plus ``COMMON_GEOMETRIES``."""
    found: dict[tuple[int, int, int], DatGeometry] = {
        (g.width, g.height, g.header_cols): g for g in COMMON_GEOMETRIES
    }
    for plane_bytes in _divisors(size):
        pixels = 8 * plane_bytes
        if size // plane_bytes < 2 or pixels < MIN_SIDE * MIN_SIDE or pixels > MAX_SIDE * MAX_SIDE:
            continue
        for width in _divisors(pixels):
            height = pixels // width
            if MIN_SIDE <= width <= MAX_SIDE and MIN_SIDE <= height <= MAX_SIDE \
                    and max(width / height, height / width) <= MAX_ASPECT:
                found.setdefault((width, height, 0), DatGeometry(width, height))
    return list(found.values())


def _divisors(n: int) -> list[int]:
    small = [d for d in range(1, math.isqrt(n) + 1) if n % d == 0]
    return sorted(set(small + [n // d for d in small]))


def guess_geometry(path: str | os.PathLike[str], top: int = 5) -> list[GeometryGuess]:
    """The ``top`` likeliest geometries of the capture at ``path``, best first.

    Raises ``InputError`` for a missing, unreadable or empty file. A list whose best score is below
    ``CONVINCING_SCORE`` means that no geometry makes the data look like images.
    """
    path = Path(path)
    try:
        if path.is_dir():
            raise InputError(f"{path}: is a directory, not a .dat file")
        size = path.stat().st_size
        with open(path, "rb") as handle:
            sample = handle.read(SAMPLE_BYTES)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if size == 0:
        raise InputError(f"{path}: empty file")
    foreign = foreign_format(path)
    if foreign is not None:
        raise InputError(f"{path}: is {foreign}, not a spike capture: it has no plane geometry to guess")
    bits = np.unpackbits(np.frombuffer(sample, dtype=np.uint8), bitorder="little")
    screen = bits[: 8 * SCREEN_BYTES]
    candidates = [g for g in candidate_geometries(size) if g.plane_bytes <= len(sample)]
    # planes too big for the screening sample (at least two planes) are screened on the whole sample
    screened = sorted(candidates, key=lambda g: -_score(screen if 16 * g.plane_bytes <= len(screen) else bits,
                                                        g, size).score)
    finalists = screened[:FINALISTS] + [g for g in screened[FINALISTS:] if g in COMMON_GEOMETRIES]
    guesses = _rank_multiples_below([_score(bits, g, size) for g in finalists])
    common = {(g.width, g.height, g.header_cols) for g in COMMON_GEOMETRIES}
    guesses.sort(key=lambda c: (-(c.score + COMMON_BONUS * ((c.geometry.width, c.geometry.height,
                                                             c.geometry.header_cols) in common)),
                                c.geometry.plane_bytes, c.geometry.width))
    return guesses[:top]


def better_geometry(path: Path, assumed: DatGeometry) -> tuple[GeometryGuess, GeometryGuess] | None:
    """(a geometry that makes the start of ``path`` look far more like images than ``assumed`` does, by ``BETTER_BY``
    and convincingly; ``assumed``'s own score), or None: the quick check (``SCREEN_BYTES``, tens of milliseconds) of
    a capture read at the default size because nothing gave its own. The candidates are the planes of ``assumed``'s
    size in other shapes (a camera turned on its side) and the common camera geometries."""
    size = path.stat().st_size
    with open(path, "rb") as handle:
        sample = handle.read(SCREEN_BYTES)
    if len(sample) < 2 * assumed.plane_bytes:
        return None
    bits = np.unpackbits(np.frombuffer(sample, dtype=np.uint8), bitorder="little")
    others = [g for g in candidate_geometries(size) if g != assumed and 2 * g.plane_bytes <= len(sample)
              and (g.plane_bytes == assumed.plane_bytes or g in COMMON_GEOMETRIES)]
    if not others:
        return None
    best = max((_score(bits, g, size) for g in others), key=lambda guess: guess.score)
    mine = _score(bits, assumed, size)
    if best.score >= BETTER_CONVINCING and best.score >= mine.score + BETTER_BY:
        return best, mine
    return None


def tied_with_best(guesses: list[GeometryGuess]) -> list[GeometryGuess]:
    """The ``guesses`` (best first) whose score lies within ``TIE_SCORE`` of the best one's: more than one means the
    data cannot choose between them."""
    return [g for g in guesses if g.score >= guesses[0].score - TIE_SCORE]


def _score(bits: np.ndarray, geometry: DatGeometry, size: int) -> GeometryGuess:
    plane_pixels = geometry.width * geometry.height
    n = len(bits) // plane_pixels
    planes = bits[: n * plane_pixels].reshape(n, geometry.height, geometry.width)[:, :, : geometry.image_width]
    image = planes.sum(axis=0, dtype=np.uint32)
    rows = _correlation(image[:-1], image[1:])
    if n >= 2:
        h, w = (s // POOL * POOL for s in planes.shape[1:])
        pooled = planes[:, :h, :w].reshape(n, h // POOL, POOL, w // POOL, POOL).sum(axis=(2, 4), dtype=np.uint8)
        plane = _correlation(pooled[:-1], pooled[1:]) if pooled.size else 0.0
    else:
        plane = 0.0
    return GeometryGuess(geometry, (rows + plane) / 2, rows, plane, size // geometry.plane_bytes,
                         size % geometry.plane_bytes)


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two equally shaped arrays; 0 when either is constant."""
    a = a.ravel().astype(np.float64) - a.mean(dtype=np.float64)
    b = b.ravel().astype(np.float64) - b.mean(dtype=np.float64)
    # elementwise products, not BLAS dot: a threaded BLAS stalls on a busy machine for these small sizes
    denominator = math.sqrt(float(np.multiply(a, a).sum()) * float(np.multiply(b, b).sum()))
    return float(np.multiply(a, b).sum()) / denominator if denominator > 0 else 0.0


def _rank_multiples_below(guesses: list[GeometryGuess]) -> list[GeometryGuess]:
    """Lower the score of a plane holding several whole planes of an about as good smaller candidate."""
    result = []
    for guess in guesses:
        g = guess.geometry
        shadowed = any(
            o.geometry.plane_bytes < g.plane_bytes and g.plane_bytes % o.geometry.plane_bytes == 0
            and o.score >= guess.score - MULTIPLE_TOLERANCE
            for o in guesses
        )
        result.append(guess if not shadowed else GeometryGuess(
            g, guess.score - 2 * MULTIPLE_TOLERANCE, guess.row_correlation, guess.plane_correlation,
            guess.planes, guess.trailing_bytes))
    return result

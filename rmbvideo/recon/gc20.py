"""GC20 baseline (Gnanasambandam & Chan 2020, "HDR imaging with quanta image sensors"): per-pixel
maximum-likelihood exposure from the 1-bit and multi-bit readings of a temporal window.

Reading model. Every reading is a clamped count of *jots*, independent binary samples that each
fire with the same probability p(theta), theta being the project's linear unit (expected charge per
raw readout interval relative to the threshold):

- a 1-bit reading is one jot (binned data: one raw pixel of one raw plane, see ``sensor.binning``);
- a binned multi-bit reading counts ``4 * raw_per_readout`` jots (2x2 pixels x 2 planes = 8),
  clamped at ``level`` (7): P(v) = Binom(v; 8, p) for v < 7, P(7) = P(Binom(8, p) >= 7);
- a native multi-bit reading (``raw_per_readout == 1``) is modelled as ``level`` jots (L sub-threshold
  quanta of Q_th / L), so its mean is L * p, clamped at L (no clamp in effect).

``response`` gives p(theta): ``"poisson"`` (GC20's thresholded-Poisson QIS model, the default):
p = 1 - exp(-theta); ``"rate"``: p = min(theta, 1), the marginal firing probability of an
integrate-and-fire pixel, unbiased in the simulator's units below saturation but blind above it.
Both agree at low exposure. The method's ``convention`` option picks the one that matches what made the spikes
(``CONVENTION_RESPONSES``): a pixel reset to zero at a spike saturates about as the Poisson model does (its inverse
reads rmbvideo's camera within 4 % up to half a threshold per plane, within 14 % up to 1), while a pixel that keeps
the charge past its threshold (spikezoo's streams, cameras such as ``car.dat``'s) fires at the rate of its light,
which the Poisson model reads 39 % too bright at half a spike per plane. Where a row was read as multi-bit, its
1-bit value is ignored: for binned data it is one of the 8 jots already counted.

The log-likelihood is concave in p (binomial terms are, and a binomial upper tail is a Beta CDF in p,
hence log-concave), so the MLE is the unique root of the score; it is found by vectorised bisection
on logit(p). Bounds from a 1/2 pseudo-count: p in [1/(2E), 1 - 1/(2E)] with E the window's jots,
so all-dark and all-saturated pixels stay finite (theta_max = ln(2E) for ``"poisson"``).

Frames follow ``recon.classical.Tfw`` exactly: frame i is centred at readout c_i = i*step + step/2
(``step`` and ``window`` in readouts of the RMB stream, counted from readout 0 of the file), time
stamp c_i / rate_hz; a frame is produced for every centre inside the data pushed; its window starts
at round(c_i - window/2) (half up) and is clipped to the data that exists. Statistics are stored per
``block`` readouts, so step, window and window start must be whole blocks (checked).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np
from scipy.special import expit, log_expit

from rmbvideo.chunks import Frame, RmbChunk

Response = Literal["poisson", "rate"]
RESPONSES: tuple[str, ...] = ("poisson", "rate")
#: The response that matches each sensor convention (``rmbvideo.sensor.conventions.CONVENTIONS``).
CONVENTION_RESPONSES: dict[str, Response] = {"physical": "poisson", "spikezoo": "rate"}
BISECTION_STEPS = 36


@dataclass
class ReadingStats:
    """Per-pixel sufficient statistics of a set of readings under the clamped-jot model (float32)."""

    single_ones: np.ndarray
    single_zeros: np.ndarray
    multi_sum: np.ndarray      # sum of multi-bit values below the clamp
    multi_below: np.ndarray    # number of multi-bit readings below the clamp
    multi_clamped: np.ndarray  # number of multi-bit readings at the clamp

    @classmethod
    def zeros(cls, shape: tuple[int, int]) -> "ReadingStats":
        """Statistics of no readings."""
        return cls(*(np.zeros(shape, np.float32) for _ in range(5)))

    def arrays(self) -> tuple[np.ndarray, ...]:
        """The five statistic arrays in field order."""
        return (self.single_ones, self.single_zeros, self.multi_sum, self.multi_below, self.multi_clamped)

    def add(self, other: "ReadingStats", weight: np.ndarray | float = 1.0) -> None:
        """Accumulate ``weight * other`` in place (weights make a weighted likelihood)."""
        for mine, theirs in zip(self.arrays(), other.arrays()):
            mine += theirs * weight

    def fires(self, model: "JotModel") -> np.ndarray:
        """Fired jots (clamped readings counted at the clamp)."""
        return self.single_ones + self.multi_sum + model.clamp * self.multi_clamped

    def jots(self, model: "JotModel") -> np.ndarray:
        """Jots observed."""
        return self.single_ones + self.single_zeros + model.multi_jots * (self.multi_below + self.multi_clamped)


@dataclass(frozen=True)
class JotModel:
    """Jots per multi-bit reading, its clamp, and the response p(theta) (see the module docstring)."""

    multi_jots: int
    clamp: int
    response: Response = "poisson"

    @classmethod
    def for_chunk(cls, chunk: RmbChunk, response: Response) -> "JotModel":
        """The model for a binned (raw_per_readout > 1) or native (raw_per_readout == 1) stream."""
        if response not in RESPONSES:
            raise ValueError(f"unknown response {response!r} (expected one of {', '.join(RESPONSES)})")
        jots = 4 * chunk.raw_per_readout if chunk.raw_per_readout > 1 else chunk.level
        return cls(multi_jots=jots, clamp=min(chunk.level, jots), response=response)


def readings_stats(chunk: RmbChunk, lo: int, hi: int, model: JotModel) -> ReadingStats:
    """Sufficient statistics of readouts ``lo:hi`` (indices within ``chunk``)."""
    multi_read = chunk.multi_rows[lo:hi, :, None]
    single = chunk.single[lo:hi].astype(bool)
    multi = chunk.multi[lo:hi]
    single_used = ~multi_read
    clamped = multi_read & (multi >= model.clamp)
    below = multi_read & ~clamped
    return ReadingStats(
        single_ones=np.count_nonzero(single & single_used, axis=0).astype(np.float32),
        single_zeros=np.count_nonzero(~single & single_used, axis=0).astype(np.float32),
        multi_sum=np.where(below, multi, 0).sum(axis=0, dtype=np.float32),
        multi_below=np.count_nonzero(below, axis=0).astype(np.float32),
        multi_clamped=np.count_nonzero(clamped, axis=0).astype(np.float32),
    )


def _log_choose(n: int, k: int) -> float:
    return math.lgamma(n + 1) - math.lgamma(k + 1) - math.lgamma(n - k + 1)


def solve_exposure(stats: ReadingStats, model: JotModel, steps: int = BISECTION_STEPS) -> np.ndarray:
    """Maximum-likelihood theta per pixel, float32 (H, W), finite and >= 0 (see the module docstring)."""
    n, c = model.multi_jots, model.clamp
    successes = stats.single_ones.astype(np.float64) + stats.multi_sum
    failures = stats.single_zeros + n * stats.multi_below.astype(np.float64) - stats.multi_sum
    clamped = stats.multi_clamped.astype(np.float64)
    if c >= n:  # a reading at the clamp is simply all jots fired
        successes = successes + n * clamped
        clamped = np.zeros_like(clamped)
    jots = np.maximum(stats.jots(model).astype(np.float64), 1.0)
    p_min = 0.5 / jots
    lo = np.log(p_min) - np.log1p(-p_min)  # logit bounds, symmetric: [logit(1/2E), logit(1 - 1/2E)]
    hi = -lo
    tail = np.flatnonzero(clamped > 0)  # pixels with clamped readings need the binomial-tail term
    clamped_tail = clamped.ravel()[tail]
    tail_choose = [_log_choose(n, j) for j in range(c, n + 1)]
    tail_numerator = math.log(n) + _log_choose(n - 1, c - 1)
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        p = expit(mid)
        # score * p (1 - p): positive where the likelihood still increases with p
        score = successes * (1.0 - p) - failures * p
        if tail.size:
            m = mid.ravel()[tail]
            log_p, log_q = log_expit(m), log_expit(-m)
            log_tail = np.logaddexp.reduce(
                [lc + j * log_p + (n - j) * log_q for lc, j in zip(tail_choose, range(c, n + 1))], axis=0
            )
            # d/dp log P(Binom(n, p) >= c) = n Binom(c-1; n-1, p) / P(Binom(n, p) >= c), times p (1 - p)
            score.ravel()[tail] += clamped_tail * np.exp(tail_numerator + c * log_p + (n - c + 1) * log_q - log_tail)
        rising = score > 0
        lo = np.where(rising, mid, lo)
        hi = np.where(rising, hi, mid)
    logit_p = 0.5 * (lo + hi)
    if model.response == "poisson":
        theta = np.logaddexp(0.0, logit_p)  # -log(1 - p) = softplus(logit p)
    else:
        theta = expit(logit_p)
    return theta.astype(np.float32)


@dataclass(frozen=True)
class Gc20Config:
    """GC20 settings: ``window`` and frame ``step`` in readouts as TFW-L (70, 10), ``block`` readouts
    summed per stored statistic, and the response p(theta)."""

    window: int = 70
    step: int = 10
    block: int = 10
    response: Response = "poisson"


@dataclass
class _StreamState:
    """Where the stream is: geometry and model (fixed by the first chunk) and the readout cursor."""

    model: JotModel
    shape: tuple[int, int]
    rate_hz: float
    first_readout: int
    next_readout: int
    next_frame: int
    blocks: dict[int, ReadingStats] = field(default_factory=dict)


class BlockWindowReconstructor(ABC):
    """Streaming skeleton shared by GC20 and MG20: per-block statistics in a bounded store, frames on
    the classical timing; subclasses turn the blocks of one window into an image (``_frame_image``)."""

    input_kind: ClassVar[str] = "rmb"  # consumes RmbChunks (the pipeline's Reconstructor protocol)

    def __init__(self, window: int, step: int, block: int, response: Response) -> None:
        if window < 1 or step < 1 or block < 1:
            raise ValueError(f"window, step and block must be >= 1, got {window}, {step}, {block}")
        if response not in RESPONSES:
            raise ValueError(f"unknown response {response!r} (expected one of {', '.join(RESPONSES)})")
        self.window, self.step, self.block, self.response = window, step, block, response
        self._state: _StreamState | None = None

    def push(self, chunk: RmbChunk) -> list[Frame]:
        """Consume the next contiguous chunk; return the frames whose windows are now complete."""
        state = self._start(chunk) if self._state is None else self._state
        if chunk.start != state.next_readout:
            raise ValueError(f"chunk starts at readout {chunk.start}, expected {state.next_readout}")
        if chunk.single.shape[1:] != state.shape:
            raise ValueError(f"chunk frame size {chunk.single.shape[1:]} differs from the stream's {state.shape}")
        offset = 0
        while offset < len(chunk.single):
            readout = chunk.start + offset
            index = readout // self.block
            stop = min(len(chunk.single), (index + 1) * self.block - chunk.start)
            stats = readings_stats(chunk, offset, stop, state.model)
            if index in state.blocks:
                state.blocks[index].add(stats)
            else:
                state.blocks[index] = stats
            offset = stop
        state.next_readout = chunk.stop
        return self._emit(final=False)

    def flush(self) -> list[Frame]:
        """Emit the remaining frames with windows clipped to the end of the data."""
        if self._state is None:
            return []
        return self._emit(final=True)

    def _start(self, chunk: RmbChunk) -> _StreamState:
        if self.step % self.block or self.window % self.block or self._window_offset() % self.block:
            raise ValueError(
                f"step {self.step}, window {self.window} and block {self.block} readouts do not tile: "
                "the step, the window and its start must be whole blocks"
            )
        self._state = _StreamState(
            model=JotModel.for_chunk(chunk, self.response),
            shape=chunk.single.shape[1:],
            rate_hz=chunk.rate_hz,
            first_readout=chunk.start,
            next_readout=chunk.start,
            next_frame=max(0, -((self.step - 2 * chunk.start) // (2 * self.step))),
        )
        return self._state

    def _window_offset(self) -> int:
        """Start of frame i's window minus i * step: round(step/2 - window/2), half up."""
        return (self.step - self.window + 1) // 2

    def _emit(self, final: bool) -> list[Frame]:
        state = self._state
        offset = self._window_offset()
        frames = []
        while (2 * state.next_frame + 1) * self.step < 2 * state.next_readout:
            i = state.next_frame
            start = i * self.step + offset
            end = start + self.window
            if end > state.next_readout and not final:
                break
            first_block = max(start, state.first_readout) // self.block
            last_block = (min(end, state.next_readout) - 1) // self.block
            indices = list(range(first_block, last_block + 1))
            centre = (2 * i + 1) * self.step / 2
            reference = indices.index(int(centre) // self.block)
            image = self._frame_image([state.blocks[k] for k in indices], reference, state.model)
            frames.append(Frame(index=i, time_s=centre / state.rate_hz, image=image))
            state.next_frame += 1
            keep_from = (state.next_frame * self.step + offset) // self.block
            for k in [k for k in state.blocks if k < keep_from]:
                del state.blocks[k]
        return frames

    @abstractmethod
    def _frame_image(self, blocks: list[ReadingStats], reference: int, model: JotModel) -> np.ndarray:
        """The linear frame from the statistics of the window's blocks (``reference``: the frame's own)."""


def tiling_block(window: int, step: int, block: int) -> int:
    """The largest block of at most ``block`` readouts that tiles ``step``, ``window`` and the window's start
    (``BlockWindowReconstructor`` keeps its statistics per block)."""
    return math.gcd(block, step, window, (step - window + 1) // 2)


class Gc20Reconstructor(BlockWindowReconstructor):
    """GC20: the MLE of theta from all readings of the window, pixel by pixel (no alignment). Its blocks only group
    the window's sums, so a step or window they do not tile (``--step 2``: a frame a readout) gets smaller ones."""

    def __init__(self, config: Gc20Config | None = None) -> None:
        config = config or Gc20Config()
        super().__init__(config.window, config.step, tiling_block(config.window, config.step, config.block),
                         config.response)
        self.config = config

    def _frame_image(self, blocks: list[ReadingStats], reference: int, model: JotModel) -> np.ndarray:
        total = ReadingStats.zeros(blocks[0].single_ones.shape)
        for stats in blocks:
            total.add(stats)
        return solve_exposure(total, model)


def config_options(options: dict[str, object], convention: str | None) -> dict[str, object]:
    """A GC20/MG20 config's keyword options with the response ``convention`` calls for, unless one is given."""
    if convention is None or "response" in options:
        return options
    if convention not in CONVENTION_RESPONSES:
        raise ValueError(f"unknown convention {convention!r} (expected one of {', '.join(CONVENTION_RESPONSES)})")
    return {**options, "response": CONVENTION_RESPONSES[convention]}


def make_gc20(convention: str | None = None, **options: object) -> Gc20Reconstructor:
    """Method "gc20": keyword options are ``Gc20Config`` fields; ``convention`` (what made the spikes) picks the
    response when none is given."""
    return Gc20Reconstructor(Gc20Config(**config_options(options, convention)))  # type: ignore[arg-type]

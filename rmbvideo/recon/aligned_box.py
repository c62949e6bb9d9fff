"""Motion-compensated box filter of a window's multi-bit rates: the evidence of the neighbouring frames
moved onto the reference frame's grid with optical flow, and merged only where it agrees.

A plain mean over 2w+1 frames blurs anything that moves; the reference frame alone is noisy. Like
MG20's align-and-merge (Ma et al. 2020), each neighbour's rate image is warped to the reference with
OpenCV DIS flow and weighted per pixel by a robust test: the local (``patch`` x ``patch``) means of the
warped neighbour and of the reference are compared on the variance-stabilised arcsine-sqrt scale, and
the weight is ``min(1, tau / z^2)`` (pixels the flow maps outside the frame carry no evidence). RMB-Net
gets the result as one more input and blend candidate (``RmbNetConfig.aligned``), so it can use a
longer, motion-compensated average where the flow is right and ignore it where it is not.

Cost: one DIS flow per frame, from each frame to the next (cached); the flow back to the previous frame
is that flow inverted (a fixed-point iteration, as accurate here as computing it: equal scores on the
held-out sequences at half the cost), and a neighbour k frames away is reached by composing k flows,
outwards one step at a time (one remap per neighbour).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from rmbvideo.net.blend import BIN_TRIALS
from rmbvideo.recon.flow import dis_flow

#: OpenCV DIS presets by name.
DIS_PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
               "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
#: Percentile of a frame's square-root rates mapped to white in its 8-bit flow image.
WHITE_PERCENTILE = 99.5
#: Fixed-point iterations that invert a forward flow into the backward one.
INVERSION_ITERATIONS = 2


@dataclass(frozen=True)
class AlignedBoxConfig:
    """DIS preset, its gradient-descent and variational-refinement iterations (the "medium" preset has 25
    and 5: 12 and 2 score the same on the development sets at 30 % less flow time) and its patch stride (the
    preset's 3: 4 scores the same on the 21 development sequences, 35.43 against 35.42 dB, at 30 % less flow
    time again; the "fast" preset's coarser finest scale loses on fast motion), the blur of the images
    flow is computed on, the robust merge's patch and threshold, ``trials``: Bernoulli trials behind one
    pixel's rate per frame (N readouts x 8 raw pixel-planes), and ``sharp_trials``: those behind a sharp
    image's (its k central readouts x 8)."""

    preset: str = "medium"
    descent_iterations: int = 12
    refinement_iterations: int = 2
    patch_stride: int = 4
    sigma: float = 1.0
    patch: int = 5
    tau: float = 4.0
    trials: int = 80
    sharp_trials: int = 16

    @classmethod
    def for_frames(cls, n: int, sharp_readouts: int = 0) -> "AlignedBoxConfig":
        """The defaults with the trials of frames of ``n`` binned readouts and of sharp images of their central
        ``sharp_readouts`` (each binned count is 8 raw pixel-planes), so the robust test's variance is right."""
        return cls(trials=BIN_TRIALS * n, sharp_trials=BIN_TRIALS * max(sharp_readouts, 1))

    def __post_init__(self) -> None:
        if self.preset not in DIS_PRESETS:
            raise ValueError(f"preset must be one of {sorted(DIS_PRESETS)}, got {self.preset!r}")
        if self.patch < 1 or self.tau <= 0 or self.sigma < 0 or self.trials < 1 or self.sharp_trials < 1:
            raise ValueError(f"patch, tau and trials must be positive and sigma >= 0, got {self}")
        if self.descent_iterations < 1 or self.refinement_iterations < 0 or self.patch_stride < 1:
            raise ValueError(f"descent iterations and patch stride must be >= 1 and refinement iterations >= 0, "
                             f"got {self}")


def _clean(rate: np.ndarray) -> np.ndarray:
    return np.clip(np.nan_to_num(np.asarray(rate, np.float32), nan=0.0), 0.0, 1.0)


def _white(image: np.ndarray) -> float:
    """White of an 8-bit flow image: its 99.5th percentile (the order statistic below, no interpolation), so a few
    bright lights do not darken the rest; one partial sort, 8x faster than ``np.percentile``'s."""
    flat = image.ravel()
    k = int(WHITE_PERCENTILE / 100.0 * (flat.size - 1))
    return float(np.partition(flat, k)[k])


def _arcsine_sqrt(p: np.ndarray) -> np.ndarray:
    """Variance-stabilised proportion: 2 asin(sqrt(p)) has variance ~1/n for n trials (a new array)."""
    out = np.clip(p, 0.0, 1.0)
    np.sqrt(out, out=out)
    np.arcsin(out, out=out)
    out *= 2.0
    return out


class AlignedBox:
    """Aligned, robustly merged means of rate images keyed by frame index (``add``, ``mean``, ``evict``).

    Rates are fractions in [0, 1] (a pixel's fired share of its trials), (H, W) float32 each. A frame may
    also bring a sharp image: the rate of its central few readouts, which a fast-moving edge has crossed
    less of than the whole frame's; it is moved by the same flows (computed on the whole-frame rates) and
    merged by its own robust test.
    """

    def __init__(self, config: AlignedBoxConfig | None = None) -> None:
        self.config = config or AlignedBoxConfig()
        self._local = threading.local()  # one DIS object per thread: several threads may compute flows at once
        self._lock = threading.Lock()  # guards the stores' changes against an eviction iterating over them
        self._rates: dict[int, np.ndarray] = {}
        self._sharp: dict[int, np.ndarray] = {}
        self._images: dict[int, np.ndarray] = {}
        self._whites: dict[int, float] = {}
        self._flows: dict[tuple[int, int], np.ndarray] = {}
        self._flow_statistics: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._grid: tuple[np.ndarray, np.ndarray] | None = None

    def add(self, index: int, rate: np.ndarray, sharp: np.ndarray | None = None) -> None:
        """Keep frame ``index``'s rate image and, if given, its sharp image (both clipped to [0, 1], NaN as 0)."""
        rate = _clean(rate)
        blurred = cv2.GaussianBlur(rate, (0, 0), self.config.sigma) if self.config.sigma > 0 else rate
        image = np.sqrt(np.maximum(blurred, 0.0))
        white = _white(image)
        with self._lock:
            if self._grid is None or self._grid[0].shape != rate.shape:
                h, w = rate.shape
                self._grid = tuple(np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)))
            self._rates[index], self._images[index], self._whites[index] = rate, image, white
            if sharp is not None:
                self._sharp[index] = _clean(sharp)

    def evict(self, oldest_needed: int) -> None:
        """Forget frames (and flows) older than ``oldest_needed``."""
        with self._lock:
            for store in (self._rates, self._sharp, self._images, self._whites):
                for key in [k for k in store if k < oldest_needed]:
                    del store[key]
            for flows in (self._flows, self._flow_statistics):
                for key in [k for k in flows if min(k) < oldest_needed]:
                    del flows[key]

    def _dis(self) -> cv2.DISOpticalFlow:
        """This thread's DIS object (made on first use)."""
        dis = getattr(self._local, "dis", None)
        if dis is None:
            dis = cv2.DISOpticalFlow_create(DIS_PRESETS[self.config.preset])
            dis.setGradientDescentIterations(self.config.descent_iterations)
            dis.setVariationalRefinementIterations(self.config.refinement_iterations)
            dis.setPatchStride(self.config.patch_stride)
            self._local.dis = dis
        return dis

    def flows_between(self, a: int) -> None:
        """Compute the flows between frames ``a - 1`` and ``a`` both ways now (a worker pool's task; the flows are
        the same whichever thread computes them)."""
        self._step_flow(a, a - 1)

    def _step_flow(self, a: int, b: int) -> np.ndarray:
        """Flow from frame ``a`` to its neighbour ``b`` (a(x) ~ b(x + F(x))): DIS on square-root images
        scaled to 8 bits by the pair's joint white from the earlier frame to the later one, inverted
        for the way back (B(x) = -F(x + B(x)), iterated from B = -F)."""
        if b < a and (a, b) not in self._flows:
            forward = self._step_flow(b, a)
            gx, gy = self._grid  # type: ignore[misc]
            back = -forward
            for _ in range(INVERSION_ITERATIONS):
                back = -cv2.remap(forward, gx + back[..., 0], gy + back[..., 1], cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_REPLICATE)
            with self._lock:
                self._flows[(a, b)] = back
        if (a, b) not in self._flows:
            ia, ib = self._images[a], self._images[b]
            scale = 255.0 / max(self._whites[a], self._whites[b], 1e-3)
            a8 = np.clip(ia * scale + 0.5, 0, 255).astype(np.uint8)
            b8 = np.clip(ib * scale + 0.5, 0, 255).astype(np.uint8)
            flow = np.nan_to_num(dis_flow(self._dis(), a8, b8), nan=0.0, posinf=0.0, neginf=0.0)
            with self._lock:
                self._flows[(a, b)] = flow
        return self._flows[(a, b)]

    def _flows_from(self, i: int, neighbours: Sequence[int]) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        """Where each neighbour's pixels lie seen from frame ``i`` (``i`` itself skipped): the sampling maps
        x + F(i, k) and y + F(i, k), with the flows composed outwards one step at a time on each side
        (F(i, k+1) = F(i, k) + F(k, k+1) at x + F(i, k)), so a radius r costs r remaps a side. Each map is made
        once and serves both the next composition and the neighbour's warp."""
        gx, gy = self._grid  # type: ignore[misc]
        wanted = set(neighbours) - {i}
        for d in (-1, 1):
            side = [j for j in wanted if (j - i) * d > 0]
            if not side:
                continue
            far = max(side, key=lambda j: abs(j - i))
            flow = self._step_flow(i, i + d)
            map_x, map_y = gx + flow[..., 0], gy + flow[..., 1]
            for k in range(i + d, far + d, d):
                if k != i + d:
                    step = self._step_flow(k - d, k)
                    flow = flow + cv2.remap(step, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                    map_x, map_y = gx + flow[..., 0], gy + flow[..., 1]
                if k in wanted:
                    yield k, map_x, map_y

    def mean(self, i: int, neighbours: Sequence[int],
             statistics: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Frame ``i``'s rate averaged with the ``neighbours`` warped onto it, each pixel weighted by
        the robust agreement test: (H, W) float32 in [0, 1]; (2, H, W) with the sharp images' mean second
        when frame ``i`` brought one (then every neighbour must have). With ``statistics``, also how far that
        mean can be trusted per pixel (``STATISTICS``, (4, H, W) float32)."""
        cfg = self.config
        kinds = [(self._rates, cfg.trials)] + ([(self._sharp, cfg.sharp_trials)] if i in self._sharp else [])
        merges = [_RobustMerge(images[i], trials, cfg, spread=statistics and k == 0)
                  for k, (images, trials) in enumerate(kinds)]
        h, w = self._rates[i].shape
        for j, map_x, map_y in self._flows_from(i, neighbours):
            inside = (map_x >= 0) & (map_x <= w - 1) & (map_y >= 0) & (map_y <= h - 1)
            for merge, (images, _) in zip(merges, kinds):
                merge.add(cv2.remap(images[j], map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
                          inside)
        means = [merge.result() for merge in merges]
        mean = means[0] if len(means) == 1 else np.stack(means)
        return (mean, self._statistics(i, merges[0], neighbours)) if statistics else mean

    def _statistics(self, i: int, merge: "_RobustMerge", neighbours: Sequence[int]) -> np.ndarray:
        """``STATISTICS`` of frame ``i``'s mean from its merge over the window's frames ``neighbours`` (the DIS flows
        from frame i to the next and from the previous one to i, where the window has those frames)."""
        steps = [self._step_statistics(key) for key in ((i, i + 1), (i - 1, i)) if set(key) <= {i, *neighbours}]
        if steps:
            roughness, magnitude = np.max([gradient for gradient, _ in steps], axis=0), steps[0][1]
        else:  # a window of one frame: no flow
            roughness = magnitude = np.zeros(self._rates[i].shape, np.float32)
        return np.stack([roughness, magnitude, merge.support(len(neighbours)), merge.spread()])

    def _step_statistics(self, key: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """The DIS flow ``key``'s local gradient and magnitude, each blurred (made once: a flow between two frames
        serves the earlier one's statistics and the later one's)."""
        if key not in self._flow_statistics:
            flow = self._flows[key]
            squares = sum(np.square(cv2.Sobel(flow[..., c], cv2.CV_32F, dx, 1 - dx) / 8) for c in (0, 1) for dx in (0, 1))
            gradient = cv2.GaussianBlur(np.sqrt(squares), (0, 0), STATISTICS_SIGMA)
            magnitude = cv2.GaussianBlur(np.hypot(flow[..., 0], flow[..., 1]), (0, 0), STATISTICS_SIGMA)
            with self._lock:
                self._flow_statistics[key] = (gradient, magnitude)
        return self._flow_statistics[key]


#: What ``AlignedBox.mean(statistics=True)`` says of each pixel of a mean, in this order: how far the flow around the
#: frame is from one rigid motion (its spatial gradient, pixels of motion per pixel), how far it moves (pixels per
#: frame), the share of the window's frames the robust test kept, and how far the kept neighbours scatter around the
#: mean (log(1 + their variance over a rate's Bernoulli variance)). The pans whose default output gains from leaning
#: on the aligned mean are those that move as one piece with neighbours that agree (models/experiments/blend-hedging).
STATISTICS = ("flow gradient", "flow magnitude", "support", "spread")
#: Gaussian blur (pixels) of the flow statistics: a flow's gradient is noisy pixel by pixel.
STATISTICS_SIGMA = 1.5


class _RobustMerge:
    """Running robust mean onto a reference image: a warped neighbour counts per pixel by
    ``min(1, tau / z^2)``, z the difference of local means on the arcsine-sqrt scale over its standard error.
    With ``spread`` it also keeps the weighted squares, for the neighbours' scatter around the mean."""

    def __init__(self, reference: np.ndarray, trials: int, config: AlignedBoxConfig, spread: bool = False) -> None:
        self._size = (config.patch, config.patch)
        self._tau = config.tau
        self._trials = trials
        self._variance = 2.0 / (trials * config.patch * config.patch)
        self._angle = _arcsine_sqrt(self._local(reference))
        self._total, self._weights = reference.copy(), np.ones_like(reference)
        # float32 is enough: the squares' rounding (~1e-8) is far below a rate's Bernoulli variance (>= 1.6e-4 here)
        self._squares = np.square(reference) if spread else None

    def _local(self, a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, -1, self._size, normalize=True, borderType=cv2.BORDER_REPLICATE)

    def add(self, warped: np.ndarray, inside: np.ndarray) -> None:
        weight = _arcsine_sqrt(self._local(warped))  # in place from here: z^2, then its weight
        weight -= self._angle
        np.square(weight, out=weight)
        weight /= self._variance
        np.maximum(weight, 1e-12, out=weight)
        np.divide(self._tau, weight, out=weight)
        np.minimum(weight, 1.0, out=weight)
        weight *= inside  # no evidence from outside the frame
        self._weights += weight
        weight *= warped
        self._total += weight
        if self._squares is not None:
            self._squares += weight * warped

    def result(self) -> np.ndarray:
        return (self._total / self._weights).astype(np.float32)

    def support(self, frames: int) -> np.ndarray:
        """The merge's weights over the ``frames`` frames of its window: 1 where every one was kept."""
        return (self._weights / max(frames, 1)).astype(np.float32)

    def spread(self) -> np.ndarray:
        """log(1 + the weighted variance of the merged images over a rate's Bernoulli variance at the mean)."""
        mean = self._total / self._weights
        variance = np.maximum(self._squares / self._weights - np.square(mean), 0.0)
        bernoulli = np.maximum(mean * (1.0 - mean), 1.0 / self._trials) / self._trials
        return np.log1p(variance / bernoulli).astype(np.float32)


def aligned_window(i: int, radius: int, count: int | None, shift: bool = False) -> range:
    """The frames whose evidence frame ``i``'s aligned mean merges: ``i - radius .. i + radius``, cut at the
    clip's start and, where ``count`` (the clip's length) is known, its end; with ``shift`` a window that
    would be cut slides inwards instead, so the first and last frames keep 2 radius + 1 frames of evidence
    (all from their one side) where the clip is that long."""
    if radius < 0:
        raise ValueError(f"radius must be >= 0, got {radius}")
    lo = max(0, i - radius)
    if shift and count is not None:
        lo = min(lo, max(0, count - 1 - 2 * radius))
    hi = lo + 2 * radius if shift else i + radius
    return range(lo, hi + 1 if count is None else min(count, hi + 1))


def aligned_means(rates: np.ndarray, radius: int, config: AlignedBoxConfig | None = None, shift: bool = False,
                  sharp: np.ndarray | None = None,
                  statistics: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Every frame's aligned mean over its ``aligned_window`` in a clip: ``rates`` (F, H, W) -> (F, H, W)
    float32, or (F, 2, H, W) with the means of the ``sharp`` images (F, H, W) second (what the streaming
    engine computes for a clip); with ``statistics``, also their ``STATISTICS`` (F, 4, H, W)."""
    box = AlignedBox(config)
    count = len(rates)
    for k, rate in enumerate(rates):
        box.add(k, rate, None if sharp is None else sharp[k])
    results = [box.mean(i, aligned_window(i, radius, count, shift), statistics) for i in range(count)]
    if not statistics:
        return np.stack(results)
    return np.stack([mean for mean, _ in results]), np.stack([stats for _, stats in results])


def network_input(mean: np.ndarray, statistics: np.ndarray | None, scale: float) -> np.ndarray:
    """One frame's aligned mean (H, W) or means (A, H, W), as rates, in the form RMB-Net reads (``RmbNet.step``'s
    ``aligned``): sums (the rates x ``scale``, the trials behind a frame's rate), then the ``statistics`` (4, H, W)
    when given, float32."""
    sums = np.asarray(mean, np.float32) * np.float32(scale)
    if statistics is None:
        return sums
    return np.concatenate([sums.reshape(-1, *sums.shape[-2:]), np.asarray(statistics, np.float32)])

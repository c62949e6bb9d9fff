"""The aligned window means of ``rmbvideo.recon.aligned_box`` for many frames at once, in torch on the network's
device: the same DIS flows (OpenCV, on a pool of CPU threads, which DIS runs without the interpreter lock), then
the flows' inversion and composition, the warps and the robust merge batched over the frames with ``grid_sample``.

On a GPU the per-frame work of ``AlignedBox.mean`` (30 remaps and 20 merges, each a few small OpenCV and numpy
calls) is what a pool of CPU threads could not do as fast as the network makes frames: its Python steps take
turns on the interpreter lock. Here it is a few dozen batched kernels per run. Bilinear sampling is at the exact
positions, where OpenCV rounds them to 1/32 pixel, so the means agree with ``AlignedBox``'s to float and that
rounding (tested), not bit for bit. Their statistics (``aligned_box.STATISTICS``), when asked for, likewise: the
flows' Sobel gradients and Gaussian blurs as ``cv2``'s kernels with its reflected border.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from rmbvideo.recon.aligned_box import INVERSION_ITERATIONS, STATISTICS_SIGMA, AlignedBox, AlignedBoxConfig
from rmbvideo.recon.aligned_worker import BusyClock

Request = tuple[int, tuple[int, ...], bool]  # frame, its window, whether its statistics are wanted
# a mean (H,W) or means (A,H,W), with their statistics (4,H,W) where wanted: numpy, or tensors with ``on_device``
Means = np.ndarray | tuple[np.ndarray, np.ndarray] | torch.Tensor | tuple[torch.Tensor, torch.Tensor]


def network_input_on_device(mean: torch.Tensor, statistics: torch.Tensor | None, scale: float) -> torch.Tensor:
    """``aligned_box.network_input`` for means kept on the device (``on_device``): the sums, then the statistics."""
    sums = mean.float() * scale
    if statistics is None:
        return sums
    return torch.cat([sums.reshape(-1, *sums.shape[-2:]), statistics.float()])


def warp(image: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """``image`` (B,C,H,W) sampled at x + flow(x) (flow (B,2,H,W) in pixels, x then y), bilinear, the border
    replicated: ``cv2.remap`` with ``INTER_LINEAR`` and ``BORDER_REPLICATE`` at exact positions."""
    _, _, h, w = flow.shape
    xs = torch.arange(w, device=flow.device, dtype=flow.dtype)
    ys = torch.arange(h, device=flow.device, dtype=flow.dtype)
    gx = (xs + flow[:, 0]) * (2.0 / max(w - 1, 1)) - 1.0
    gy = (ys[:, None] + flow[:, 1]) * (2.0 / max(h - 1, 1)) - 1.0
    return F.grid_sample(image, torch.stack([gx, gy], dim=-1), mode="bilinear", padding_mode="border",
                         align_corners=True)


def _reflect_101(size: int, pad: int) -> list[int]:
    """Source index of each position -pad .. size - 1 + pad under OpenCV's default border (BORDER_REFLECT_101:
    ``gfedcb|abcdefgh|gfedcba``), repeated as often as a small image needs."""
    if size == 1:
        return [0] * (size + 2 * pad)
    period = 2 * (size - 1)
    out = []
    for p in range(-pad, size + pad):
        q = p % period
        out.append(q if q < size else period - q)
    return out


def _filter(images: torch.Tensor, rows: torch.Tensor, columns: torch.Tensor) -> torch.Tensor:
    """``images`` (B,1,H,W) filtered by the separable kernel ``rows`` x ``columns`` (1-D, odd lengths, correlation as
    cv2.filter2D/sepFilter2D) with OpenCV's default reflected border."""
    _, _, h, w = images.shape
    ky, kx = len(columns) // 2, len(rows) // 2
    padded = images[:, :, _reflect_101(h, ky)][..., _reflect_101(w, kx)]
    out = F.conv2d(padded, rows.reshape(1, 1, 1, -1))
    return F.conv2d(out, columns.reshape(1, 1, -1, 1))


def _flow_statistics(flows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per flow (U,2,H,W): its local gradient and its magnitude, each Gaussian-blurred, (U,1,H,W) each (what
    ``AlignedBox._statistics`` computes of one flow with OpenCV)."""
    dev, dtype = flows.device, flows.dtype
    gauss = torch.from_numpy(cv2.getGaussianKernel(int(round(STATISTICS_SIGMA * 8 + 1)) | 1, STATISTICS_SIGMA,
                                                   cv2.CV_32F)[:, 0]).to(dev, dtype)
    smooth = torch.tensor((1.0, 2.0, 1.0), device=dev, dtype=dtype)
    slope = torch.tensor((-1.0, 0.0, 1.0), device=dev, dtype=dtype)
    components = flows.reshape(-1, 1, *flows.shape[-2:])
    squares = sum(_filter(components, a, b).square() for a, b in ((slope, smooth), (smooth, slope))) / 64.0
    gradient = squares.reshape(flows.shape).sum(dim=1, keepdim=True).sqrt()
    magnitude = torch.hypot(flows[:, :1], flows[:, 1:])
    return _filter(gradient, gauss, gauss), _filter(magnitude, gauss, gauss)


def _inside(flow: torch.Tensor) -> torch.Tensor:
    """(B,1,H,W): where x + flow(x) falls inside the frame (the evidence a warped neighbour has)."""
    _, _, h, w = flow.shape
    x = torch.arange(w, device=flow.device, dtype=flow.dtype) + flow[:, 0]
    y = torch.arange(h, device=flow.device, dtype=flow.dtype)[:, None] + flow[:, 1]
    return ((x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)).unsqueeze(1).to(flow.dtype)


class _BatchedMerge:
    """``aligned_box._RobustMerge`` for a batch of references, one channel per kind (rate, sharp) with its own
    variance."""

    def __init__(self, reference: torch.Tensor, variance: torch.Tensor, config: AlignedBoxConfig,
                 spread: bool = False) -> None:
        self._patch, self._tau, self._variance = config.patch, config.tau, variance
        self._angle = self._arcsine_sqrt(self._local(reference))
        self.total, self.weights = reference.clone(), torch.ones_like(reference)
        # weighted squares of the first kind (the rate), for the kept neighbours' scatter (``_RobustMerge.spread``)
        self.squares = reference[:, :1].double().square() if spread else None

    def _local(self, a: torch.Tensor) -> torch.Tensor:
        pad = self._patch // 2
        return F.avg_pool2d(F.pad(a, (pad, self._patch - 1 - pad, pad, self._patch - 1 - pad), mode="replicate"),
                            self._patch, stride=1)

    @staticmethod
    def _arcsine_sqrt(p: torch.Tensor) -> torch.Tensor:
        return 2.0 * torch.asin(torch.sqrt(p.clamp(0.0, 1.0)))

    def add(self, rows: torch.Tensor, warped: torch.Tensor, inside: torch.Tensor) -> None:
        """Merge ``warped`` neighbours into the references ``rows`` (indices into the batch)."""
        z2 = (self._arcsine_sqrt(self._local(warped)) - self._angle[rows]).square() / self._variance
        weight = (self._tau / z2.clamp(min=1e-12)).clamp(max=1.0) * inside
        self.weights[rows] += weight
        self.total[rows] += weight * warped
        if self.squares is not None:
            self.squares[rows] += (weight[:, :1] * warped[:, :1]).double() * warped[:, :1].double()

    def result(self) -> torch.Tensor:
        return self.total / self.weights

    def support_spread(self, rows: Sequence[int], frames: torch.Tensor,
                       trials: int) -> tuple[torch.Tensor, torch.Tensor]:
        """For references ``rows``: the rate's support over their ``frames`` (R,) and the kept neighbours' spread,
        (R,1,H,W) each (``_RobustMerge.support`` and ``spread``)."""
        weights, total = self.weights[list(rows), :1], self.total[list(rows), :1]
        mean = total.double() / weights.double()
        variance = (self.squares[list(rows)] / weights.double() - mean.square()).clamp(min=0.0)  # type: ignore[index]
        bernoulli = (mean * (1.0 - mean)).clamp(min=1.0 / trials) / trials
        support = weights / frames.clamp(min=1).to(weights.dtype).reshape(-1, 1, 1, 1)
        return support, torch.log1p(variance / bernoulli).to(weights.dtype)


class BatchedAlignedMean:
    """One frame's aligned mean, queued: ``result()`` computes every queued mean at once the first time."""

    def __init__(self, worker: "BatchedAlignedWorker", request: Request) -> None:
        self._worker, self._request = worker, request

    def result(self) -> Means:
        return self._worker._result(self._request)


class BatchedAlignedWorker:
    """``AlignedWorker``'s interface (``add``, ``mean``, ``evict``, ``close``, ``busy_seconds``, ``waited_seconds``)
    with the means computed in batches on ``device``: each queued mean is made, with every other queued one,
    when the first of them is asked for. ``workers``: CPU threads for the DIS flows (at least 1). ``on_device``: the
    means and their statistics come as tensors on ``device`` (for the network there, which would otherwise copy
    them to the host and back), else as numpy arrays like ``AlignedBox``'s."""

    pooled = True
    concurrent = True

    def __init__(self, config: AlignedBoxConfig, device: torch.device | str, workers: int,
                 on_device: bool = False) -> None:
        self.config = config
        self.device = torch.device(device)
        self.on_device = on_device
        self._box = AlignedBox(config)  # the frames' flow images and the DIS flows between neighbours
        self._executor = ThreadPoolExecutor(max_workers=max(1, workers), thread_name_prefix="aligned-flow")
        self._cv_threads = cv2.getNumThreads()
        cv2.setNumThreads(1)  # the pool's threads are the parallelism (the count is process-wide, until close())
        self._busy = BusyClock()
        self._images: dict[int, torch.Tensor] = {}  # (C,H,W) on the device: rate, then sharp
        self._arrived: dict[int, np.ndarray] = {}  # the same in host memory, until the next batch copies them over
        self._added: dict[int, Future] = {}  # frames' flow images, made on the pool
        self._flows: dict[int, Future] = {}  # DIS flow from frame k - 1 to k, by k
        self._steps: dict[tuple[int, int], torch.Tensor] = {}  # one-step flows (2,H,W) on the device
        self._queued: list[Request] = []
        self._done: dict[Request, Means] = {}
        self.waited_seconds = 0.0

    def add(self, index: int, rate: np.ndarray, sharp: np.ndarray | None = None) -> None:
        """Keep frame ``index`` (its images on the device, cleaned as ``AlignedBox.add`` cleans them) and queue, on
        the pool, its flow image (``AlignedBox.add``) and the flow from frame ``index - 1`` to it."""
        kinds = [rate] + ([sharp] if sharp is not None else [])
        self._arrived[index] = np.stack([np.asarray(k, np.float32) for k in kinds])
        self._added[index] = self._executor.submit(self._timed, self._box.add, index, rate, sharp)
        if index - 1 in self._added:
            needs = (self._added[index - 1], self._added[index])
            self._flows[index] = self._executor.submit(self._timed, self._flow, index, needs)

    def _flow(self, index: int, needs: tuple[Future, Future]) -> np.ndarray:
        """DIS from frame ``index - 1`` to ``index`` once both are added (queued earlier, so a thread of the pool is
        on them or done: no deadlock)."""
        for need in needs:
            need.result()
        return self._box._step_flow(index - 1, index)

    @property
    def busy_seconds(self) -> float:
        return self._busy.seconds

    def _timed(self, func: Callable[..., Any], *args: Any) -> Any:
        return self._busy.timed(func, *args)

    def mean(self, i: int, neighbours: Sequence[int], statistics: bool = False) -> BatchedAlignedMean:
        """Queue frame ``i``'s aligned mean over ``neighbours`` (``AlignedBox.mean``, with its ``statistics``)."""
        request = (i, tuple(neighbours), statistics)
        self._queued.append(request)
        return BatchedAlignedMean(self, request)

    def evict(self, oldest_needed: int) -> None:
        """Forget frames (and flows) older than ``oldest_needed``; queued means are made first."""
        if self._queued:
            self._compute()
        for key in [k for k in self._flows if k - 1 < oldest_needed]:
            self._flows.pop(key).result()
        for key in [k for k in self._added if k < oldest_needed]:
            self._added.pop(key).result()
        for store in (self._images, self._arrived):
            for key in [k for k in store if k < oldest_needed]:
                del store[key]
        for key in [k for k in self._steps if min(k) < oldest_needed]:
            del self._steps[key]
        self._box.evict(oldest_needed)

    def close(self) -> None:
        """Let the flow threads end and give OpenCV its thread count back."""
        self._executor.shutdown(wait=False)
        if self._cv_threads is not None:
            cv2.setNumThreads(self._cv_threads)
            self._cv_threads = None

    def _result(self, request: Request) -> Means:
        if request not in self._done:
            self._compute()
        return self._done.pop(request)

    def _copy_arrived(self) -> None:
        """The frames added since the last batch onto the device, in one copy, cleaned as ``AlignedBox.add`` cleans
        them (NaN -> 0, clipped to [0, 1])."""
        if not self._arrived:
            return
        indices = sorted(self._arrived)
        images = torch.from_numpy(np.stack([self._arrived.pop(k) for k in indices])).to(self.device)
        for index, image in zip(indices, torch.nan_to_num(images, nan=0.0).clamp_(0.0, 1.0)):
            self._images[index] = image

    def _step(self, a: int, b: int) -> torch.Tensor:
        """The one-step flow from frame ``a`` to ``b = a +- 1`` on the device (``_prepare_steps`` made it)."""
        if (a, b) not in self._steps:
            self._prepare_steps([(a, b)])
        return self._steps[(a, b)]

    def _prepare_steps(self, pairs: Sequence[tuple[int, int]]) -> None:
        """The one-step flows ``pairs`` (a, b = a +- 1) not made yet, all at once: the forward ones copied to the
        device in one stack, the backward ones the forward flows inverted in one batch (B(x) = -F(x + B(x)), as
        ``AlignedBox``), where one by one they took a few dozen small launches and a copy each."""
        missing = sorted({pair for pair in pairs if pair not in self._steps})
        forward = sorted({(min(p), max(p)) for p in missing} - set(self._steps))
        if forward:
            flows = torch.from_numpy(np.stack([self._flows[b].result() for _, b in forward])).to(self.device)
            for pair, flow in zip(forward, flows.permute(0, 3, 1, 2)):
                self._steps[pair] = flow
        backward = [(a, b) for a, b in missing if b < a]
        if backward:
            ahead = torch.stack([self._steps[(b, a)] for a, b in backward])
            back = -ahead
            for _ in range(INVERSION_ITERATIONS):
                back = -warp(ahead, back)
            for pair, flow in zip(backward, back):
                self._steps[pair] = flow

    def _compute(self) -> None:
        """Every queued mean in one batch: per side, each step outwards composes the batch's flows one frame
        further (F(i, k + 1) = F(i, k) + F(k, k + 1) at x + F(i, k)) and merges the neighbours reached."""
        requests, self._queued = self._queued, []
        waited = time.perf_counter()
        for i, neighbours, _ in requests:  # the flows a request reads, made on the pool
            for k in range(min((i, *neighbours)) + 1, max((i, *neighbours)) + 1):
                if k in self._flows:
                    self._flows[k].result()
        began = time.perf_counter()
        cfg = self.config
        self._copy_arrived()
        # how many frames each request reaches on each side; every one-step flow that takes made at once (the
        # statistics' flows from i - 1 to i and from i to i + 1 among them)
        reach = {d: [max([(j - i) * d for j in n if (j - i) * d > 0], default=0) for i, n, _ in requests]
                 for d in (-1, 1)}
        self._prepare_steps([(i + d * (s - 1), i + d * s) for d, far in reach.items()
                             for (i, _, _), f in zip(requests, far) for s in range(1, f + 1)])
        reference = torch.stack([self._images[i] for i, _, _ in requests])
        variance = torch.tensor([2.0 / (t * cfg.patch * cfg.patch) for t in (cfg.trials, cfg.sharp_trials)],
                                dtype=reference.dtype, device=self.device)[: reference.shape[1]].reshape(1, -1, 1, 1)
        wanted = [r for r, request in enumerate(requests) if request[2]]
        merge = _BatchedMerge(reference, variance, cfg, spread=bool(wanted))
        for d, far in reach.items():
            flow: torch.Tensor | None = None
            for s in range(1, max(far, default=0) + 1):
                rows = [r for r, f in enumerate(far) if f >= s]
                steps = torch.stack([self._step(requests[r][0] + d * (s - 1), requests[r][0] + d * s) for r in rows])
                if flow is None:
                    flow = steps
                else:
                    still = set(rows)  # the requests reaching this far: a subset of the previous step's
                    flow = flow[[k for k, r in enumerate(previous) if r in still]]
                    flow = flow + warp(steps, flow)
                previous = rows
                reached = [k for k, r in enumerate(rows) if requests[r][0] + d * s in requests[r][1]]
                if reached:
                    picked = flow[reached]
                    images = torch.stack([self._images[requests[rows[k]][0] + d * s] for k in reached])
                    merge.add(torch.tensor([rows[k] for k in reached], device=self.device), warp(images, picked),
                              _inside(picked))
        means = merge.result() if self.on_device else merge.result().cpu().numpy()
        statistics = dict(zip(wanted, self._statistics([requests[r] for r in wanted], merge, wanted)))
        for r, (request, mean) in enumerate(zip(requests, means)):
            mean = mean[0] if mean.shape[0] == 1 else mean
            self._done[request] = (mean, statistics[r]) if r in statistics else mean
        ended = time.perf_counter()
        self._busy.add(ended - began)  # the batch's own time is the stage's work, and the caller's wait like the flows'
        self.waited_seconds += ended - waited

    def _statistics(self, requests: Sequence[Request], merge: _BatchedMerge,
                    rows: Sequence[int]) -> list[np.ndarray] | list[torch.Tensor]:
        """``STATISTICS`` (4,H,W) of each request's mean (rows ``rows`` of ``merge``), as ``AlignedBox._statistics``:
        the flow gradient (the larger of the DIS flows from frame i to the next and from the previous one to i, where
        the window has those frames), the magnitude of the first of them, the merge's support and spread."""
        if not requests:
            return []
        h, w = self._images[requests[0][0]].shape[-2:]
        steps = [[k for k in (i + 1, i) if {k - 1, k} <= {i, *n}] for i, n, _ in requests]  # flows k-1 -> k
        used = sorted({k for ks in steps for k in ks})
        gradient = magnitude = None
        if used:
            gradient, magnitude = _flow_statistics(torch.stack([self._step(k - 1, k) for k in used]))
        place = {k: u for u, k in enumerate(used)}
        zero = torch.zeros((1, h, w), device=self.device, dtype=torch.float32)
        frames = torch.tensor([len(n) for _, n, _ in requests], device=self.device)
        support, spread = merge.support_spread(rows, frames, self.config.trials)
        out = []
        for r, ks in enumerate(steps):
            rough = torch.stack([gradient[place[k]] for k in ks]).amax(dim=0) if ks else zero  # type: ignore[index]
            moved = magnitude[place[ks[0]]] if ks else zero  # type: ignore[index]
            out.append(torch.cat([rough, moved, support[r], spread[r]]).float())
        return out if self.on_device else [o.cpu().numpy() for o in out]

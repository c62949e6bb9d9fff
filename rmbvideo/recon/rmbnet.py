"""Streaming RMB-Net reconstruction: preliminary frames in, linear HDR ``Frame``s out.

Each preliminary frame is encoded once and kept in a ring buffer of the last 2w+1 encodings; XBA
pair logits (which depend on a pair of frames only) are cached while both frames are in the
buffer; the ConvLSTM state is carried from frame to frame, so the output is the same however the
input is chunked, and equal to ``RmbNet.forward_sequence`` over the whole capture (with the same ``prime``).
Output frame i needs frames up to i+w, so output lags input by w frames until ``flush``. At the edges of the
capture the window's positions past the edge are left out (``window_valid``); the first frame's state is primed
by running the network backwards over the w frames after it (``RmbNet.step_backward``), so the first frames
read their future through the state as later frames read their past (the first output waits for 2w + 1 frames).

A model with ``config.aligned`` also gets each reference frame's motion-compensated window mean
(``rmbvideo.recon.aligned_box``: consecutive DIS flows, computed once per frame and kept while needed).

With ``align`` other than "none", the window's frames are warped to the reference frame's time
with optical flow before encoding (paper Fig. 6); encodings then depend on the reference, so each
window is encoded afresh and only the flow fields are cached.
"""

from __future__ import annotations

import copy
import logging
import time
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import nullcontext
from pathlib import Path
from typing import ClassVar, Protocol

import numpy as np
import torch
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

from rmbvideo.chunks import Frame, RmbChunk
from rmbvideo.errors import InputError
from rmbvideo.net.activations import InplaceReLU
from rmbvideo.net.blend import BIN_TRIALS
from rmbvideo.net.decoder import DecoderState
from rmbvideo.net.encoder import Encoder
from rmbvideo.net.model import (
    EncodedFrame,
    PairCache,
    RmbNet,
    evict_pairs,
    priming_frames,
    window_indices,
    window_reach,
    window_valid,
)
from rmbvideo.recon.aligned_box import AlignedBoxConfig, aligned_window, network_input
from rmbvideo.recon.aligned_batched import BatchedAlignedMean, BatchedAlignedWorker, Means, network_input_on_device
from rmbvideo.recon.aligned_worker import AlignedMean, AlignedWorker, Ready
from rmbvideo.recon.clip_edges import ClipEdges
from rmbvideo.recon.precision import PRECISIONS, uses_bf16
from rmbvideo.recon.prelim import MultiUpsampler, PreliminaryFrames, select_centre
from rmbvideo.recon.recurrent_state import state_from_tensors, state_tensors
from rmbvideo.sensor.conventions import CONVENTIONS, RESPONSES
from rmbvideo.threads import available_cores, compute_threads, default_threads, work_beside

log = logging.getLogger(__name__)

ALIGN_METHODS = ("none", "dis", "farneback", "tvl1")
# Frames encoded per call: bounds the full-resolution activations whatever the chunk size.
ENCODE_BATCH = 8
#: Frames between the snapshots of the recurrent state kept for a resumable run (``keep_state_snapshots``), and how
#: many are kept: enough to reach back over a chunk's frames, which the network makes before the sink writes them
SNAPSHOT_EVERY = 16
SNAPSHOTS_KEPT = 16


class PrelimLike(Protocol):
    """What the engine reads from a preliminary frame (``rmbvideo.recon.prelim.PrelimFrame``); ``i_c``
    (central sums) only for a model with centre windows."""

    index: int
    time_s: float
    i_s: np.ndarray
    i_m: np.ndarray
    i_c: np.ndarray | None


class EdgeModelMismatch(ValueError):
    """An edge model whose window (w) or readouts per frame (N) are not its model's."""


def inference_copy(model: RmbNet, bf16: bool = False) -> RmbNet:
    """An eval-mode copy of ``model`` for fast inference: each BatchNorm folded into the conv before it
    (same function, one pass less over the features), NHWC (channels-last) weights, which oneDNN runs about
    twice as fast on CPU, and ReLUs that take bf16 features through their bit pattern (``relu_``, the same
    values). ``bf16``: for bf16 autocast, the convolutions' weights are stored in bf16 once instead of being cast
    at every call (the same values; the encoders' first convolutions, which autocast leaves in fp32, keep theirs).
    ``model`` itself is left unchanged (it may be training)."""
    fast = copy.deepcopy(model).eval()
    for module in fast.modules():
        if isinstance(module, nn.Sequential):
            layers = list(module)
            for k in range(len(layers) - 1):
                if isinstance(layers[k], nn.Conv2d) and isinstance(layers[k + 1], nn.BatchNorm2d):
                    module[k] = fuse_conv_bn_eval(layers[k], layers[k + 1])
                    module[k + 1] = nn.Identity()
            for k, layer in enumerate(layers):
                if isinstance(layer, nn.ReLU):
                    module[k] = InplaceReLU()
    fast = fast.to(memory_format=torch.channels_last)
    if bf16:
        fp32 = {id(encoder.blocks[0][0]) for encoder in fast.modules() if isinstance(encoder, Encoder)}
        for conv in fast.modules():
            if isinstance(conv, nn.Conv2d) and id(conv) not in fp32:
                conv.to(torch.bfloat16)
    return fast


def all_finite(t: torch.Tensor) -> bool:
    """Whether every value of ``t`` is finite: its sum is unless one is not or the sum overflows (then each value is
    checked). One pass where ``torch.isfinite(t).all()`` makes three, on every frame."""
    return bool(torch.isfinite(t.sum())) or bool(torch.isfinite(t).all())


def resolve_device(device: str | torch.device) -> torch.device:
    """"auto" -> CUDA when available, else CPU; an explicit "cuda" without a GPU is an error."""
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    resolved = torch.device(device)
    if resolved.type == "cuda" and not torch.cuda.is_available():
        raise InputError("--device cuda: no CUDA device is available (use --device cpu or auto)")
    return resolved


#: frames whose aligned means a concurrent worker may make ahead of the network (bounds the memory they hold)
ALIGNED_AHEAD = 2
#: output frames per batched pass on a GPU at most (``frame_batch``'s default there, where a pass of 128 made 200x125
#: frames 1.1-1.3x as fast as one of 32 on an H200; on a CPU batching loses), and the binned pixels one pass
#: may hold (its activations and pair logits peak at about 1.2 kB a pixel in fp32, measured on the CPU: 5 GB)
GPU_FRAME_BATCH = 128
GPU_BATCH_PIXELS = 1 << 22


def default_frame_batch(device: torch.device, size: tuple[int, int] | None = None) -> int:
    """Output frames per batched pass by default: on a GPU ``GPU_FRAME_BATCH``, fewer for frames of ``size`` (H, W)
    so a pass holds at most ``GPU_BATCH_PIXELS``; 1 (frame by frame) elsewhere."""
    if device.type != "cuda":
        return 1
    pixels = 1 if size is None else max(1, size[0] * size[1])
    return max(1, min(GPU_FRAME_BATCH, GPU_BATCH_PIXELS // pixels))


def preliminary_beside_by_default(device: torch.device) -> bool:
    """Whether the preliminary frames are made in a thread of their own, a chunk ahead of the network: on a GPU, where
    the host's work on one thread is what limits the frame rate (the same frames)."""
    return device.type == "cuda"


def aligned_workers(device: torch.device, threads: int | None) -> int:
    """Threads for the aligned window means: with the network on a GPU, ``threads`` when given, else every core but
    one (the network's feeder), since the network outruns one core's optical flow; on a CPU one beside the network
    when a core is free for it (``rmbvideo.threads.work_beside``), else none (inline)."""
    if device.type == "cuda":
        return threads if threads is not None else max(1, available_cores() - 1)
    return 1 if work_beside(threads) else 0


def aligned_worker_for(device: torch.device, config: AlignedBoxConfig,
                       workers: int) -> AlignedWorker | BatchedAlignedWorker:
    """What makes the aligned window means: on a GPU, batches of them there (``BatchedAlignedWorker``: the DIS flows on
    ``workers`` CPU threads, the warps and merges batched on the GPU, which a pool of CPU threads could not keep up
    with); elsewhere OpenCV's inline or on ``workers`` threads (``AlignedWorker``; bit for bit the same)."""
    if device.type == "cuda":
        return BatchedAlignedWorker(config, device, workers, on_device=True)
    return AlignedWorker(config, workers)


class RmbNetReconstructor:
    """``push(chunk or prelim frames) -> list[Frame]``, ``flush() -> list[Frame]``.

    ``precision``: "auto" uses bf16 autocast on CPUs with AVX512-BF16/AMX, where it is measured faster
    (``rmbvideo.recon.precision``), and fp32 elsewhere, CUDA included; "bf16"/"fp32" force it.
    ``threads``: the threads it may use (restored afterwards); None follows the project's thread policy
    (``rmbvideo.threads``: one thread for the network on a busy or small machine). A model that reads the
    aligned window means computes them in a thread of their own beside the network, which gets the rest,
    when two or more are given or, under the policy, when a second core is idle
    (``rmbvideo.recon.aligned_worker``; the frames are the same bit for bit).
    ``frame_batch``: output frames made per batched pass (``RmbNet.step_run``: everything but the ConvLSTM
    recurrences on the whole run of frames at once; the same frames to float rounding); None: up to 128 on a GPU
    (``default_frame_batch``; frames wait until a whole run is ready, so passes are that long whatever the chunks,
    and a CUDA graph is captured once), 1 on a CPU, where
    batching loses. With the network on a GPU, the aligned means are made there in batches, their optical flows
    on ``threads`` CPU threads (default: every core but one; ``aligned_worker_for``).
    ``prime``: frames the first frame's state is primed over, backwards in time (default w; 0: a fresh state).
    ``cuda_graphs``: on a GPU, batched passes replay their ConvLSTM recurrences as CUDA graphs (the same frames).
    ``preliminary_beside``: the preliminary frames of a pushed chunk are made in a thread of their own while the network
    works on the chunk before (the same frames, a chunk later); None: on a GPU (``preliminary_beside_by_default``).
    ``response``: how a camera's rates are read back as light (``RESPONSES``; "emission-model" only for streams
    rmbvideo simulated in the physical convention). ``edge_model``: an RMB-Net (same w and N) that makes the clip's
    first and last w frames, each edge as a clip of its own of 2w frames (``rmbvideo.recon.clip_edges``); the other
    frames are ``model``'s, unchanged. ``n`` is the readouts per preliminary frame when RmbChunks are pushed (default: the model's N)
    and ``upsampler`` the band upsampler they go through (default: flow-free interpolation; see
    ``rmbvideo.recon.flow.FlowUpsampler``).
    """

    input_kind: ClassVar[str] = "rmb"

    def __init__(
        self,
        model: RmbNet,
        device: str | torch.device = "auto",
        align: str = "none",
        precision: str = "auto",
        n: int | None = None,
        upsampler: MultiUpsampler | None = None,
        threads: int | None = None,
        convention: str = "physical",
        frame_batch: int | None = None,
        prime: int | None = None,
        cuda_graphs: bool = True,
        response: str = "closed-form",
        preliminary_beside: bool | None = None,
        edge_model: RmbNet | None = None,
    ) -> None:
        if threads is not None and threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        if align not in ALIGN_METHODS:
            raise ValueError(f"align must be one of {ALIGN_METHODS}, got {align!r}")
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        if convention not in CONVENTIONS:
            raise ValueError(f"convention must be one of {CONVENTIONS}, got {convention!r}")
        if response not in RESPONSES:
            raise ValueError(f"response must be one of {RESPONSES}, got {response!r}")
        if frame_batch is not None and frame_batch < 1:
            raise ValueError(f"frame_batch must be >= 1, got {frame_batch}")
        if prime is not None and prime < 0:
            raise ValueError(f"prime must be >= 0, got {prime}")
        if edge_model is not None and (edge_model.config.w, edge_model.config.n) != (model.config.w, model.config.n):
            raise EdgeModelMismatch(f"the edge model's w = {edge_model.config.w}, N = {edge_model.config.n} differ "
                                    f"from those (w = {model.config.w}, N = {model.config.n})")
        self._convention = float(CONVENTIONS.index(convention))
        self.device = resolve_device(device)
        self.model = model.to(self.device).eval()
        self._autocast = uses_bf16(precision, self.device)
        self._net = inference_copy(self.model, bf16=self._autocast)
        self._net.tabulated_response = response == "emission-model"
        self._threads = threads if threads is not None else default_threads()
        self._frame_batch = frame_batch
        self._graphed = cuda_graphs and self.device.type == "cuda"
        workers = aligned_workers(self.device, threads)
        self.align = align
        self.n = model.config.n if n is None else n
        self._w = model.config.w
        self._slide = model.config.edge_slide
        if self._slide and align != "none":  # warped windows are encoded by position: a slid frame would pass as own
            raise ValueError(f"a model whose edge windows slide inwards (edge_slide) reads unwarped windows, not "
                             f"align={align!r}")
        self._prime = self._w if prime is None else prime
        self._kept_means: dict[int, Ready] = {}
        self._primed = False
        self._upsampler = upsampler
        self._prelim: PreliminaryFrames | None = None
        if preliminary_beside is None:
            preliminary_beside = preliminary_beside_by_default(self.device)
        self._ahead = (ThreadPoolExecutor(max_workers=1, thread_name_prefix="preliminary") if preliminary_beside
                       else None)
        self._pending: Future | None = None  # the last pushed chunk's preliminary frames, made in ``_ahead``
        self._raw: dict[int, PrelimLike] = {}
        self._encoded: dict[int, EncodedFrame] = {}
        self._pair_cache: PairCache = {}
        self._flow_cache: dict = {}
        self._aligned_box = (aligned_worker_for(self.device, AlignedBoxConfig.for_frames(
                                 self.n, self._net.config.aligned_centre), workers)
                             if self._net.config.aligned else None)
        self._received = 0
        self._next_out = 0
        self._state = None
        #: frames whose index is a multiple of it are seen (``EveryKthFrame``: a multiple of the model's step), and so is
        #: the frame before each (the raw gate reads its change); the others are made for the recurrent state alone
        #: (``RmbNet.advance``: no head, no aligned mean) and come out without an image
        self.emit_every = 1
        self._snapshots: deque[tuple[int, dict[str, torch.Tensor]]] | None = None
        self._restore: tuple[int, DecoderState] | None = None
        self._size: tuple[int, int] | None = None
        self.nonfinite_frames = 0
        self._edge_model = None if edge_model is None else edge_model.to(self.device).eval()
        self._edges = None if edge_model is None else ClipEdges(self._edge_run, self._w)
        #: seconds spent making preliminary frames, in the network (with its caches and state) and, for a
        #: model that reads it, on the aligned window mean (optical flow and warps; not in "network")
        self.stage_seconds = {"preliminary frames": 0.0, "network": 0.0}
        if self._aligned_box is not None:
            self.stage_seconds["aligned mean"] = 0.0

    @classmethod
    def from_file(
        cls, path: str | Path, device: str = "auto", input_mode: str | None = None, edges: str = "auto", **options
    ) -> "RmbNetReconstructor":
        """Load a safetensors model (see ``rmbvideo.net.weights``) and wrap it; with ``edges`` "auto", its edge model
        beside it (``edge_model_path``) makes the clip's edge frames where there is one."""
        from rmbvideo.errors import ModelError
        from rmbvideo.net.weights import load_model
        from rmbvideo.shipped import EDGE_MODEL_KINDS, edge_model_path

        if edges not in EDGE_MODEL_KINDS:
            raise ValueError(f"edges must be one of {EDGE_MODEL_KINDS}, got {edges!r}")
        model, _card = load_model(path, expect_input_mode=input_mode, device=resolve_device(device))
        edge_path = edge_model_path(path) if edges == "auto" else None
        if edge_path is None:
            return cls(model, device=device, **options)
        edge_model, _card = load_model(edge_path, expect_input_mode=model.config.input_mode,
                                       device=resolve_device(device))
        try:
            return cls(model, device=device, edge_model=edge_model, **options)
        except EdgeModelMismatch as exc:
            raise ModelError(f"{edge_path}: {exc} of {Path(path).name}") from None

    def push(self, item: RmbChunk | PrelimLike | Iterable[PrelimLike]) -> list[Frame]:
        """Consume an RMB chunk or preliminary frames; return the frames that became complete."""
        if isinstance(item, RmbChunk):
            frames = self._preliminary_frames(lambda prelim: prelim.push(item), final=False)
        else:
            frames = self._preliminary_frames(None, final=False)
            frames += [item] if hasattr(item, "i_s") else list(item)  # type: ignore[list-item, arg-type]
        return self._consume(frames, final=False)

    def flush(self) -> list[Frame]:
        """End of capture: emit the last w frames (their windows end at the last frame)."""
        return self._consume(self._preliminary_frames(lambda prelim: prelim.flush(), final=True), final=True)

    def keep_state_snapshots(self) -> None:
        """Keep a copy of the recurrent state every ``SNAPSHOT_EVERY`` frames (the last ``SNAPSHOTS_KEPT``), for a
        resumable run to save (``recurrent_state``)."""
        self._snapshots = deque(maxlen=SNAPSHOTS_KEPT)

    def recurrent_state(self, at_most: int) -> tuple[int, dict[str, torch.Tensor]] | None:
        """The newest kept snapshot of the recurrent state after a frame of index ``at_most`` or less: that frame's
        index and the state's tensors by name, on the CPU; None before the first."""
        for index, tensors in reversed(self._snapshots or ()):
            if index <= at_most:
                return index, tensors
        return None

    def resume_from(self, after: int, tensors: dict[str, torch.Tensor]) -> None:
        """Make the frame after frame ``after`` from this recurrent state (``recurrent_state``'s) instead of the one
        built over the frames before it: a resumed run's warm-up refills the windows, and this sets back the state's
        long memory, which a warm-up rebuilds only to about 1 % of the light on a few pixels."""
        self._restore = (after, state_from_tensors(tensors, self.device))

    def _edge_run(self, frames: list[PrelimLike]) -> list[Frame]:
        """The edge model's frames of ``frames`` run as a clip of their own (``ClipEdges``), with this run's settings."""
        run = RmbNetReconstructor(
            self._edge_model, device=self.device, align=self.align, precision="bf16" if self._autocast else "fp32",
            n=self.n, threads=self._threads, convention=CONVENTIONS[int(self._convention)], frame_batch=1,
            prime=self._prime, cuda_graphs=False,
            response="emission-model" if self._net.tabulated_response else "closed-form", preliminary_beside=False)
        made = run.push(frames) + run.flush()
        self.nonfinite_frames += run.nonfinite_frames
        return made

    def _preliminary_frames(self, task: Callable[[PreliminaryFrames], list[PrelimLike]] | None,
                            final: bool) -> list[PrelimLike]:
        """The preliminary frames ready now: with a thread ahead, those of the step queued before, and ``task`` (a step
        of ``PreliminaryFrames``) queued in its place, made now at ``final``; without one, ``task``'s made now."""
        done = [] if self._pending is None else self._pending.result()
        self._pending = None
        if task is None:
            return done
        if final:
            if self._ahead is not None:
                self._ahead.shutdown(wait=False)
            return done + (self._timed_preliminary(task) if self._prelim is not None else [])
        if self._ahead is None:
            return done + self._timed_preliminary(task)
        self._pending = self._ahead.submit(self._timed_preliminary, task)
        return done

    def _timed_preliminary(self, task: Callable[[PreliminaryFrames], list[PrelimLike]]) -> list[PrelimLike]:
        began = time.perf_counter()
        try:
            return task(self._preliminary())
        finally:
            self.stage_seconds["preliminary frames"] += time.perf_counter() - began

    def _preliminary(self) -> PreliminaryFrames:
        if self._prelim is None:
            self._prelim = PreliminaryFrames(n=self.n, upsampler=self._upsampler)
        return self._prelim

    @property
    def aligned_beside(self) -> bool:
        """Whether the aligned window means run in a thread of their own beside the network."""
        return self._aligned_box is not None and self._aligned_box.concurrent

    @property
    def light_reading(self) -> tuple[float, bool]:
        """How this run reads a camera's rates as light: the convention (0 a reset-to-zero pixel, 1 the rate
        convention) and whether by the emission model's table (``response``); a stage beside it reads the same way."""
        return self._convention, self._net.tabulated_response

    @property
    def network(self) -> RmbNet:
        """The inference copy of the model that actually runs (BatchNorm folded, channels-last)."""
        return self._net

    def _precision(self):
        if self._autocast:
            return torch.autocast(self.device.type, dtype=torch.bfloat16)
        return nullcontext()

    def _consume(self, frames: list[PrelimLike], final: bool) -> list[Frame]:
        began = time.perf_counter()
        box = self._aligned_box
        waited_before = box.waited_seconds if box is not None else 0.0
        try:
            return self._network(frames, final)
        finally:
            if self.device.type == "cuda":
                torch.cuda.synchronize(self.device)
            waited = box.waited_seconds - waited_before if box is not None else 0.0
            self.stage_seconds["network"] += time.perf_counter() - began - waited
            if box is not None:
                self.stage_seconds["aligned mean"] = box.busy_seconds
                if final:
                    box.close()

    def _threads_for(self) -> tuple[int, int]:
        """(torch, OpenCV) threads: with the aligned means in a thread of their own, that thread is
        OpenCV's one and the network gets the others (at least one); a pool sets OpenCV's count itself."""
        if self._aligned_box is not None and self._aligned_box.pooled:
            return self._threads, 1
        if self.aligned_beside:
            return max(1, self._threads - 1), 1
        return self._threads, self._threads

    def _network(self, frames: list[PrelimLike], final: bool) -> list[Frame]:
        torch_threads, cv_threads = self._threads_for()
        with compute_threads(torch_threads, cv_threads), torch.inference_mode(), self._precision():
            self._accept(frames)
            if self._edges is not None:
                self._edges.see(frames)
            count = self._received if final else None
            if not self._primed and (final or self._ready(self._prime)):
                self._prime_state(count)
            ready = []
            while self._primed and self._next_out + len(ready) < self._received and (
                    final or self._ready(self._next_out + len(ready))):
                ready.append(self._next_out + len(ready))
            runs = self._runs(ready, count)
            batched = self.align == "none" and self.frame_batch > 1
            if batched and not final and runs and runs[-1][0] >= self._w and len(runs[-1]) < self.frame_batch:
                runs.pop()  # a short batched run waits for the next chunk, so passes are whole whatever the chunks
            ready = [i for run in runs for i in run]
            # a concurrent worker makes the next frames' aligned means while the network makes this one; a pool
            # of workers, all of the frames ready now
            ahead = (len(ready) if self._aligned_box is not None and self._aligned_box.pooled
                     else ALIGNED_AHEAD if self.aligned_beside else 0)
            means: dict[int, AlignedMean | None] = {}
            # the frames made whole: every frame of a batched pass, else those seen (``emit_every``)
            whole = {i for run in runs for i in run if len(run) > 1 or self._seen(i)}
            out: list[Frame] = []
            for run in runs:
                self._restore_before(run[0])
                for j in range(run[0], min(run[-1] + ahead + 1, ready[-1] + 1)):  # ready is consecutive
                    if j not in means and j in whole:
                        means[j] = self._kept_means.pop(j, None) or self._aligned(j, count)
                if len(run) > 1:
                    out += self._emit_run(run, count, [means.pop(i) for i in run])
                elif run[0] in whole:
                    out.append(self._emit(run[0], count, means.pop(run[0])))
                else:
                    out.append(self._advance(run[0], count))
                self._next_out = run[-1] + 1
                self._evict(self._next_out)
            return out if self._edges is None else self._edges.edge_frames(out, final)

    def _restore_before(self, i: int) -> None:
        """Set the state ``resume_from`` gave before frame ``i`` when ``i`` is the frame after its own."""
        if self._restore is not None and int(self._raw[i].index) == self._restore[0] + 1:
            self._state, self._restore = self._restore[1], None

    def _made(self, index: int, state: DecoderState | None) -> None:
        """The state after the frame of ``index`` (the last of a pass); snapshotted when one is due."""
        self._state = state
        if self._snapshots is None or state is None:
            return
        last = self._snapshots[-1][0] if self._snapshots else -1
        if index // SNAPSHOT_EVERY > last // SNAPSHOT_EVERY:
            self._snapshots.append((index, state_tensors(state)))

    @property
    def frame_batch(self) -> int:
        """Output frames per batched pass: as given, else the device's default for the frames seen so far."""
        if self._frame_batch is not None:
            return self._frame_batch
        return default_frame_batch(self.device, self._size)

    def _runs(self, ready: list[int], count: int | None) -> list[list[int]]:
        """``ready`` in runs of up to ``frame_batch`` frames whose windows are whole (a window cut by the clip's edge
        is a run of its own, made by ``step``). With ``align`` each window is warped to its own reference and encoded
        afresh, so every frame is a run of its own."""
        limit = self.frame_batch if self.align == "none" else 1
        runs: list[list[int]] = []
        restart = None if self._restore is None else self._restore[0] + 1
        for i in ready:
            whole = i >= self._w and (count is None or i + self._w < count)
            if (whole and runs and len(runs[-1]) < limit and runs[-1][-1] == i - 1 and runs[-1][-1] >= self._w
                    and self._raw[i].index != restart):
                runs[-1].append(i)
            else:
                runs.append([i])
        return runs

    def _prime_state(self, count: int | None) -> None:
        """The state frame 0 starts from: the network run backwards over frames ``prime`` .. 1
        (``RmbNet.step_backward``), so the first frames, which have no past, read their future through the state as
        later frames read their past. Encodings and aligned means do not depend on the direction of time; the means
        are kept for the frames' own turn."""
        self._primed, state = True, None
        for i in priming_frames(self._prime, count):
            mean = self._aligned(i, count)
            if mean is not None:
                self._kept_means[i] = mean = Ready(mean.result())
            state = self._net.step_backward(self._window(i, count), state, self._valid(i, count),
                                            self._convention, self._aligned_input(mean))
        self._state = state

    def _ready(self, i: int) -> bool:
        """Frame ``i`` can be made before the capture ends: its window and, for a model that reads it,
        its aligned mean's window (whatever the clip's length) have all been received."""
        reach = window_reach(i, self._w, None, self._slide).stop - 1
        if self._aligned_box is None:
            return reach < self._received
        config = self._net.config
        last = aligned_window(i, config.aligned_half_width, None, config.aligned_shift)[-1]
        return max(reach, last) < self._received

    def _accept(self, frames: list[PrelimLike]) -> None:
        if not frames:
            return
        for frame in frames:
            size = tuple(np.shape(frame.i_s))
            if self._size is None:
                self._size = size  # type: ignore[assignment]
            if size != self._size or np.shape(frame.i_m) != size:
                raise InputError(f"preliminary frame {frame.index}: shape {size} differs from {self._size}")
        ids = list(range(self._received, self._received + len(frames)))
        for fid, frame in zip(ids, frames):
            self._raw[fid] = frame
            if self._aligned_box is not None:
                self._aligned_box.add(fid, np.asarray(frame.i_m, np.float32) / (BIN_TRIALS * self.n), self._sharp(frame))
        self._received += len(frames)
        if self.align == "none":
            for a in range(0, len(frames), ENCODE_BATCH):
                batch = frames[a : a + ENCODE_BATCH]
                i_s = torch.from_numpy(np.stack([np.asarray(f.i_s, np.float32) for f in batch])).to(self.device)
                i_m = torch.from_numpy(np.stack([np.asarray(f.i_m, np.float32) for f in batch])).to(self.device)
                for encoded in self._net.encode(i_s, i_m, ids[a : a + ENCODE_BATCH], self._centre(batch)):
                    self._encoded[encoded.index] = encoded

    def _sharp(self, frame: PrelimLike) -> np.ndarray | None:
        """The rate of the frame's central ``aligned_centre`` readouts, for a model that reads their aligned mean."""
        k = self._net.config.aligned_centre
        if not k:
            return None
        try:
            return select_centre(frame.i_c, self.n, (k,))[0].astype(np.float32) / (BIN_TRIALS * k)
        except ValueError as exc:
            raise InputError(f"preliminary frame {frame.index}: {exc}") from None

    def _valid(self, i: int, count: int | None) -> list[bool]:
        """Which positions of frame ``i``'s window hold real frames (``window_valid``, slid where the model's are)."""
        return window_valid(i, self._w, count, self._slide)

    def _window(self, i: int, count: int | None) -> list[EncodedFrame]:
        ids = window_indices(i, self._w, count, self._slide)
        if self.align == "none":
            return [self._encoded[j] for j in ids]
        from rmbvideo.recon.flow import align

        raw = [self._raw[j] for j in ids]
        aligned = align(raw, self._w, self.align, cache=self._flow_cache, keys=ids)
        i_s = torch.from_numpy(np.stack([a[0] for a in aligned])).to(self.device)
        i_m = torch.from_numpy(np.stack([a[1] for a in aligned])).to(self.device)
        # positions, not frame ids: aligned encodings are valid for this window only; only the reference's
        # central sums are read, and the reference is not warped
        return self._net.encode(i_s, i_m, range(len(ids)), self._centre(raw))

    def _centre(self, frames: list[PrelimLike]) -> torch.Tensor | None:
        """The frames' central sums over the model's centre windows, (F,C,H,W), or None if it has none."""
        windows = self._net.config.centre_windows
        if not windows:
            return None
        try:
            sums = np.stack([select_centre(f.i_c, self.n, windows) for f in frames])
        except ValueError as exc:
            raise InputError(f"preliminary frame {frames[0].index}: {exc}") from None
        return torch.from_numpy(sums).to(self.device)

    def _aligned(self, i: int, count: int | None) -> AlignedMean | BatchedAlignedMean | None:
        """Frame ``i``'s aligned window mean(s), queued, for a model that reads them."""
        if self._aligned_box is None:
            return None
        config = self._net.config
        return self._aligned_box.mean(i, aligned_window(i, config.aligned_half_width, count, config.aligned_shift),
                                      config.aligned_evidence)

    def _aligned_inputs(self, values: list[Means]) -> torch.Tensor:
        """Aligned means' results ((H,W) or (2,H,W) rates; with their statistics, a pair) as the network reads them
        (``aligned_box.network_input``: sums, then the statistics), (F,...) on the device; means already there
        (``BatchedAlignedWorker.on_device``) are stacked there."""
        scale = BIN_TRIALS * self.n
        pairs = [value if isinstance(value, tuple) else (value, None) for value in values]
        if isinstance(pairs[0][0], torch.Tensor):
            return torch.stack([network_input_on_device(m, s, scale) for m, s in pairs])  # type: ignore[arg-type]
        return torch.from_numpy(np.stack([network_input(m, s, scale) for m, s in pairs])).to(self.device)

    def _aligned_input(self, mean: AlignedMean | Ready | None) -> torch.Tensor | None:
        """A queued aligned mean as the network's input (``_aligned_inputs``), (1,...) on the device."""
        if mean is None:
            return None
        return self._aligned_inputs([mean.result()])

    def _seen(self, i: int) -> bool:
        """Whether frame ``i`` is made whole (``emit_every``): a frame kept, or the one before it."""
        index = int(self._raw[i].index)
        return index % self.emit_every in (0, self.emit_every - 1)

    def _advance(self, i: int, count: int | None) -> Frame:
        """Frame ``i`` for the recurrent state alone (``RmbNet.advance``): its frame comes out without an image."""
        cache = self._pair_cache if self.align == "none" else None
        self._kept_means.pop(i, None)  # a priming step's aligned mean, kept for a frame that needs none
        state = self._net.advance(self._window(i, count), self._state, cache, valid=self._valid(i, count))
        if not all(all_finite(t) for cell in state for t in cell):
            self.nonfinite_frames += 1
            log.warning("RMB-Net's recurrent state became NaN/Inf at frame %d; reset", i)
            state = None
        source = self._raw[i]
        self._made(int(source.index), state)
        return Frame(index=int(source.index), time_s=float(source.time_s), image=None)

    def _emit(self, i: int, count: int | None, mean: AlignedMean | Ready | None) -> Frame:
        """Frame ``i`` from its window and its queued aligned mean (the network's input made by ``_aligned_input``)."""
        cache = self._pair_cache if self.align == "none" else None
        t, state = self._net.step(self._window(i, count), self._state, cache, valid=self._valid(i, count),
                                  convention=self._convention, aligned=self._aligned_input(mean))
        if not all_finite(t):
            self.nonfinite_frames += 1
            log.warning("RMB-Net produced NaN/Inf in frame %d; replaced by 0 and reset the recurrent state", i)
            t = torch.nan_to_num(t, nan=0.0, posinf=0.0, neginf=0.0)
            state = None
        source = self._raw[i]
        self._made(int(source.index), state)
        image = self._net.to_linear(t)[0, 0].float().cpu().numpy()
        return Frame(index=int(source.index), time_s=float(source.time_s), image=image)

    def _emit_run(self, run: list[int], count: int | None, means: list[AlignedMean | None]) -> list[Frame]:
        """Frames ``run`` (consecutive, their windows whole) in one batched pass (``RmbNet.step_run``); a run with
        a NaN/Inf frame is made again frame by frame, so the state is reset right after the bad frame."""
        rates = None if means[0] is None else [m.result() for m in means]  # type: ignore[union-attr]
        aligned = None if rates is None else self._aligned_inputs(rates)
        frames = [self._encoded[j] for j in range(run[0] - self._w, run[-1] + self._w + 1)]
        try:
            t, state = self._net.step_run(frames, self._state, convention=self._convention, aligned=aligned,
                                          graphed=self._graphed)
        except RuntimeError as error:
            if not self._graphed:
                raise
            log.warning("CUDA graphs failed (%s); RMB-Net runs without them", str(error).splitlines()[0])
            self._graphed = False
            t, state = self._net.step_run(frames, self._state, convention=self._convention, aligned=aligned)
        if not all_finite(t):
            return [self._emit(i, count, None if rates is None else Ready(rates[k])) for k, i in enumerate(run)]
        self._made(int(self._raw[run[-1]].index), state)
        images = self._net.to_linear(t)[:, 0].float().cpu().numpy()
        return [Frame(index=int(self._raw[i].index), time_s=float(self._raw[i].time_s), image=images[k])
                for k, i in enumerate(run)]

    def _evict(self, next_out: int) -> None:
        """Forget what no frame from ``next_out`` on needs: the network looks w frames back (2w when its edge windows
        slide inwards: the clip's end is not known yet), the aligned mean its radius (twice that when its window
        slides inwards)."""
        oldest_needed = next_out - self._w * (2 if self._slide else 1)
        for store in (self._encoded, self._raw):
            for fid in [k for k in store if k < oldest_needed]:
                del store[fid]
        evict_pairs(self._pair_cache, oldest_needed)
        for key in [k for k in self._flow_cache if min(k[:2]) < oldest_needed]:
            del self._flow_cache[key]
        if self._aligned_box is not None:
            config = self._net.config
            self._aligned_box.evict(next_out - config.aligned_half_width * (2 if config.aligned_shift else 1))


def make_rmbnet(
    model: str | Path | None = None,
    device: str = "auto",
    align: str = "none",
    precision: str = "auto",
    input_mode: str | None = None,
    upsampling: str = "interp",
    threads: int | None = None,
    w: int | None = None,
    convention: str = "physical",
    readout: str | None = None,
    frame_batch: int | None = None,
    prime: int | None = None,
    cuda_graphs: bool = True,
    response: str = "closed-form",
    preliminary_beside: bool | None = None,
    edges: str = "auto",
) -> RmbNetReconstructor:
    """Pipeline factory for method "rmbnet": ``model`` is a .safetensors path; ``upsampling`` is
    "interp" (flow-free band interpolation) or a flow method ("dis", "farneback", "tvl1").
    Without ``model`` the shipped weights for ``input_mode`` (default "binned") are used, the one
    with window half-width ``w`` when it is given; a ``model`` whose ``w`` differs is refused.
    ``convention``: the sensor convention that made the stream (``CONVENTIONS``: "physical" for a
    camera, "spikezoo" for streams simulated in the rate convention); models without the
    convention input ignore it. ``readout``: without ``model``, the shipped model trained on that
    readout design (the default model's when None). ``frame_batch``: output frames per batched pass, ``prime``
    the frames the first state is primed over, ``cuda_graphs``, ``response`` and ``preliminary_beside``
    (``RmbNetReconstructor``); ``edges``: "auto" has the model's edge model (``edge_model_path``) make a clip's first
    and last w frames where there is one, "off" the model itself."""
    from rmbvideo.errors import ModelError
    from rmbvideo.net.weights import default_model_path, shipped_model_with_window
    from rmbvideo.recon.flow import FlowUpsampler

    if model is None:
        mode = input_mode or "binned"
        model = default_model_path(mode, readout) if w is None else shipped_model_with_window(mode, w)
    upsampler = None if upsampling == "interp" else FlowUpsampler(method=upsampling)
    recon = RmbNetReconstructor.from_file(
        model, device=device, input_mode=input_mode, align=align, precision=precision, upsampler=upsampler,
        threads=threads, convention=convention, frame_batch=frame_batch, prime=prime, cuda_graphs=cuda_graphs,
        response=response, preliminary_beside=preliminary_beside, edges=edges,
    )
    if w is not None and recon.network.config.w != w:
        raise ModelError(f"{model}: the model's window half-width is w = {recon.network.config.w}, not {w}")
    return recon


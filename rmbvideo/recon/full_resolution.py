"""Full camera resolution from a real 1-bit capture: a binned method's frames plus the raw stream's detail.

The binned path (2x2x2 binning, RMB readout, RMB-Net) gives the tonal range and low noise at half the
camera's resolution; the raw 1-bit planes still hold the detail inside each 2x2 block. ``FullResolution``
runs both on one stream: the binned method on the binned readouts, TFP over ``detail_window`` raw planes
on the raw ones, and per frame

    full = to_block_levels(upsample(binned) * detail, binned),   detail = 1 + g * (tfp / block_mean(tfp) - 1)

where ``block_mean`` is the 2x2 block mean spread back to its pixels and ``g`` a per-block Wiener gain
(0..1): the share of the TFP variance inside the block that is not Bernoulli noise of ``detail_window``
samples. A block whose raw counts cannot tell its pixels apart keeps the binned value (no invented
texture); ``to_block_levels`` rescales each 2x2 block of the product so that its mean is the binned pixel
(bilinear upsampling alone blurs the levels of neighbouring blocks into each other), so averaging the
full frame over 2x2 blocks gives the binned frame back. This is joint (guided) upsampling with a
noise-aware gain.

With a learned detail stage (``rmbvideo.net.detail.DetailNet``, ``detail=``) the factor is predicted
instead, from TFP over each of the stage's windows (and TFI when the stage reads it). With the binned method on a
GPU those rates are made there too, in a thread beside it (``rmbvideo.recon.device_rates``, the same frames).

With RMB-Net as the binned method and a raw-interval gate (``rmbvideo.net.raw_gate``, ``raw_gate=``), each binned
frame is first mixed per pixel with TFI of the raw planes (read as light and 2x2-averaged) where the gate trusts it:
single intervals resolve dim fine texture of slow scenes that the binned counts blur. The detail then shapes that
frame, so the full output still averages back to it over 2x2 blocks; where the gate took a TFI candidate's level, a
share (``CANDIDATE_DETAIL``) of the detail inside each block is that candidate's own pixels instead
(``with_candidate_detail``). With ``output="binned"`` the gated frames
themselves are the output, at the binned size (``--resolution binned`` on a 1-bit capture): the raw stream's evidence
without the detail stage's cost.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, ClassVar

import numpy as np

from rmbvideo.chunks import Frame, SpikeChunk
from rmbvideo.image_pool import ImagePool
from rmbvideo.io.dat import DECODED_POOL_BYTES, PackedChunk
from rmbvideo.recon.classical import BlockScans, Tfi, Tfp, push_by_block
from rmbvideo.sensor.binning import StreamBinner
from rmbvideo.sensor.readout import RmbReadout
from rmbvideo.threads import compute_threads, default_threads, work_beside

log = logging.getLogger(__name__)

DEFAULT_DETAIL_WINDOW = 20  # raw planes: the frame interval, so moving detail is not smeared
#: How the detail inside each 2x2 block is found: "learned" (the shipped detail stage), "classical"
#: (the Wiener-gated TFP ratio), "auto" (learned when the detail stage is installed).
DETAIL_KINDS = ("auto", "learned", "classical")
#: Whether RMB-Net's binned frames of a 1-bit capture are mixed with raw TFI: "auto" (with the shipped raw-interval
#: gate when installed) or "off".
RAW_GATE_KINDS = ("auto", "off")
#: raw planes a chunk is pushed in on a CPU (``max_push_planes``): the finishing thread then starts after a chunk's first
#: piece, not after the whole chunk (on two cores a 100-frame 400x250 capture 12.0 -> 9.8 s, 500 frames 43.5 either way)
CPU_PUSH_PLANES = 256
#: What ``FullResolution`` emits: "full" (the camera's size) or "binned" (the gated binned frames, half each side).
OUTPUTS = ("full", "binned")
#: Where the gate takes a TFI candidate's level for a block, the share of the detail inside it that comes from the
#: candidate's own raw pixels rather than the detail stage's shape (``with_candidate_detail``). Chosen on the
#: development sets at full resolution among 0, 1/4, 1/2, 3/4, 1 (``models/experiments/raw-tfi-gate/full_shares.py``):
#: the synthetic sequences 29.75 -> 29.80 dB, the real-video streams 30.53 -> 31.03.
CANDIDATE_DETAIL = 0.5
#: full-resolution pixels one call of the detail stage holds on a GPU (its activations: under 1 kB a pixel)
DETAIL_BATCH_PIXELS = 1 << 22


@dataclass(frozen=True)
class DetailSettings:
    """How much raw detail is added: TFP window (raw planes) and a floor on the noise estimate."""

    window: int = DEFAULT_DETAIL_WINDOW
    min_noise_spikes: float = 0.5  # Bernoulli variance floor, in spikes, for blocks with rates near 0 or 1


def detail_stage(kind: str = "auto") -> Any:
    """The learned detail stage for ``kind`` (see ``DETAIL_KINDS``), or None for the classical detail."""
    from rmbvideo.errors import OptionError
    from rmbvideo.net.weights import default_detail_path, load_detail_model

    if kind not in DETAIL_KINDS:
        raise OptionError(f"--detail: must be one of {', '.join(DETAIL_KINDS)}, not {kind!r}")
    path = default_detail_path()
    if kind == "classical" or (kind == "auto" and not path.is_file()):
        return None
    return load_detail_model(path)[0]


#: Models already warned about by ``raw_gate_stage`` in this process.
_WARNED_MODELS: set[str] = set()


def raw_gate_stage(kind: str = "auto", model: Any = None) -> Any:
    """The shipped raw-interval gate for ``kind`` (see ``RAW_GATE_KINDS``), or None ("off", or none installed). With
    ``model`` (an RMB-Net weight file) a warning says so when the gate was fitted to another network's frames."""
    from pathlib import Path

    from rmbvideo.errors import OptionError
    from rmbvideo.net.weights import default_raw_gate_path, load_raw_gate

    if kind not in RAW_GATE_KINDS:
        raise OptionError(f"--raw-gate: must be one of {', '.join(RAW_GATE_KINDS)}, not {kind!r}")
    path = default_raw_gate_path()
    if kind == "off" or not path.is_file():
        return None
    gate, card = load_raw_gate(path)
    fitted_to = card.data.get("model")
    if model is not None and fitted_to and Path(model).name != fitted_to and str(model) not in _WARNED_MODELS:
        _WARNED_MODELS.add(str(model))  # once a process: an evaluation builds the stage for every sequence
        log.warning("%s: the raw gate was fitted to %s's frames, not this model's; its mix may not suit them "
                    "(--raw-gate off keeps the model's frames; rmbvideo train-raw-gate --model fits one)", model,
                    fitted_to)
    return gate


def detail_inference_copy(detail: Any, precision: str = "auto", device: Any = "cpu") -> Any:
    """An eval-mode copy of a detail stage for fast inference on ``device``: channels-last convolutions (1.7x faster
    on this project's CPU), their weights in bf16 where the project's precision policy runs bf16
    (``rmbvideo.recon.precision``: 2.8x faster than channels-last fp32 on this project's CPU), and ReLUs that take
    bf16 through its bit pattern (``InplaceReLU``, the same values). ``detail`` itself is left unchanged."""
    import copy

    import torch

    from rmbvideo.recon.precision import uses_bf16

    from rmbvideo.net.activations import InplaceReLU

    device = torch.device(device)
    fast = copy.deepcopy(detail).eval().to(device, memory_format=torch.channels_last)
    for k, layer in enumerate(fast.body):
        if isinstance(layer, torch.nn.ReLU):
            fast.body[k] = InplaceReLU()
    if uses_bf16(precision, device):
        for layer in fast.body:
            if isinstance(layer, torch.nn.Conv2d):
                layer.to(torch.bfloat16)
    return fast


def detail_batch(device: Any, full_size: tuple[int, int]) -> int:
    """Frames the detail stage makes per call: 1 on a CPU (batching gains nothing there), on a GPU as many as keep a
    call at ``DETAIL_BATCH_PIXELS`` full-resolution pixels (``full_size`` (H, W)): one call instead of a few dozen
    small kernels a frame."""
    if getattr(device, "type", "cpu") != "cuda":
        return 1
    return max(1, DETAIL_BATCH_PIXELS // max(1, full_size[0] * full_size[1]))


def rates_beside_by_default(device: Any) -> bool:
    """Whether the raw stream's rates get a thread of their own beside the binned method: when that method runs on
    a GPU and leaves the CPU idle (on a CPU its cores are the network's and the aligned means')."""
    return getattr(device, "type", "cpu") == "cuda"


#: the most threads the network may have for the full-resolution stages to run beside it by default: measured on two
#: cores (1.35-1.52x the frames a second with 1 or 2); with more, each side's OpenMP team would want the cores the other
#: holds, which was not measured, so they stay inline and use them all
MOST_THREADS_BESIDE = 2


def finish_beside_by_default(device: Any, threads: int | None) -> bool:
    """Whether each chunk's raw rates, gate and detail stage run in a thread of their own, a chunk behind the binned
    method: on a CPU, when a core is free for them beside the network (``rmbvideo.threads.work_beside``) and the
    network runs on at most ``MOST_THREADS_BESIDE`` threads (on a GPU the network leaves the CPU to them anyway)."""
    if getattr(device, "type", "cpu") == "cuda":
        return False
    return (threads if threads is not None else default_threads()) <= MOST_THREADS_BESIDE and work_beside(threads)


def rates_on_device_by_default(device: Any) -> bool:
    """Whether the raw stream's rates (TFP, TFI) are made on the binned method's device: on a GPU, where one CPU core
    would cap the frame rate (``rmbvideo.recon.device_rates``; the same frames)."""
    return getattr(device, "type", "cpu") == "cuda"


def spread(image: np.ndarray) -> np.ndarray:
    """Each pixel of ``image`` (h, w) copied to the 2x2 block it covers: (2h, 2w)."""
    return np.repeat(np.repeat(image, 2, axis=0), 2, axis=1)


def block_mean(image: np.ndarray) -> np.ndarray:
    """2x2 block means of ``image`` (even sides), spread back to every pixel of the block."""
    h, w = image.shape
    return spread(image.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3)))


def relative_detail(rates: np.ndarray, window: int, settings: DetailSettings = DetailSettings()) -> np.ndarray:
    """Per-pixel detail factor (mean 1 over each 2x2 block) from TFP ``rates`` over ``window`` raw planes.

    Wiener gain per block: (variance within the block - expected Bernoulli noise) / variance within the
    block, clipped to 0..1; blocks with no spikes get factor 1."""
    rates = rates.astype(np.float64)
    mean = block_mean(rates)
    spread = block_mean((rates - mean) ** 2)
    noise = np.maximum(mean * (1.0 - mean), settings.min_noise_spikes / window) / window
    gain = np.clip(1.0 - noise / np.maximum(spread, 1e-12), 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(mean > 0, rates / mean, 1.0)
    return (1.0 + gain * (ratio - 1.0)).astype(np.float32)


def with_candidate_detail(full: np.ndarray, gated: np.ndarray, shares: np.ndarray, candidates: np.ndarray,
                          strength: float = CANDIDATE_DETAIL) -> np.ndarray:
    """``full`` (2h, 2w), whose 2x2 blocks average to the ``gated`` frame (h, w), with ``strength`` of each TFI
    candidate's detail inside a block in place of ``full``'s own shape there, by the gate's ``shares`` (K, h, w) of the
    candidates (K, 2h, 2w; light per raw pixel): full + strength * sum_k s_k * (c_k - block_mean(c_k) * full / gated).
    The block means stay the gated frame's, and the result is >= 0 (each candidate's part of the block level is
    reshaped, never more)."""
    if strength == 0 or not len(shares):
        return full
    level = spread(gated.astype(np.float32))
    shape = np.where(level > 0, full / np.maximum(level, 1e-30), 1.0).astype(np.float32)
    own = sum(spread(share) * (candidate - block_mean(candidate) * shape)
              for share, candidate in zip(shares, candidates))
    return np.maximum(full + np.float32(strength) * own, 0.0).astype(np.float32)


def upsample(image: np.ndarray) -> np.ndarray:
    """Bilinear 2x upsampling with pixel centres aligned (each binned pixel covers a 2x2 block)."""
    import cv2  # on first use: listing the commands does not load OpenCV

    h, w = image.shape
    return cv2.resize(image.astype(np.float32), (2 * w, 2 * h), interpolation=cv2.INTER_LINEAR)


def to_block_levels(image: np.ndarray, binned: np.ndarray) -> np.ndarray:
    """``image`` (2h, 2w), >= 0, rescaled per 2x2 block so that every block's mean is its ``binned`` pixel:
    the numpy twin of ``rmbvideo.net.detail.to_block_levels``."""
    level = spread(binned.astype(np.float32))
    return (image * (level / np.maximum(block_mean(image), 1e-30))).astype(np.float32)


class FullResolution:
    """A method on the binned stream, made full resolution with the raw stream's detail (see module); with
    ``output="binned"``, RMB-Net's binned frames mixed with the raw intervals by the gate, at their own size."""

    input_kind: ClassVar[str] = "spikes"
    #: Stored bits come undecoded: TFP sums them bit-sliced; binning and TFI get them decoded once.
    accepts_packed: ClassVar[bool] = True

    def __init__(self, binned: Any, readout: RmbReadout | None, step: int = 20,
                 settings: DetailSettings = DetailSettings(), detail: Any = None, threads: int | None = None,
                 precision: str = "auto", rates_beside: bool | None = None,
                 rates_on_device: bool | None = None, raw_gate: Any = None,
                 finish_beside: bool | None = None, output: str = "full",
                 candidate_detail: float = CANDIDATE_DETAIL, keep_every: int = 1) -> None:
        if binned.input_kind != "rmb":
            raise ValueError(f"full resolution wraps a method on the binned stream, not {type(binned).__name__}")
        if output not in OUTPUTS:
            raise ValueError(f"output must be one of {OUTPUTS}, not {output!r}")
        if not 0.0 <= candidate_detail <= 1.0:
            raise ValueError(f"candidate_detail must lie in 0..1, not {candidate_detail}")
        if keep_every < 1:
            raise ValueError(f"keep_every must be >= 1, not {keep_every}")
        # frames whose index is not a multiple of it are dropped by the caller (``EveryKthFrame``: RMB-Net at a multiple
        # of its step), so neither gated nor shaped here: they are made for the recurrent state, not to be seen
        self.keep_every = keep_every
        self.binned = binned
        self.readout = readout
        self.settings = settings
        self.output = output
        full = output == "full"
        # the binned method's device (a GPU for RMB-Net there), so frames do not wait for the CPU
        self.device = getattr(binned, "device", None)
        detail = detail if full else None
        self.detail = None if detail is None else detail_inference_copy(detail, precision, self.device or "cpu")
        # the gate mixes RMB-Net's frames only (it was fitted to them): how RMB-Net reads light, or None
        reading = getattr(binned, "light_reading", None)
        self.raw_gate = None if raw_gate is None or reading is None else raw_gate.eval()
        if not full and self.raw_gate is None:
            raise ValueError("binned output is RMB-Net's frames mixed by a raw-interval gate: give RMB-Net and a gate")
        self._reading = reading
        self.candidate_detail = candidate_detail
        self._previous: np.ndarray | None = None  # the last binned frame, before the gate (its change is a feature)
        # resolved once, as the RMB-Net engine does: the policy, not the load of each frame's moment
        self.threads = threads if threads is not None else default_threads()
        self._binner = StreamBinner()
        self._decoded = ImagePool(DECODED_POOL_BYTES)  # decoded chunks, reused once released
        # the rates the detail reads: none for binned output
        windows = () if not full else detail.config.windows if detail is not None else (settings.window,)
        # TFI for the detail stage and for the gate: one search over the longer reach gives both (``Tfi``'s
        # ``shorter``), except a gate's TFI over central planes (``tfi_window``, ``long_window``): a search of its own,
        # which reads the others' scan of each block (``BlockScans``)
        detail_reach = detail.config.interval_reach if detail is not None else 0
        gate = self.raw_gate.config if self.raw_gate is not None else None
        gate_windows = (gate.tfi_window, gate.long_window)[:gate.candidates] if gate is not None else ()
        shared_reach = gate.tfi_reach if gate is not None and 0 in gate_windows else 0
        reaches = sorted({r for r in (detail_reach, shared_reach) if r})
        tfi = dict(max_reach=reaches[-1], shorter=tuple(reaches[:-1])) if reaches else None
        # TFI over central planes (the gate's candidates, the detail stage's interval windows): one search each
        # (reach, window). The detail stage reads a window the gate also reads from the gate's search, at its longer
        # reach (the same planes but for pixels darker than a spike in 40 planes; on the development sets level or
        # up to 0.1 dB better than its own search at ``interval_reach``, which costs 5 ms a 400x250 frame)
        gate_searches = [(gate.tfi_reach, w) for w in gate_windows if w]
        detail_searches = [(gate.tfi_reach if (gate.tfi_reach, w) in gate_searches else detail_reach, w)
                           if gate is not None else (detail_reach, w)
                           for w in (detail.config.interval_windows if detail is not None else ())]
        searches = list(dict.fromkeys(gate_searches + detail_searches))
        windowed = [dict(max_reach=reach, window=w) for reach, w in searches]
        # where each reader's planes are among a frame's raw rates (the windows' TFP, TFI at each reach, the searches)
        first_search = len(windows) + len(reaches)
        self._detail_planes = [*range(len(windows)), *([len(windows) + reaches.index(detail_reach)]
                                                       if detail_reach else []),
                               *(first_search + searches.index(s) for s in detail_searches)]
        self._gate_planes = [len(windows) + reaches.index(shared_reach) if not w
                             else first_search + searches.index((gate.tfi_reach, w)) for w in gate_windows]
        # on a GPU the raw stream's rates are made there too (``rmbvideo.recon.device_rates``: the same frames)
        if rates_on_device is None:
            rates_on_device = rates_on_device_by_default(self.device)
        self._rates_device = None
        if rates_on_device:
            import torch

            from rmbvideo.recon.device_rates import DeviceTfi, DeviceTfp

            self._rates_device = torch.device(self.device if self.device is not None else "cpu")
            # the detail stage runs on the same device: its inputs stay there (no copy to host memory and back)
            on_device = self.detail is not None
            self._rates: list = [DeviceTfp(window=w, step=step, on_device=on_device) for w in windows]
            self._rates += [DeviceTfi(step=step, on_device=on_device, **tfi)] if tfi else []
            self._rates += [DeviceTfi(step=step, on_device=on_device, **options) for options in windowed]
        else:
            # the TFI searches (the detail stage's, the gate's windows) scan each block of planes once between them
            self._scans = BlockScans()
            self._rates = [Tfp(window=w, step=step) for w in windows]
            self._rates += [Tfi(step=step, scans=self._scans, **tfi)] if tfi else []
            self._rates += [Tfi(step=step, scans=self._scans, **options) for options in windowed]
        # the TFI searches among them, fed block by block (``push_by_block``) so that they share each block's scan
        self._searches = [rate for rate in self._rates if isinstance(rate, Tfi)]
        # whether a raw-rate method on the CPU reads decoded planes (TFI; TFP sums the stored bits)
        self._rates_decode = self._rates_device is None and not all(getattr(r, "accepts_packed", False)
                                                                    for r in self._rates)
        self._coarse: dict[int, Frame] = {}
        self._fine: list[dict[int, Frame]] = [{} for _ in self._rates]
        self.stage_seconds = getattr(binned, "stage_seconds", {})
        # the raw stream's rates (TFP, TFI: a few ms a frame of one core at 400x250) in a thread of their own while
        # the binned method works on the same chunk
        if rates_beside is None:
            rates_beside = rates_beside_by_default(self.device)
        # or, with the binned method on a CPU, the rates and everything after them (gate, detail stage) in a thread of
        # their own, a chunk behind it: on two cores about 1.5x the frames a second (``_finish``; the same frames)
        if finish_beside is None:
            finish_beside = finish_beside_by_default(self.device, threads)
        self._behind = ThreadPoolExecutor(max_workers=1, thread_name_prefix="finishing") if finish_beside else None
        self._finishing: Future | None = None  # the last pushed chunk's frames, finished in ``_behind``
        self._beside = (ThreadPoolExecutor(max_workers=1, thread_name_prefix="raw-rates")
                        if rates_beside and not finish_beside else None)
        # read by ``iter_frames``: on a CPU each chunk arrives in pieces (the frames are the same to float rounding)
        self.max_push_planes = CPU_PUSH_PLANES if getattr(self.device, "type", "cpu") != "cuda" else None
        self.stage_seconds.setdefault("raw rates", 0.0)

    def push(self, chunk: SpikeChunk | PackedChunk) -> list[Frame]:
        stored = isinstance(chunk, PackedChunk) and chunk.geometry.byte_aligned
        # decoded only where a method needs the planes (the binning of other geometries, TFI on the CPU): with the
        # finishing thread, stored bits are decoded there
        decode = isinstance(chunk, PackedChunk) and (not stored or (self._rates_decode and self._behind is None))
        spikes = chunk.unpack(self._decoded) if decode else chunk
        if self._behind is not None:
            coarse = self._binned_frames(chunk, spikes, stored)
            done = [] if self._finishing is None else self._finishing.result()
            self._finishing = self._behind.submit(self._finish, chunk, spikes, coarse)
            return done
        rates = self._start(lambda: self._push_rates(chunk, spikes))
        self._keep(self._coarse, self._binned_frames(chunk, spikes, stored))
        for store, frames in zip(self._fine, rates.result()):
            self._keep(store, frames)
        return self._combine()

    def flush(self) -> list[Frame]:
        done = [] if self._finishing is None else self._finishing.result()
        self._finishing = None
        rates = self._start(lambda: [rate.flush() for rate in self._rates])
        self._keep(self._coarse, self.binned.flush())
        for store, frames in zip(self._fine, rates.result()):
            self._keep(store, frames)
        for executor in (self._beside, self._behind):
            if executor is not None:
                executor.shutdown(wait=False)
        frames = done + self._combine()
        self._coarse.clear()
        self._previous = None
        for store in self._fine:
            store.clear()
        return frames

    def _binned_frames(self, chunk: SpikeChunk | PackedChunk, spikes: SpikeChunk | PackedChunk,
                       stored: bool) -> list[Frame]:
        """The binned method's frames from ``chunk``: binned from its stored bits (``stored``) or decoded ``spikes``."""
        if stored:
            g = chunk.geometry
            binned = self._binner.push_stored(chunk.data, chunk.start, chunk.rate_hz, g.height, g.image_width, g.flip)
        else:
            binned = self._binner.push(spikes)
        if binned is None:
            return []
        if self.readout is not None:
            binned = self.readout.apply(binned)
        return self.binned.push(binned)

    def _finish(self, chunk: SpikeChunk | PackedChunk, spikes: SpikeChunk | PackedChunk,
                coarse: list[Frame]) -> list[Frame]:
        """In the finishing thread: ``chunk``'s raw rates (its planes decoded here if TFI needs them), then every frame
        both sides have made, gated and shaped. Each chunk's step ends before the next is queued, and only this thread
        touches the stores, the gate's previous frame and the TFI scans: the frames are the inline ones."""
        if self._rates_decode and isinstance(spikes, PackedChunk):
            spikes = spikes.unpack(self._decoded)
        for store, frames in zip(self._fine, self._push_rates(chunk, spikes)):
            self._keep(store, frames)
        self._keep(self._coarse, coarse)
        return self._combine()

    def _push_rates(self, chunk: SpikeChunk | PackedChunk, spikes: SpikeChunk | PackedChunk) -> list[list[Frame]]:
        """Each raw-rate method's frames from ``chunk``: on the device from its planes sent there once, else from the
        stored bits (TFP) or the decoded planes."""
        began = time.perf_counter()
        try:
            return self._rates_of(chunk, spikes)
        finally:
            self.stage_seconds["raw rates"] += time.perf_counter() - began

    def _rates_of(self, chunk: SpikeChunk | PackedChunk, spikes: SpikeChunk | PackedChunk) -> list[list[Frame]]:
        if self._rates_device is not None:
            from rmbvideo.recon.device_rates import to_device

            planes = to_device(chunk, self._rates_device)
            return [rate.push(planes) for rate in self._rates]
        # (without TFI the planes may stay undecoded: nothing to push block by block)
        by_block = iter(push_by_block(self._searches, spikes) if self._searches else ())
        frames = [next(by_block) if rate in self._searches else
                  rate.push(chunk if getattr(rate, "accepts_packed", False) else spikes) for rate in self._rates]
        self._scans.clear()
        return frames

    def _start(self, task: Callable[[], list[list[Frame]]]) -> Future:
        """``task`` (the raw-rate methods' step, in order): in their thread when they have one (their state is theirs
        alone, and each chunk's task ends before the next is queued: the frames are the same), else now."""
        if self._beside is None:
            done: Future = Future()
            done.set_result(task())
            return done
        return self._beside.submit(task)

    @staticmethod
    def _keep(store: dict[int, Frame], frames: list[Frame]) -> None:
        store.update((frame.index, frame) for frame in frames)

    def _combine(self) -> list[Frame]:
        ready = sorted(set(self._coarse).intersection(*self._fine))
        coarse = [self._coarse.pop(index) for index in ready]
        fine = [[store.pop(index).image for store in self._fine] for index in ready]
        # the binned frame before each, before the gate (whose change the gate reads; None at a clip's start)
        previous = [self._previous, *(c.image for c in coarse[:-1])]
        if coarse:
            self._previous = coarse[-1].image
        # the frames kept (a binned method that knows it makes the others for its state alone, without an image)
        kept = [k for k, index in enumerate(ready) if index % self.keep_every == 0]
        if len(kept) < len(ready):
            ready, coarse, fine, previous = ([items[k] for k in kept] for items in (ready, coarse, fine, previous))
        # per frame: the TFP windows, then TFI at each reach, shortest first
        rates = [_planes([image[..., : 2 * c.image.shape[0], : 2 * c.image.shape[1]] for image in images])
                 for images, c in zip(fine, coarse)]
        mixes: list[tuple[np.ndarray, np.ndarray]] = []  # per gated frame: the candidates' shares and own pixels
        if self.raw_gate is not None:
            began = time.perf_counter()
            gated, mixes = self._gated([c.image for c in coarse], previous,
                                       [[r[k] for k in self._gate_planes] for r in rates])
            coarse = [Frame(index=c.index, time_s=c.time_s, image=image) for c, image in zip(coarse, gated)]
            self.stage_seconds["raw gate"] = self.stage_seconds.get("raw gate", 0.0) + time.perf_counter() - began
        if self.output == "binned":
            return coarse
        rates = [[r[k] for k in self._detail_planes] for r in rates]
        began = time.perf_counter()
        if self.detail is not None:
            images = self._learned([c.image for c in coarse], rates)
        else:
            images = [to_block_levels(upsample(c.image) * relative_detail(r[0], self.settings.window, self.settings),
                                      c.image) for c, r in zip(coarse, rates)]
        images = [with_candidate_detail(image, c.image, *mix, self.candidate_detail)
                  for image, c, mix in zip(images, coarse, mixes)] if mixes else images
        self.stage_seconds["detail"] = self.stage_seconds.get("detail", 0.0) + time.perf_counter() - began
        # Frames one side made and the other never will (edges of the clip) are dropped at flush.
        return [Frame(index=index, time_s=c.time_s, image=image) for index, c, image in zip(ready, coarse, images)]

    def _gated(self, coarse: list[np.ndarray], previous: list[np.ndarray | None], tfis: list[list[Any]]
               ) -> tuple[list[np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
        """Each binned frame mixed with its raw TFI candidates (read as RMB-Net reads light, 2x2-averaged) by the
        gate, and per frame the gate's shares of the candidates (K, h, w) and their light per raw pixel (K, 2h, 2w);
        ``previous``: each frame's binned frame before it, before the gate (None at a clip's start: the frame
        itself)."""
        import torch

        from rmbvideo.net.pooling import mean_2x2
        from rmbvideo.net.raw_gate import tfi_light

        convention, tabulated = self._reading
        out, mixes = [], []
        with compute_threads(self.threads), torch.inference_mode():
            for image, before, candidates in zip(coarse, previous, tfis):
                binned = torch.from_numpy(np.ascontiguousarray(image, np.float32))[None, None]
                change = binned if before is None else torch.from_numpy(np.ascontiguousarray(before, np.float32))[
                    None, None]
                full = torch.cat([tfi_light(torch.as_tensor(tfi).float().cpu()[None, None], convention, tabulated)
                                  for tfi in candidates], dim=1)
                mixed, shares = self.raw_gate.mix(binned, mean_2x2(full), change, convention)
                out.append(mixed[0, 0].numpy())
                mixes.append((shares[0].numpy(), full[0].numpy()))
        return out, mixes

    def _learned(self, coarse: list[np.ndarray], rates: list[list[Any]]) -> list[np.ndarray]:
        """The detail stage on the frames, ``detail_batch`` of them per call."""
        import torch

        if not coarse:
            return []
        device = next(self.detail.parameters()).device
        bf16 = self.detail.body[0].weight.dtype == torch.bfloat16  # as detail_inference_copy chose
        batch = detail_batch(device, rates[0][0].shape)
        out: list[np.ndarray] = []
        with compute_threads(self.threads), torch.inference_mode(), \
                torch.autocast(device.type, torch.bfloat16, enabled=bf16):
            for a in range(0, len(coarse), batch):
                binned = torch.from_numpy(np.stack(coarse[a : a + batch]).astype(np.float32, copy=False))[:, None]
                full = self.detail(binned.to(device), _stacked_rates(rates[a : a + batch]).to(device))
                out += list(full[:, 0].float().cpu().numpy())
        return out


def _planes(images: list[Any]) -> list[Any]:
    """The raw-rate images of a frame, a stacked one (``Tfi`` with shorter reaches) split into its planes."""
    return [plane for image in images for plane in (image if image.ndim == 3 else [image])]


def _stacked_rates(rates: list[list[Any]]) -> Any:
    """The frames' raw rates as one (F, R, H, W) float32 tensor: stacked on their device when they are device tensors
    (``DeviceTfp(on_device=True)``), numpy images copied once into one array (not stacked twice and cast)."""
    import torch

    count, kinds = len(rates), len(rates[0])
    if isinstance(rates[0][0], torch.Tensor):
        return torch.stack([image for frame in rates for image in frame]).unflatten(0, (count, kinds))
    out = np.empty((count, kinds, *np.shape(rates[0][0])), np.float32)
    for k, frame in enumerate(rates):
        for j, image in enumerate(frame):
            out[k, j] = image
    return torch.from_numpy(out)

"""Training samples: a short run of preliminary frames of a random scene with its HDR ground
truth, simulated once and cached on disk (``.npz``, loaded with ``allow_pickle=False``).

Two input modes (two models):

- ``binned``: 1-bit spikes at twice the output size and (raw) rate with realistic camera noise,
  binned 2x2x2 exactly as real captures are (``StreamBinner``), read out by ``RmbReadout`` (rmb by
  default; pure-s / pure-m / full-m for ablations), then preliminary frames of N readouts.
- ``native``: a native RMB sensor simulated directly (multi-bit emission, level L = 7, band 4,
  shift 2; ``pure-m`` simulates full L-bit planes), then preliminary frames.

Ground truth of frame i is ``ground_truth`` of the scene at the frame's centre time, in the
project's linear unit (expected photo-charge per raw readout relative to the threshold). The
sensor starts empty, so the first ``warmup_frames`` frames are simulated and dropped.
"""

from __future__ import annotations

import hashlib
import json
import logging
import multiprocessing
import signal
import threading
import zipfile
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import torch

from rmbvideo.chunks import RmbChunk, SpikeChunk
from rmbvideo.io.atomic import atomic_path, atomic_write_text
from rmbvideo.recon.prelim import PrelimFrame, PreliminaryFrames
from rmbvideo.scenes.render import SceneRenderer, bin_image, ground_truth
from rmbvideo.sensor.binning import StreamBinner
from rmbvideo.sensor.conventions import CONVENTIONS
from rmbvideo.sensor.emission import ReadoutSpec
from rmbvideo.simulate.capture import CaptureSimulator, capture_planes
from rmbvideo.sensor.readout import ReadoutMode, RmbReadout
from rmbvideo.scenes.random_scenes import EVAL_SEED_START, SceneRanges, random_scene
from rmbvideo.scenes.video import FLAT_MIN_RATE, VideoScene, VideoSceneRanges

log = logging.getLogger(__name__)

SAMPLE_FORMAT_VERSION = 3  # 2: physical captures start mid-stream (SpikeEmitter.settle); 3: central sums i_c
DATA_MODES = ("binned", "native")
NATIVE_READOUTS = ("rmb", "pure-m")
RAW_RATE_HZ = 20000.0
#: ``panorama``: pans over the bundled panoramas (``random_scenes``); ``video``: dead-leaves video
#: scenes with independent motion (``video_scenes``).
SCENE_KINDS = ("panorama", "video")


@dataclass(frozen=True)
class SampleSpec:
    """What one training sample is: input mode, readout design, size and length, scene ranges.

    ``crop`` is the output (binned) size, square; ``frames`` = 2w + K preliminary frames of ``n``
    readouts each. Every field enters the cache key, so changing any of them makes a new cache.
    """

    mode: str = "binned"
    readout: str = "rmb"
    crop: int = 64
    frames: int = 10
    n: int = 10
    warmup_frames: int = 3
    level: int = 7
    band: int = 4
    shift: int = 2
    ranges: SceneRanges = field(default_factory=SceneRanges)
    scenes: str = "panorama"
    spikezoo_fraction: float = 0.0
    flat_fraction: float = 0.0
    low_contrast_fraction: float = 0.0
    flat_min_rate: float = FLAT_MIN_RATE
    subtract_fraction: float = 0.0
    pan_fraction: float = 0.0

    def __post_init__(self) -> None:
        if self.scenes not in SCENE_KINDS:
            raise ValueError(f"scenes must be one of {SCENE_KINDS}, got {self.scenes!r}")
        if self.scenes == "video" and self.mode != "binned":
            raise ValueError("video scenes are simulated as 1-bit captures: use mode = \"binned\"")
        if not 0.0 <= self.spikezoo_fraction <= 1.0:
            raise ValueError(f"spikezoo_fraction must be in [0, 1], got {self.spikezoo_fraction}")
        if not 0.0 <= self.flat_fraction <= 1.0:
            raise ValueError(f"flat_fraction must be in [0, 1], got {self.flat_fraction}")
        if not 0.0 <= self.low_contrast_fraction <= 1.0:
            raise ValueError(f"low_contrast_fraction must be in [0, 1], got {self.low_contrast_fraction}")
        if not 0.0 <= self.subtract_fraction <= 1.0:
            raise ValueError(f"subtract_fraction must be in [0, 1], got {self.subtract_fraction}")
        if not 0.0 <= self.pan_fraction <= 1.0:
            raise ValueError(f"pan_fraction must be in [0, 1], got {self.pan_fraction}")
        if not 0.0 < self.flat_min_rate < 1.0:
            raise ValueError(f"flat_min_rate must be in (0, 1), got {self.flat_min_rate}")
        if self.mode not in DATA_MODES:
            raise ValueError(f"data mode must be one of {DATA_MODES}, got {self.mode!r}")
        ReadoutMode(self.readout)  # raises ValueError naming the valid modes
        if self.mode == "native" and self.readout not in NATIVE_READOUTS:
            raise ValueError(f"native mode supports readouts {NATIVE_READOUTS}, got {self.readout!r}")
        if self.crop < 16 or self.crop % 8:
            raise ValueError(f"crop must be a multiple of 8, >= 16, got {self.crop}")
        if self.frames < 1 or self.n < 1 or self.warmup_frames < 0:
            raise ValueError("frames and n must be >= 1 and warmup_frames >= 0")

    @property
    def raw_per_readout(self) -> int:
        """Raw planes per readout: 2 for binned data, 1 for a native sensor."""
        return 2 if self.mode == "binned" else 1

    @property
    def quanta(self) -> int | None:
        """Raw pixel-planes (Bernoulli trials) behind one multi-bit value, where multi-bit values
        are per-readout rates: 8 for binned data, L for a native pure-M sensor. None for a native
        RMB sensor, whose band value reads all charge carried since the pixel's last reset."""
        if self.mode == "binned":
            return 8
        return self.level if self.readout == "pure-m" else None

    def key(self) -> str:
        """Short stable hash of the spec (and the sample format version): the cache folder name."""
        fields = asdict(self)
        for name in ("flat_fraction", "low_contrast_fraction", "subtract_fraction", "pan_fraction"):  # older caches keep their names
            if not fields[name]:
                del fields[name]
        if fields["flat_min_rate"] == SampleSpec.flat_min_rate:
            del fields["flat_min_rate"]
        text = json.dumps({"version": SAMPLE_FORMAT_VERSION, **fields}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:12]


@dataclass
class Sample:
    """F consecutive preliminary frames and their ground truth: ``i_s``, ``i_m``, ``gt`` (F, H, W)
    float32, ``m_valid`` (F, H) bool (rows with multi-bit evidence), ``times_s`` (F,) float64,
    ``i_c`` (F, C, H, W) float32 central sums (``PrelimFrame.i_c``), ``convention``: the index in
    ``CONVENTIONS`` of the sensor convention that made the spikes."""

    i_s: np.ndarray
    i_m: np.ndarray
    gt: np.ndarray
    m_valid: np.ndarray
    times_s: np.ndarray
    i_c: np.ndarray
    convention: float = 0.0


def _scene_for(spec: SampleSpec, seed: int):
    total_frames = spec.frames + spec.warmup_frames
    raw_planes = total_frames * spec.n * spec.raw_per_readout
    duration = raw_planes / RAW_RATE_HZ
    if spec.mode == "binned":
        readout = ReadoutSpec(kind="binned")
        size = 2 * spec.crop
    else:
        kind = "rmb" if spec.readout == "rmb" else "Lbit"
        readout = ReadoutSpec(kind=kind, level=spec.level, band=spec.band, shift=spec.shift)
        size = spec.crop
    return random_scene(seed, size, size, duration, RAW_RATE_HZ, readout, spec.ranges)


def _video_planes(spec: SampleSpec, seed: int) -> tuple[Iterator[SpikeChunk], VideoScene, str]:
    """Raw 1-bit planes of the video scene of ``seed`` at twice the crop, in chunks, the scene, and the convention
    its spikes are in. A fraction ``spikezoo_fraction`` of the seeds uses spikezoo's rate convention, the rest the
    physical emission model with a real camera's noise; of those, a fraction ``subtract_fraction`` has a pixel reset
    by subtraction, like ``car.dat``'s camera, whose noisy spikes are in the rate convention. A fraction ``flat_fraction`` of the training
    seeds (never the validation seeds, which stay one fixed set) is a static, nearly flat field (level
    log-uniform from ``flat_min_rate`` to 1), a fraction ``low_contrast_fraction`` of them has its
    background's contrast compressed, and a fraction ``pan_fraction`` is a rigid pan (no movers, no shake)."""
    rng = np.random.default_rng([seed, 0xC0DE])
    convention = "spikezoo" if rng.random() < spec.spikezoo_fraction else "physical"
    reset = "subtract" if convention == "physical" and rng.random() < spec.subtract_fraction else "zero"
    planes = (spec.frames + spec.warmup_frames) * spec.n * spec.raw_per_readout
    train = seed < EVAL_SEED_START
    ranges = VideoSceneRanges(flat_probability=spec.flat_fraction if train else 0.0,
                              low_contrast_probability=spec.low_contrast_fraction if train else 0.0,
                              pan_probability=spec.pan_fraction if train else 0.0,
                              flat_rate=(spec.flat_min_rate, 1.0))
    scene = VideoScene(seed, 2 * spec.crop, 2 * spec.crop, planes, ranges, convention=convention)
    return capture_planes(scene, planes, RAW_RATE_HZ, reset=reset), scene, "spikezoo" if reset == "subtract" else convention


def simulate_sample(spec: SampleSpec, seed: int) -> Sample:
    """Simulate the sample of ``seed`` from scratch (deterministic in ``seed`` and ``spec``)."""
    if spec.scenes == "video":
        return _simulate_video_sample(spec, seed)
    scene = _scene_for(spec, seed)
    prelim = PreliminaryFrames(n=spec.n)
    frames: list[PrelimFrame] = []
    if spec.mode == "binned":
        binner = StreamBinner()
        readout = RmbReadout(ReadoutMode(spec.readout), spec.band, spec.shift)
        for chunk in CaptureSimulator(scene).chunks(chunk_readouts=64):
            assert isinstance(chunk, SpikeChunk)
            binned = binner.push(chunk)
            if binned is not None:
                frames += prelim.push(readout.apply(binned))
    else:
        for chunk in CaptureSimulator(scene).chunks(chunk_readouts=64):
            assert isinstance(chunk, RmbChunk)
            frames += prelim.push(chunk)
    frames += prelim.flush()
    kept = [f for f in frames if f.index >= spec.warmup_frames][: spec.frames]
    if len(kept) != spec.frames:
        raise RuntimeError(f"seed {seed}: simulated {len(kept)} frames, expected {spec.frames}")
    renderer = SceneRenderer(scene)
    gt = np.stack([ground_truth(renderer, f.time_s) for f in kept]).astype(np.float32)
    return Sample(
        i_s=np.stack([f.i_s for f in kept]).astype(np.float32),
        i_m=np.stack([f.i_m for f in kept]).astype(np.float32),
        gt=np.nan_to_num(gt, nan=0.0, posinf=0.0, neginf=0.0),
        m_valid=np.stack([f.m_valid for f in kept]),
        times_s=np.array([f.time_s for f in kept], dtype=np.float64),
        i_c=np.stack([f.i_c for f in kept]).astype(np.float32),
    )


def _simulate_video_sample(spec: SampleSpec, seed: int) -> Sample:
    chunks, scene, convention = _video_planes(spec, seed)
    prelim = PreliminaryFrames(n=spec.n)
    binner = StreamBinner()
    readout = RmbReadout(ReadoutMode(spec.readout), spec.band, spec.shift)
    frames: list[PrelimFrame] = []
    for chunk in chunks:
        binned = binner.push(chunk)
        if binned is not None:
            frames += prelim.push(readout.apply(binned))
    frames += prelim.flush()
    kept = [f for f in frames if f.index >= spec.warmup_frames][: spec.frames]
    if len(kept) != spec.frames:
        raise RuntimeError(f"seed {seed}: simulated {len(kept)} frames, expected {spec.frames}")
    gt = np.stack([bin_image(scene.render(f.time_s * RAW_RATE_HZ)) for f in kept])
    return Sample(
        i_s=np.stack([f.i_s for f in kept]).astype(np.float32),
        i_m=np.stack([f.i_m for f in kept]).astype(np.float32),
        gt=np.nan_to_num(gt, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32),
        m_valid=np.stack([f.m_valid for f in kept]),
        times_s=np.array([f.time_s for f in kept], dtype=np.float64),
        i_c=np.stack([f.i_c for f in kept]).astype(np.float32),
        convention=float(CONVENTIONS.index(convention)),
    )


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored in the block (on the main thread): processes started in it inherit that, and Python keeps it.
    A Ctrl-C in the block itself is lost, so it only starts processes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _started() -> None:
    """A worker's first task: nothing, so that submitting it starts the worker."""


def _worker_init() -> None:
    """One thread per simulation process (the processes already fill the cores); a terminal's Ctrl-C, which reaches
    every process of the group, is left to the training process, which stops its workers itself (a worker it reached
    would print a traceback)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    cv2.setNumThreads(1)
    torch.set_num_threads(1)


class SamplePrefetcher:
    """Simulates the samples of upcoming steps in ``workers`` processes while the network trains, so
    fresh scenes cost no training time when simulation keeps up with the steps.

    ``seeds_of(step)`` names a step's seeds; ``get(step)`` returns that batch. Seeds of the next
    ``depth`` steps are simulated ahead; a seed used by several steps is simulated once and dropped
    when no upcoming step needs it. Nothing is stored on disk: the scenes never repeat across a run.
    """

    def __init__(self, spec: SampleSpec, seeds_of: Callable[[int], list[int]], depth: int = 3,
                 workers: int = 1) -> None:
        self.spec, self.seeds_of, self.depth = spec, seeds_of, depth
        self._pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                         initializer=_worker_init)
        with _sigint_ignored():  # every worker starts now, ignoring SIGINT from birth: a Ctrl-C while one still
            for _ in range(workers):  # imports reached it before _worker_init and printed its traceback
                self._pool.submit(_started)
        self._pending: dict[int, Future] = {}

    def get(self, step: int) -> list[Sample]:
        upcoming = [seed for ahead in range(step, step + self.depth + 1) for seed in self.seeds_of(ahead)]
        for seed in upcoming:
            if seed not in self._pending:
                self._pending[seed] = self._pool.submit(simulate_sample, self.spec, seed)
        samples = [self._pending[seed].result() for seed in self.seeds_of(step)]
        for seed in set(self._pending) - set(upcoming[len(self.seeds_of(step)):]):
            self._pending.pop(seed).cancel()
        return samples

    def close(self) -> None:
        """Stop the workers: the samples queued are cancelled and the ones being simulated (a second or so) are let
        finish. They are not terminated: a worker killed while it held the pool's queue could leave the pool's own
        threads waiting on it forever (a training run's Ctrl-C hung so once in CI)."""
        self._pool.shutdown(wait=True, cancel_futures=True)


class SampleCache:
    """Samples of one ``SampleSpec`` on disk under ``root/<mode>-<readout>-<key>/``.

    ``get(seed)`` loads a cached sample or simulates and stores it; ``simulated`` counts the samples
    this instance had to simulate, so a warm cache provably re-simulates nothing. A cache file that
    cannot be read is simulated again and replaced.
    """

    def __init__(self, root: str | Path, spec: SampleSpec) -> None:
        self.spec = spec
        self.dir = Path(root) / f"{spec.mode}-{spec.readout}-{spec.key()}"
        self.dir.mkdir(parents=True, exist_ok=True)
        spec_file = self.dir / "spec.json"
        if not spec_file.exists():
            atomic_write_text(spec_file, json.dumps(asdict(spec), indent=2) + "\n")
        self.simulated = 0

    def path(self, seed: int) -> Path:
        """Cache file of ``seed``."""
        return self.dir / f"sample-{seed:08d}.npz"

    def get(self, seed: int) -> Sample:
        """The sample of ``seed``, simulated only if it is not cached yet."""
        path = self.path(seed)
        if path.exists():
            try:
                with np.load(path, allow_pickle=False) as data:
                    return Sample(**{name: data[name] for name in Sample.__dataclass_fields__})
            except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
                log.warning("%s: unreadable cached sample (%s); simulating it again", path, exc)
        sample = simulate_sample(self.spec, seed)
        self.simulated += 1
        with atomic_path(path) as temp:
            with open(temp, "wb") as handle:
                np.savez(handle, **{name: getattr(sample, name) for name in Sample.__dataclass_fields__})
        return sample

"""The held-out synthetic evaluation set (the analog of the paper's Table 2 test data), cached on disk.

Each sequence is a random HDR scene from ``rmbvideo.scenes.random_scenes`` with a seed from the
evaluation range (``>= EVAL_SEED_START``; those seeds may also draw the held-out panorama), so no
sequence was ever seen in training. It is simulated exactly as real captures are processed: 1-bit
spikes at twice the output size and rate with the generator's realistic noise effects, then 2x2x2
binning (``rmbvideo.sensor.binning``) into a pure-M RMB stream at half size and 10 kHz.

Frames: frame ``i`` is centred at binned readout ``i*FRAME_STEP + FRAME_STEP/2`` (raw plane
``20i + 10``), the schedule of every reconstructor here; its ground truth is the scene's linear
radiance at that instant (``rmbvideo.scenes.render.ground_truth``: expected photo-charge per raw
readout relative to the threshold, 2x2-averaged to the binned size).

Scored frames (edge policy): only frames whose whole ``edge_readouts``-readout neighbourhood on both
sides lies inside the sequence are scored, for every method alike. The default, 35 readouts, is half
of TFW-L's/GC20's 70-readout window and RMB-Net's 2w+1 = 7 frames, so no scored frame comes from a
window clipped or padded at an edge.

Cache: one ``.npz`` per sequence (``np.savez_compressed``, no pickle; raw planes bit-packed), named by
the cache format version and every setting that changes its content, written to a temporary name and
renamed when complete.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from rmbvideo.chunks import RmbChunk, SpikeChunk
from rmbvideo.errors import InputError, OutputError
from rmbvideo.io.atomic import atomic_path
from rmbvideo.scenes.video import VideoSceneRanges
from rmbvideo.sensor.params import RESETS
from rmbvideo.sensor.binning import MULTI_LEVEL, bin_2x2x2

log = logging.getLogger(__name__)

#: 2: captures start mid-stream (``SpikeEmitter.settle``).
CACHE_FORMAT = 2
FRAME_STEP = 10  # binned readouts per output frame (N of the paper)
RAW_RATE_HZ = 20000.0
_SIMULATE_CHUNK = 64  # raw planes simulated at once
VIDEO_SEED_START = 1_500_000  # held-out video sequences (evaluation range, apart from the panorama scenes)


@dataclass(frozen=True)
class HeldoutConfig:
    """Size of the held-out set: ``count`` sequences of ``readouts`` binned readouts at the binned size
    ``width`` x ``height`` (raw: twice each), seeds ``EVAL_SEED_START + first_seed_offset + k``; ``reset``: what a
    spike does to the simulated cameras' pixels (``SensorParams.reset``: "zero", the paper's, or "subtract", a pixel
    that keeps the charge past its threshold, like ``car.dat``'s camera; then its streams are in the rate
    convention, with the camera's noise)."""

    count: int = 6
    width: int = 200
    height: int = 125
    readouts: int = 200
    edge_readouts: int = 35
    first_seed_offset: int = 0
    reset: str = "zero"

    def __post_init__(self) -> None:
        if self.count < 1 or self.width < 8 or self.height < 8:
            raise ValueError(f"need >= 1 sequence of at least 8x8 pixels, got {self}")
        if self.readouts < FRAME_STEP or self.readouts % FRAME_STEP:
            raise ValueError(f"readouts must be a positive multiple of {FRAME_STEP}, got {self.readouts}")
        if self.edge_readouts < 0:
            raise ValueError(f"edge_readouts must be >= 0, got {self.edge_readouts}")
        if self.reset not in RESETS:
            raise ValueError(f"reset must be one of {RESETS}, got {self.reset!r}")


#: The full set: 6 sequences of 200 binned readouts (20 ms, 20 frames, 14 scored) at 200x125.
FULL = HeldoutConfig()
#: ``--quick``: 2 smaller, shorter sequences (112x64, 120 readouts: 12 frames, 6 scored).
QUICK = HeldoutConfig(count=2, width=112, height=64, readouts=120)


@dataclass
class Sequence:
    """One held-out sequence: the binned pure-M stream, the raw 1-bit planes, and per-frame ground truth.

    ``single``/``multi``: (T, H, W) uint8 binned readouts at ``rate_hz``; ``raw_packed``: (2T, 2H,
    ceil(2W/8)) bit-packed raw planes (little bit order) at ``2 * rate_hz``; ``gt``: (F, H, W) float32
    linear ground truth of frames ``0 .. F-1`` with F = T / FRAME_STEP.
    """

    name: str
    seed: int
    rate_hz: float
    single: np.ndarray
    multi: np.ndarray
    raw_packed: np.ndarray
    gt: np.ndarray
    edge_readouts: int
    description: str = ""

    @property
    def readouts(self) -> int:
        """Binned readouts in the sequence."""
        return len(self.single)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the binned stream and of the ground truth."""
        return self.single.shape[1:]

    @property
    def raw_shape(self) -> tuple[int, int]:
        """(H, W) of the raw 1-bit planes."""
        return 2 * self.shape[0], 2 * self.shape[1]

    @property
    def scored_frames(self) -> list[int]:
        """Frame indices scored for every method (see the module docstring's edge policy)."""
        last = self.readouts - self.edge_readouts
        return [i for i in range(len(self.gt))
                if i * FRAME_STEP + FRAME_STEP / 2 - self.edge_readouts >= 0
                and i * FRAME_STEP + FRAME_STEP / 2 <= last]

    def frame_time(self, index: int) -> float:
        """Capture time (s) of frame ``index``: the centre of its readouts."""
        return (index * FRAME_STEP + FRAME_STEP / 2) / self.rate_hz

    def rmb_chunks(self, chunk_readouts: int = 64) -> Iterator[RmbChunk]:
        """The binned stream as pure-M ``RmbChunk``s (every row multi-bit), as ``DatReader.binned_chunks``."""
        for start in range(0, self.readouts, chunk_readouts):
            stop = min(start + chunk_readouts, self.readouts)
            yield RmbChunk(single=self.single[start:stop], multi=self.multi[start:stop],
                           multi_rows=np.ones((stop - start, self.shape[0]), dtype=bool), start=start,
                           rate_hz=self.rate_hz, level=MULTI_LEVEL, raw_per_readout=2)

    @property
    def n_planes(self) -> int:
        """Raw planes in the sequence (the ``SpikeSource`` view used by ``reconstruct_stream``)."""
        return len(self.raw_packed)

    def chunks(self, chunk_planes: int = 128, start: int = 0, stop: int | None = None) -> Iterator[SpikeChunk]:
        """Raw planes from plane 0 (``start``/``stop`` must be 0 and None: sequences are scored whole)."""
        _whole(start, stop, self.n_planes)
        return self.raw_chunks(chunk_planes)

    def binned_chunks(self, chunk_planes: int = 128, start: int = 0, stop: int | None = None) -> Iterator[RmbChunk]:
        """The binned pure-M stream, ``chunk_planes`` raw planes (half as many readouts) per chunk."""
        _whole(start, stop, self.n_planes)
        return self.rmb_chunks(max(1, chunk_planes // 2))

    def raw_chunks(self, chunk_planes: int = 128) -> Iterator[SpikeChunk]:
        """The raw 1-bit planes as ``SpikeChunk``s at the raw rate."""
        width = self.raw_shape[1]
        for start in range(0, len(self.raw_packed), chunk_planes):
            packed = self.raw_packed[start:start + chunk_planes]
            planes = np.unpackbits(packed, axis=-1, count=width, bitorder="little")
            yield SpikeChunk(planes=planes, start=start, rate_hz=2 * self.rate_hz)


def _whole(start: int, stop: int | None, n_planes: int) -> None:
    if start != 0 or stop not in (None, n_planes):
        raise ValueError("held-out sequences are read whole (start 0, no stop)")


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/rmbvideo/heldout`` (``~/.cache/...``), or a temp folder without a home."""
    base = os.environ.get("XDG_CACHE_HOME") or (Path.home() / ".cache" if Path.home().is_dir() else None)
    root = Path(base) if base else Path(tempfile.gettempdir())
    return root / "rmbvideo" / "heldout"


def _cache_name(config: HeldoutConfig, seed: int) -> str:
    return f"heldout-v{CACHE_FORMAT}-seed{seed}-{config.width}x{config.height}-{config.readouts}{_reset_tag(config)}.npz"


def _reset_tag(config: HeldoutConfig) -> str:
    """The cache name's mark of a pixel other than the paper's (none for it: its caches keep their names)."""
    return "" if config.reset == "zero" else f"-reset-{config.reset}"


def _convention(config: HeldoutConfig, convention: str) -> str:
    """The convention a stream simulated in ``convention`` is in: a pixel reset by subtraction makes the rate
    convention's streams (rate = light), with the camera's noise."""
    return "spikezoo" if config.reset == "subtract" else convention


def _check_seed(seed: int, training: bool) -> None:
    """Held-out sequences use evaluation seeds only; ``training`` sequences (for a stage fitted on the same kinds,
    ``rmbvideo.train.raw_gate``) training seeds only."""
    from rmbvideo.scenes.random_scenes import is_eval_seed

    if is_eval_seed(seed) == training:
        raise ValueError(f"seed {seed} is {'an evaluation' if training else 'a training'} seed; "
                         f"{'training' if training else 'held-out'} sequences use "
                         f"{'training' if training else 'evaluation'} seeds only")


def simulate_sequence(seed: int, config: HeldoutConfig, training: bool = False) -> Sequence:
    """Simulate the held-out sequence of ``seed`` (an evaluation seed; a training seed when ``training``) at
    ``config``'s size and length."""
    from rmbvideo.scenes.random_scenes import random_scene
    from rmbvideo.scenes.render import ground_truth
    from rmbvideo.simulate.capture import CaptureSimulator

    _check_seed(seed, training)
    raw_planes = 2 * config.readouts
    scene = random_scene(seed, 2 * config.width, 2 * config.height, duration_s=raw_planes / RAW_RATE_HZ,
                         rate_hz=RAW_RATE_HZ)
    scene = replace(scene, sensor=replace(scene.sensor, reset=config.reset))
    simulator = CaptureSimulator(scene)
    if simulator.total_readouts != raw_planes:
        raise RuntimeError(f"scene {scene.name}: simulated {simulator.total_readouts} raw planes, "
                           f"expected {raw_planes}")
    single, multi, packed = [], [], []
    for chunk in simulator.chunks(_SIMULATE_CHUNK):
        s, m = bin_2x2x2(chunk.planes)  # chunks are even-sized from plane 0: bins never straddle them
        single.append(s)
        multi.append(m)
        packed.append(np.packbits(chunk.planes, axis=-1, bitorder="little"))
    frames = config.readouts // FRAME_STEP
    gt = np.stack([ground_truth(simulator.renderer, (20 * i + 10) / RAW_RATE_HZ) for i in range(frames)])
    background = scene.background
    description = json.dumps({"scene": scene.name, "panorama": background.panorama,
                              "exposure": scene.exposure, "objects": len(scene.objects),
                              "dark_regions": len(scene.dark_regions), "effects": list(scene.effects),
                              "convention": _convention(config, "physical"), "reset": config.reset})
    return Sequence(name=scene.name, seed=seed, rate_hz=RAW_RATE_HZ / 2, single=np.concatenate(single),
                    multi=np.concatenate(multi), raw_packed=np.concatenate(packed),
                    gt=gt.astype(np.float32), edge_readouts=config.edge_readouts, description=description)


@dataclass(frozen=True)
class VideoHeldout:
    """A held-out video-like sequence kind: ``name`` and the ranges its scenes are drawn from
    (``rmbvideo.scenes.video``), in the physical convention or spikezoo's."""

    name: str
    ranges: VideoSceneRanges
    convention: str = "physical"


#: Video-like held-out kinds: fast motion (camera ~1 raw px/plane and fast objects), dark (median
#: 1e-3..5e-3 spikes per raw plane), both, spikezoo's convention with fast motion, and low-contrast
#: fine texture under slow to moderate motion (gravel, foliage: reflectances 0.35-0.6 only, no lights;
#: made another way than the training scenes' contrast compression, so it tests more than that).
VIDEO_KINDS = (
    VideoHeldout("fast", VideoSceneRanges(camera_speed=(0.8, 1.2), static_probability=0.0,
                                          object_speed=(0.5, 1.5), median_rate=(0.02, 0.3))),
    VideoHeldout("dark", VideoSceneRanges(median_rate=(1e-3, 5e-3), light_probability=0.5)),
    VideoHeldout("fast-dark", VideoSceneRanges(camera_speed=(0.8, 1.2), static_probability=0.0,
                                               object_speed=(0.5, 1.5), median_rate=(2e-3, 1e-2))),
    VideoHeldout("spikezoo-fast", VideoSceneRanges(camera_speed=(0.5, 1.2), static_probability=0.0,
                                                   object_speed=(0.3, 1.5)), convention="spikezoo"),
    VideoHeldout("low-contrast", VideoSceneRanges(camera_speed=(0.02, 0.3), static_probability=0.0,
                                                  object_speed=(0.02, 0.5), panorama_probability=0.0,
                                                  reflectance=(0.35, 0.6), light_probability=0.0,
                                                  median_rate=(0.02, 0.3))),
)


def simulate_video_sequence(seed: int, kind: VideoHeldout, config: HeldoutConfig,
                            training: bool = False) -> Sequence:
    """The held-out video sequence of ``seed`` (an evaluation seed; a training seed when ``training``) of ``kind``
    at ``config``'s size."""
    from rmbvideo.scenes.render import bin_image
    from rmbvideo.scenes.video import VideoScene
    from rmbvideo.simulate.capture import capture_planes

    _check_seed(seed, training)
    raw_planes = 2 * config.readouts
    scene = VideoScene(seed, 2 * config.width, 2 * config.height, raw_planes, kind.ranges, kind.convention)
    single, multi, packed = [], [], []
    for chunk in capture_planes(scene, raw_planes, RAW_RATE_HZ, _SIMULATE_CHUNK, reset=config.reset):
        s, m = bin_2x2x2(chunk.planes)
        single.append(s)
        multi.append(m)
        packed.append(np.packbits(chunk.planes, axis=-1, bitorder="little"))
    frames = config.readouts // FRAME_STEP
    gt = np.stack([bin_image(scene.render(20 * i + 10)) for i in range(frames)])
    description = json.dumps({"scene": f"{kind.name}-{seed}", "kind": kind.name,
                              "convention": _convention(config, kind.convention), "objects": len(scene.layers) - 1,
                              "reset": config.reset})
    return Sequence(name=f"{kind.name}-{seed - (0 if training else VIDEO_SEED_START)}", seed=seed, rate_hz=RAW_RATE_HZ / 2,
                    single=np.concatenate(single), multi=np.concatenate(multi), raw_packed=np.concatenate(packed),
                    gt=gt.astype(np.float32), edge_readouts=config.edge_readouts, description=description)


def load_video_heldout(quick: bool, cache: Path | None = None, per_kind: int = 1, first: int = 0,
                       reset: str = "zero", kinds: Collection[str] | None = None) -> list[Sequence]:
    """``per_kind`` held-out video sequences of every ``VIDEO_KINDS`` entry (``QUICK``/``FULL`` size; of those named
    in ``kinds`` only, when given), seeds from ``first`` on within each kind's range, simulated once and then read
    from ``cache``; ``reset``: the cameras' pixel (``HeldoutConfig``; spikezoo's kind has none)."""
    config = replace(QUICK if quick else FULL, reset=reset)
    cache = Path(cache) if cache is not None else default_cache_dir()
    sequences = []
    for k, kind in enumerate(VIDEO_KINDS):
        if kinds is not None and kind.name not in kinds:
            continue
        for j in range(first, first + per_kind):
            seed = VIDEO_SEED_START + 100 * k + j
            digest = hashlib.sha256(repr(kind).encode()).hexdigest()[:8]  # any change of the kind is a new file
            tag = _reset_tag(config) if kind.convention == "physical" else ""
            path = cache / (f"video-v{CACHE_FORMAT}-{kind.name}-{digest}-seed{seed}-{config.width}x{config.height}"
                            f"-{config.readouts}{tag}.npz")
            kind_config = config if kind.convention == "physical" else replace(config, reset="zero")
            sequences.append(_cached(path, config, lambda: simulate_video_sequence(seed, kind, kind_config)))
    return sequences


def _cached(path: Path, config: HeldoutConfig, simulate: Callable[[], Sequence]) -> Sequence:
    """The sequence cached at ``path``, or ``simulate()`` stored there (a cache that cannot be
    written is only a warning: the sequence is still returned)."""
    if path.is_file():
        return load_sequence(path, config.edge_readouts)
    log.info("simulating held-out sequence into %s", path)
    sequence = simulate()
    try:
        save_sequence(sequence, path)
    except (OSError, OutputError) as exc:
        log.warning("%s: cannot cache the held-out sequence (%s); continuing without cache", path, exc)
    return sequence


def save_sequence(sequence: Sequence, path: Path) -> None:
    """Write ``sequence`` as a compressed ``.npz`` (arrays only), atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as temp:
        with open(temp, "wb") as fh:
            np.savez_compressed(fh, single=sequence.single, multi=sequence.multi,
                                raw_packed=sequence.raw_packed, gt=sequence.gt,
                                rate_hz=np.float64(sequence.rate_hz), seed=np.int64(sequence.seed),
                                name=np.str_(sequence.name), description=np.str_(sequence.description))


def load_sequence(path: Path, edge_readouts: int) -> Sequence:
    """Read a cached sequence; a damaged or foreign file is an ``InputError`` naming it."""
    try:
        with np.load(path, allow_pickle=False) as data:
            seq = Sequence(name=str(data["name"]), seed=int(data["seed"]), rate_hz=float(data["rate_hz"]),
                           single=data["single"], multi=data["multi"], raw_packed=data["raw_packed"],
                           gt=data["gt"], edge_readouts=edge_readouts, description=str(data["description"]))
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"{path}: not a readable held-out sequence ({exc}); delete it to rebuild") from None
    frames = seq.readouts // FRAME_STEP
    if seq.multi.shape != seq.single.shape or seq.gt.shape != (frames, *seq.shape) \
            or seq.raw_packed.shape[0] != 2 * seq.readouts or not np.isfinite(seq.gt).all():
        raise InputError(f"{path}: inconsistent held-out sequence arrays; delete it to rebuild")
    return seq


def heldout_seeds(config: HeldoutConfig) -> list[int]:
    """The evaluation seeds of ``config``'s sequences."""
    from rmbvideo.scenes.random_scenes import EVAL_SEED_START

    return [EVAL_SEED_START + config.first_seed_offset + k for k in range(config.count)]


def load_heldout_config(config: HeldoutConfig, cache: Path | None = None) -> list[Sequence]:
    """The sequences of ``config``, simulated once and then read from ``cache``."""
    cache = Path(cache) if cache is not None else default_cache_dir()
    sequences = []
    for seed in heldout_seeds(config):
        sequences.append(_cached(cache / _cache_name(config, seed), config,
                                 lambda: simulate_sequence(seed, config)))  # noqa: B023 (called at once)
    return sequences


def load_heldout(quick: bool, cache: Path | None = None, reset: str = "zero") -> list[Sequence]:
    """The held-out set (``QUICK`` when ``quick``, else ``FULL``) with the cameras' pixel ``reset``
    (``HeldoutConfig``), cached under ``cache``."""
    return load_heldout_config(replace(QUICK if quick else FULL, reset=reset), cache)


#: Seeds of the development sequences: random scenes from this offset, video kinds from this index in their range.
DEVELOPMENT_RANDOM_OFFSET = 50
DEVELOPMENT_VIDEO_FIRST = 7


def load_development(cache: Path | None = None, reset: str = "zero") -> list[Sequence]:
    """Development sequences for choosing between candidate models: the held-out kinds (two random scenes,
    one video sequence of each kind) drawn from other evaluation seeds, so the validation set stays untuned;
    ``reset``: the cameras' pixel (``HeldoutConfig``)."""
    randoms = replace(FULL, count=2, first_seed_offset=DEVELOPMENT_RANDOM_OFFSET, reset=reset)
    return (load_heldout_config(randoms, cache)
            + load_video_heldout(False, cache, first=DEVELOPMENT_VIDEO_FIRST, reset=reset))

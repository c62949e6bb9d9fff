"""Development clips in the real-video format: textures panned at known speeds in spikezoo's convention.

The real-video streams (``real_video``) are a validation set: too few to tune on, and never trained on.
These clips reproduce their hard case with known content and motion, for choosing between models: a
dead-leaves texture (seeds from the evaluation range, so never a training scene) at a low or a moderate
contrast around the brightness of REDS footage, panned at 0 to 0.28 raw pixels per plane and turned into
spikes by spikezoo's rate rule (accumulate 0.6 x the 8-bit value, fire and subtract at 1; no noise).
Each is written as ``NAME_key_id151.dat`` + ``.png``: the texture as it stands at time 151 in planes, where the
format's reference shows the light (``real_video.RealStream.moment``; each plane shows it at its midpoint), so
``real_video.find_streams`` and its scoring read them like any folder of real-video streams.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rmbvideo.io.atomic import atomic_path
from rmbvideo.io.dat import DatGeometry, DatWriter
from rmbvideo.io.png import write_png
from rmbvideo.scenes.random_scenes import EVAL_SEED_START
from rmbvideo.scenes.video import VideoSceneRanges, dead_leaves
from rmbvideo.sensor.emission import RateIntegrateFire

PLANES = 301
REFERENCE_PLANE = 150  # "key_id151"
SPIKEZOO_RATE = 0.6  # spikes per plane at 8-bit value 255
MEAN_VALUE = 0.59  # 8-bit mean 150, as the REDS stream 200_part3
SEED_START = EVAL_SEED_START + 2_000_000  # apart from every held-out sequence's seeds
CACHE_VERSION = 2  # 2: the reference at the format's moment (time 151, not plane 150's start)
_PAD = 100  # texture margin (px) beyond the frame, more than the fastest pan covers


@dataclass(frozen=True)
class TexturePan:
    """One clip: texture ``seed`` with log-contrast (standard deviation) ``contrast``, panned at ``speed``
    raw pixels per plane in a direction drawn from the seed."""

    seed: int
    contrast: float
    speed: float

    @property
    def name(self) -> str:
        return f"pan-c{round(100 * self.contrast):02d}-v{round(100 * self.speed):02d}-{self.seed - SEED_START}"


#: Low (0.16, as gravel or sand) and moderate (0.32) contrast, each static, slow, REDS-like and fast.
TEXTURE_PANS = tuple(TexturePan(SEED_START + k, contrast, speed)
                     for k, contrast in enumerate((0.16, 0.32)) for speed in (0.0, 0.07, 0.14, 0.28))


def texture(pan: TexturePan, height: int, width: int) -> np.ndarray:
    """The (height, width) texture in [0, 1]: dead leaves, log-contrast normalised to ``pan.contrast``."""
    rng = np.random.default_rng([pan.seed, 0x7E47])
    leaves = dead_leaves(rng, height, width, 6.0, 1.0, 40.0, VideoSceneRanges(reflectance=(0.2, 0.9)))
    log_value = np.log(leaves)
    log_value = (log_value - np.median(log_value)) / max(float(log_value.std()), 1e-6)
    return np.clip(MEAN_VALUE * np.exp(pan.contrast * log_value), 0.0, 1.0).astype(np.float32)


def write_texture_pan(pan: TexturePan, folder: Path, geometry: DatGeometry = DatGeometry()) -> Path:
    """Write ``pan`` into ``folder`` (atomically, capture then reference); the capture's path."""
    height, width = geometry.height, geometry.image_width
    big = texture(pan, height + 2 * _PAD, width + 2 * _PAD)
    reference = big[_PAD:_PAD + height, _PAD:_PAD + width]
    angle = np.random.default_rng([pan.seed, 0xA46]).uniform(0.0, 2.0 * math.pi)
    vx, vy = pan.speed * math.cos(angle), pan.speed * math.sin(angle)
    emitter = RateIntegrateFire((height, width), seed=pan.seed)
    stem = folder / f"{pan.name}_key_id{REFERENCE_PLANE + 1}"
    capture = stem.with_suffix(".dat")
    with atomic_path(capture) as temp, DatWriter(temp, geometry) as writer:
        for plane in range(PLANES):
            elapsed = plane + 0.5 - (REFERENCE_PLANE + 1)  # from the reference's moment to this plane's midpoint
            shift_x, shift_y = vx * elapsed, vy * elapsed
            warp = np.float32([[1, 0, _PAD - shift_x], [0, 1, _PAD - shift_y]])  # output px -> texture px
            frame = cv2.warpAffine(big, warp, (width, height), flags=cv2.INTER_LANCZOS4 | cv2.WARP_INVERSE_MAP)
            writer.write(emitter.emit_one(SPIKEZOO_RATE * np.clip(frame, 0.0, 1.0))[None])
    write_png(stem.with_suffix(".png"), np.round(255 * reference).astype(np.uint8))
    return capture


def texture_pan_folder(cache: Path) -> Path:
    """The folder of every clip in ``TEXTURE_PANS`` under ``cache``, written on first use."""
    folder = cache / f"texture-pans-v{CACHE_VERSION}"
    folder.mkdir(parents=True, exist_ok=True)
    for pan in TEXTURE_PANS:
        if not (folder / f"{pan.name}_key_id{REFERENCE_PLANE + 1}.png").is_file():
            write_texture_pan(pan, folder)
    return folder

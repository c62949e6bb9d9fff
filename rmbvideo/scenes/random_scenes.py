"""Random HDR training scenes (paper Sec. 4.3): panorama pans/zooms, moving textured objects,
light sources far brighter than the background, deep shadows, and a random exposure level.

Every scene is a pure function of its seed. Seeds are split so evaluation never sees training
content: training seeds are ``0 .. EVAL_SEED_START - 1`` and draw panoramas (background and object
textures) from ``TRAIN_PANORAMAS`` only; evaluation seeds are ``>= EVAL_SEED_START`` (1,000,000)
and draw from all bundled panoramas, including the held-out ``HELD_OUT_PANORAMA`` ("sunrise").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rmbvideo.scenes.scene import Background, DarkRegion, Scene, SceneObject
from rmbvideo.sensor.effects import REALISTIC_EFFECTS
from rmbvideo.sensor.emission import ReadoutSpec
from rmbvideo.sensor.params import SensorParams

EVAL_SEED_START = 1_000_000
HELD_OUT_PANORAMA = "sunrise"
TRAIN_PANORAMAS = ("city", "courtyard", "forest", "interior", "studio")
EVAL_PANORAMAS = TRAIN_PANORAMAS + (HELD_OUT_PANORAMA,)
PANORAMA_SIZE = (1024, 512)  # bundled panoramas, width x height


@dataclass(frozen=True)
class SceneRanges:
    """Ranges the random scenes are drawn from (speeds in raw image px/s, exposure in electrons per
    raw readout at the panorama's median radiance, so median values are exposure / Q_r)."""

    exposure: tuple[float, float] = (2.0, 60.0)
    zoom: tuple[float, float] = (0.7, 3.0)
    pan_speed: float = 2500.0
    zoom_rate: float = 5.0
    max_objects: int = 3
    object_speed: float = 3000.0
    light_probability: float = 0.35
    light_radiance: tuple[float, float] = (10.0, 1e4)
    dark_probability: float = 0.5
    dark_attenuation: tuple[float, float] = (1e-3, 1e-1)


def is_eval_seed(seed: int) -> bool:
    """Whether ``seed`` belongs to the held-out evaluation range."""
    return seed >= EVAL_SEED_START


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(math.exp(rng.uniform(math.log(low), math.log(high))))


def _random_object(rng: np.random.Generator, ranges: SceneRanges, width: int, height: int,
                   panoramas: tuple[str, ...]) -> SceneObject:
    size = (float(rng.uniform(0.1, 0.5) * width), float(rng.uniform(0.1, 0.5) * height))
    speed = rng.uniform(0.0, ranges.object_speed)
    direction = rng.uniform(0.0, 2 * math.pi)
    light = rng.random() < ranges.light_probability
    if light:
        texture = "led" if rng.random() < 0.5 else "uniform"
        radiance = _log_uniform(rng, *ranges.light_radiance)
    else:
        texture = str(rng.choice(["checker", "uniform", "panorama"], p=[0.3, 0.2, 0.5]))
        radiance = _log_uniform(rng, 0.1, 5.0)
    crop = None
    if texture == "panorama":
        name = str(rng.choice(panoramas))
        texture = f"panorama:{name}"
        crop_w, crop_h = size[0] * rng.uniform(0.5, 2.0), size[1] * rng.uniform(0.5, 2.0)
        crop = (float(rng.uniform(0, PANORAMA_SIZE[0])), float(rng.uniform(0, PANORAMA_SIZE[1] - crop_h)),
                float(crop_w), float(crop_h))
    return SceneObject(
        shape=str(rng.choice(["rect", "ellipse"])),
        size=size,
        position=(float(rng.uniform(0, width)), float(rng.uniform(0, height))),
        velocity=(float(speed * math.cos(direction)), float(speed * math.sin(direction))),
        angle_deg=float(rng.uniform(0, 360)),
        angular_velocity_deg=float(rng.normal(0.0, 600.0)),
        texture=texture,
        radiance=radiance,
        crop=crop,
        grid=(int(rng.integers(2, 6)), int(rng.integers(2, 5))),
    )


def random_scene(seed: int, width: int, height: int, duration_s: float, rate_hz: float = 20000.0,
                 readout: ReadoutSpec | None = None, ranges: SceneRanges | None = None,
                 effects: tuple[str, ...] = REALISTIC_EFFECTS) -> Scene:
    """The random scene of ``seed`` at raw size ``width`` x ``height`` (see the module docstring
    for which panoramas a seed may use)."""
    ranges = ranges or SceneRanges()
    readout = readout or ReadoutSpec(kind="binned")
    rng = np.random.default_rng([seed, 0x5CE7E])
    panoramas = EVAL_PANORAMAS if is_eval_seed(seed) else TRAIN_PANORAMAS
    zoom = _log_uniform(rng, *ranges.zoom)
    center = (float(rng.uniform(0, PANORAMA_SIZE[0])),
              float(rng.uniform(0.2, 0.8) * PANORAMA_SIZE[1]))
    pan = rng.uniform(0.0, ranges.pan_speed) / zoom  # image px/s -> panorama px/s
    direction = rng.uniform(0.0, 2 * math.pi)
    background = Background(
        panorama=str(rng.choice(panoramas)),
        gain=1.0,
        center=center,
        velocity=(float(pan * math.cos(direction)), float(pan * math.sin(direction))),
        zoom=zoom,
        zoom_rate=float(rng.uniform(-ranges.zoom_rate, ranges.zoom_rate)),
    )
    objects = tuple(_random_object(rng, ranges, width, height, panoramas)
                    for _ in range(int(rng.integers(0, ranges.max_objects + 1))))
    dark_regions: tuple[DarkRegion, ...] = ()
    if rng.random() < ranges.dark_probability:
        view_w, view_h = width / zoom, height / zoom
        regions = []
        for _ in range(int(rng.integers(1, 3))):
            w, h = view_w * rng.uniform(0.2, 0.7), view_h * rng.uniform(0.2, 0.7)
            x = center[0] + rng.uniform(-0.5, 0.5) * view_w - w / 2
            y = center[1] + rng.uniform(-0.5, 0.5) * view_h - h / 2
            regions.append(DarkRegion(rect=(float(x), float(y), float(w), float(h)),
                                      attenuation=_log_uniform(rng, *ranges.dark_attenuation),
                                      softness=float(rng.uniform(0.0, 6.0))))
        dark_regions = tuple(regions)
    level = readout.level if readout.is_multibit else 1
    return Scene(
        name=f"random-{seed}",
        description=f"random training scene, seed {seed}",
        width=width,
        height=height,
        rate_hz=rate_hz,
        duration_s=duration_s,
        exposure=_log_uniform(rng, *ranges.exposure),
        seed=int(seed),
        effects=tuple(effects),
        readout=readout,
        sensor=SensorParams(level=level),
        background=background,
        objects=objects,
        dark_regions=dark_regions,
    )

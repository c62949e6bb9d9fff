"""Random video-like training scenes: dead-leaves textures, independent moving objects, camera
motion and shake, HDR lighting, rendered exactly at any time.

Real captures are not slow pans over six panoramas: they have texture at every scale, objects that
move on their own and occlude each other, and motion up to about a raw pixel per raw plane. A
``VideoScene`` is a stack of layers over a background canvas:

- the background is a dead-leaves image (occluding random shapes with a power-law size
  distribution, which reproduces natural-image statistics), each leaf flat, graded, striped or
  noise-textured, or a crop of a real HDR panorama (natural texture and contrast), optionally under
  a soft shadow; the camera moves over it with a velocity, an
  acceleration, a zoom rate and a small high-frequency shake;
- foreground objects are dead-leaves patches of their own with an anti-aliased outline (ellipse,
  rectangle or polygon), each with its own translation, rotation and scaling, composited back to
  front; some are light sources far brighter than the rest.

Every layer is a static texture under an affine map of time, so ``render(t)`` is exact at any t
(bilinear sampling of the textures). Values are linear radiance relative to the scene's median;
``rate`` scales them to the project's unit (expected charge per raw plane relative to the threshold).

Every scene is a pure function of its seed; training draws seeds below
``rmbvideo.scenes.random_scenes.EVAL_SEED_START`` and validation seeds at or above it.
``rmbvideo.simulate.capture.capture_planes`` turns a scene into a 1-bit capture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from rmbvideo.scenes.random_scenes import EVAL_PANORAMAS, EVAL_SEED_START, TRAIN_PANORAMAS
from rmbvideo.scenes.render import panorama_luminance
from rmbvideo.sensor.conventions import CONVENTIONS

#: spikezoo's REDS streams fire at about this fraction of the 8-bit intensity per plane.
SPIKEZOO_RATE = 0.6
_SMALL_LEAF = 10  # leaves smaller than this (raw px) are flat ellipses drawn without anti-aliasing
#: default floor of the static flat fields' level (charge per raw plane / threshold); training can lower it
FLAT_MIN_RATE = 1e-3
_SUPERSAMPLE = 4  # outline masks are drawn this much finer, then area-averaged (anti-aliasing)


@dataclass(frozen=True)
class VideoSceneRanges:
    """Ranges the video scenes are drawn from. Speeds are raw pixels per raw plane; ``median_rate``
    is the median scene value in charge per raw plane relative to the threshold (the dark-current
    floor of the emission model is ~5e-4, saturation is 1)."""

    median_rate: tuple[float, float] = (2e-3, 0.5)
    camera_speed: tuple[float, float] = (0.005, 1.2)  # log-uniform: most video moves slowly, some fast
    static_probability: float = 0.15
    shake_px: float = 0.6
    zoom_rate: float = 2e-3          # per raw plane, either sign
    max_objects: int = 6
    object_speed: tuple[float, float] = (0.01, 1.5)  # log-uniform
    object_spin: float = 0.01        # rad per raw plane
    object_zoom_rate: float = 3e-3   # per raw plane, either sign
    light_probability: float = 0.3
    panorama_probability: float = 0.4  # background from a real HDR panorama instead of dead leaves
    light_radiance: tuple[float, float] = (5.0, 300.0)
    shadow_probability: float = 0.4
    shadow_attenuation: tuple[float, float] = (0.01, 0.3)
    coverage: tuple[float, float] = (3.0, 8.0)  # mean number of leaves over a background point
    reflectance: tuple[float, float] = (0.03, 1.0)
    flat_probability: float = 0.0    # a static, nearly flat field (a wall, the sky, a lens cap) instead
    flat_rate: tuple[float, float] = (FLAT_MIN_RATE, 1.0)  # its level, log-uniform: half of them darker than 0.03
    flat_gradient: float = 0.3       # +- relative brightness change across it
    low_contrast_probability: float = 0.0  # the background's contrast compressed (gravel, foliage, haze)
    low_contrast_gamma: tuple[float, float] = (0.1, 0.5)  # its log-contrast times this (uniform)
    pan_probability: float = 0.0     # a rigid pan instead: no movers, no shake, zoom or spin (the aligned mean's case)
    pan_speed: tuple[float, float] = (0.02, 0.5)  # its camera speed, log-uniform


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(math.exp(rng.uniform(math.log(low), math.log(high))))


def _leaf_texture(rng: np.random.Generator, h: int, w: int, ranges: VideoSceneRanges) -> np.ndarray:
    """An (h, w) reflectance patch: flat, a linear gradient, a grating or band-limited noise."""
    base = _log_uniform(rng, *ranges.reflectance)
    kind = rng.choice(4, p=[0.45, 0.15, 0.15, 0.25])
    if kind == 0:
        return np.full((h, w), base, np.float32)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    angle = rng.uniform(0, math.pi)
    u = x * math.cos(angle) + y * math.sin(angle)
    if kind == 1:
        ramp = u / max(float(np.ptp(u)), 1.0)
        return (base * np.exp(rng.uniform(-1.5, 1.5) * (ramp - 0.5))).astype(np.float32)
    if kind == 2:
        period = _log_uniform(rng, 2.5, 40.0)
        contrast = rng.uniform(0.2, 0.9)
        return (base * (1 + contrast * np.sin(2 * math.pi * u / period + rng.uniform(0, 6.3)))).astype(np.float32)
    scale = _log_uniform(rng, 1.0, 12.0)
    small = rng.standard_normal((max(2, int(h / scale) + 2), max(2, int(w / scale) + 2))).astype(np.float32)
    noise = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    return (base * np.exp(rng.uniform(0.1, 0.8) * noise)).astype(np.float32)


def _shape_mask(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Anti-aliased (h, w) coverage in [0, 1] of an ellipse, rotated rectangle or random polygon."""
    s = _SUPERSAMPLE
    big = np.zeros((h * s, w * s), np.uint8)
    cx, cy, rx, ry = w * s / 2, h * s / 2, w * s / 2 - 1, h * s / 2 - 1
    kind = rng.choice(3)
    if kind == 0:
        cv2.ellipse(big, (int(cx), int(cy)), (int(rx), int(ry)), 0, 0, 360, 255, -1)
    else:
        count = 4 if kind == 1 else int(rng.integers(5, 9))
        angles = np.sort(rng.uniform(0, 2 * math.pi, count)) if kind == 2 else \
            np.array([0.25, 0.75, 1.25, 1.75]) * math.pi + rng.uniform(0, math.pi / 2)
        radii = rng.uniform(0.6, 1.0, count) if kind == 2 else np.ones(count)
        pts = np.stack([cx + rx * radii * np.cos(angles), cy + ry * radii * np.sin(angles)], 1)
        cv2.fillPoly(big, [np.round(pts).astype(np.int32)], 255)
    return cv2.resize(big.astype(np.float32) / 255.0, (w, h), interpolation=cv2.INTER_AREA)


def dead_leaves(rng: np.random.Generator, h: int, w: int, coverage: float, r_min: float, r_max: float,
                ranges: VideoSceneRanges) -> np.ndarray:
    """A dead-leaves reflectance image: textured shapes with radius density ~ r^-3 on [r_min, r_max],
    each drawn over the earlier ones, as many as cover each point ``coverage`` times on average."""
    image = np.full((h, w), _log_uniform(rng, *ranges.reflectance), np.float32)
    mean_r2 = 2 * r_min ** 2 * math.log(r_max / r_min) / (1 - (r_min / r_max) ** 2)  # E[r^2] of r^-3
    count = min(int(coverage * h * w / (math.pi * mean_r2)) + 1, 20000)
    u = rng.random(count)
    radii = 1.0 / np.sqrt(u / r_min ** 2 + (1 - u) / r_max ** 2)  # inverse CDF of p(r) ~ r^-3
    for r in radii:
        rh, rw = max(2, int(2 * r * rng.uniform(0.5, 1.5))), max(2, int(2 * r * rng.uniform(0.5, 1.5)))
        if max(rh, rw) < _SMALL_LEAF:  # most leaves: flat, drawn directly (no per-leaf texture or mask)
            centre = (int(rng.integers(0, w)), int(rng.integers(0, h)))
            cv2.ellipse(image, centre, (rw // 2, rh // 2), float(rng.uniform(0, 180)), 0, 360,
                        _log_uniform(rng, *ranges.reflectance), -1)
            continue
        x0, y0 = int(rng.integers(-rw // 2, w - rw // 2)), int(rng.integers(-rh // 2, h - rh // 2))
        ys, xs = slice(max(y0, 0), min(y0 + rh, h)), slice(max(x0, 0), min(x0 + rw, w))
        if ys.start >= ys.stop or xs.start >= xs.stop:
            continue
        mask = _shape_mask(rng, rh, rw)[ys.start - y0: ys.stop - y0, xs.start - x0: xs.stop - x0]
        tex = _leaf_texture(rng, rh, rw, ranges)[ys.start - y0: ys.stop - y0, xs.start - x0: xs.stop - x0]
        patch = image[ys, xs]
        image[ys, xs] = patch + mask * (tex - patch)
    return image


def _panorama_canvas(rng: np.random.Generator, h: int, w: int, held_out: bool) -> np.ndarray:
    """An (h, w) crop of a bundled HDR panorama (luminance, median 1) at a random zoom: natural
    texture and real HDR contrast. Training seeds never draw the held-out panorama."""
    names = EVAL_PANORAMAS if held_out else TRAIN_PANORAMAS
    pano = panorama_luminance(str(rng.choice(names)))
    ph, pw = pano.shape
    zoom = max(_log_uniform(rng, 0.7, 3.0), h / (0.8 * ph), w / pw)  # canvas pixels per panorama pixel
    ch, cw = h / zoom, w / zoom
    x0, y0 = rng.uniform(0, pw - cw), rng.uniform(0.1 * ph, max(0.1 * ph, 0.9 * ph - ch))
    crop = pano[int(y0): int(np.ceil(y0 + ch)), int(x0): int(np.ceil(x0 + cw))]
    interpolation = cv2.INTER_AREA if zoom < 1 else cv2.INTER_LINEAR
    return np.ascontiguousarray(cv2.resize(crop, (w, h), interpolation=interpolation), dtype=np.float32)


def _compress_contrast(image: np.ndarray, seed: int, ranges: VideoSceneRanges) -> np.ndarray:
    """With probability ``low_contrast_probability``, ``image`` with its log-contrast about the median
    scaled by a factor from ``low_contrast_gamma``: the low-contrast fine texture real surfaces have
    (gravel, grass, asphalt, haze) that dead leaves with reflectances over 0.03-1 rarely give. Drawn
    from its own stream, so scenes with the option off are unchanged."""
    rng = np.random.default_rng([seed, 0xC047])
    if not rng.random() < ranges.low_contrast_probability:
        return image
    median = max(float(np.median(image)), 1e-6)
    gamma = rng.uniform(*ranges.low_contrast_gamma)
    return (median * np.power(np.maximum(image, 1e-6) / median, gamma)).astype(np.float32)


@dataclass
class _Layer:
    """A static texture (value, coverage) and its affine pose over time (in raw pixels, raw planes)."""

    value: np.ndarray
    alpha: np.ndarray | None
    center: np.ndarray        # texture point that sits at ``position(t)``
    position0: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    angle0: float
    spin: float
    zoom0: float
    zoom_rate: float
    shake: np.ndarray         # (k, 4): amplitude x, amplitude y, angular frequency, phase

    def matrix(self, k: float) -> np.ndarray:
        """2x3 affine map texture -> image at raw-plane time ``k``."""
        pos = self.position0 + self.velocity * k + 0.5 * self.acceleration * k * k
        for ax, ay, omega, phase in self.shake:
            pos = pos + np.array([ax, ay]) * math.sin(omega * k + phase)
        angle = self.angle0 + self.spin * k
        zoom = self.zoom0 * math.exp(self.zoom_rate * k)
        c, s = zoom * math.cos(angle), zoom * math.sin(angle)
        rot = np.array([[c, -s], [s, c]])
        return np.concatenate([rot, (pos - rot @ self.center)[:, None]], axis=1)


class VideoScene:
    """A random video-like scene at raw size ``width`` x ``height``; ``render(k)`` is the linear
    value at raw-plane time ``k`` (plane ``k`` spans [k, k+1)) in charge per raw plane relative to
    the threshold, float32 (H, W)."""

    def __init__(self, seed: int, width: int, height: int, planes: int,
                 ranges: VideoSceneRanges | None = None, convention: str = "physical") -> None:
        if convention not in CONVENTIONS:
            raise ValueError(f"convention must be one of {CONVENTIONS}, got {convention!r}")
        ranges = ranges or VideoSceneRanges()
        self.seed, self.width, self.height, self.convention = seed, width, height, convention
        self.layers: list[_Layer] = []
        self.planes = planes
        # drawn apart from the main stream, so the other scenes of a seed do not depend on it
        if np.random.default_rng([seed, 0xF1A7]).random() < ranges.flat_probability:
            self._flat_field(np.random.default_rng([seed, 0xF1A7, 1]), ranges, convention)
            return
        rng = np.random.default_rng([seed, 0x71DE0])
        pan_rng = np.random.default_rng([seed, 0x9A11])  # apart from the main stream, like the flat fields
        rigid = pan_rng.random() < ranges.pan_probability
        # the background canvas wraps around, so a camera of any speed stays on it
        speed = 0.0 if rng.random() < ranges.static_probability else _log_uniform(rng, *ranges.camera_speed)
        if rigid:
            speed = _log_uniform(pan_rng, *ranges.pan_speed)
        direction = rng.uniform(0, 2 * math.pi)
        velocity = speed * np.array([math.cos(direction), math.sin(direction)])
        canvas_w, canvas_h = 2 * width, 2 * height
        diag = math.hypot(width, height)
        if rng.random() < ranges.panorama_probability:
            background = _panorama_canvas(rng, canvas_h, canvas_w, held_out=seed >= EVAL_SEED_START)
        else:
            background = dead_leaves(rng, canvas_h, canvas_w, rng.uniform(*ranges.coverage), 1.0, 0.5 * diag, ranges)
        background = _compress_contrast(background, seed, ranges)
        if rng.random() < ranges.shadow_probability:
            shade = _shape_mask(rng, int(canvas_h * rng.uniform(0.3, 0.8)), int(canvas_w * rng.uniform(0.3, 0.8)))
            full = np.zeros_like(background)
            y0 = int(rng.integers(0, canvas_h - shade.shape[0] + 1))
            x0 = int(rng.integers(0, canvas_w - shade.shape[1] + 1))
            full[y0:y0 + shade.shape[0], x0:x0 + shade.shape[1]] = shade
            full = cv2.GaussianBlur(full, (0, 0), rng.uniform(0.5, 6.0))
            background *= 1.0 - (1.0 - _log_uniform(rng, *ranges.shadow_attenuation)) * full
        shake = np.array([[rng.uniform(-1, 1) * ranges.shake_px, rng.uniform(-1, 1) * ranges.shake_px,
                           2 * math.pi / rng.uniform(20, 400), rng.uniform(0, 2 * math.pi)]
                          for _ in range(int(rng.integers(0, 3)))]).reshape(-1, 4)
        moving = float(speed > 0 and not rigid)  # a rigid pan: constant velocity, nothing else
        if rigid:
            shake = shake[:0]
        centre = np.array([canvas_w / 2, canvas_h / 2])
        self.layers.append(_Layer(
            value=background, alpha=None, center=centre,
            position0=np.array([width / 2, height / 2]) - velocity * planes / 2,
            velocity=velocity, acceleration=rng.normal(0, 2e-4, 2) * moving,
            angle0=0.0, spin=rng.normal(0, 2e-4) * moving, zoom0=1.0,
            zoom_rate=rng.uniform(-1, 1) * ranges.zoom_rate * moving, shake=shake))
        for _ in range(0 if rigid else int(rng.integers(0, ranges.max_objects + 1))):
            self.layers.append(self._object(rng, ranges, planes))
        median = float(np.median(self._render_raw(planes / 2)))
        level = _log_uniform(rng, *ranges.median_rate)
        if convention == "spikezoo":
            # an 8-bit video: intensity in [0, 1] (median 0.1-0.8), firing rate 0.6 x intensity
            self.scale = rng.uniform(0.1, 0.8) / max(median, 1e-6)
            self.clip = 1.0
            self.gain = SPIKEZOO_RATE
        else:
            self.scale = level / max(median, 1e-6)
            self.clip = math.inf
            self.gain = 1.0

    def _flat_field(self, rng: np.random.Generator, ranges: VideoSceneRanges, convention: str) -> None:
        """A static field with a gentle linear gradient: the dark flat regions where a network must
        neither invent texture nor pull the level down."""
        y, x = np.mgrid[0:2 * self.height, 0:2 * self.width].astype(np.float32)
        angle = rng.uniform(0, 2 * math.pi)
        u = (x * math.cos(angle) + y * math.sin(angle)) / max(2 * self.width, 2 * self.height)
        value = (1.0 + ranges.flat_gradient * rng.uniform(-1, 1) * (u - float(u.mean()))).astype(np.float32)
        self.layers.append(_Layer(
            value=value, alpha=None, center=np.array([self.width, self.height], float),
            position0=np.array([self.width / 2, self.height / 2]), velocity=np.zeros(2), acceleration=np.zeros(2),
            angle0=0.0, spin=0.0, zoom0=1.0, zoom_rate=0.0, shake=np.zeros((0, 4))))
        if convention == "spikezoo":
            self.scale, self.clip, self.gain = rng.uniform(0.05, 0.8), 1.0, SPIKEZOO_RATE
        else:
            self.scale, self.clip, self.gain = _log_uniform(rng, *ranges.flat_rate), math.inf, 1.0

    def _object(self, rng: np.random.Generator, ranges: VideoSceneRanges, planes: int) -> _Layer:
        diag = math.hypot(self.width, self.height)
        h, w = (max(6, int(diag * rng.uniform(0.06, 0.45))) for _ in range(2))
        light = rng.random() < ranges.light_probability
        if light:
            value = np.full((h, w), _log_uniform(rng, *ranges.light_radiance), np.float32)
            if rng.random() < 0.5:  # a textured lamp / screen
                value *= _leaf_texture(rng, h, w, ranges) / ranges.reflectance[1]
        else:
            value = dead_leaves(rng, h, w, rng.uniform(1.0, 4.0), 1.0, 0.5 * max(h, w), ranges)
        speed = _log_uniform(rng, *ranges.object_speed)
        direction = rng.uniform(0, 2 * math.pi)
        velocity = speed * np.array([math.cos(direction), math.sin(direction)])
        # place it so it crosses the view around the middle of the sample
        mid = np.array([rng.uniform(0, self.width), rng.uniform(0, self.height)])
        return _Layer(
            value=np.ascontiguousarray(value), alpha=_shape_mask(rng, h, w), center=np.array([w / 2, h / 2]),
            position0=mid - velocity * planes / 2, velocity=velocity, acceleration=rng.normal(0, 1e-3, 2),
            angle0=rng.uniform(0, 2 * math.pi), spin=rng.uniform(-1, 1) * ranges.object_spin,
            zoom0=1.0, zoom_rate=rng.uniform(-1, 1) * ranges.object_zoom_rate, shake=np.zeros((0, 4)))

    def _render_raw(self, k: float) -> np.ndarray:
        size = (self.width, self.height)
        image = None
        for layer in self.layers:
            m = layer.matrix(k)
            border = cv2.BORDER_WRAP if layer.alpha is None else cv2.BORDER_REFLECT
            value = cv2.warpAffine(layer.value, m, size, flags=cv2.INTER_LINEAR, borderMode=border)
            if layer.alpha is None:
                image = value
                continue
            alpha = cv2.warpAffine(layer.alpha, m, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            image += alpha * (value - image)
        assert image is not None
        return image

    def render(self, k: float) -> np.ndarray:
        """Linear value (H, W) float32 at raw-plane time ``k``: charge per raw plane / threshold."""
        image = np.minimum(self._render_raw(k) * np.float32(self.scale), np.float32(self.clip))
        return np.maximum(image * np.float32(self.gain), 0.0)

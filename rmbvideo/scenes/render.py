"""Exact, cheap rendering of a scene at any time, and its exact optical flow.

Geometry: image pixel ``(x, y)`` has its centre at ``(x + 0.5, y + 0.5)``; the camera looks at
panorama point ``center(t) + (X - size/2) / zoom(t)`` with ``center(t) = center + velocity * t``
and ``zoom(t) = zoom * exp(zoom_rate * t)``. The panorama wraps horizontally and is mirrored at
its top and bottom. Sampling is bilinear (``cv2.remap``) without prefiltering, so keep ``zoom``
near or above 0.5. Objects move in image space over the background; each pixel's coverage by an
object is anti-aliased over one pixel of its edge.

Times may be a scalar or an (H, 1) array (one time per row), which renders a rolling readout
exactly at the same cost.

Flow ``flow(t0, t1)`` is the forward motion of the content visible at each pixel at ``t0``
(the topmost object whose coverage exceeds one half, else the background) to where that same
point is at ``t1``. Occlusions are not masked: a background point hidden by an object at ``t1``
still gets its background motion.
"""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np

from rmbvideo.errors import InputError
from rmbvideo.scenes.scene import HDRI_DIR, Background, DarkRegion, Scene, SceneObject, bundled_panoramas

_PAD = 2  # columns of horizontal wrap padding, so bilinear sampling crosses the seam
_LED_BASE = 0.01  # housing of an LED array, relative to the LED peak


def panorama_path(name: str) -> Path:
    """Path of a bundled panorama by name, or ``name`` itself when it is a file."""
    bundled = HDRI_DIR / f"{name}.exr"
    if bundled.is_file():
        return bundled
    path = Path(name)
    if path.is_file():
        return path
    raise InputError(f"{name}: no such panorama file or bundled panorama (bundled: {', '.join(bundled_panoramas())})")


@functools.lru_cache(maxsize=8)
def panorama_luminance(name: str) -> np.ndarray:
    """Linear luminance of a panorama divided by its median (so typical content is ~1), float32."""
    from rmbvideo.io.exr import read_exr_rgb

    rgb = read_exr_rgb(panorama_path(name))
    lum = np.maximum(rgb @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32), 0.0)
    median = float(np.median(lum))
    if median <= 0:
        positive = lum[lum > 0]
        median = float(np.median(positive)) if positive.size else 1.0
    lum = (lum / median).astype(np.float32)
    lum.setflags(write=False)
    return lum


def _attenuation_mask(shape: tuple[int, int], regions: tuple[DarkRegion, ...]) -> np.ndarray:
    mask = np.ones(shape, dtype=np.float32)
    for region in regions:
        x, y, w, h = region.rect
        box = np.zeros(shape, dtype=np.float32)
        x0, x1 = int(round(x)), int(round(x + w))
        y0, y1 = max(0, int(round(y))), min(shape[0], int(round(y + h)))
        cols = np.arange(x0, x1) % shape[1]  # rectangles may cross the horizontal seam
        box[y0:y1, cols] = 1.0
        if region.softness > 0:
            box = cv2.GaussianBlur(box, (0, 0), region.softness, borderType=cv2.BORDER_REFLECT)
        mask *= 1.0 - (1.0 - region.attenuation) * box
    return mask


def _rotation(angle: np.ndarray | float) -> tuple[np.ndarray | float, np.ndarray | float]:
    return np.cos(angle), np.sin(angle)


class _ObjectLayer:
    """One object: its texture and its pose at any time."""

    def __init__(self, obj: SceneObject) -> None:
        self.obj = obj
        self.width, self.height = obj.size
        self.texture = (self._texture(obj) * obj.radiance).astype(np.float32)
        self.radius = 0.5 * float(np.hypot(self.width, self.height)) + 1.0

    @staticmethod
    def _texture(obj: SceneObject) -> np.ndarray:
        tw, th = max(8, int(np.ceil(obj.size[0]))), max(8, int(np.ceil(obj.size[1])))
        if obj.texture == "uniform":
            return np.ones((th, tw), dtype=np.float32)
        if obj.texture == "checker":
            yy, xx = np.mgrid[0:th, 0:tw]
            return np.where(((yy // 8) + (xx // 8)) % 2 == 0, 1.0, 0.2).astype(np.float32)
        if obj.texture == "led":
            cols, rows = obj.grid
            yy, xx = np.mgrid[0:th, 0:tw].astype(np.float32) + 0.5
            cell_w, cell_h = tw / cols, th / rows
            dx = (xx % cell_w) - cell_w / 2
            dy = (yy % cell_h) - cell_h / 2
            sigma = max(0.7, min(cell_w, cell_h) / 6)
            return (_LED_BASE + np.exp(-(dx ** 2 + dy ** 2) / (2 * sigma ** 2))).astype(np.float32)
        pano = panorama_luminance(obj.texture.split(":", 1)[1])
        x, y, w, h = obj.crop if obj.crop is not None else (
            (pano.shape[1] - tw) / 2, (pano.shape[0] - th) / 2, tw, th)
        cols = np.arange(int(round(x)), int(round(x + w))) % pano.shape[1]
        rows = np.clip(np.arange(int(round(y)), int(round(y + h))), 0, pano.shape[0] - 1)
        return pano[np.ix_(rows, cols)]

    def pose(self, t: np.ndarray | float) -> tuple:
        """Centre (x, y) and angle (radians) at time(s) ``t``."""
        o = self.obj
        cx = o.position[0] + o.velocity[0] * t
        cy = o.position[1] + o.velocity[1] * t
        angle = np.deg2rad(o.angle_deg + o.angular_velocity_deg * t)
        return cx, cy, angle

    def local(self, X: np.ndarray, Y: np.ndarray, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Object-frame coordinates of image points (X, Y) at time(s) ``t``."""
        cx, cy, angle = self.pose(t)
        c, s = _rotation(angle)
        dx, dy = X - cx, Y - cy
        return c * dx + s * dy, -s * dx + c * dy

    def coverage(self, qx: np.ndarray, qy: np.ndarray) -> np.ndarray:
        """Fraction of a pixel covered, from the signed distance to the edge (1-px ramp)."""
        hw, hh = self.width / 2, self.height / 2
        if self.obj.shape == "rect":
            distance = np.maximum(np.abs(qx) - hw, np.abs(qy) - hh)
        else:
            norm = np.sqrt((qx / hw) ** 2 + (qy / hh) ** 2)
            distance = (norm - 1.0) * min(hw, hh)
        return np.clip(0.5 - distance, 0.0, 1.0).astype(np.float32)

    def sample(self, qx: np.ndarray, qy: np.ndarray) -> np.ndarray:
        th, tw = self.texture.shape
        map_x = ((qx / self.width + 0.5) * tw - 0.5).astype(np.float32)
        map_y = ((qy / self.height + 0.5) * th - 0.5).astype(np.float32)
        return cv2.remap(self.texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def bounds(self, t_min: float, t_max: float, width: int, height: int) -> tuple[slice, slice] | None:
        """Image rows/columns the object can touch between two times (None if off-screen)."""
        x0, y0, _ = self.pose(t_min)
        x1, y1, _ = self.pose(t_max)
        left = int(np.floor(min(x0, x1) - self.radius))
        right = int(np.ceil(max(x0, x1) + self.radius)) + 1
        top = int(np.floor(min(y0, y1) - self.radius))
        bottom = int(np.ceil(max(y0, y1) + self.radius)) + 1
        left, right = max(left, 0), min(right, width)
        top, bottom = max(top, 0), min(bottom, height)
        if left >= right or top >= bottom:
            return None
        return slice(top, bottom), slice(left, right)


class SceneRenderer:
    """Linear radiance (luminance) of a scene at the raw sensor size, at any time."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.width, self.height = scene.width, scene.height
        self.background: Background = scene.background
        pano = panorama_luminance(self.background.panorama)
        if scene.dark_regions:
            pano = pano * _attenuation_mask(pano.shape, scene.dark_regions)
        self.pano_width = pano.shape[1]
        self.pano = np.ascontiguousarray(
            np.concatenate([pano[:, -_PAD:], pano, pano[:, :_PAD]], axis=1) * self.background.gain,
            dtype=np.float32)
        self.layers = [_ObjectLayer(obj) for obj in scene.objects]
        self.x = np.arange(self.width, dtype=np.float64)[None, :] + 0.5
        self.y = np.arange(self.height, dtype=np.float64)[:, None] + 0.5

    def rows_past_panorama(self, t_end: float) -> tuple[float, float]:
        """Panorama rows the view reaches above the top and below the bottom over [0, t_end], where
        the panorama is mirrored. Both reaches (``h / 2 / zoom(t) -+ cy(t)`` past an edge) are convex in t, so
        their maxima lie at the ends."""
        above = below = 0.0
        for t in (0.0, t_end):
            _, cy, zoom = self.camera(t)
            half = self.height / 2 / zoom
            above, below = max(above, half - cy), max(below, cy + half - self.pano.shape[0])
        return above, below

    def camera(self, t: np.ndarray | float) -> tuple:
        """Panorama centre (x, y) and zoom at time(s) ``t``."""
        b = self.background
        zoom = b.zoom * np.exp(b.zoom_rate * t)
        return b.center[0] + b.velocity[0] * t, b.center[1] + b.velocity[1] * t, zoom

    def render(self, t: np.ndarray | float) -> np.ndarray:
        """Radiance (H, W) float32 at time ``t`` (scalar, or (H, 1) for one time per row)."""
        cx, cy, zoom = self.camera(t)
        u = cx + (self.x - self.width / 2) / zoom
        v = cy + (self.y - self.height / 2) / zoom
        shape = (self.height, self.width)
        map_x = np.broadcast_to(np.mod(u - 0.5, self.pano_width) + _PAD, shape).astype(np.float32)
        map_y = np.broadcast_to(v - 0.5, shape).astype(np.float32)
        image = cv2.remap(self.pano, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        times = np.asarray(t, dtype=np.float64)
        for layer in self.layers:
            box = layer.bounds(float(times.min()), float(times.max()), self.width, self.height)
            if box is None:
                continue
            rows, cols = box
            t_box = times[rows] if times.ndim == 2 else times
            qx, qy = layer.local(self.x[:, cols], self.y[rows], t_box)
            cover = layer.coverage(qx, qy)
            patch = image[rows, cols]
            image[rows, cols] = patch + cover * (layer.sample(qx, qy) - patch)
        return image

    def flow(self, t0: float, t1: float) -> np.ndarray:
        """Exact forward flow (H, W, 2) float32 (dx, dy) in pixels of the content visible at ``t0``."""
        cx0, cy0, z0 = self.camera(t0)
        cx1, cy1, z1 = self.camera(t1)
        X = np.broadcast_to(self.x, (self.height, self.width))
        Y = np.broadcast_to(self.y, (self.height, self.width))
        flow = np.empty((self.height, self.width, 2), dtype=np.float64)
        flow[..., 0] = (cx0 - cx1) * z1 + (X - self.width / 2) * (z1 / z0 - 1.0)
        flow[..., 1] = (cy0 - cy1) * z1 + (Y - self.height / 2) * (z1 / z0 - 1.0)
        for layer in self.layers:
            qx, qy = layer.local(X, Y, t0)
            visible = layer.coverage(qx, qy) > 0.5
            if not visible.any():
                continue
            cx, cy, angle = layer.pose(t1)
            c, s = _rotation(angle)
            flow[..., 0] = np.where(visible, cx + c * qx - s * qy - X, flow[..., 0])
            flow[..., 1] = np.where(visible, cy + s * qx + c * qy - Y, flow[..., 1])
        return flow.astype(np.float32)


def bin_image(image: np.ndarray) -> np.ndarray:
    """Average 2x2 blocks (drops a trailing odd row/column), keeping the units of ``image``."""
    h, w = image.shape[0] // 2 * 2, image.shape[1] // 2 * 2
    return cv2.resize(image[:h, :w], (w // 2, h // 2), interpolation=cv2.INTER_AREA)


def ground_truth(renderer: SceneRenderer, t: float) -> np.ndarray:
    """Linear HDR ground truth at time ``t``: exposure * radiance / Q_r, i.e. expected photo-charge
    per *raw* readout relative to the threshold, at the output size of the scene's readout."""
    scene = renderer.scene
    image = renderer.render(t) * np.float32(scene.exposure / scene.sensor.q_r)
    return bin_image(image) if scene.readout.kind == "binned" else image


def ground_truth_flow(renderer: SceneRenderer, t0: float, t1: float) -> np.ndarray:
    """Exact flow from ``t0`` to ``t1`` at the output size of the scene's readout (pixels there)."""
    flow = renderer.flow(t0, t1)
    return bin_image(flow) * np.float32(0.5) if renderer.scene.readout.kind == "binned" else flow

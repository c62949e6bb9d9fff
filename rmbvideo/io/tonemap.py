"""Tone mapping linear HDR frames to 8-bit display video.

``ToneMapper`` applies the paper's tone curve (``rmbvideo.mulaw``)
to a stream of frames with a robust, temporally smoothed exposure so the video does not flicker:
each frame's high percentile sets a white point, and that white point is smoothed with an
exponential moving average in log space. OpenCV's Reinhard, Drago and Mantiuk operators are
offered as alternatives on the same normalised input.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from rmbvideo.mulaw import mu_law

log = logging.getLogger(__name__)

ToneMethod = Literal["exposure", "mulaw", "reinhard", "drago", "mantiuk"]
TONE_METHODS: tuple[str, ...] = ("exposure", "mulaw", "reinhard", "drago", "mantiuk")
#: "exposure": the log-average light of a frame (smoothed over time) is exposed to this grey ...
MIDDLE_GREY = 0.18
#: ... with a gain limited to this range, so a dark capture stays dark and a bright one is not crushed.
GAIN_RANGE = (0.125, 8.0)

# Frames larger than this are subsampled (with a fixed stride) to estimate the white point.
_MAX_PERCENTILE_SAMPLES = 1 << 18


@dataclass(frozen=True)
class ToneMapConfig:
    """How linear frames become 8-bit: the operator and its exposure normalisation.

    ``percentile`` of each frame is mapped to white; it is smoothed over frames with an exponential
    moving average of time constant ``smoothing_frames`` (0 disables smoothing) in log space.
    ``min_white`` floors the white point so dark frames are not amplified without limit.
    ``gamma`` applies to the OpenCV operators only (the mu-law curve is already perceptual).
    """

    method: ToneMethod = "exposure"
    mu: float = 5000.0
    percentile: float = 99.5
    smoothing_frames: float = 8.0
    min_white: float = 1e-6
    gamma: float = 2.2

    def __post_init__(self) -> None:
        if self.method not in TONE_METHODS:
            raise ValueError(f"unknown tone-mapping method {self.method!r}; use one of {TONE_METHODS}")
        if not 0.0 < self.percentile <= 100.0:
            raise ValueError(f"percentile must be in (0, 100], got {self.percentile}")
        if self.smoothing_frames < 0:
            raise ValueError(f"smoothing_frames must be >= 0, got {self.smoothing_frames}")
        if not self.min_white > 0:
            raise ValueError(f"min_white must be positive, got {self.min_white}")
        if self.mu <= 0 or self.gamma <= 0:
            raise ValueError("mu and gamma must be positive")


class ToneMapper:
    """Streaming tone mapper: feed linear frames in order, get uint8 (H, W) frames back.

    Deterministic: the output depends only on the config and the frames fed so far.
    ``nonfinite_pixels`` counts NaN/Inf input pixels that were treated as 0.
    """

    def __init__(self, config: ToneMapConfig | None = None) -> None:
        self.config = config or ToneMapConfig()
        self._log_white: float | None = None
        self._log_key: float | None = None
        self._uses_opencv = _opencv_operator(self.config) is not None
        self.nonfinite_pixels = 0
        self._fallback_logged = False

    @property
    def state(self) -> list[float | None]:
        """The smoothed exposure state (log white point, log key), which ``restore`` sets back: a resumed run
        continues the tone mapping exactly where the interrupted one was."""
        return [self._log_white, self._log_key]

    def restore(self, state: list[float | None]) -> None:
        """Set the state ``state`` gave."""
        self._log_white, self._log_key = state

    @property
    def white(self) -> float:
        """The current smoothed linear value that maps to white."""
        if self._log_white is None:
            return self.config.min_white
        return math.exp(self._log_white)

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """Tone-map one linear (H, W) frame to uint8, updating the exposure state."""
        if image.ndim != 2:
            raise ValueError(f"expected a (H, W) image, got shape {image.shape}")
        linear = np.asarray(image, dtype=np.float32)
        finite = np.isfinite(linear)
        if not finite.all():
            bad = int(finite.size - np.count_nonzero(finite))
            if self.nonfinite_pixels == 0:
                log.warning("tone mapping: %d NaN/Inf pixels in a frame treated as 0", bad)
            self.nonfinite_pixels += bad
            linear = np.where(finite, linear, np.float32(0.0))
        linear = np.maximum(linear, np.float32(0.0))
        self._update_white(linear)
        if self.config.method == "exposure":
            return _to_uint8(self._expose(linear))
        normalised = linear / np.float32(self.white)
        if not self._uses_opencv:
            display = mu_law(normalised, self.config.mu)
        else:
            display = self._apply_opencv(normalised)
        return _to_uint8(display)

    def _expose(self, linear: np.ndarray) -> np.ndarray:
        """The default operator: a camera-like exposure that follows the absolute scene level.

        The frame's log-average light (smoothed over frames in log space, like the white point) is
        exposed to ``MIDDLE_GREY`` with a gain within ``GAIN_RANGE``; Reinhard's extended curve rolls
        the highlights off so the smoothed white point reaches 1; BT.709's transfer function encodes
        the result (the tags the MP4 and PNG outputs carry)."""
        key = float(np.mean(np.log(linear.astype(np.float64) + 1e-4)))  # log of the log-average light
        if self._log_key is None or self.config.smoothing_frames == 0:
            self._log_key = key
        else:
            self._log_key += (1.0 - math.exp(-1.0 / self.config.smoothing_frames)) * (key - self._log_key)
        gain = float(np.clip(MIDDLE_GREY / math.exp(self._log_key), *GAIN_RANGE))
        white = max(1.0, gain * self.white)
        x = np.minimum(linear.astype(np.float64) * gain, white)  # at the white point the curve is 1
        y = x * (1.0 + x / (white * white)) / (1.0 + x)
        return np.where(y < 0.018, 4.5 * y, 1.099 * np.power(np.minimum(y, 1.0), 0.45) - 0.099)

    def _update_white(self, linear: np.ndarray) -> None:
        """Blend this frame's white point into the running estimate (log-space EMA)."""
        samples = linear.ravel()
        if samples.size > _MAX_PERCENTILE_SAMPLES:
            samples = samples[:: -(-samples.size // _MAX_PERCENTILE_SAMPLES)]
        frame_white = float(np.percentile(samples, self.config.percentile))
        if not frame_white > 0.0:
            return  # an all-dark frame carries no exposure information
        log_white = math.log(max(frame_white, self.config.min_white))
        if self._log_white is None or self.config.smoothing_frames == 0:
            self._log_white = log_white
        else:
            weight = 1.0 - math.exp(-1.0 / self.config.smoothing_frames)
            self._log_white += weight * (log_white - self._log_white)

    def _apply_opencv(self, normalised: np.ndarray) -> np.ndarray:
        """Run the OpenCV operator on a replicated 3-channel image; NaN output becomes 0."""
        if not normalised.max() > 0.0:
            return np.zeros_like(normalised)  # OpenCV's operators reject an all-black image
        import cv2

        bgr = np.ascontiguousarray(np.repeat(normalised[:, :, None], 3, axis=2))
        try:
            # a fresh operator a frame: OpenCV's Reinhard keeps state between calls (the same image mapped twice by one
            # operator differs by up to 0.033), so a frame's tones would depend on how many frames came before it
            mapped = _opencv_operator(self.config).process(bgr)[:, :, 0]
        except cv2.error:
            # Degenerate frames (e.g. perfectly flat) fail OpenCV's internal checks.
            if not self._fallback_logged:
                log.warning("tone mapping: %s rejected a degenerate frame; using mu-law for it",
                            self.config.method)
                self._fallback_logged = True
            return mu_law(normalised, self.config.mu)
        return np.nan_to_num(mapped, nan=0.0, posinf=1.0, neginf=0.0)


def _opencv_operator(config: ToneMapConfig) -> Any:
    """The OpenCV tone-map object for ``config.method``, or None for the built-in operators."""
    if config.method in ("mulaw", "exposure"):
        return None
    import cv2

    if config.method == "reinhard":
        return cv2.createTonemapReinhard(gamma=config.gamma)
    if config.method == "drago":
        return cv2.createTonemapDrago(gamma=config.gamma)
    return cv2.createTonemapMantiuk(gamma=config.gamma)


def _to_uint8(display: np.ndarray) -> np.ndarray:
    """Map display values in [0, 1] to uint8 with rounding; out-of-range values are clipped."""
    return np.rint(np.clip(display, 0.0, 1.0) * 255.0).astype(np.uint8)

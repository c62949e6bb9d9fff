"""HDR video: HEVC Main10 in BT.2020 with the PQ (SMPTE ST 2084, "HDR10") or HLG (ARIB STD-B67)
transfer, so the capture's dynamic range reaches an HDR display without tone compression.

Exposure: the light a pixel encodes is ``nits = linear * nits_per_unit`` (linear in the project's
unit, expected charge per raw plane relative to the threshold, as in the EXR output): monotone, one
number for the whole video. Unless given, it is chosen once per capture from its first frames
(``auto_nits_per_unit``: their median at ``MID_NITS``, kept between ``NITS_PER_UNIT_RANGE``) and
logged. PQ encodes absolute luminance up to 10,000 nits; HLG is relative to a 1,000-nit display
(``HLG_PEAK_NITS``), values above it are clipped. Frames are grey (R = G = B), so only luma carries
information; odd sizes are padded by one edge row/column (Main10 is 4:2:0). HDR10 streams carry
mastering-display and content-light-level metadata: MaxCLL is the brightest light any pixel can
encode (sensor saturation, 1 unit, times ``nits_per_unit``), MaxFALL the first frames' mean.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from rmbvideo.errors import OutputError
from rmbvideo.io.sinks import Mp4Sink
from rmbvideo.io.tonemap import ToneMapConfig

log = logging.getLogger(__name__)

PQ_PEAK_NITS = 10000.0
HLG_PEAK_NITS = 1000.0
MID_NITS = 20.0
NITS_PER_UNIT_RANGE = (200.0, 10000.0)
LUMA_BLACK, LUMA_SPAN, CHROMA_NEUTRAL = 64, 876, 512  # 10-bit limited ("tv") range
PREPARE_FRAMES = 8  # frames buffered to choose the exposure before encoding starts
#: x265 refuses pictures under 16 pixels a side ("Image size is too small"), after the odd-size padding
#: (models/experiments/ffmpeg-limits/scan.py).
HEVC_MIN_SIDE = 16
_X265_CRF = 18
# SMPTE ST 2084 constants
_M1, _M2 = 2610 / 16384, 2523 / 4096 * 128
_C1, _C2, _C3 = 3424 / 4096, 2413 / 4096 * 32, 2392 / 4096 * 32
# ARIB STD-B67 constants
_A, _B, _C = 0.17883277, 0.28466892, 0.55991073
# BT.2020 primaries and D65 white in units of 0.00002 (x265 master-display syntax)
_BT2020_DISPLAY = "G(8500,39850)B(6550,2300)R(35400,14600)WP(15635,16450)"
_COMMON_TAGS = ["-colorspace", "bt2020nc", "-color_primaries", "bt2020", "-color_range", "tv", "-tag:v", "hvc1",
                "-profile:v", "main10"]


def pq_encode(nits: np.ndarray) -> np.ndarray:
    """SMPTE ST 2084 inverse EOTF: absolute luminance (cd/m^2) -> signal in [0, 1]."""
    y = np.clip(np.asarray(nits, np.float64) / PQ_PEAK_NITS, 0.0, 1.0) ** _M1
    return ((_C1 + _C2 * y) / (1.0 + _C3 * y)) ** _M2


def pq_decode(signal: np.ndarray) -> np.ndarray:
    """SMPTE ST 2084 EOTF: signal in [0, 1] -> absolute luminance (cd/m^2)."""
    e = np.clip(np.asarray(signal, np.float64), 0.0, 1.0) ** (1.0 / _M2)
    return PQ_PEAK_NITS * (np.maximum(e - _C1, 0.0) / (_C2 - _C3 * e)) ** (1.0 / _M1)


def hlg_encode(nits: np.ndarray) -> np.ndarray:
    """ARIB STD-B67 OETF of light relative to a ``HLG_PEAK_NITS`` display -> signal in [0, 1]."""
    e = np.clip(np.asarray(nits, np.float64) / HLG_PEAK_NITS, 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_part = _A * np.log(np.maximum(12.0 * e - _B, 1e-12)) + _C
    return np.where(e <= 1.0 / 12.0, np.sqrt(3.0 * e), log_part)


def hlg_decode(signal: np.ndarray) -> np.ndarray:
    """Inverse of ``hlg_encode``: signal in [0, 1] -> nits (relative to ``HLG_PEAK_NITS``)."""
    v = np.clip(np.asarray(signal, np.float64), 0.0, 1.0)
    e = np.where(v <= 0.5, v * v / 3.0, (np.exp((v - _C) / _A) + _B) / 12.0)
    return e * HLG_PEAK_NITS


ENCODE = {"pq": pq_encode, "hlg": hlg_encode}
DECODE = {"pq": pq_decode, "hlg": hlg_decode}


def auto_nits_per_unit(images: list[np.ndarray]) -> float:
    """The exposure of a capture from its first frames: their median light at ``MID_NITS``, the
    result kept within ``NITS_PER_UNIT_RANGE`` (so a dark capture stays dark, a bright one fits)."""
    values = np.concatenate([np.asarray(i, np.float64).ravel() for i in images]) if images else np.zeros(1)
    median = float(np.median(values[values > 0])) if np.any(values > 0) else 0.0
    low, high = NITS_PER_UNIT_RANGE
    return float(np.clip(MID_NITS / median, low, high)) if median > 0 else low


class HdrVideoSink(Mp4Sink):
    """HEVC Main10 HDR video (``transfer`` "pq" for HDR10, "hlg" for HLG) with ``frames.csv``."""

    def __init__(self, outdir: Path, stem: str, *, transfer: str, fps: float, nits_per_unit: float | None,
                 capture_rate_hz: float | None, frame_rate_hz: float | None) -> None:
        if transfer not in ENCODE:
            raise ValueError(f"transfer must be one of {sorted(ENCODE)}, got {transfer!r}")
        if nits_per_unit is not None and not nits_per_unit > 0:
            raise ValueError(f"nits per unit must be positive, got {nits_per_unit}")
        super().__init__(outdir, stem, fps=fps, tonemap=ToneMapConfig(), pixel_format="yuv420p",
                         capture_rate_hz=capture_rate_hz, frame_rate_hz=frame_rate_hz)
        self.pixel_format = "yuv420p10le"
        self.transfer = transfer
        self.nits_per_unit = nits_per_unit
        self._pending: list[tuple] = []
        self._mean_nits = 0.0

    def _encode(self, image: np.ndarray) -> np.ndarray:
        """Linear frame -> 10-bit limited-range luma codes (64 + 876 E'), computed here so the
        stream holds exactly the transfer function's values."""
        signal = ENCODE[self.transfer](image.astype(np.float64) * self.nits_per_unit)
        return np.round(LUMA_BLACK + LUMA_SPAN * signal).astype("<u2")

    def _frame_bytes(self, pixels: np.ndarray) -> bytes:
        """Planar 4:2:0 10-bit: the luma codes and neutral chroma (grey, R = G = B)."""
        height, width = pixels.shape
        chroma = np.full((2, height // 2, width // 2), CHROMA_NEUTRAL, "<u2")
        return np.ascontiguousarray(pixels).tobytes() + chroma.tobytes()

    def _codec_args(self, shape: tuple[int, int]) -> tuple[str, str, str, list[str]]:
        if self.transfer == "pq":
            max_cll = int(round(min(PQ_PEAK_NITS, self.nits_per_unit)))
            max_fall = int(round(min(max_cll, self._mean_nits)))
            x265 = (f"hdr10=1:hdr10-opt=1:repeat-headers=1:colorprim=bt2020:transfer=smpte2084:"
                    f"colormatrix=bt2020nc:range=limited:master-display={_BT2020_DISPLAY}"
                    f"L({max_cll * 10000},1):max-cll={max_cll},{max_fall}:log-level=error")
            trc = "smpte2084"
        else:
            x265 = "repeat-headers=1:colorprim=bt2020:transfer=arib-std-b67:colormatrix=bt2020nc:range=limited:log-level=error"
            trc = "arib-std-b67"
        params = ["-crf", str(_X265_CRF), *_COMMON_TAGS, "-color_trc", trc, "-x265-params", x265]
        return self.pixel_format, self.pixel_format, "libx265", params

    def _write(self, frame, image: np.ndarray) -> None:
        if self.frames_written == 0 and not self._pending:
            self._check_size(image.shape)
        if self.nits_per_unit is None:  # hold the first frames until the exposure is chosen
            self._pending.append((frame, image))
            if len(self._pending) < PREPARE_FRAMES:
                return
            self._choose_exposure()
            return
        if self._encoder is None and not self._mean_nits:
            self._mean_nits = float(np.mean(image)) * self.nits_per_unit
        super()._write(frame, image)

    def _check_size(self, shape: tuple[int, ...]) -> None:
        """Refuse, at the first frame, a size x265 would refuse only when the whole capture has run."""
        height, width = shape[:2]
        if min(height + height % 2, width + width % 2) < HEVC_MIN_SIDE:
            fmt = "hdr10" if self.transfer == "pq" else "hlg"
            raise OutputError(
                f"{self.path}: HEVC ({fmt}) needs frames at least {HEVC_MIN_SIDE - 1}x{HEVC_MIN_SIDE - 1} "
                f"pixels; these are {width}x{height}: use --format mp4, png or exr")

    def _choose_exposure(self) -> None:
        images = [image for _, image in self._pending]
        if self.nits_per_unit is None:
            self.nits_per_unit = auto_nits_per_unit(images)
            log.info("%s: exposure %.4g nits per unit (median of the first %d frames at %g nits; "
                     "override with --nits-per-unit)", self.path.name, self.nits_per_unit, len(images), MID_NITS)
        self._mean_nits = float(np.mean([np.mean(i) for i in images])) * self.nits_per_unit if images else 0.0
        pending, self._pending = self._pending, []
        for frame, image in pending:
            Mp4Sink._write(self, frame, image)

    def _commit(self) -> None:
        if self._pending or self.nits_per_unit is None:
            self._choose_exposure()
        super()._commit()

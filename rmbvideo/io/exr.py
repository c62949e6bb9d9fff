"""OpenEXR frames: single-channel linear HDR output with its capture time, and RGB input.

Output frames hold one channel ``Y`` (linear luminance in the sensor model's units), ZIP
compressed. Half floats are the default: they cover about 6e-8 .. 65504 with 11 significant
bits, ample for camera noise; values above 65504 are clipped to 65504 (never written as Inf).
``dtype="float"`` keeps full float32. The capture time goes in the header twice: ``captureTime``
(an EXR float, about 7 significant digits) and ``rmbvideo:time_s`` (a string, exact).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Literal

import numpy as np

from rmbvideo.errors import InputError, OutputError, RmbvideoError
from rmbvideo.io.atomic import atomic_path

log = logging.getLogger(__name__)

ExrDtype = Literal["half", "float"]
HALF_MAX = 65504.0
TIME_ATTRIBUTE = "rmbvideo:time_s"
CAPTURE_TIME_ATTRIBUTE = "captureTime"


def write_exr(
    path: Path,
    image: np.ndarray,
    *,
    time_s: float,
    dtype: ExrDtype = "half",
    attrs: dict[str, Any] | None = None,
) -> int:
    """Write a linear (H, W) frame as a one-channel ``Y`` EXR, atomically.

    NaN/Inf pixels are written as 0 (returns how many there were, so callers can count them).
    ``attrs`` adds header attributes (str, int, float values).
    """
    path = Path(path)
    if image.ndim != 2:
        raise ValueError(f"write_exr expects a (H, W) image, got shape {image.shape}")
    if dtype not in ("half", "float"):
        raise ValueError(f"EXR dtype must be 'half' or 'float', got {dtype!r}")
    pixels = np.asarray(image, dtype=np.float32)
    finite = np.isfinite(pixels)
    nonfinite = int(finite.size - np.count_nonzero(finite))
    if nonfinite:
        log.warning("%s: %d NaN/Inf pixels written as 0", path, nonfinite)
        pixels = np.where(finite, pixels, np.float32(0.0))
    if dtype == "half":
        pixels = np.clip(pixels, -HALF_MAX, HALF_MAX).astype(np.float16)
    openexr = _openexr(path)

    header: dict[str, Any] = {
        "compression": openexr.ZIP_COMPRESSION,
        "type": openexr.scanlineimage,
        CAPTURE_TIME_ATTRIBUTE: float(time_s),
        TIME_ATTRIBUTE: repr(float(time_s)),
    }
    header.update(attrs or {})
    exr = openexr.File(header, {"Y": np.ascontiguousarray(pixels)})
    with atomic_path(path) as temp:
        try:
            exr.write(str(temp))
        except RuntimeError as exc:  # OpenEXR reports I/O failures (full disk...) this way
            raise OutputError(f"{path}: cannot write EXR: {exc}") from exc
    return nonfinite


def _openexr(path: Path) -> Any:
    """The OpenEXR module, imported when an EXR is first read or written; a one-line error naming ``path`` where the
    environment lacks it (a dependency, so only a broken or partial install does). A signal that arrives while the
    module initialises (Ctrl-C, a termination) fails the import as "initialization failed": it is raised as itself,
    so the run ends as interrupted, not as a missing module."""
    try:
        import OpenEXR
    except ImportError as exc:
        cause = exc.__cause__ or exc.__context__
        if cause is not None and not isinstance(cause, Exception):
            raise cause from None
        missing = ("is not installed (pip install OpenEXR)" if isinstance(exc, ModuleNotFoundError)
                   else "cannot be loaded")
        raise RmbvideoError(f"{path}: OpenEXR {missing}: {exc}") from None
    return OpenEXR


def _open_exr(path: Path) -> Any:
    """Open an EXR file for reading, turning failures into ``InputError``."""
    openexr = _openexr(path)

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        return openexr.File(str(path), separate_channels=True)
    except RuntimeError as exc:
        raise InputError(f"{path}: not a readable OpenEXR file ({exc})") from exc


def read_exr(path: Path) -> tuple[np.ndarray, dict[str, Any]]:
    """Read a one-channel EXR (as written by :func:`write_exr`): (image float32 (H, W), header).

    The header's ``rmbvideo:time_s`` string, when present, is also parsed into ``time_s``.
    """
    exr = _open_exr(path)
    channels = exr.channels()
    name = "Y" if "Y" in channels else (next(iter(channels)) if len(channels) == 1 else None)
    if name is None:
        raise InputError(f"{path}: expected a single-channel (Y) EXR, found channels {sorted(channels)}")
    header = dict(exr.header())
    if TIME_ATTRIBUTE in header:
        try:
            header["time_s"] = float(header[TIME_ATTRIBUTE])
        except ValueError as exc:
            raise InputError(f"{path}: bad {TIME_ATTRIBUTE} header value {header[TIME_ATTRIBUTE]!r}") from exc
    return np.asarray(channels[name].pixels, dtype=np.float32), header


def read_exr_rgb(path: Path) -> np.ndarray:
    """Read an RGB EXR (e.g. an HDR panorama, any compression) as (H, W, 3) float32, R-G-B order.

    NaN/Inf pixels (possible in foreign files) are replaced by 0.
    """
    exr = _open_exr(path)
    channels = exr.channels()
    missing = [c for c in "RGB" if c not in channels]
    if missing:
        raise InputError(f"{path}: not an RGB EXR (missing channels {missing}; has {sorted(channels)})")
    rgb = np.stack([np.asarray(channels[c].pixels, dtype=np.float32) for c in "RGB"], axis=-1)
    if not np.isfinite(rgb).all():
        log.warning("%s: NaN/Inf pixels read as 0", path)
        rgb = np.where(np.isfinite(rgb), rgb, np.float32(0.0))
    return rgb

"""Capture sidecars: geometry and rate stored beside a ``.dat`` so nobody has to remember them.

Looked up in order: ``<stem>.capture.json`` next to the file (one capture), then ``capture.json``
in the same folder (all captures of that folder). Keys: ``width``, ``height``, ``rate_hz``,
``flip``, ``header_cols`` (all optional). Command-line options override the sidecar. ``rmbvideo simulate`` also
records the scene, its sensor ``effects`` and the pixel's ``reset`` (``simulated_camera``), so a reader knows the
camera that made it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from rmbvideo.errors import InputError
from rmbvideo.io.dat import MAX_RATE_HZ, MIN_RATE_HZ

SIDECAR_KEYS = {"width": int, "height": int, "rate_hz": float, "flip": bool, "header_cols": int}


@dataclass(frozen=True)
class CaptureInfo:
    """Geometry and timing of a capture; ``None`` means "not specified here"."""

    width: int | None = None
    height: int | None = None
    rate_hz: float | None = None
    flip: bool | None = None
    header_cols: int | None = None

    def override(self, **options: Any) -> "CaptureInfo":
        """Return a copy where every option that is not ``None`` replaces the stored value."""
        merged = {f.name: getattr(self, f.name) for f in fields(self)}
        merged.update({k: v for k, v in options.items() if v is not None and k in merged})
        return CaptureInfo(**merged)


def sidecar_path(dat_path: Path) -> Path | None:
    """The sidecar that applies to ``dat_path``, or ``None``."""
    for candidate in (dat_path.with_name(dat_path.stem + ".capture.json"),
                      dat_path.with_name("capture.json")):
        if candidate.is_file():
            return candidate
    return None


def read_sidecar(dat_path: Path) -> CaptureInfo:
    """Read the sidecar of ``dat_path`` (empty ``CaptureInfo`` if there is none)."""
    path, data = _sidecar_record(dat_path)
    if path is None:
        return CaptureInfo()
    values: dict[str, Any] = {}
    for key, kind in SIDECAR_KEYS.items():
        if key in data and data[key] is not None:
            value = data[key]
            if kind is bool and not isinstance(value, bool):
                raise InputError(f"{path}: '{key}' must be true or false")
            if kind in (int, float) and (isinstance(value, bool) or not isinstance(value, (int, float))
                                         or not math.isfinite(value)):
                raise InputError(f"{path}: '{key}' must be a finite number, not {value!r}")
            if kind is int and value != int(value):
                raise InputError(f"{path}: '{key}' must be a whole number, not {value!r}")
            if key == "rate_hz" and not MIN_RATE_HZ <= value <= MAX_RATE_HZ:
                raise InputError(f"{path}: 'rate_hz' must be between {MIN_RATE_HZ:g} and {MAX_RATE_HZ:g} Hz, not {value!r}")
            if key in ("width", "height") and not value >= 1:
                raise InputError(f"{path}: '{key}' must be at least 1, not {value!r}")
            if key == "header_cols" and value < 0:
                raise InputError(f"{path}: 'header_cols' must be >= 0, not {value!r}")
            values[key] = kind(value)
    return CaptureInfo(**values)


def write_sidecar(dat_path: Path, info: CaptureInfo, **extra: Any) -> Path:
    """Write ``<stem>.capture.json`` beside ``dat_path`` (atomically) and return its path."""
    from rmbvideo.io.atomic import atomic_write_text

    path = Path(dat_path).with_name(Path(dat_path).stem + ".capture.json")
    data = {f.name: getattr(info, f.name) for f in fields(info) if getattr(info, f.name) is not None}
    data.update(extra)
    atomic_write_text(path, json.dumps(data, indent=2) + "\n")
    return path


@dataclass(frozen=True)
class SimulatedCamera:
    """The camera ``rmbvideo simulate`` modelled, as its sidecar records it: the sensor ``effects`` and what a spike
    did to the pixel's charge (``reset``, ``SensorParams.reset``; "zero", the paper's pixel, where it does not say)."""

    effects: tuple[str, ...]
    reset: str = "zero"


def simulated_camera(dat_path: Path) -> SimulatedCamera | None:
    """The camera that made ``dat_path`` when ``rmbvideo simulate`` did (its sidecar lists the effects), else None (a
    real camera's capture, or one simulated before effects were recorded)."""
    path, data = _sidecar_record(dat_path)
    effects, reset = data.get("effects"), data.get("reset", "zero")
    if effects is None:
        return None
    if not isinstance(effects, list) or not all(isinstance(e, str) for e in effects):
        raise InputError(f"{path}: 'effects' must be a list of effect names")
    if not isinstance(reset, str):
        raise InputError(f"{path}: 'reset' must be a string, not {reset!r}")
    return SimulatedCamera(tuple(effects), reset)


def _sidecar_record(dat_path: Path) -> tuple[Path | None, dict]:
    """The sidecar of ``dat_path`` and its JSON object ({} without a sidecar)."""
    path = sidecar_path(Path(dat_path))
    if path is None:
        return None, {}
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"{path}: not a valid capture sidecar ({str(exc).splitlines()[0][:200]})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: a capture sidecar must be a JSON object")
    return path, data

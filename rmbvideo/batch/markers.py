"""Completion markers: the digest of everything that changes a capture's output, written last."""

from __future__ import annotations

import hashlib
import json
import logging
import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from rmbvideo import __version__
from rmbvideo.batch.jobs import (
    MARKER_FORMAT,
    MARKER_NAME,
    NON_OUTPUT_OPTIONS,
    CaptureJob,
)
from rmbvideo.io.atomic import atomic_write_text

log = logging.getLogger(__name__)

def output_fingerprint(job: CaptureJob, reader: Any) -> dict[str, Any]:
    """Everything that decides the output of ``job``, as JSON data (``reader``: the opened capture)."""
    options = {k: _describe(v) for k, v in sorted(job.options.items())
               if k not in NON_OUTPUT_OPTIONS and k != "capture"}
    g = reader.geometry
    stat = job.input_path.stat()
    return {
        "code_version": __version__,
        "options": options,
        "capture": {"width": g.width, "height": g.height, "header_cols": g.header_cols, "flip": g.flip,
                    "rate_hz": reader.rate_hz},
        "input": {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns},
    }


def _describe(value: Any) -> Any:
    """JSON form of an option value; a value naming an existing file also records its size and mtime."""
    if isinstance(value, dict):
        return {str(k): _describe(v) for k, v in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [_describe(v) for v in value]
    if isinstance(value, (str, os.PathLike)):
        text = os.fspath(value)
        if text and os.path.isfile(text):
            stat = os.stat(text)
            return {"file": text, "size": stat.st_size, "mtime_ns": stat.st_mtime_ns}
        return text
    if value is None or isinstance(value, (bool, int, float)):
        return value
    return str(value)


def fingerprint_digest(fingerprint: dict[str, Any]) -> str:
    """A stable hash of a fingerprint."""
    return hashlib.sha256(json.dumps(fingerprint, sort_keys=True).encode("utf-8")).hexdigest()


def read_marker(output_dir: Path, digest: str) -> dict[str, Any] | None:
    """The completion marker of ``output_dir`` if it proves a complete output for ``digest``, else ``None``."""
    try:
        marker = json.loads((output_dir / MARKER_NAME).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(marker, dict) or marker.get("format") != MARKER_FORMAT or marker.get("digest") != digest:
        return None
    files = marker.get("files")
    if not isinstance(files, list):
        return None
    for entry in files:
        try:
            if (output_dir / entry["path"]).stat().st_size != entry["size"]:
                return None
        except (OSError, KeyError, TypeError):
            return None
    return marker


def write_marker(work: Path, job: CaptureJob, fingerprint: dict[str, Any], frames: int, planes: int,
                  seconds: float) -> None:
    files = sorted(p for p in work.rglob("*") if p.is_file())
    marker = {
        "format": MARKER_FORMAT,
        "version": 1,
        "input": str(job.input_path),
        "digest": fingerprint_digest(fingerprint),
        "fingerprint": fingerprint,
        "files": [{"path": p.relative_to(work).as_posix(), "size": p.stat().st_size} for p in files],
        "frames": frames,
        "planes": planes,
        "seconds": seconds,
        "completed_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    atomic_write_text(work / MARKER_NAME, json.dumps(marker, indent=2) + "\n")

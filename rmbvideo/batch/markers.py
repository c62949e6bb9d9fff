"""Completion markers: the digest of everything that changes a capture's output, written last."""

from __future__ import annotations

import json
import logging
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from rmbvideo.batch.jobs import (
    MARKER_FORMAT,
    MARKER_NAME,
    NON_OUTPUT_OPTIONS,
    CaptureJob,
)
from rmbvideo.io.atomic import atomic_write_text
from rmbvideo.recon.fingerprint import fingerprint_digest, run_fingerprint

log = logging.getLogger(__name__)

def output_fingerprint(job: CaptureJob, reader: Any) -> dict[str, Any]:
    """Everything that decides the output of ``job``, as JSON data (``reader``: the opened capture)."""
    options = {k: v for k, v in job.options.items() if k not in NON_OUTPUT_OPTIONS and k != "capture"}
    return run_fingerprint(job.input_path, options, reader)


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

"""The fingerprint of a run: everything that decides its output files, as JSON data, and a stable digest of it.

Batch's completion markers and a resumed run's record both compare it, so that an output is never taken for one made
from another input or with other options.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from pathlib import Path
from typing import Any

from rmbvideo import __version__
from rmbvideo.shipped import MODELS_DIR


def run_fingerprint(input_path: Path, options: dict[str, Any], reader: Any) -> dict[str, Any]:
    """Everything that decides the output of a run over ``input_path`` (``reader``: the opened capture) with
    ``options`` (the output-deciding ones only), as JSON data."""
    g = reader.geometry
    stat = Path(input_path).stat()
    return {
        "code_version": __version__,
        "shipped_models": shipped_models(),
        "options": {k: describe_option(v) for k, v in sorted(options.items())},
        "capture": {"width": g.width, "height": g.height, "header_cols": g.header_cols, "flip": g.flip,
                    "rate_hz": reader.rate_hz},
        "input": {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns},
    }


def shipped_models() -> dict[str, str]:
    """The SHA-256 of every shipped weight file by name: a run made with other shipped weights (retrained in a newer
    checkout under the same version number) is another run, not one to continue or skip."""
    return {path.name: _file_digest(str(path), *_stat_key(path)) for path in sorted(MODELS_DIR.glob("*.safetensors"))}


def _stat_key(path: Path) -> tuple[int, int]:
    stat = path.stat()
    return stat.st_size, stat.st_mtime_ns


@functools.lru_cache(maxsize=64)
def _file_digest(path: str, size: int, mtime_ns: int) -> str:
    """SHA-256 of file ``path``, once per process for each (size, mtime) it has had."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def describe_option(value: Any) -> Any:
    """JSON form of an option value; a value naming an existing file also records its size and mtime."""
    if isinstance(value, dict):
        return {str(k): describe_option(v) for k, v in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [describe_option(v) for v in value]
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

"""Find the captures named on the command line and give each a collision-free output name."""

from __future__ import annotations

import glob
import hashlib
import logging
import os
from collections import Counter
from collections.abc import Sequence
from pathlib import Path, PurePath
from typing import Any

from rmbvideo.batch.jobs import (
    CAPTURE_SUFFIX,
    HASH_CHARS,
    LOCK_NAME,
    REPORT_NAME,
    UNSAFE_NAME_CHARS,
    CaptureJob,
    FoundCapture,
)
from rmbvideo.errors import InputError

log = logging.getLogger(__name__)

def discover_captures(inputs: Sequence[str | os.PathLike[str]]) -> list[FoundCapture]:
    """Expand files, folders (searched recursively for ``.dat``) and globs, in order, without duplicates.

    Globs are expanded here, so quoted patterns work (``**`` is recursive). A literal path that does
    not exist is kept, so that it is reported as a failed capture; a glob that matches nothing is
    logged. Raises ``InputError`` when nothing at all was found.
    """
    found: list[FoundCapture] = []
    seen: set[Path] = set()

    def add(path: Path, relative: PurePath) -> None:
        key = path.resolve()
        if key not in seen:
            seen.add(key)
            found.append(FoundCapture(path, relative))

    for item in inputs:
        text = os.fspath(item)
        path = Path(text)
        if glob.has_magic(text):
            root = _glob_root(text)
            matches = sorted(glob.glob(text, recursive=True))
            if not matches:
                log.warning("%s: no file matches this pattern", text)
            for match in map(Path, matches):
                if match.is_dir():
                    for capture in _captures_in(match):
                        add(capture, capture.relative_to(root))
                else:
                    add(match, match.relative_to(root))
        elif path.is_dir():
            captures = _captures_in(path)
            if not captures:
                log.warning("%s: folder holds no %s files", path, CAPTURE_SUFFIX)
            for capture in captures:
                add(capture, capture.relative_to(path))
        else:
            add(path, PurePath(path.name))
    if not found:
        raise InputError(f"{', '.join(map(os.fspath, inputs)) or '(no inputs)'}: no {CAPTURE_SUFFIX} captures found")
    return found


def _captures_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.suffix.lower() == CAPTURE_SUFFIX and p.is_file())


def _glob_root(pattern: str) -> Path:
    """The folder made of the pattern's leading parts without wildcards."""
    parts: list[str] = []
    for part in PurePath(pattern).parts:
        if glob.has_magic(part):
            break
        parts.append(part)
    return Path(*parts) if parts else Path(".")


def output_names(captures: Sequence[FoundCapture]) -> list[str]:
    """A folder name per capture: its relative path with separators as ``__``, suffix dropped.

    Deterministic: unsafe characters become ``_`` and names that collide (ignoring case, as some
    file systems do) or clash with the batch's own files all get ``-<hash of the full path>``.
    """
    base = [_safe_name(c.relative) for c in captures]
    counts = Counter(name.casefold() for name in base)
    reserved = {REPORT_NAME.casefold(), LOCK_NAME.casefold()}
    names = []
    for capture, name in zip(captures, base):
        if counts[name.casefold()] > 1 or name.casefold() in reserved:
            digest = hashlib.sha1(str(capture.path.resolve()).encode("utf-8")).hexdigest()[:HASH_CHARS]
            name = f"{name}-{digest}"
        names.append(name)
    return names


def _safe_name(relative: PurePath) -> str:
    parts = [p for p in relative.parts if p not in ("", ".", "..", "/")]
    if parts and parts[-1].lower().endswith(CAPTURE_SUFFIX):
        parts[-1] = parts[-1][: -len(CAPTURE_SUFFIX)]
    name = "__".join(UNSAFE_NAME_CHARS.sub("_", p) for p in parts if p)
    if name.startswith("."):
        name = "_" + name[1:]
    return name or "capture"


def plan_jobs(inputs: Sequence[str | os.PathLike[str]], batch_dir: Path, options: dict[str, Any]) -> list[CaptureJob]:
    """Discover the captures of ``inputs`` and make one job per capture writing under ``batch_dir``."""
    captures = discover_captures(inputs)
    return [CaptureJob(c.path, Path(batch_dir), name, dict(options))
            for c, name in zip(captures, output_names(captures))]

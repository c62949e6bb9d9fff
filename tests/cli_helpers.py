"""Helpers shared by the fault and robustness tests: a small capture and the CLI as a user runs it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from rmbvideo.io.dat import DatGeometry, write_dat

GEOM = ("--width", "64", "--height", "48")


def capture(path: Path, planes: int = 60, seed: int = 0) -> Path:
    """A 64x48 capture with a firing-rate ramp across the columns."""
    rng = np.random.default_rng(seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_dat(path, (rng.random((planes, 48, 64)) < np.linspace(0.05, 0.9, 64)).astype(np.uint8), DatGeometry(64, 48))
    return path


def cli(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rmbvideo", *map(str, args)], capture_output=True, text=True)


def one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> None:
    """Exit 2, one line on stderr naming what went wrong, no traceback."""
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]



"""The Python API a notebook uses: the README's example runs as written, and frames match the CLI's."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest

import rmbvideo
from rmbvideo.errors import OptionError
from rmbvideo.io.exr import read_exr

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_example_runs(tmp_path, monkeypatch):
    code = re.search(r"## Python API.*?```python\n(.*?)```", README.read_text(), re.S).group(1)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)  # noqa: S102 (the README's own example)
    first, written = namespace["first"], namespace["written"]
    assert first.image.dtype == np.float32 and np.isfinite(first.image).all() and first.image.min() >= 0
    assert written >= 5 and len(list((tmp_path / "out").glob("*.exr"))) == written


def test_reconstruct_streams_the_cli_frames(tmp_path):
    capture = tmp_path / "c.dat"
    rmbvideo.simulate_capture(rmbvideo.load_scene("demo"), capture, duration_s=0.004)
    frames = list(rmbvideo.reconstruct(capture, method="tfw", window=20))
    assert [f.index for f in frames] == list(range(len(frames))) and len(frames) >= 3
    from rmbvideo.cli import main

    main([ "reconstruct", str(capture), "-o", str(tmp_path / "out"), "--method", "tfw", "--window", "20",
          "--format", "exr", "--exr-dtype", "float", "-q"], standalone_mode=False)
    for frame in frames:
        on_disk = read_exr(tmp_path / "out" / f"frame_{frame.index:06d}.exr")[0]
        np.testing.assert_array_equal(on_disk, frame.image)
    with pytest.raises(OptionError, match="takes no option model"):
        rmbvideo.reconstruct(capture, method="tfp", model="x.safetensors")
    assert "torch" not in rmbvideo.__all__ and os.fspath(capture)

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
    # threads is every method's, as --threads on the command line (it was refused for the classical ones)
    threaded = list(rmbvideo.reconstruct(capture, method="tfw", window=20, threads=1))
    assert all(np.array_equal(a.image, b.image) for a, b in zip(threaded, frames, strict=True))
    assert "torch" not in rmbvideo.__all__ and os.fspath(capture)


def test_prime_reaches_the_engine_from_the_api_and_the_cli(tmp_path):
    """``prime`` (``--prime``) sets how many frames RMB-Net's first state is primed over: 0 makes another first frame
    than the default, and the CLI writes the API's frames."""
    capture = tmp_path / "c.dat"
    rmbvideo.simulate_capture(rmbvideo.load_scene("demo"), capture, duration_s=0.006)
    options = dict(resolution="binned", threads=1, precision="fp32")
    default = list(rmbvideo.reconstruct(capture, **options))
    unprimed = list(rmbvideo.reconstruct(capture, prime=0, **options))
    assert len(default) == len(unprimed) >= 5
    assert not np.allclose(default[0].image, unprimed[0].image, rtol=1e-4)
    from rmbvideo.cli import main

    main(["reconstruct", str(capture), "-o", str(tmp_path / "out"), "--prime", "0", "--resolution", "binned",
          "--threads", "1", "--precision", "fp32", "--format", "exr", "--exr-dtype", "float", "-q"],
         standalone_mode=False)
    for frame in unprimed:
        np.testing.assert_array_equal(read_exr(tmp_path / "out" / f"frame_{frame.index:06d}.exr")[0], frame.image)


def test_a_multiple_of_rmbnets_step_keeps_every_kth_of_its_frames(tmp_path):
    """RMB-Net makes a frame every 20 raw planes (its recurrent state steps through them all): at --step 40 the
    output is every second of those frames (at --step 60 every third), the same images at the same times, numbered on
    from 0, at either output size, inline, with the full-resolution stages in a thread of their own or with frames
    made in batched passes (a GPU's way, where a pass makes every frame whole): the frames it
    drops are neither gated nor shaped, and those no kept frame reads as its previous one are made for the recurrent
    state alone. A resumed run could not tell where the state stood, so --resume is refused there."""
    from rmbvideo.recon.run import run_reconstruction

    capture = tmp_path / "c.dat"
    rmbvideo.simulate_capture(rmbvideo.load_scene("demo"), capture, duration_s=0.008)
    for options in (dict(threads=1), dict(threads=2), dict(threads=1, resolution="binned"),
                    dict(threads=1, frame_batch=3)):  # batched passes, as on a GPU
        options = dict(precision="fp32", **options)
        every = list(rmbvideo.reconstruct(capture, **options))
        assert len(every) == 8
        for k in (2, 3):  # at 3 a frame neither kept nor before a kept one is made for the state alone
            kth = list(rmbvideo.reconstruct(capture, step=20 * k, **options))
            assert [f.index for f in kth] == list(range(len(every[::k]))), (options, k)
            for frame, made in zip(kth, every[::k], strict=True):
                assert frame.time_s == made.time_s and np.array_equal(frame.image, made.image), (options, k)
    from rmbvideo.recon.decimate import EveryKthFrame
    from rmbvideo.recon.run import prepare_run

    inner, kept = prepare_run(capture).method, prepare_run(capture, step=40).method
    assert isinstance(kept, EveryKthFrame) and kept.every == 2
    for name in ("input_kind", "accepts_packed", "max_push_planes"):  # read by the streaming loop
        assert getattr(kept, name) == getattr(inner, name, None if name == "max_push_planes" else False), name
    with pytest.raises(OptionError, match="--resume: rmbnet at --step 40 keeps one in 2"):
        run_reconstruction(capture, tmp_path / "out", step=40, fmt="exr", resume=True)
    assert not (tmp_path / "out").exists()

"""Peak memory does not grow with capture length: ``reconstruct`` on a capture 5x longer raises the
peak memory of its process by less than 10 % (measured inside a fresh subprocess).

The measure is the anonymous RSS (heap, arrays, tensors). Total RSS also counts the file pages of the
memory-mapped input that were touched; the kernel drops those at will, but until it does they grow
with the length read, so the high-water mark of the total is reported alongside and not asserted on.
"""

from __future__ import annotations

import pytest
import torch

from rmbvideo.bench.memory import reconstruct_peak_rss, write_random_capture
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import ModelCard, save_model
from rmbvideo.recon.run import CHUNK_BYTES

WIDTH, HEIGHT = 400, 250
FACTOR = 5


def peaks(tmp_path, planes: int, extra: list[str], startup_env: dict[str, str]) -> list[int]:
    """Anonymous peak RSS of reconstruct on ``planes`` and FACTOR x ``planes`` planes, in children started
    with the session's startup environment (so other tests' imports cannot change what they load)."""
    out = []
    for count in (planes, FACTOR * planes):
        path = write_random_capture(tmp_path / f"c{count}.dat", count, WIDTH, HEIGHT, seed=count)
        out.append(reconstruct_peak_rss([str(path), "-o", str(tmp_path / "out"), "--format", "null", "-q",
                                         "--width", str(WIDTH), "--height", str(HEIGHT), *extra],
                                        env={"OMP_NUM_THREADS": "1"}, base_env=startup_env).anonymous)
    return out


@pytest.mark.parametrize("method", ["tfp", "tfw"])
def test_classical_peak_rss_independent_of_length(tmp_path, method, startup_env):
    """The method's own memory: TFW at its binned size (the full-resolution stage's memory is RMB-Net's test's)."""
    short, long = peaks(tmp_path, 2048, ["--method", method, "--resolution", "binned"], startup_env)
    assert long < 1.10 * short, (short, long)


def test_rmbnet_peak_rss_independent_of_length(tmp_path, startup_env):
    """The default job at full resolution with every thread it can have (``--threads 2``: the aligned means and the
    raw rates, gate and detail stage each beside the network, a chunk in flight; the thread policy would choose by the
    machine's load). 128-plane chunks, so that the shorter run is five chunks long: past the pipeline's filling, whose
    own peak is not a growth with length."""
    torch.manual_seed(0)
    model = save_model(tmp_path / "tiny", RmbNet(RmbNetConfig(w=1, width=0.25)), ModelCard(name="tiny"))
    short, long = peaks(tmp_path, 640, ["--method", "rmbnet", "--model", str(model), "--device", "cpu",
                                        "--chunk-planes", "128", "--threads", "2"], startup_env)
    assert long < 1.10 * short, (short, long)


def test_a_leak_would_be_seen(tmp_path, startup_env):
    """The measurement can fail: holding the whole capture in memory (read it all at once, decoded: the longer one
    still under the chunk's memory bound, ``CHUNK_BYTES``) shows."""
    planes = 256
    assert FACTOR * planes * WIDTH * HEIGHT < CHUNK_BYTES
    short, long = peaks(tmp_path, planes, ["--method", "tfw", "--resolution", "binned",
                                           "--chunk-planes", str(FACTOR * planes)], startup_env)
    assert long > 1.10 * short, (short, long)

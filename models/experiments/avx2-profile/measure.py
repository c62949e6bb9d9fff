"""The one-core figures of docs/speed.md "Where the time goes on an AVX2-only host", measured again. Run from the repository
root (each well under a minute):

    python models/experiments/avx2-profile/measure.py convs   # the network's convolution shapes, one thread: fp32 GFLOP/s,
                                                              # and int8 (fbgemm, quantised input and output) beside it
    python models/experiments/avx2-profile/measure.py tfp     # TFP on a random 1 s 400x250 capture, in this process
    python models/experiments/avx2-profile/measure.py tfp-against REV [ROUNDS]   # `tfp` of the code at git REV and of
                                                              # this checkout, alternated in fresh processes; medians
    python models/experiments/avx2-profile/measure.py decode-against REV [ROUNDS]  # `bench decode --planes 40000`
                                                              # of both, alternated the same way; medians and ratios
    python models/experiments/avx2-profile/measure.py ops     # one core: ns a byte of the element-wise ways to bin
                                                              # (numpy on uint64 words, torch, cv2.LUT gathers) and
                                                              # the full-resolution path's decode (unpack_planes)
    python models/experiments/avx2-profile/measure.py slow-convs  # the binned engine's convolutions that fall to
                                                              # PyTorch's slow path, by input shape (torch.profiler)
"""

import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
import torch.nn.functional as F

from rmbvideo.bench.memory import write_random_capture
from rmbvideo.io.dat import DatGeometry, DatReader
from rmbvideo.recon.classical import Tfp
from rmbvideo.recon.run import run_reconstruction

#: (in, out, kernel, height, width, batch): the encoders' 5x5 levels (8 frames a call) and the head's first 3x3
SHAPES = [(12, 12, 5, 128, 200, 8), (16, 16, 5, 64, 100, 8), (27, 12, 3, 128, 200, 1), (24, 48, 3, 64, 100, 1)]


def best_ms(work, runs: int = 8) -> float:
    work()
    times = []
    for _ in range(runs):
        began = time.perf_counter()
        work()
        times.append(time.perf_counter() - began)
    return 1e3 * min(times)


def convs() -> None:
    torch.set_num_threads(1)
    torch.backends.quantized.engine = "fbgemm"
    for cin, cout, k, h, w, b in SHAPES:
        x = torch.randn(b, cin, h, w).contiguous(memory_format=torch.channels_last)
        weight = torch.randn(cout, cin, k, k).contiguous(memory_format=torch.channels_last)
        ms = best_ms(lambda: F.conv2d(x, weight, padding=k // 2))
        gflop = 2 * b * h * w * cin * cout * k * k / 1e9
        int8 = torch.ao.nn.quantized.Conv2d(cin, cout, k, padding=k // 2)
        int8.set_weight_bias(torch.quantize_per_channel(weight, torch.full((cout,), 0.05), torch.zeros(cout, dtype=torch.long),
                                                        0, torch.qint8), None)
        qx = torch.quantize_per_tensor(x, 0.05, 64, torch.quint8)
        int8_ms = best_ms(lambda: int8(qx))
        print(f"{cin:3d} -> {cout:3d} {k}x{k} at {w}x{h}, batch {b}: {ms:7.2f} ms, {gflop / ms * 1e3:5.1f} GFLOP/s; "
              f"int8 {int8_ms:7.2f} ms")


def tfp() -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = write_random_capture(Path(folder) / "c.dat", 20000, 400, 250)
        chunks = list(DatReader(path, DatGeometry(400, 250)).packed_chunks(1024))

        def method_alone() -> None:
            method = Tfp(41, 20)
            for chunk in chunks:
                method.push(chunk)
            method.flush()

        def end_to_end() -> None:
            run_reconstruction(path, Path(folder) / "out", method="tfp", fmt="null", extra_options={"threads": 1})

        for name, work in (("TFP alone, chunks in memory", method_alone), ("reconstruct --format null", end_to_end)):
            ms = best_ms(work, runs=3)
            print(f"{name}: {ms / 1e3:.2f} s for 1 s of capture ({1e3 / ms:.2f}x real time)")


def _alternated(rev: str, rounds: int, command: list[str]) -> dict[str, list[str]]:
    """``command``'s output from the code at ``rev`` (a temporary git worktree) and from this checkout, in alternated
    fresh processes, so both meet the same drift of a shared host: ``rounds`` outputs of each."""
    root = Path(__file__).resolve().parents[3]
    outputs: dict[str, list[str]] = {rev: [], "this checkout": []}
    with tempfile.TemporaryDirectory() as folder:
        old = Path(folder) / "old"
        subprocess.run(["git", "-C", str(root), "worktree", "add", "--detach", "-q", str(old), rev], check=True)
        try:
            for r in range(rounds):
                for name, tree in ((rev, old), ("this checkout", root)):
                    run = subprocess.run([sys.executable, *command], env={**os.environ, "PYTHONPATH": str(tree)},
                                         capture_output=True, text=True, check=True, cwd=tree)
                    outputs[name].append(run.stdout)
                    print(f"round {r + 1}, {name}: {run.stdout.strip()[:200]}", flush=True)
        finally:
            subprocess.run(["git", "-C", str(root), "worktree", "remove", "--force", str(old)], check=True)
    return outputs


def tfp_against(rev: str, rounds: str = "5") -> None:
    """``tfp`` of the code at ``rev`` and of this checkout, alternated; prints each round and the medians of the
    real-time factors."""
    for name, runs in _alternated(rev, int(rounds), [__file__, "tfp"]).items():
        rows = [[float(x) for x in re.findall(r"\(([0-9.]+)x real time\)", out)] for out in runs]
        alone, end_to_end = (statistics.median(column) for column in zip(*rows))
        print(f"{name}: medians TFP alone {alone:.2f}x, reconstruct --format null {end_to_end:.2f}x real time")


def decode_against(rev: str, rounds: str = "7") -> None:
    """``rmbvideo bench decode --planes 40000`` of the code at ``rev`` and of this checkout, alternated; prints the
    medians of the fused path's planes/s and of the rounds' ratios (this checkout over ``rev``)."""
    runs = _alternated(rev, int(rounds), ["-m", "rmbvideo.bench.decode", "--planes", "40000", "--json"])
    rates = {name: [json.loads(out)["fused"]["planes_per_s"] for out in outs] for name, outs in runs.items()}
    for name, values in rates.items():
        print(f"{name}: median {statistics.median(values):,.0f} planes/s ({', '.join(f'{v:,.0f}' for v in values)})")
    ratios = [new / old for old, new in zip(*rates.values())]
    print(f"ratio this checkout / {rev}: median {statistics.median(ratios):.2f} (range {min(ratios):.2f}-{max(ratios):.2f})")


def ops() -> None:
    """ns a byte of one pass over a 64-plane block (about 400 kB, in cache), one thread, best of 300; and
    ``unpack_planes`` (the full-resolution path's decode for TFI) per 400x250 plane."""
    import cv2
    import numpy as np

    from rmbvideo.io.dat import unpack_planes

    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    x = np.random.default_rng(0).integers(0, 256, 32 * 2 * 62 * 2 * 50, dtype=np.uint8)
    y = np.empty_like(x)
    xw, yw = x.view(np.uint64), y.view(np.uint64)
    tx, ty = torch.from_numpy(x), torch.from_numpy(y)
    tw, tyw = torch.from_numpy(xw.view(np.int64)), torch.from_numpy(yw.view(np.int64))
    image = x.reshape(-1, 400)
    lut = {"uint8": np.arange(256, dtype=np.uint8).reshape(1, 256), "uint16": np.arange(256, dtype=np.uint16),
           "int32": np.arange(256, dtype=np.int32)}
    work = {
        "numpy AND, uint64 words": lambda: np.bitwise_and(xw, np.uint64(0x5555555555555555), out=yw),
        "numpy right shift, uint64 words": lambda: np.right_shift(xw, 1, out=yw),
        "numpy add, uint8": lambda: np.add(x, x, out=y),
        "torch AND, uint8": lambda: torch.bitwise_and(tx, 0x55, out=ty),
        "torch right shift, uint8": lambda: torch.bitwise_right_shift(tx, 1, out=ty),
        "torch right shift, int64": lambda: torch.bitwise_right_shift(tw, 1, out=tyw),
        **{f"cv2.LUT uint8 -> {name}": (lambda table=table: cv2.LUT(image, table)) for name, table in lut.items()},
    }
    for name, run in work.items():
        print(f"{name:34s} {best_ms(run, runs=300) * 1e6 / x.nbytes:.3f} ns a byte")
    geometry = DatGeometry(400, 250)
    packed = np.random.default_rng(1).integers(0, 256, (256, geometry.plane_bytes), dtype=np.uint8)
    print(f"unpack_planes, 256 planes of 400x250: {best_ms(lambda: unpack_planes(packed, geometry)) * 1e3 / 256:.1f} "
          f"us a plane")


def slow_convs(frames: str = "30") -> None:
    """The binned engine (one thread, fp32) on a random 400x250 capture under torch.profiler: every convolution that
    ran on PyTorch's slow path (``_slow_conv2d_forward``), by input shape, and their time a frame."""
    from torch.profiler import ProfilerActivity, profile

    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as folder:
        path = write_random_capture(Path(folder) / "c.dat", 20 * int(frames), 400, 250)

        def run(name: str):
            return run_reconstruction(path, Path(folder) / name, fmt="null", extra_options={"threads": 1},
                                      overwrite=True, resolution="binned")

        run("warm")
        with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as prof:
            summary = run("profiled")
    slow = [e for e in prof.key_averages(group_by_input_shape=True) if e.key == "aten::_slow_conv2d_forward"]
    total_ms = sum(e.self_cpu_time_total for e in slow) / 1e3
    for e in sorted(slow, key=lambda e: -e.self_cpu_time_total):
        print(f"{e.count:4d} calls {e.self_cpu_time_total / 1e3:7.1f} ms  input, weight: {e.input_shapes[:2]}")
    print(f"{sum(e.count for e in slow) / summary.frames:.1f} slow-path convolutions a frame, "
          f"{total_ms / summary.frames:.2f} ms a frame (profiled), over {summary.frames} frames")


if __name__ == "__main__":
    {"convs": convs, "tfp": tfp, "tfp-against": tfp_against, "decode-against": decode_against, "ops": ops,
     "slow-convs": slow_convs}[sys.argv[1]](*sys.argv[2:])

"""The figures of the stop of 2026-12-07 that no rmbvideo command prints (one thread, fp32). Run from the repository
root:

    python models/experiments/session-2026-12-07/measure.py convs      # per-shape convolution time of the default job
    python models/experiments/session-2026-12-07/measure.py padding    # 12-channel layers against 16, one shape each
    python models/experiments/session-2026-12-07/measure.py age 600    # a still scene's quality as the state ages

The whole-command timings (TFP start-up, --step 660, TFW memory) are `/usr/bin/time` on `rmbvideo reconstruct` over
a capture from `rmbvideo.bench.memory.write_random_capture` (README.md in this folder).
"""

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)


def convs(frames: int = 60) -> None:
    """Self time of each convolution shape of the default job at 400x250, ms a frame, and its calls a frame."""
    from torch.profiler import ProfilerActivity, profile

    from rmbvideo.bench.memory import write_random_capture
    from rmbvideo.recon.run import run_reconstruction

    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        path = write_random_capture(work / "c.dat", 20 * frames, 400, 250)

        def run(name: str, duration: float | None = None):
            return run_reconstruction(path, work / name, fmt="null", duration_s=duration,
                                      capture=dict(width=400, height=250),
                                      extra_options=dict(threads=1, precision="fp32"), overwrite=True)

        run("warm", 0.1)
        with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as prof:
            summary = run("profiled")
    rows = sorted(((e.self_cpu_time_total / 1e3 / summary.frames, e.count / summary.frames, e.key, str(e.input_shapes))
                   for e in prof.key_averages(group_by_input_shape=True)
                   if e.key in ("aten::mkldnn_convolution", "aten::_slow_conv2d_forward")), reverse=True)
    print(f"convolutions: {sum(r[0] for r in rows):.1f} ms a frame over {summary.frames} frames")
    for ms, calls, key, shapes in rows[:30]:
        print(f"{ms:6.2f} ms {calls:5.1f}/frame {key[6:]} {shapes[:100]}")


def padding(reps: int = 20) -> None:
    """ms and GFLOP/s of a convolution at the shipped model's 12 channels and at 16 (zero-padded would compute the
    same), channels-last, and of the detail stage's 16->1 layer."""
    shapes = [(12, 12, 5, (8, 128, 200)), (16, 16, 5, (8, 128, 200)), (29, 12, 3, (1, 128, 200)),
              (32, 16, 3, (1, 128, 200)), (12, 12, 3, (1, 128, 200)), (16, 16, 3, (1, 128, 200)),
              (16, 1, 3, (1, 250, 400)), (16, 8, 3, (1, 250, 400))]
    for cin, cout, k, (n, h, w) in shapes:
        x = torch.randn(n, cin, h, w).contiguous(memory_format=torch.channels_last)
        conv = torch.nn.Conv2d(cin, cout, k, padding=k // 2).to(memory_format=torch.channels_last)
        with torch.no_grad():
            for _ in range(3):
                conv(x)
            began = time.perf_counter()
            for _ in range(reps):
                conv(x)
            seconds = (time.perf_counter() - began) / reps
        print(f"{cin:3d}->{cout:3d} {k}x{k} on {n}x{h}x{w}: {seconds * 1e3:7.2f} ms "
              f"{2 * cin * cout * k * k * n * h * w / seconds / 1e9:6.1f} GFLOP/s")


def age(frames: int = 600) -> None:
    """The default model's mu-law PSNR on a still textured scene (112x64) by the state's age, both conventions."""
    from rmbvideo.evaluate.video_checks import band_sequence, state_age_report

    for convention in ("spikezoo", "physical"):
        report = state_age_report("rmbnet", {"threads": 1}, band_sequence(112, 64, frames, static=True,
                                                                           convention=convention))
        psnr = np.array(report.psnr)
        spans = [(3, 9), (9, 50), (50, 100)] + [(a, a + 200) for a in range(100, frames, 200)]
        print(convention, " ".join(f"{a}-{b}: {psnr[a:b].mean():.2f}" for a, b in spans if b <= frames))


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "convs"
    {"convs": convs, "padding": padding, "age": lambda: age(int(sys.argv[2]) if len(sys.argv) > 2 else 600)}[what]()

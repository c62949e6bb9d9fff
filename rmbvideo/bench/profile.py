"""Where an end-to-end RMB-Net run spends its time on one device, by operation: the engine (``run_reconstruction``,
default options, sink null) on a random capture, once unprofiled for its frames/s and once under ``torch.profiler``
(every thread; CUDA kernels and copies too on a GPU), and once under ``cProfile`` (the main thread's Python: numpy
stacks, casts, copies waited for). On a GPU the host side (kernel launches, copies from pageable memory) can set the
pace rather than the kernels, which only such a profile shows."""

from __future__ import annotations

import cProfile
import io
import pstats
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from rmbvideo.bench.memory import write_random_capture
from rmbvideo.recon.run import DEFAULT_RESOLUTION, run_reconstruction

#: host-side CUDA runtime calls counted per frame in the summary
HOST_CALLS = ("cudaLaunchKernel", "cudaLaunchKernelExC", "cudaMemcpyAsync", "cudaStreamSynchronize",
              "cudaGraphLaunch")


@dataclass
class EngineProfile:
    """One profiled run: its size, frames/s unprofiled, the CPU and device time totals and the tables."""

    device: str
    raw: str
    precision: str
    resolution: str
    frames: int
    fps: float
    cpu_ms_per_frame: float  # self CPU time of torch's operations over every thread
    device_ms_per_frame: float  # self device time (kernels and copies); 0 on a CPU
    host_calls: dict[str, tuple[int, float]]  # name -> (calls, self CPU ms), CUDA runtime calls only
    tables: dict[str, str]  # sort key -> torch.profiler table
    python: str  # cProfile of the main thread, by own time

    def markdown(self) -> str:
        lines = [f"# Engine profile: {self.device}, {self.raw} raw, {self.precision}, {self.resolution} resolution, "
                 f"{self.frames} frames", "",
                 f"- end to end, unprofiled: {self.fps:.1f} frames/s",
                 f"- torch's operations: {self.cpu_ms_per_frame:.2f} ms a frame of CPU time (every thread)"]
        if self.device_ms_per_frame > 0:
            lines.append(f"- the device busy {self.device_ms_per_frame:.2f} ms a frame (kernels and copies)")
        for name, (calls, ms) in self.host_calls.items():
            lines.append(f"- `{name}`: {calls / self.frames:.1f} calls a frame, {ms / self.frames:.3f} ms a frame")
        for key, table in self.tables.items():
            lines += ["", f"## by {key.replace('_', ' ')}", "", "```", table, "```"]
        lines += ["", "## the main thread's Python (cProfile), by own time", "", "```", self.python, "```"]
        return "\n".join(lines) + "\n"


def profile_engine(device: str = "cpu", width: int = 400, height: int = 250, frames: int = 240,
                   precision: str = "fp32", threads: int | None = None, rows: int = 25,
                   resolution: str = DEFAULT_RESOLUTION) -> EngineProfile:
    """Profile the default engine on ``device`` over ``frames`` output frames of a random ``width`` x ``height``
    capture (20 raw planes a frame), after a short warm-up run; ``resolution`` as ``reconstruct --resolution``
    ("binned": the network alone makes the frames, as the speed targets count them: without the raw gate)."""
    import torch
    from torch.profiler import ProfilerActivity, profile

    options = dict(device=device, precision=precision, threads=threads)
    capture = dict(width=width, height=height)
    with tempfile.TemporaryDirectory(prefix="rmbvideo-profile-") as folder:
        work = Path(folder)
        path = write_random_capture(work / "capture.dat", 20 * frames, width, height)

        def run(name: str, duration_s: float | None = None):
            return run_reconstruction(path, work / name, fmt="null", duration_s=duration_s, capture=capture,
                                      extra_options=options, overwrite=True, resolution=resolution,
                                      raw_gate="auto" if resolution == "full" else "off")

        run("warm", duration_s=0.1)  # as ``bench sizes`` warms up: the model loaded, the kernels chosen
        began = time.perf_counter()
        summary = run("plain")
        fps = summary.frames / (time.perf_counter() - began)
        activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device == "cuda" else [])
        with profile(activities=activities) as prof:
            run("profiled")
        python = cProfile.Profile()
        python.enable()
        run("python")
        python.disable()
    events = prof.key_averages()
    count = max(summary.frames, 1)
    cpu_us = sum(e.self_cpu_time_total for e in events)
    device_us = sum(e.self_device_time_total for e in events) if device == "cuda" else 0.0
    host = {e.key: (e.count, e.self_cpu_time_total / 1e3) for e in events if e.key in HOST_CALLS}
    keys = ("self_cpu_time_total",) + (("self_device_time_total",) if device == "cuda" else ())
    tables = {key: events.table(sort_by=key, row_limit=rows, max_name_column_width=45) for key in keys}
    return EngineProfile(device=torch.cuda.get_device_name(0) if device == "cuda" else "CPU",
                         raw=f"{width}x{height}", precision=precision, resolution=resolution,
                         frames=summary.frames, fps=fps,
                         cpu_ms_per_frame=cpu_us / 1e3 / count, device_ms_per_frame=device_us / 1e3 / count,
                         host_calls=host, tables=tables, python=_own_time_table(python, rows))


def _own_time_table(python: cProfile.Profile, rows: int) -> str:
    """cProfile's table of the ``rows`` functions with the most own time, from its column header on."""
    text = io.StringIO()
    pstats.Stats(python, stream=text).sort_stats("tottime").print_stats(rows)
    lines = text.getvalue().splitlines()
    start = next((k for k, line in enumerate(lines) if line.lstrip().startswith("ncalls")), 0)
    return "\n".join(line.rstrip() for line in lines[start:] if line.strip())

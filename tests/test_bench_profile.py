"""``rmbvideo bench profile``: the engine's time by operation (torch.profiler) and the main thread's Python
(cProfile), on a small random capture on the CPU."""

from __future__ import annotations

from rmbvideo.bench.profile import profile_engine


def test_profile_has_frames_per_second_the_torch_tables_and_the_main_threads_python():
    result = profile_engine("cpu", 64, 48, frames=10, threads=1, rows=8)
    assert result.frames == 10 and result.fps > 0 and result.cpu_ms_per_frame > 0
    assert result.device_ms_per_frame == 0 and set(result.tables) == {"self_cpu_time_total"}
    header, *rows = result.python.splitlines()
    assert header.split()[:2] == ["ncalls", "tottime"] and 1 <= len(rows) <= 8
    text = result.markdown()
    assert "## the main thread's Python (cProfile), by own time" in text and result.python in text
    assert "aten::" in result.tables["self_cpu_time_total"]


def test_profile_of_the_binned_network_alone():
    """The binned run never enters the full-resolution stage; the default (full) run does (every function the main
    thread ran is in a table of 1,000 rows)."""
    binned = profile_engine("cpu", 64, 48, frames=10, threads=1, rows=1000, resolution="binned")
    assert binned.frames == 10 and binned.resolution == "binned"
    assert binned.markdown().startswith("# Engine profile: CPU, 64x48 raw, fp32, binned resolution, 10 frames")
    full = profile_engine("cpu", 64, 48, frames=10, threads=1, rows=1000)
    def stage(python: str) -> list[str]:  # the full-resolution stage's work (its loader may be asked, and say off)
        return [line for line in python.splitlines() if "full_resolution.py" in line and "_stage)" not in line]

    assert stage(full.python) and not stage(binned.python)

"""Simulator speed: ``rmbvideo simulate`` against a plain numpy reference, in one run.

The reference is the simplest simulator with the same statistics for shot noise: per readout, one
Poisson draw per pixel (``Generator.poisson``) added to the carried charge, a threshold compare and a
reset, in a Python loop over readouts, on the scene's expected photo-charge of the first readout
(no rendering, no other effects). The simulator renders the scene at every readout, runs every effect
the scene lists and writes the capture. Both are reported as pixel-readouts per second; their ratio is
the figure of merit (issue: >= 2x), next to the capture's real-time factor; each is the median of a few runs,
alternated.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from rmbvideo.scenes.scene import Scene, resolve_scene
from rmbvideo.simulate.capture import CaptureSimulator, simulate_capture


def reference_emission(expected: np.ndarray, readouts: int, threshold: float, seed: int = 0) -> np.ndarray:
    """The numpy reference: ``readouts`` 1-bit planes from Poisson photo-charge per pixel per readout."""
    rng = np.random.default_rng(seed)
    charge = np.zeros(expected.shape)
    fired_total = np.zeros(expected.shape, dtype=np.int64)
    for _ in range(readouts):
        charge += rng.poisson(expected)
        fired = charge >= threshold
        charge[fired] = 0.0
        fired_total += fired
    return fired_total


def bench_simulate(scene_name: str = "demo", duration_s: float = 0.02, repeats: int = 3) -> dict:
    """Pixel-readouts/s of ``simulate`` on ``scene_name`` and of the numpy reference, same run: ``repeats`` runs of
    each, alternated (which goes first swaps), the median of each (a shared machine's load moves single runs)."""
    scene: Scene = resolve_scene(scene_name)
    simulator = CaptureSimulator(scene, duration_s)
    readouts = simulator.total_readouts
    pixels = scene.width * scene.height
    expected = simulator.expected_photo(0)
    times: dict[str, list[float]] = {"simulator": [], "reference": []}
    with tempfile.TemporaryDirectory(prefix="rmbvideo-bench-sim-") as folder:
        work = {"simulator": lambda: simulate_capture(scene, Path(folder) / "capture.dat", duration_s=duration_s,
                                                      overwrite=True),
                "reference": lambda: reference_emission(expected, readouts, scene.sensor.q_r)}
        for rep in range(repeats):
            for name in (list(work) if rep % 2 == 0 else list(work)[::-1]):
                began = time.perf_counter()
                work[name]()
                times[name].append(time.perf_counter() - began)
    simulated_s, reference_s = statistics.median(times["simulator"]), statistics.median(times["reference"])
    simulator_rate = readouts * pixels / simulated_s
    reference_rate = readouts * pixels / reference_s
    return {
        "scene": scene_name, "width": scene.width, "height": scene.height, "readouts": readouts,
        "effects": list(scene.effects), "repeats": repeats, "simulator_s": simulated_s, "reference_s": reference_s,
        "simulator_pixel_readouts_per_s": simulator_rate, "reference_pixel_readouts_per_s": reference_rate,
        "ratio": simulator_rate / reference_rate,
        "real_time_factor": (readouts / scene.rate_hz) / simulated_s,
    }


def summary(result: dict) -> str:
    """Human-readable lines of ``bench_simulate``'s result."""
    return "\n".join([
        f"simulate {result['scene']}: {result['width']}x{result['height']}, {result['readouts']} readouts, "
        f"effects: {', '.join(result['effects']) or 'none'}; medians of {result['repeats']} alternated runs",
        f"  simulator  {result['simulator_pixel_readouts_per_s'] / 1e6:8.2f} M pixel-readouts/s "
        f"({result['simulator_s']:.2f} s; {result['real_time_factor']:.4f}x real time)",
        f"  reference  {result['reference_pixel_readouts_per_s'] / 1e6:8.2f} M pixel-readouts/s "
        f"(numpy Poisson per pixel per readout, {result['reference_s']:.2f} s)",
        f"  simulator / reference: {result['ratio']:.2f}x (target >= 2x)",
    ])

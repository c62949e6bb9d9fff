"""Decode+bin speed: the fused path against its numpy form, plain numpy and a per-plane Python loop, in one run.

``python -m rmbvideo.bench.decode [--planes N] [--json]`` writes a random 400x250 capture
(firing rate 0.3) to a temporary folder and reports planes/s of each path, single-threaded
(numpy ufuncs use one core), and whether the fused path keeps up with a 20 kHz camera (``TARGET_PLANES_PER_S``) and
reaches the speed issue's goal (``GOAL_PLANES_PER_S``). The fused path is what the reader runs: the compiled
kernel where the install built one (``rmbvideo.sensor.compiled.COMPILED``); its numpy form (the fallback, and the code before the
kernel) is timed beside it, the two alternated ``ROUNDS`` times, medians reported.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from rmbvideo.io.dat import DatGeometry, DatReader, DatWriter
from rmbvideo.sensor.binning import bin_2x2x2, bin_packed
from rmbvideo.sensor.compiled import COMPILED

TARGET_PLANES_PER_S = 20000.0
#: the speed issue's goal on one core: five times a 20 kHz camera, so a method has the rest of the core
GOAL_PLANES_PER_S = 100000.0
FIRING_RATE = 0.3
CHUNK_PLANES = 1024  # the fused path reads in the pipeline's default chunk
PLAIN_CHUNK_PLANES = 32  # the plain path's best: unpacked chunks that stay in cache (1024 is ~7x slower)
_POOL_PLANES = 256  # distinct random planes, repeated to the requested length (speed is data-independent)
ROUNDS = 3  # alternated runs of the fused path and its numpy form (this host's speed drifts within minutes)


def _write_random_capture(path: Path, n_planes: int, geometry: DatGeometry, seed: int) -> None:
    """A capture of Bernoulli(FIRING_RATE) planes, written in bounded chunks."""
    rng = np.random.default_rng(seed)
    pool = (rng.random((_POOL_PLANES, geometry.height, geometry.image_width)) < FIRING_RATE).astype(np.uint8)
    with DatWriter(path, geometry) as writer:
        for s in range(0, n_planes, _POOL_PLANES):
            writer.write(pool[: min(_POOL_PLANES, n_planes - s)])


def _timed(work: Callable[[], int]) -> dict[str, float]:
    """Run ``work`` (returns planes processed); planes/s by wall clock and by process CPU time."""
    wall0, cpu0 = time.perf_counter(), time.process_time()
    planes = work()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    return {
        "planes": planes,
        "wall_s": wall,
        "planes_per_s": planes / max(wall, 1e-9),
        "cpu_planes_per_s": planes / max(cpu, 1e-9),
    }


def _fused(reader: DatReader, n_planes: int) -> int:
    for chunk in reader.binned_chunks(CHUNK_PLANES, 0, n_planes):
        pass
    return n_planes


def _fused_numpy(reader: DatReader, n_planes: int) -> int:
    """The same chunks, read as stored and binned by ``bin_packed``'s numpy form into a reused output."""
    g = reader.geometry
    out = np.empty((2, CHUNK_PLANES // 2, g.height // 2, g.image_width // 2), np.uint8)
    for chunk in reader.packed_chunks(CHUNK_PLANES, 0, n_planes):
        n = len(chunk.data) // 2 * 2
        whole = n == CHUNK_PLANES
        bin_packed(chunk.data[:n].reshape(n, g.height, -1), g.image_width, g.flip, out=out if whole else None,
                   compiled=False)
    return n_planes


def _median_run(runs: list[dict[str, float]]) -> dict[str, float]:
    """The run of median speed."""
    speeds = [r["planes_per_s"] for r in runs]
    return runs[speeds.index(statistics.median_low(speeds))]


def _plain(reader: DatReader, n_planes: int) -> int:
    """np.unpackbits of cache-sized chunks, then numpy reshape/slice-sum binning."""
    for chunk in reader.chunks(PLAIN_CHUNK_PLANES, 0, n_planes):
        bin_2x2x2(chunk.planes)
    return n_planes


def _per_plane_loop(path: Path, geometry: DatGeometry, n_planes: int) -> int:
    """What common spike-camera loaders do: read, unpack, reshape and flip one plane at a time."""
    h, w = geometry.height, geometry.width
    pair: list[np.ndarray] = []
    with open(path, "rb") as file:
        for _ in range(n_planes):
            raw = np.frombuffer(file.read(geometry.plane_bytes), dtype=np.uint8)
            plane = np.unpackbits(raw, bitorder="little").reshape(h, w)[::-1]
            pair.append(plane)
            if len(pair) == 2:
                bin_2x2x2(np.stack(pair))
                pair.clear()
    return n_planes


def bench_decode(n_planes: int = 20000, seed: int = 0) -> dict:
    """Measure decode+bin planes/s of the fused path, its numpy form, and the plain and per-plane-loop paths.

    The plain path and the loop run on up to 4096 planes (they are slower); the fused output and its numpy
    form are checked bit-exact against the plain one on the first chunk.
    """
    if n_planes < 2:
        raise ValueError(f"n_planes must be >= 2, got {n_planes}")
    geometry = DatGeometry()
    with tempfile.TemporaryDirectory(prefix="rmbvideo-bench-") as folder:
        path = Path(folder) / "random.dat"
        _write_random_capture(path, n_planes, geometry, seed)
        reader = DatReader(path, geometry)
        first = min(n_planes, CHUNK_PLANES) // 2 * 2
        fused_chunk = reader.read_binned(0, first)
        plain_single, plain_multi = bin_2x2x2(reader.read(0, first))
        stored = next(reader.packed_chunks(first, 0, first)).data.reshape(first, geometry.height, -1)
        numpy_single, numpy_multi = bin_packed(stored, geometry.image_width, geometry.flip, compiled=False)
        bit_exact = all(np.array_equal(a, b) for a, b in [(fused_chunk.single, plain_single), (fused_chunk.multi, plain_multi),
                                                          (numpy_single, plain_single), (numpy_multi, plain_multi)])
        fused_runs, numpy_runs = [], []
        for _ in range(ROUNDS):
            fused_runs.append(_timed(lambda: _fused(reader, n_planes)))
            numpy_runs.append(_timed(lambda: _fused_numpy(reader, n_planes)))
        fused, fused_numpy = _median_run(fused_runs), _median_run(numpy_runs)
        plain = _timed(lambda: _plain(reader, min(n_planes, 4096)))
        loop = _timed(lambda: _per_plane_loop(path, geometry, min(n_planes, 4096)))
        firing_rate = reader.mean_firing_rate()
        reader.close()  # before the folder is removed
    return {
        "width": geometry.width,
        "height": geometry.height,
        "firing_rate": firing_rate,
        "kernel": "compiled" if COMPILED else "numpy",
        "fused": fused,
        "fused_numpy": fused_numpy,
        "fused_vs_numpy": fused["planes_per_s"] / fused_numpy["planes_per_s"],
        "plain": plain,
        "per_plane_loop": loop,
        "fused_vs_plain": fused["planes_per_s"] / plain["planes_per_s"],
        "fused_vs_loop": fused["planes_per_s"] / loop["planes_per_s"],
        "target_planes_per_s": TARGET_PLANES_PER_S,
        "meets_target": fused["planes_per_s"] >= TARGET_PLANES_PER_S,
        "goal_planes_per_s": GOAL_PLANES_PER_S,
        "meets_goal": fused["planes_per_s"] >= GOAL_PLANES_PER_S,
        "bit_exact": bit_exact,
    }


def _summary(result: dict) -> str:
    lines = [f"decode+bin of {result['width']}x{result['height']} planes, firing rate {result['firing_rate']:.3f}, one core; "
             f"the fused path runs the {result['kernel']} kernel (medians of {ROUNDS} alternated runs)"]
    for name in ("fused", "fused_numpy", "plain", "per_plane_loop"):
        r = result[name]
        lines.append(
            f"  {name:15s} {r['planes_per_s']:>10,.0f} planes/s  ({r['cpu_planes_per_s']:,.0f} per CPU-s, "
            f"{r['planes']} planes in {r['wall_s']:.2f} s)"
        )
    lines.append(f"  fused is {result['fused_vs_numpy']:.2f}x its numpy form, {result['fused_vs_plain']:.1f}x plain and "
                 f"{result['fused_vs_loop']:.1f}x the per-plane loop")
    verdict = "keeps" if result["meets_target"] else "does NOT keep"
    goal = "reaches" if result["meets_goal"] else "MISSES"
    lines.append(f"  {verdict} up with a 20 kHz camera ({result['target_planes_per_s']:,.0f} planes/s); {goal} the "
                 f"{result['goal_planes_per_s']:,.0f} planes/s goal; bit-exact: {result['bit_exact']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Command-line entry: print the measurement as text or JSON."""
    parser = argparse.ArgumentParser(prog="python -m rmbvideo.bench.decode", description=__doc__.splitlines()[0])
    parser.add_argument("--planes", type=int, default=20000, help="raw planes in the generated capture")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    args = parser.parse_args(argv)
    result = bench_decode(args.planes)
    print(json.dumps(result, indent=2) if args.json else _summary(result))


if __name__ == "__main__":
    main()

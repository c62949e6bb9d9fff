"""The exact dynamic-range law against an earlier revision of it: the same values, and the time.

    python models/experiments/dynamic-range-speed/measure.py compare [REV]   # default REV 49c8b5e (before the change)
    python models/experiments/dynamic-range-speed/measure.py scaling        # the current code at larger Q_r
    python models/experiments/dynamic-range-speed/measure.py exact [REV]    # --variance exact against REV 0e9b8fc

``compare`` loads ``rmbvideo/sensor/theory.py`` as it was at REV (``git show``) beside the current one, checks the
spike laws' relative differences (L = 1, 3, 7, 15 at Q_r = 105 and 300), then times the paper's table (L = 1, 3, 7, its
seven N) and L = 1 and 7 at Q_r = 400 with the two alternated in one process, one thread. ``scaling`` times one level
of the paper's N at Q_r = 800 and 2,000 (L = 1 and 7).
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rmbvideo.sensor import theory as current  # noqa: E402
from rmbvideo.sensor.params import SensorParams  # noqa: E402

PAPER_N = [1, 10, 30, 70, 1000, 10000, 20000]


def params(level: int, q_r: float) -> SensorParams:
    base = SensorParams(level=level)
    return replace(base, voltage=q_r / base.capacitance)


def revision(rev: str):
    """``rmbvideo.sensor.theory`` as it was at ``rev``, as a module of its own."""
    source = subprocess.run(["git", "show", f"{rev}:rmbvideo/sensor/theory.py"], check=True, capture_output=True,
                            text=True, cwd=Path(__file__).resolve().parents[3]).stdout
    path = Path(tempfile.mkdtemp()) / "theory_at_revision.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("theory_at_revision", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def timed(module, jobs, exact: bool = False) -> tuple[float, list[float]]:
    start = time.perf_counter()
    values = [r.dr_db for p, ns in jobs for r in module.dynamic_range(p, ns, exact=exact)]
    return time.perf_counter() - start, values


def compare(rev: str = "49c8b5e") -> None:
    old = revision(rev)
    lam = np.logspace(-6, 6, 300)
    for level in (1, 3, 7, 15):
        for q_r in (105, 300):
            a, b = old.spike_law(lam, params(level, q_r)), current.spike_law(lam, params(level, q_r))
            kept = a.pmf > 1e-280
            rel = float((np.abs(a.pmf - b.pmf)[kept] / a.pmf[kept]).max())
            print(f"L = {level}, Q_r = {q_r}: spike law pmf max relative difference {rel:.1e} "
                  f"(smallest probability {a.pmf[a.pmf > 0].min():.1e})")
    cases = {"paper table (L = 1, 3, 7; Q_r = 105)": [(params(level, 105), PAPER_N) for level in (1, 3, 7)],
             "L = 1, Q_r = 400, N = 1, 10, 1000, 20000": [(params(1, 400), [1, 10, 1000, 20000])],
             "L = 7, Q_r = 400, N = 1, 10, 1000, 20000": [(params(7, 400), [1, 10, 1000, 20000])]}
    for label, jobs in cases.items():
        times = {"current": [], rev: []}
        values = {}
        for _ in range(2):
            for name, module in (("current", current), (rev, old)):
                seconds, values[name] = timed(module, jobs)
                times[name].append(seconds)
        worst = max(abs(a - b) for a, b in zip(values["current"], values[rev]))
        print(f"{label}: {rev} {min(times[rev]):.1f} s, current {min(times['current']):.1f} s "
              f"({min(times[rev]) / min(times['current']):.1f}x; best of two alternated), tables differ by at most "
              f"{worst:.1e} dB")


def scaling() -> None:
    for q_r in (800, 2000):
        for level in (1, 7):
            seconds, _ = timed(current, [(params(level, q_r), PAPER_N)])
            print(f"Q_r = {q_r}, L = {level}: {seconds:.1f} s a level")


def exact(rev: str = "0e9b8fc") -> None:
    """The exact-variance rows of the paper's table: L = 7 and 3 against ``rev`` (matrix powers per N), L = 1 alone
    (at ``rev`` it did not finish in 15 minutes)."""
    old = revision(rev)
    for level in (7, 3):
        jobs = [(params(level, 105), PAPER_N)]
        (t_old, v_old), (t_new, v_new) = timed(old, jobs, exact=True), timed(current, jobs, exact=True)
        worst = max(abs(a - b) for a, b in zip(v_old, v_new))
        print(f"exact, L = {level}: {rev} {t_old:.1f} s, current {t_new:.1f} s ({t_old / t_new:.1f}x), "
              f"rows differ by at most {worst:.1e} dB")
    seconds, values = timed(current, [(params(1, 105), PAPER_N)], exact=True)
    print(f"exact, L = 1: current {seconds:.0f} s, {' '.join(f'{v:.2f}' for v in values)} dB")


if __name__ == "__main__":
    command, *args = sys.argv[1:] or ["compare"]
    {"compare": compare, "scaling": scaling, "exact": exact}[command](*args)

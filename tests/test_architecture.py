"""The layer rule, checked on the code's own imports (lazy ones included): packages form no cycle,
nothing outside ``cli`` imports the CLI or click, the network imports torch and its siblings only,
and the cheap commands do not pay for torch, SciPy or OpenCV."""

from __future__ import annotations

import ast
import subprocess
import sys
import time
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "rmbvideo"
#: lower layers first; a package may import only packages at its own position or before it.
LAYERS = ["errors", "shipped", "chunks", "image_pool", "mulaw", "threads", "allocator", "sensor", "io", "scenes", "net", "recon", "simulate", "evaluate", "train",
          "bench", "batch", "cli"]


def imports() -> list[tuple[str, str, str]]:
    """(file, importing package, imported rmbvideo module) for every import in the package."""
    found = []
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE)
        src = rel.parts[0].removesuffix(".py")
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 else []
            found += [(str(rel), src, name) for name in names]
    return found


def test_imports_only_point_down():
    wrong = []
    for rel, src, name in imports():
        if src in ("__init__", "__main__") or not name.startswith("rmbvideo."):
            continue
        dst = name.split(".")[1]
        if dst != src and LAYERS.index(dst) > LAYERS.index(src):
            wrong.append(f"{rel} imports {name}")
    assert not wrong, wrong


def test_only_the_cli_uses_click():
    users = [rel for rel, src, name in imports() if name.split(".")[0] == "click" and src != "cli"]
    assert not users, users


def test_the_network_imports_torch_and_its_siblings_only():
    allowed = ("torch", "rmbvideo.net", "rmbvideo.mulaw", "__future__", "math", "collections", "dataclasses",
               "typing")
    parts = [(rel, name) for rel, src, name in imports() if src == "net" and not rel.endswith("weights.py")]
    assert parts and all(name.startswith(allowed) for _, name in parts), parts


def _modules_loaded(*args: str) -> set[str]:
    code = ("import sys\nfrom rmbvideo.cli import main\ntry:\n    main(%r, standalone_mode=False)\nexcept SystemExit:\n"
            "    pass\nprint(' '.join(sorted(m.split('.')[0] for m in sys.modules)))" % (list(args),))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return set(result.stdout.split()[-1000:])


def test_help_and_info_import_neither_torch_scipy_nor_opencv(tmp_path):
    from rmbvideo.io.dat import DatGeometry, write_dat
    import numpy as np

    capture = tmp_path / "c.dat"
    write_dat(capture, np.zeros((4, 16, 16), np.uint8), DatGeometry(16, 16))
    for args in (["--help"], ["info", str(capture), "--width", "16", "--height", "16"]):
        heavy = _modules_loaded(*args) & {"torch", "scipy", "cv2"}
        assert not heavy, (args, heavy)


def test_a_raw_classical_run_and_a_refused_run_never_load_torch(tmp_path):
    """TFP and TFI on the raw planes need no network, and a run refused for its input fails before any network is
    loaded: importing torch alone takes a second or more, which such a run would spend waiting."""
    from rmbvideo.io.dat import DatGeometry, write_dat
    import numpy as np

    capture = tmp_path / "c.dat"
    write_dat(capture, (np.random.default_rng(0).random((80, 16, 16)) < 0.3).astype(np.uint8), DatGeometry(16, 16))
    geometry = ["--width", "16", "--height", "16", "--quiet"]
    for method in ("tfp", "tfi"):
        out = tmp_path / method
        assert "torch" not in _modules_loaded("reconstruct", str(capture), "-o", str(out), "--method", method,
                                              "--format", "png", *geometry)
        assert len(list(out.glob("frame_*.png"))) == 4
    (tmp_path / "c.capture.json").write_text('{"width": 0}')
    assert "torch" not in _modules_loaded("reconstruct", str(capture), "-o", str(tmp_path / "refused"))
    assert not (tmp_path / "refused").exists()


def test_one_thread_policy(monkeypatch):
    """Small or busy machines get one thread (threads there wait for each other); idle cores are used."""
    from rmbvideo import threads

    monkeypatch.setattr(threads, "available_cores", lambda: 2)
    assert threads.default_threads() == 1
    monkeypatch.setattr(threads, "available_cores", lambda: 16)
    monkeypatch.setattr(threads, "busy_cores", lambda: 15.6)
    assert threads.default_threads() == 1
    monkeypatch.setattr(threads, "busy_cores", lambda: 2.0)
    assert threads.default_threads() == threads.MAX_THREADS


def test_work_beside_the_network_needs_a_second_idle_core_or_two_threads_asked_for(monkeypatch):
    """Work that never waits for a partner (the aligned means) gets its own thread on an idle 2-core machine,
    not on a busy one; an explicit thread count decides by itself."""
    from rmbvideo import threads

    monkeypatch.setattr(threads, "available_cores", lambda: 2)
    monkeypatch.setattr(threads, "busy_cores", lambda: 0.2)
    assert threads.default_threads() == 1 and threads.work_beside(None)
    monkeypatch.setattr(threads, "busy_cores", lambda: 1.3)
    assert threads.default_threads() == 1 and not threads.work_beside(None)
    assert threads.work_beside(2) and not threads.work_beside(1)
    monkeypatch.setattr(threads, "available_cores", lambda: 1)
    monkeypatch.setattr(threads, "busy_cores", lambda: 0.0)
    assert not threads.work_beside(None)


def test_busy_cores_are_measured_on_this_process_cores_and_count_another_process_spinning():
    """An idle machine reads near 0 busy cores, one with a process spinning on one core near 1 (the
    measurement sleeps itself, so it never counts its own process)."""
    import subprocess
    import sys

    from rmbvideo import threads

    if threads._cpu_times() is None or threads.available_cores() < 2:
        pytest.skip("no /proc/stat or a single core")
    threads._measured = None
    spinner = subprocess.Popen([sys.executable, "-c", "import time\nend = time.time() + 30\nwhile time.time() < end: pass"])
    try:
        time.sleep(0.5)
        busy = threads.busy_cores()
        assert busy >= 0.7, busy
    finally:
        spinner.kill()
        spinner.wait()
        threads._measured = None


def _openmp_threads() -> int:
    """OpenMP's thread count for parallel regions started by the calling thread (each thread has its own)."""
    import re

    import torch

    found = re.search(r"omp_get_max_threads\(\) : (\d+)", torch.__config__.parallel_info())
    if found is None:
        pytest.skip("this torch build does not use OpenMP")
    return int(found.group(1))


def test_compute_threads_sets_the_count_of_a_thread_beside_the_main_one() -> None:
    """A stage running beside another (full resolution's finishing thread) sets its own torch count, OpenMP's for
    that thread, and keeps it; the main thread's count and OpenCV's are left alone."""
    import threading

    import torch

    from rmbvideo import threads

    import cv2

    main_before, cv_before = _openmp_threads(), cv2.getNumThreads()
    seen = {}

    def beside() -> None:
        with threads.compute_threads(3, 3):
            seen["inside"] = _openmp_threads()
            seen["cv"] = cv2.getNumThreads()
        seen["after"] = _openmp_threads()

    worker = threading.Thread(target=beside)
    worker.start()
    worker.join()
    assert seen == {"inside": 3, "cv": cv_before, "after": 3}  # that thread's, for good: it is the stage's own
    assert _openmp_threads() == main_before and cv2.getNumThreads() == cv_before
    with threads.compute_threads(2):
        assert _openmp_threads() == 2 == torch.get_num_threads()
    assert _openmp_threads() == main_before


def test_compute_threads_applies_the_policy_to_torch_and_opencv_and_restores_the_counts(monkeypatch):
    import cv2
    import torch

    from rmbvideo import threads

    before, before_cv = torch.get_num_threads(), cv2.getNumThreads()
    monkeypatch.setattr(threads, "available_cores", lambda: 2)
    with threads.compute_threads():
        assert torch.get_num_threads() == 1 and cv2.getNumThreads() == 1
        with threads.compute_threads(3):
            assert torch.get_num_threads() == 3 and cv2.getNumThreads() == 3
        assert torch.get_num_threads() == 1 and cv2.getNumThreads() == 1
    assert torch.get_num_threads() == before and cv2.getNumThreads() == before_cv

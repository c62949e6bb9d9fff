"""Hostile input and faults end in one line and exit 2 (or the signal's code), never a traceback, and
leave no output behind: sidecars with NaN/Infinity/zero rate, geometries with no pixel left,
absurd rates, .mbit headers that would divide by zero, models with NaN weights or the wrong input
mode, SIGTERM in the middle of a run, absurd scenes, a full disk (injected with RLIMIT_FSIZE), a pipe
as input, running out of memory (RLIMIT_AS), an interrupted batch, a Dask cluster with no worker."""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from rmbvideo.errors import ModelError
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import ModelCard, load_model, save_model
from cli_helpers import GEOM, capture, cli, one_line_error


@pytest.mark.parametrize("sidecar, needle", [
    ('{"width": NaN}', "'width' must be a finite number"),
    ('{"width": Infinity}', "'width' must be a finite number"),
    ('{"header_cols": NaN}', "'header_cols' must be a finite number"),
    ('{"rate_hz": 0}', "'rate_hz' must be between"),
    ('{"width": 64.5}', "'width' must be a whole number"),
])
def test_hostile_sidecars(tmp_path: Path, sidecar: str, needle: str) -> None:
    dat = capture(tmp_path / "cap.dat")
    (tmp_path / "cap.capture.json").write_text(sidecar)
    one_line_error(cli("info", dat), "cap.capture.json", needle)
    one_line_error(cli("reconstruct", dat, "-o", tmp_path / "out"), needle)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args, needle", [
    (("--header-cols", "63"), "needs at least 1x1 pixels"),
    (("--method", "tfw", "--header-cols", "63"), "needs at least 1x1 pixels"),
    (("--rate", "1e-300"), "plane rate must be between"),
    (("--method", "tfp", "--window", "100000000"), "--window: tfp takes 1..20000"),
])
def test_absurd_options_are_refused_up_front(tmp_path: Path, args, needle: str) -> None:
    dat = capture(tmp_path / "cap.dat")
    geometry = () if "--width" in args else GEOM
    one_line_error(cli("reconstruct", dat, "-o", tmp_path / "out", *geometry, *args), needle)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("field, value", [("band", 0), ("shift", -2), ("bits", 0), ("level", 0)])
def test_hostile_mbit_headers(tmp_path: Path, field: str, value: int) -> None:
    dat = capture(tmp_path / "cap.dat")
    header = {"version": 1, "width": 64, "height": 48, "level": 7, "bits": 3, "rate_hz": 20000.0, "flip": True,
              "band": 4, "shift": 2, "rows": "band", field: value}
    text = json.dumps(header).encode()
    (tmp_path / "cap.mbit").write_bytes(b"RMBMBIT1" + struct.pack("<I", len(text)) + text + bytes(4096))
    one_line_error(cli("info", dat), "cap.mbit", "bad header")


def test_models_with_nan_weights_or_the_wrong_input_mode_are_refused(tmp_path: Path) -> None:
    model = RmbNet(RmbNetConfig(w=1, width=0.25))
    with torch.no_grad():
        next(model.parameters()).view(-1)[0] = float("nan")
    save_model(tmp_path / "nan.safetensors", model, ModelCard(name="nan"))
    with pytest.raises(ModelError, match="NaN or Inf"):
        load_model(tmp_path / "nan.safetensors")
    native = RmbNet(RmbNetConfig(w=1, width=0.25, input_mode="native"))
    save_model(tmp_path / "native.safetensors", native, ModelCard(name="native"))
    dat = capture(tmp_path / "cap.dat")
    one_line_error(cli("reconstruct", dat, "-o", tmp_path / "out", *GEOM, "--model", tmp_path / "native.safetensors"),
                   "trained for 'native' input")
    assert not (tmp_path / "out").exists()


def test_a_card_that_contradicts_its_weights_is_refused(tmp_path: Path) -> None:
    """w changes no tensor shape, so only the architecture stored inside the weights can catch a card
    edited to say w = 1 for w = 3 weights."""
    path = save_model(tmp_path / "m.safetensors", RmbNet(RmbNetConfig(w=3, width=0.25)), ModelCard(name="m"))
    load_model(path)
    card = json.loads(path.with_suffix(".json").read_text())
    card["architecture"]["w"] = 1
    path.with_suffix(".json").write_text(json.dumps(card))
    with pytest.raises(ModelError, match=r"contradicts the weights' own \(w\)"):
        load_model(path)


def test_sigterm_mid_run_leaves_no_output(tmp_path: Path) -> None:
    dat = capture(tmp_path / "cap.dat", planes=40000)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "rmbvideo", "reconstruct", str(dat), "-o", str(out), *GEOM,
                             "--method", "tfp", "--format", "exr", "--window", "2001"], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not list(tmp_path.glob(".out.partial-*/frame_*.exr")):
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "stopped by SIGTERM" in err and "Traceback" not in err
    assert not out.exists() and not list(tmp_path.glob(".out.*"))


def test_batch_workers_die_with_their_parent(tmp_path: Path) -> None:
    """kill -9 of a batch leaves no worker writing on: workers get SIGTERM when their parent dies."""
    import os

    ready = tmp_path / "ready"
    child = ("from rmbvideo.batch.pool import die_with_parent; import time, pathlib; die_with_parent(); "
             f"pathlib.Path({str(ready)!r}).write_text('x'); time.sleep(120)")
    parent_code = ("import subprocess, sys, time; "
                   f"p = subprocess.Popen([sys.executable, '-c', {child!r}]); print(p.pid, flush=True); time.sleep(120)")
    parent = subprocess.Popen([sys.executable, "-c", parent_code], stdout=subprocess.PIPE, text=True)
    child_pid = int(parent.stdout.readline())
    deadline = time.monotonic() + 60
    while not ready.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        try:
            os.kill(child_pid, 0)
        except ProcessLookupError:
            break
        try:  # reap it if it became our zombie (it is the orphan of a dead parent, re-parented)
            os.waitpid(child_pid, os.WNOHANG)
        except ChildProcessError:
            pass
        time.sleep(0.05)
    else:
        os.kill(child_pid, signal.SIGKILL)
        pytest.fail("the worker outlived its parent")


# --- simulate: absurd scenes and a full disk -------------------------------------------------------

@pytest.mark.parametrize("scene, needle", [
    ("width = 16384\nheight = 16384", "'width' must be at most"),
    ("width = 4096\nheight = 4096", "more than this simulator's limit"),
    ("subsamples = 100000000", "'subsamples' must be at most 64"),
    ("duration_s = 1e9", "'duration_s' must be at most"),
    ("rate_hz = 1e-300", "'rate_hz' must be between"),
    ("[background]\nzoom = 1e-300", "'background.zoom' must be between"),
    ("[background]\nzoom_rate = 1e6", "'background.zoom_rate' takes the zoom outside"),
    ("[background]\ncenter = [1e300, 0]", "'background.center' values must be at most"),
    ("[[objects]]\ngrid = [100000, 100000]\ntexture = 'led'", "'objects[0].grid' values must be at most"),
])
def test_absurd_scenes_are_refused_up_front(tmp_path: Path, scene: str, needle: str) -> None:
    (tmp_path / "absurd.toml").write_text(scene + "\n")
    one_line_error(cli("simulate", tmp_path / "absurd.toml", "-o", tmp_path / "x.dat"), "absurd.toml", needle)
    assert list(tmp_path.iterdir()) == [tmp_path / "absurd.toml"]


def test_a_capture_longer_than_the_free_disk_is_refused_up_front(tmp_path: Path) -> None:
    (tmp_path / "long.toml").write_text("duration_s = 3600\nrate_hz = 1e6\n")  # 45 TB
    one_line_error(cli("simulate", tmp_path / "long.toml", "-o", tmp_path / "x.dat", "-q"), "x.dat", "GB free")
    assert not (tmp_path / "x.dat").exists()


def _file_size_limit(limit: int):
    """A child process whose writes fail with EFBIG past ``limit`` bytes per file (a full disk, injected)."""
    import resource

    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


@pytest.mark.parametrize("limit", [10_000, 200_000])
def test_simulate_on_a_full_disk_leaves_neither_capture_nor_ground_truth(tmp_path: Path, limit: int) -> None:
    """The ground truth fails (10 kB) or the capture does (200 kB): nothing is left either way."""
    proc = subprocess.run([sys.executable, "-m", "rmbvideo", "simulate", "demo", "-o", str(tmp_path / "x.dat"),
                           "--duration", "0.01", "--gt", str(tmp_path / "gt"), "-q"], capture_output=True,
                          text=True, preexec_fn=_file_size_limit(limit))
    one_line_error(proc, "File too large")
    assert list(tmp_path.iterdir()) == []


# --- capture files: geometry, pipes, memory ------------------------------------------------------

def test_geometry_errors_name_the_file(tmp_path: Path) -> None:
    dat = capture(tmp_path / "cap.dat")
    for command in (("info",), ("reconstruct", "-o", tmp_path / "out")):
        one_line_error(cli(*command[:1], dat, *command[1:], "--width", "9", "--height", "7"),
                       "cap.dat", "multiple of 8")
    assert not (tmp_path / "out").exists()


def test_a_pipe_as_input_is_refused_not_waited_on(tmp_path: Path) -> None:
    import os

    os.mkfifo(tmp_path / "live.dat")
    proc = subprocess.run([sys.executable, "-m", "rmbvideo", "reconstruct", str(tmp_path / "live.dat"), "-o",
                           str(tmp_path / "out")], capture_output=True, text=True, timeout=60)
    one_line_error(proc, "live.dat", "not a regular file")


def test_running_out_of_memory_is_one_line(tmp_path: Path) -> None:
    """A geometry the file can hold but memory cannot (one 16384x16384 plane under a 3 GB limit)."""
    import resource

    big = tmp_path / "big.dat"
    big.write_bytes(bytes(16384 * 16384 // 8))

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))
    proc = subprocess.run([sys.executable, "-m", "rmbvideo", "preview", str(big), "--width", "16384", "--height",
                           "16384", "-o", str(tmp_path / "p.png")], capture_output=True, text=True, preexec_fn=limit)
    one_line_error(proc, "preview: out of memory")
    assert not (tmp_path / "p.png").exists()


# --- batch: interrupted runs and a cluster without workers ----------------------------------------

def test_interrupted_batch_reports_captures_finished_before_it_as_done(tmp_path: Path) -> None:
    from rmbvideo.batch.jobs import CaptureJob
    from rmbvideo.batch.pool import _fill_unfinished
    from rmbvideo.batch.runner import run_capture_job

    options = {"capture": {"width": 64, "height": 48}, "method": "tfp", "fmt": "png"}
    jobs = [CaptureJob(capture(tmp_path / "in" / f"{n}.dat", seed=i), tmp_path / "out", n, options)
            for i, n in enumerate("ab")]
    assert run_capture_job(jobs[0]).status == "ok"  # finished in a worker; the parent never heard back
    results = [None, None]
    _fill_unfinished(jobs, results, "interrupted before it finished")
    assert results[0].status == "ok" and results[0].frames > 0
    assert results[1].status == "failed" and "interrupted" in results[1].error


def test_dask_batch_without_a_live_worker_fails_within_the_timeout(tmp_path: Path, monkeypatch) -> None:
    distributed = pytest.importorskip("distributed")
    from rmbvideo.batch import pool
    from rmbvideo.batch.jobs import CaptureJob

    monkeypatch.setattr(pool, "DASK_POLL_S", 0.2)
    monkeypatch.setattr(pool, "DASK_NO_WORKER_S", 2.0)
    job = CaptureJob(capture(tmp_path / "a.dat"), tmp_path / "out", "a", {"capture": {"width": 64, "height": 48}})
    results = {}
    with distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
        began = time.monotonic()
        pool._run_on_dask([job], cluster.scheduler_address, results.__setitem__)
    assert time.monotonic() - began < 30
    assert results[0].status == "failed" and "no live Dask worker" in results[0].error


@pytest.mark.parametrize("fmt", ["mp4", "exr"])
def test_reconstruct_on_a_full_disk_is_one_line_and_leaves_nothing(tmp_path: Path, fmt: str) -> None:
    dat = capture(tmp_path / "in" / "cap.dat", planes=4000)
    proc = subprocess.run([sys.executable, "-m", "rmbvideo", "reconstruct", str(dat), "-o", str(tmp_path / "out"),
                           *GEOM, "--method", "tfp", "--format", fmt, "-q"], capture_output=True, text=True,
                          preexec_fn=_file_size_limit(20_000 if fmt == "mp4" else 1_000))
    one_line_error(proc, str(tmp_path / "out"))
    assert ".partial-" not in proc.stderr and "ffmpeg version" not in proc.stderr
    if fmt == "mp4":  # ffmpeg, past the limit, is stopped by SIGXFSZ: said so, in that one line
        assert "ffmpeg was stopped by a signal: File size limit exceeded" in proc.stderr
    assert list(tmp_path.iterdir()) == [tmp_path / "in"]


def test_a_missing_ffmpeg_is_one_line_and_leaves_nothing(tmp_path: Path) -> None:
    dat = capture(tmp_path / "in" / "cap.dat", planes=400)
    env = {**os.environ, "IMAGEIO_FFMPEG_EXE": str(tmp_path / "no-ffmpeg")}
    proc = subprocess.run([sys.executable, "-m", "rmbvideo", "reconstruct", str(dat), "-o", str(tmp_path / "out"),
                           *GEOM, "--method", "tfp", "-q"], capture_output=True, text=True, env=env)
    one_line_error(proc, str(tmp_path / "out" / "frames.mp4"), "cannot start ffmpeg")
    assert list(tmp_path.iterdir()) == [tmp_path / "in"]


def test_a_signal_waits_until_an_output_swap_is_done() -> None:
    """staged_folder swaps outputs with the command's signal exceptions held back (found by the fault
    matrix: a SIGHUP between the renames left the previous output aside)."""
    import os

    from rmbvideo.cli import Terminated, _received, _terminate
    from rmbvideo.io.atomic import signals_deferred

    previous = signal.signal(signal.SIGHUP, _terminate)
    reached_the_end = False
    try:
        with pytest.raises(Terminated):
            with signals_deferred():
                os.kill(os.getpid(), signal.SIGHUP)
                time.sleep(0.05)
                reached_the_end = True
        assert reached_the_end
    finally:
        signal.signal(signal.SIGHUP, previous)
        _received.clear()


SWALLOWING_COMMAND = '''
import os, signal, sys, time
import click
from rmbvideo.cli import LazyGroup

signal.signal(signal.SIGINT, signal.default_int_handler)  # as on a terminal, also when the tests run in the background


class Dropped:
    def __del__(self):  # Python prints and drops what is raised here, as in logging's at-fork hook
        os.kill(os.getpid(), signal.{sig})
        for _ in range(10000):
            pass


@click.command()
def body():
    Dropped()
    time.sleep(5)  # the signal, sent again, ends this at once; dropped, the command would go on to the end
    print("finished")


class Group(LazyGroup):
    def get_command(self, ctx, name):
        return body


Group(name="rmbvideo")(["info"])
'''


@pytest.mark.parametrize("sig, code, message", [("SIGINT", 130, "interrupted"), ("SIGTERM", 143, "stopped by SIGTERM")])
def test_a_signal_that_lands_where_python_drops_exceptions_still_stops_the_command(sig: str, code: int,
                                                                                   message: str) -> None:
    """A signal's exception raised inside a ``__del__`` (or logging's at-fork hook, when ffmpeg starts: found by the
    fault matrix on a loaded machine) is only printed by Python, with a traceback, and the command went on; it is
    sent again and stops the command as any signal does."""
    done = subprocess.run([sys.executable, "-c", SWALLOWING_COMMAND.replace("{sig}", sig)], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == code, done.stderr
    assert "Traceback" not in done.stderr and "finished" not in done.stdout
    assert done.stderr.strip().splitlines() == [f"rmbvideo: {message}; partial output removed"]

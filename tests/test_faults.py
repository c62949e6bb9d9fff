"""Hostile input and faults end in one line and exit 2 (or the signal's code), never a traceback, and
leave no output behind: sidecars with NaN/Infinity/zero rate, geometries too small for a method,
absurd rates, .mbit headers that would divide by zero, models with NaN weights or the wrong input
mode, SIGTERM in the middle of a run."""

from __future__ import annotations

import json
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
    (("--method", "mg20", "--width", "16", "--height", "16"), "needs at least 12x12"),
    (("--align", "dis", "--width", "16", "--height", "16"), "needs at least 12x12"),
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

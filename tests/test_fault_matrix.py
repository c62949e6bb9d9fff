"""Fault injection: a signal at a random moment of ``reconstruct`` (fresh or a rerun over an earlier
output, every output format) never leaves anything that looks complete but is not. Afterwards the output
folder is absent, byte-identical to the previous complete output, or identical to a complete new run;
after SIGKILL (which nobody can catch) a rerun removes what the killed run left. ``pytest --soak N``
adds N more random moments per cell."""

from __future__ import annotations

import hashlib
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cli_helpers import GEOM, capture

SIGNALS = (signal.SIGTERM, signal.SIGHUP, signal.SIGINT, signal.SIGKILL)
FORMATS = ("exr", "png", "mp4")


def _args(dat: Path, out: Path, fmt: str, tonemap: str) -> list[str]:
    return [sys.executable, "-m", "rmbvideo", "reconstruct", str(dat), "-o", str(out), *GEOM, "--method", "tfp",
            "--window", "41", "--step", "10", "--format", fmt, "--tonemap", tonemap, "--overwrite", "-q"]


def _snapshot(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A capture and the complete outputs of the two runs every trial starts from or aims at."""
    root = tmp_path_factory.mktemp("matrix")
    dat = capture(root / "cap.dat", planes=12000)  # a run of ~1-2 s: the signals land all through it
    complete, folders = {}, {}
    for fmt in FORMATS:
        for tonemap in ("exposure", "reinhard"):
            out = folders[fmt, tonemap] = root / f"ref-{fmt}-{tonemap}"
            subprocess.run(_args(dat, out, fmt, tonemap), check=True, capture_output=True)
            complete[fmt, tonemap] = _snapshot(out)
    return {"dat": dat, "complete": complete, "folders": folders}


def _trial(setup: dict, folder: Path, fmt: str, sig: signal.Signals, rerun: bool, delay: float) -> None:
    folder.mkdir()
    out = folder / "out"
    if rerun:  # an earlier complete output (the exposure run's files, copied: the same bytes as a run there)
        shutil.copytree(setup["folders"][fmt, "exposure"], out)
    before = _snapshot(out) if rerun else None
    proc = subprocess.Popen(_args(setup["dat"], out, fmt, "reinhard"), stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert "Traceback" not in err, err
    # Ctrl-C in the few milliseconds while click parses the command line, before any handler of ours
    # exists, is click's own one-line "Aborted!" with exit 1 (nothing written yet).
    aborted_early = sig == signal.SIGINT and proc.returncode == 1 and err.strip() == "Aborted!"
    assert proc.returncode in (0, 128 + sig, 130, -sig) or aborted_early, (proc.returncode, err)
    allowed = [setup["complete"][fmt, "reinhard"]] + ([before] if rerun else [])
    if out.exists():
        assert _snapshot(out) in allowed, f"{sig.name} after {delay:.2f} s left an inconsistent {out}"
    else:
        assert not rerun, f"{sig.name} after {delay:.2f} s removed the previous output"
    if sig != signal.SIGKILL:
        assert [p.name for p in folder.iterdir()] == (["out"] if out.exists() else [])
    subprocess.run(_args(setup["dat"], out, fmt, "reinhard"), check=True, capture_output=True)
    assert _snapshot(out) == setup["complete"][fmt, "reinhard"]
    assert [p.name for p in folder.iterdir()] == ["out"], "a rerun left what the killed run wrote"


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("sig", SIGNALS, ids=lambda s: s.name)
def test_signal_at_a_random_moment_keeps_the_output_consistent(setup, tmp_path: Path, fmt: str,
                                                               sig: signal.Signals, soak: int) -> None:
    rng = random.Random(f"{fmt}-{sig.name}")
    for trial in range(1 + soak):
        rerun = trial % 2 == 0
        _trial(setup, tmp_path / f"t{trial}", fmt, sig, rerun, delay=rng.uniform(0.1, 1.5))


@pytest.mark.parametrize("fmt", ("exr", "png"))
@pytest.mark.parametrize("sig", (signal.SIGTERM, signal.SIGKILL), ids=lambda s: s.name)  # SIGINT, SIGHUP: as SIGTERM
def test_a_resumable_run_stopped_at_a_random_moment_resumes_to_the_complete_output(
        setup, tmp_path: Path, fmt: str, sig: signal.Signals, soak: int) -> None:
    """A `--resume` run stopped by a signal at a random moment: nothing under the output's name unless it is
    complete; the same command again completes the folder byte for byte as an uninterrupted run (TFP: the frames are
    exact, the PNG tone mapper's state is carried) and leaves nothing beside it."""
    rng = random.Random(f"resume-{fmt}-{sig.name}")
    for trial in range(1 + soak):
        folder = tmp_path / f"t{trial}"
        folder.mkdir()
        out = folder / "out"
        args = [a for a in _args(setup["dat"], out, fmt, "reinhard") if a != "--overwrite"] + ["--resume"]
        proc = subprocess.Popen(args, stderr=subprocess.PIPE, text=True)
        time.sleep(rng.uniform(0.1, 1.5))
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
        assert "Traceback" not in err, err
        if out.exists():
            assert _snapshot(out) == setup["complete"][fmt, "reinhard"]
            continue  # it finished before the signal
        resumed = subprocess.run(args, capture_output=True, text=True)
        assert resumed.returncode == 0, resumed.stderr
        assert _snapshot(out) == setup["complete"][fmt, "reinhard"], f"{sig.name}: resumed output differs"
        assert [p.name for p in folder.iterdir()] == ["out"], "the resume left the interrupted run's folder"

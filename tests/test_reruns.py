"""Reruns into an output folder: refused without --overwrite, replaced as a whole with it, and a
run that fails or produces no frame leaves the folder exactly as it was."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rmbvideo.chunks import Frame
from rmbvideo.cli import main
from rmbvideo.errors import InputError
from rmbvideo.io.dat import DatGeometry, write_dat
from rmbvideo.recon.methods import METHODS, Method, register_method
from rmbvideo.recon.run import run_reconstruction

GEOM = ["--width", "32", "--height", "16", "--rate", "20000"]


@pytest.fixture
def capture(tmp_path) -> Path:
    rng = np.random.default_rng(3)
    path = tmp_path / "c.dat"
    write_dat(path, (rng.random((200, 16, 32)) < 0.3).astype(np.uint8), DatGeometry(32, 16))
    return path


def run(*args: str) -> int:
    """Exit status of ``rmbvideo reconstruct ARGS -q`` (click returns it without standalone mode)."""
    try:
        return int(main(["reconstruct", *args, "-q"], standalone_mode=False) or 0)
    except SystemExit as exc:
        return int(exc.code or 0)


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_rerun_is_refused_without_overwrite_and_replaces_whole_with_it(capture, tmp_path, capsys):
    out = tmp_path / "out"
    assert run(str(capture), "-o", str(out), "--method", "tfp", "--format", "exr", *GEOM) == 0
    before = snapshot(out)
    assert len([n for n in before if n.endswith(".exr")]) == 10
    assert run(str(capture), "-o", str(out), "--method", "tfp", "--format", "exr", *GEOM) == 2
    assert "use --overwrite" in capsys.readouterr().err and snapshot(out) == before
    assert run(str(capture), "-o", str(out), "--method", "tfp", "--format", "exr", "--duration", "0.002",
               "--overwrite", *GEOM) == 0
    after = snapshot(out)
    assert len([n for n in after if n.endswith(".exr")]) == 2  # no frame of the old run is left
    listed = after["frames.csv"].decode().splitlines()[1:]
    assert sorted(line.split(",")[2] for line in listed) == sorted(n for n in after if n.endswith(".exr"))
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]  # no staging left behind


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_a_folder_with_the_users_own_files_is_never_replaced(capture, tmp_path, capsys, overwrite):
    """--overwrite replaces the output folder as a whole: a folder holding anything a run does not write (a user's
    notes, the capture itself) is refused, with or without it, and left as it was."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "c.dat").write_bytes(capture.read_bytes())
    before = snapshot(out)
    assert run(str(out / "c.dat"), "-o", str(out), "--method", "tfp", *overwrite, *GEOM) == 2
    err = capsys.readouterr().err
    assert "holds files this command does not write (c.dat, notes.txt)" in err and "Traceback" not in err
    assert snapshot(out) == before


def test_the_current_folder_is_refused_as_an_output_folder(capture, tmp_path, capsys, monkeypatch):
    """``-o .`` (or a path to the current folder) would rename the folder the shell is in; it was a traceback for
    ``.`` and, with ``--overwrite``, a path to it replaced the folder with the capture in it."""
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    for path in (".", str(here), "../here"):
        assert run(str(capture), "-o", path, "--method", "tfp", "--overwrite", *GEOM) == 2
        err = capsys.readouterr().err
        assert f"{path}: is the current folder" in err and "Traceback" not in err, err
    assert not list(here.iterdir()) and sorted(p.name for p in tmp_path.iterdir()) == ["c.dat", "here"]
    assert run(str(capture), "-o", "out/.", "--method", "tfp", *GEOM) == 0  # a folder named with a dot works
    assert sorted(p.name for p in (here / "out").iterdir()) == ["frames.csv", "frames.mp4"]


def test_a_failing_overwrite_leaves_the_previous_output(capture, tmp_path):
    out = tmp_path / "out"
    run(str(capture), "-o", str(out), "--method", "tfp", "--format", "exr", *GEOM)
    before = snapshot(out)

    class Fails:
        input_kind = "spikes"

        def __init__(self, step: int = 20) -> None:
            self.seen = 0

        def push(self, chunk):
            self.seen += 1
            if self.seen > 1:
                raise OSError(28, "No space left on device")
            return [Frame(0, 0.0, np.ones(chunk.planes.shape[1:], np.float32))]

        def flush(self):
            return []

    register_method(Method("fails-test", Fails, "spikes", "fails on its second chunk"))
    try:
        with pytest.raises(Exception):
            run_reconstruction(capture, out, method="fails-test", fmt="exr", chunk_planes=50, overwrite=True,
                               capture=dict(width=32, height=16))
    finally:
        METHODS.pop("fails-test")
    assert snapshot(out) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]


def test_a_run_without_frames_is_an_error_and_leaves_no_folder(capture, tmp_path, capsys):
    out = tmp_path / "none"
    assert run(str(capture), "-o", str(out), "--method", "tfp", "--duration", "0.0005", *GEOM) == 2
    assert "no frame" in capsys.readouterr().err and not out.exists()
    with pytest.raises(InputError):
        run_reconstruction(capture, out, method="tfw", duration_s=0.0005, capture=dict(width=32, height=16))
    assert not out.exists() and not list(tmp_path.glob(".none.*"))


def test_quiet_prints_nothing_and_verbose_works_after_the_subcommand(capture, tmp_path):
    import subprocess
    import sys

    base = [sys.executable, "-m", "rmbvideo", "reconstruct", str(capture), "--method", "tfp", *GEOM]
    quiet = subprocess.run([*base, "-o", str(tmp_path / "q"), "-q"], capture_output=True, text=True)
    assert quiet.returncode == 0 and quiet.stdout == "" and quiet.stderr == ""
    verbose = subprocess.run([*base, "-o", str(tmp_path / "v"), "-v"], capture_output=True, text=True)
    assert verbose.returncode == 0 and "DEBUG" in verbose.stderr
    typo = subprocess.run([sys.executable, "-m", "rmbvideo", "reconstrut"], capture_output=True, text=True)
    assert typo.returncode == 2 and "Did you mean 'reconstruct'?" in typo.stderr


def test_verbose_shows_rmbvideos_debug_messages_not_every_librarys():
    """``-v`` is for rmbvideo's own debug lines: matplotlib's font search wrote hundreds into ``bench -v``."""
    import logging

    from rmbvideo.cli import configure_logging

    root, ours = logging.getLogger(), logging.getLogger("rmbvideo")
    saved = root.level, list(root.handlers), ours.level
    try:
        configure_logging(verbose=True)
        assert logging.getLogger("rmbvideo.recon.run").isEnabledFor(logging.DEBUG)
        assert not logging.getLogger("matplotlib.font_manager").isEnabledFor(logging.DEBUG)
        assert logging.getLogger("distributed.scheduler").isEnabledFor(logging.INFO)
        configure_logging()
        assert not logging.getLogger("rmbvideo.recon.run").isEnabledFor(logging.DEBUG)
        assert logging.getLogger("rmbvideo.recon.run").isEnabledFor(logging.INFO)
    finally:
        root.setLevel(saved[0])
        root.handlers[:] = saved[1]
        ours.setLevel(saved[2])


def test_old_option_spellings_work_but_are_not_advertised():
    from click.testing import CliRunner

    result = CliRunner().invoke(main, ["dynamic-range", "--L", "3", "--N", "1,10", "--json"])
    assert result.exit_code == 0, result.output
    shown = CliRunner().invoke(main, ["dynamic-range", "--help"]).output
    assert "--levels" in shown and "--L " not in shown
    assert "--out " not in CliRunner().invoke(main, ["evaluate", "--help"]).output

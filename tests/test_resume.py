"""reconstruct --resume: an interrupted run of a long capture keeps its frames, and the same command continues it."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import one_line_error
from rmbvideo.io.dat import DatGeometry, write_dat
from rmbvideo.io.exr import read_exr
from rmbvideo.recon.resume import RESUME_STATE, WARM_UP_FRAMES


def moving_capture(path: Path, planes: int, width: int, height: int) -> Path:
    """Stripes drifting sideways, so that a frame depends on its neighbours' evidence."""
    rng = np.random.default_rng(0)
    t = np.arange(planes)[:, None, None]
    x = np.arange(width)[None, None, :]
    light = 0.05 + 0.8 * (0.5 + 0.5 * np.sin((x - 0.02 * t) / 5.0)) * np.ones((1, height, 1))
    write_dat(path, (rng.random((planes, height, width)) < light).astype(np.uint8), DatGeometry(width, height))
    return path


def command(capture: Path, out: Path, *options: str, fmt: str = "exr") -> list[str]:
    exr = ("--exr-dtype", "float") if fmt == "exr" else ()
    return [sys.executable, "-m", "rmbvideo", "reconstruct", str(capture), "-o", str(out), "--format", fmt, *exr,
            "--threads", "1", "-q", *options]


def interrupted(args: list[str], out: Path, frames: int, sig: int) -> subprocess.CompletedProcess:
    """Run ``args``, stop it with ``sig`` once its staging folder holds ``frames`` frame files; skip the test when the
    run ends first (a fast machine)."""
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if [p for p in out.parent.glob(f".{out.name}.partial-*") if len(list(p.glob("frame_*"))) >= frames]:
            proc.send_signal(sig)
            break
        time.sleep(0.02)
    stdout, stderr = proc.communicate(timeout=60)
    if proc.returncode == 0:
        pytest.skip("the run ended before the signal reached it")
    return subprocess.CompletedProcess(args, proc.returncode, stdout, stderr)


def frames_of(folder: Path) -> dict[str, np.ndarray]:
    """Every frame file in ``folder`` by name: EXR as linear floats, PNG as its 8-bit pixels."""
    import cv2

    frames = {p.name: read_exr(p)[0] for p in sorted(folder.glob("*.exr"))}
    return frames | {p.name: cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted(folder.glob("*.png"))}


# the default window, and PNG: tests/test_fault_matrix.py, every signal at random moments
@pytest.mark.parametrize("window", ["1201"])
def test_a_killed_window_method_run_resumes_to_the_uninterrupted_frames_bit_for_bit(tmp_path: Path,
                                                                                       window: str) -> None:
    """kill -9 in the middle of a TFP run: its frames stay in the hidden staging folder (nothing under the output's
    name); the same command with --resume keeps them, runs from a little before the first missing one (further back for
    a window wider than the warm-up), and the folder then holds exactly what an uninterrupted run writes, frames.csv
    included, and nothing else."""
    fmt = "exr"
    capture = moving_capture(tmp_path / "long.dat", 6000, 16, 16)
    options = ("--width", "16", "--height", "16", "--method", "tfp", "--step", "2", "--window", window)
    whole = tmp_path / "whole"
    subprocess.run(command(capture, whole, *options, fmt=fmt), check=True)
    out = tmp_path / "out"
    killed = interrupted(command(capture, out, *options, "--resume", fmt=fmt), out, 1000, signal.SIGKILL)
    assert killed.returncode == -signal.SIGKILL and not out.exists()
    (partial,) = tmp_path.glob(".out.partial-*")
    kept = len(list(partial.glob("frame_*")))
    resumed = subprocess.run(command(capture, out, *options, "--resume", "-v", fmt=fmt), capture_output=True,
                             text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming an interrupted run" in resumed.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["long.dat", "out", "whole"]  # the partial was taken up
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in whole.iterdir())  # no record left
    assert (out / "frames.csv").read_text() == (whole / "frames.csv").read_text()
    expected, got = frames_of(whole), frames_of(out)
    assert len(got) == 3000 and kept < 3000
    for name, image in expected.items():
        np.testing.assert_array_equal(got[name], image, err_msg=name)


def test_a_stopped_rmbnet_run_says_what_it_kept_and_resumes_to_the_uninterrupted_frames(tmp_path: Path) -> None:
    """SIGTERM in the middle of the default method's run: one line saying the frames are kept for --resume (not
    "removed"). The resumed run sets back the recurrent state saved after a frame already written, so its frames are
    the uninterrupted run's bit for bit. Without that state (a file gone or torn) it is rebuilt over the warm-up frames,
    faithful but not the same: the ConvLSTM keeps a faint long memory (measured here: 72-74 dB against the peak, at
    worst 0.8 % of it on a pixel; without a warm-up the first resumed frame is 10 % off)."""
    capture = moving_capture(tmp_path / "long.dat", 2800, 32, 24)
    options = ("--width", "32", "--height", "24")
    whole = tmp_path / "whole"
    subprocess.run(command(capture, whole, *options), check=True)
    out = tmp_path / "out"
    stopped = interrupted(command(capture, out, *options, "--resume"), out, WARM_UP_FRAMES + 20, signal.SIGTERM)
    assert stopped.returncode == 143 and "Traceback" not in stopped.stderr, stopped.stderr
    (line,) = stopped.stderr.strip().splitlines()
    assert "frames are kept for the same command with --resume" in line and "removed" not in line
    (partial,) = tmp_path.glob(".out.partial-*")
    assert (partial / RESUME_STATE).is_file()
    torn = tmp_path / "torn"  # the same interrupted run, its saved state torn
    shutil.copytree(partial, tmp_path / partial.name.replace(".out.", ".torn.", 1))
    (tmp_path / partial.name.replace(".out.", ".torn.", 1) / RESUME_STATE).write_bytes(b"\x10\x00")
    expected = frames_of(whole)
    for folder, exact in ((out, True), (torn, False)):
        resumed = subprocess.run(command(capture, folder, *options, "--resume"), capture_output=True, text=True)
        assert resumed.returncode == 0, resumed.stderr
        assert (folder / "frames.csv").read_text() == (whole / "frames.csv").read_text()
        assert sorted(p.name for p in folder.iterdir()) == sorted(p.name for p in whole.iterdir())  # no record left
        got = frames_of(folder)
        assert got.keys() == expected.keys()
        if exact:
            for name, image in expected.items():
                np.testing.assert_array_equal(got[name], image, err_msg=name)
            continue
        worst = max(float(np.abs(got[n] - expected[n]).max() / expected[n].max()) for n in expected)
        mse = np.mean([np.mean((got[n] - expected[n]) ** 2) / expected[n].max() ** 2 for n in expected])
        assert worst < 3e-2 and -10 * np.log10(mse) > 65


def test_a_partial_made_with_other_options_is_not_taken_up(tmp_path: Path) -> None:
    """A run interrupted with one --window, resumed with another: the frames are not mixed. The new run starts afresh
    (its frames are those of a plain run with its own options) and the old partial folder is removed."""
    capture = moving_capture(tmp_path / "long.dat", 6000, 16, 16)
    options = ("--width", "16", "--height", "16", "--method", "tfp", "--step", "2")
    out = tmp_path / "out"
    interrupted(command(capture, out, *options, "--window", "41", "--resume"), out, 100, signal.SIGKILL)
    resumed = subprocess.run(command(capture, out, *options, "--window", "21", "--resume", "-v"), capture_output=True,
                             text=True)
    assert resumed.returncode == 0 and "resuming" not in resumed.stderr, resumed.stderr
    assert not list(tmp_path.glob(".out.*"))
    plain = tmp_path / "plain"
    subprocess.run(command(capture, plain, *options, "--window", "21"), check=True)
    expected, got = frames_of(plain), frames_of(out)
    assert got.keys() == expected.keys()
    for name in ("frame_000000.exr", "frame_001000.exr", "frame_002999.exr"):
        np.testing.assert_array_equal(got[name], expected[name])


def test_resume_refuses_a_video_and_a_complete_output(tmp_path: Path) -> None:
    """A video stream cannot be continued where it was cut: --resume with mp4 is refused in one line naming the
    formats that can, as is RMB-Net at a multiple of its step (some of its frames unwritten); a folder holding a
    complete run is not resumed (nor replaced) without --overwrite."""
    capture = moving_capture(tmp_path / "c.dat", 200, 16, 16)
    base = [sys.executable, "-m", "rmbvideo", "reconstruct", str(capture), "-o", str(tmp_path / "v"), "--width", "16",
            "--height", "16", "--method", "tfp", "--resume"]
    proc = subprocess.run(base, capture_output=True, text=True)
    one_line_error(proc, "exr or png")
    assert not (tmp_path / "v").exists()
    every_other = [*base[:-3], "--step", "40", "--format", "exr", "--resume"]  # RMB-Net keeping every 2nd frame
    one_line_error(subprocess.run(every_other, capture_output=True, text=True), "--resume: rmbnet at --step 40")
    assert not (tmp_path / "v").exists()
    done = tmp_path / "done"
    args = command(capture, done, "--width", "16", "--height", "16", "--method", "tfp", "--resume")
    subprocess.run(args, check=True)
    before = {p.name: p.stat().st_mtime_ns for p in done.iterdir()}
    again = subprocess.run(args, capture_output=True, text=True)
    one_line_error(again, "holds a complete run already")
    assert {p.name: p.stat().st_mtime_ns for p in done.iterdir()} == before
    assert subprocess.run([*args, "--overwrite"], capture_output=True, text=True).returncode == 0


def test_a_run_that_fills_the_disk_keeps_its_frames_and_resumes_once_there_is_room(tmp_path: Path) -> None:
    """A file-size limit (as a full disk) stops a resumable run: one line, the write's reason and that its frames are
    kept; the same command run again with room completes the folder as an uninterrupted run would."""
    import resource

    capture = moving_capture(tmp_path / "long.dat", 2000, 16, 16)
    options = ("--width", "16", "--height", "16", "--method", "tfp", "--step", "2")
    whole = tmp_path / "whole"
    subprocess.run(command(capture, whole, *options), check=True)
    out = tmp_path / "out"
    limit = 4000  # bytes a file: the frame log and frames.csv reach it after about a hundred frames

    def small_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    full = subprocess.run(command(capture, out, *options, "--resume"), capture_output=True, text=True,
                          preexec_fn=small_files)
    assert full.returncode == 2 and "Traceback" not in full.stderr, full.stderr
    (line,) = full.stderr.strip().splitlines()
    assert "frames are kept for the same command with --resume" in line and not out.exists()
    resumed = subprocess.run(command(capture, out, *options, "--resume"), capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert (out / "frames.csv").read_text() == (whole / "frames.csv").read_text()
    expected, got = frames_of(whole), frames_of(out)
    assert got.keys() == expected.keys()
    for name, image in expected.items():
        np.testing.assert_array_equal(got[name], image, err_msg=name)


def test_the_fingerprint_holds_the_shipped_weights(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Weights retrained in a newer checkout under the same version number make another run: a resume does not mix
    the old weights' frames with the new ones' (nor set back a state of another network), and a batch does not skip
    the old weights' output as complete."""
    from rmbvideo.io.capture import open_capture
    from rmbvideo.recon import fingerprint

    capture = moving_capture(tmp_path / "c.dat", 40, 16, 16)
    reader = open_capture(capture, width=16, height=16)
    models = tmp_path / "models"
    models.mkdir()
    (models / "rmbnet-binned.safetensors").write_bytes(b"weights of one training")
    monkeypatch.setattr(fingerprint, "MODELS_DIR", models)
    before = fingerprint.fingerprint_digest(fingerprint.run_fingerprint(capture, {"method": "rmbnet"}, reader))
    assert before == fingerprint.fingerprint_digest(fingerprint.run_fingerprint(capture, {"method": "rmbnet"}, reader))
    (models / "rmbnet-binned.safetensors").write_bytes(b"weights of another training")
    after = fingerprint.fingerprint_digest(fingerprint.run_fingerprint(capture, {"method": "rmbnet"}, reader))
    assert after != before

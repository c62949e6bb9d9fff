"""Bad input never crashes or loses data: broken captures, wrong geometry, unwritable or full disks, bad models."""

from __future__ import annotations

import errno
import json
import os
import pickle
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import rmbvideo.io.atomic as atomic
from rmbvideo.batch import MARKER_NAME, REPORT_NAME
from rmbvideo.cli import main
from rmbvideo.io.dat import DatGeometry, write_dat
from rmbvideo.io.geometry_guess import CONVINCING_SCORE, guess_geometry, tied_with_best

from cli_helpers import GEOM, capture, cli, one_line_error



def moving_scene(planes: int, height: int, width: int, seed: int = 0) -> np.ndarray:
    """Spikes of a smooth bright blob drifting right over a gradient: image-like data."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width]
    frames = []
    for t in range(planes):
        cx = width * (0.3 + 0.4 * t / planes)
        rate = 0.1 + 0.5 * y / height + 0.4 * np.exp(-((x - cx) ** 2 + (y - height / 2) ** 2) / (0.05 * width * height))
        frames.append(rng.random((height, width)) < np.clip(rate, 0, 1))
    return np.stack(frames).astype(np.uint8)


def block_scene(planes: int, height: int, width: int, seed: int = 0) -> np.ndarray:
    """Spikes of a still pattern of 10x10 dark and bright blocks: the contrast of a real scene in a few planes."""
    rng = np.random.default_rng(seed)
    levels = np.where(rng.random((height // 10 + 1, width // 10 + 1)) < 0.5, 0.05, 0.95)
    rate = levels.repeat(10, 0).repeat(10, 1)[:height, :width]
    return (rng.random((planes, height, width)) < rate).astype(np.uint8)


# --- broken captures -----------------------------------------------------------------------------


def test_truncated_capture_processes_whole_planes(tmp_path: Path) -> None:
    from rmbvideo.io.exr import read_exr

    dat = capture(tmp_path / "cap.dat", planes=60)
    whole = tmp_path / "whole.dat"
    whole.write_bytes(dat.read_bytes()[: 59 * 64 * 48 // 8])
    with open(dat, "r+b") as f:
        f.truncate(dat.stat().st_size - 100)  # the last plane is cut short
    proc = cli("reconstruct", dat, "-o", tmp_path / "out", *GEOM, "--format", "exr", "--exr-dtype", "float")
    assert proc.returncode == 0, proc.stderr
    assert "trailing bytes" in proc.stderr
    assert cli("reconstruct", whole, "-o", tmp_path / "ref", *GEOM, "--format", "exr", "--exr-dtype",
               "float").returncode == 0
    frames = sorted((tmp_path / "out").glob("*.exr"))
    assert [p.name for p in frames] == [p.name for p in sorted((tmp_path / "ref").glob("*.exr"))]
    for frame in frames:
        np.testing.assert_array_equal(read_exr(frame)[0], read_exr(tmp_path / "ref" / frame.name)[0])


def test_random_bytes_give_noise_not_a_crash(tmp_path: Path) -> None:
    dat = tmp_path / "noise.dat"
    dat.write_bytes(np.random.default_rng(1).integers(0, 256, 64 * 48 // 8 * 40 + 7, dtype=np.uint8).tobytes())
    proc = cli("reconstruct", dat, "-o", tmp_path / "out", *GEOM, "--format", "exr", "--method", "tfw")
    assert proc.returncode == 0, proc.stderr
    from rmbvideo.io.exr import read_exr

    images = [read_exr(p)[0] for p in sorted((tmp_path / "out").glob("*.exr"))]
    assert len(images) == 2 and all(np.isfinite(i).all() and (i >= 0).all() for i in images)
    guesses = guess_geometry(dat)
    assert guesses[0].score < CONVINCING_SCORE


@pytest.mark.parametrize("args", [("--width", "100000", "--height", "100000"), ("--width", "9", "--height", "7"),
                                  ("--width", "64", "--height", "48", "--header-cols", "64")])
def test_absurd_dimensions_are_one_line_errors(tmp_path: Path, args: tuple[str, ...]) -> None:
    dat = capture(tmp_path / "cap.dat", planes=10)
    proc = cli("reconstruct", dat, "-o", tmp_path / "out", *args)
    one_line_error(proc, "geometry")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("width, height, method", [(16, 3, "rmbnet"), (8, 9, "rmbnet"), (16, 16, "mg20"),
                                                   (16, 16, "rmbnet --align dis"), (400, 24, "rmbnet")])
def test_a_tiny_capture_is_reconstructed(tmp_path: Path, width: int, height: int, method: str) -> None:
    """A capture whose binned frames OpenCV's DIS flow refuses (an 8x1 or 4x4 binned stream: a traceback) or
    crashes on (a 400x24 strip, 200x12 binned: a segmentation fault, no message) is reconstructed; the default's
    aligned means, MG20 and --align read flows."""
    rng = np.random.default_rng(3)
    dat = tmp_path / "tiny.dat"
    write_dat(dat, (rng.random((200, height, width)) < 0.3).astype(np.uint8), DatGeometry(width, height))
    name, *options = method.split()
    proc = cli("reconstruct", dat, "-o", tmp_path / "out", "--width", width, "--height", height, "--method", name,
               *options, "--format", "exr", "--quiet")
    assert proc.returncode == 0, proc.stderr
    from rmbvideo.io.exr import read_exr

    images = [read_exr(p)[0] for p in sorted((tmp_path / "out").glob("*.exr"))]
    assert images and all(np.isfinite(i).all() and (i >= 0).all() for i in images)


def test_a_video_or_picture_given_as_a_capture_is_refused_by_name(tmp_path: Path) -> None:
    """The tool's own outputs (MP4, PNG, EXR) and other formats read as planes of spikes gave noise without a word; a
    file that starts with another format's signature is now refused as what it is, by every reader."""
    dat = capture(tmp_path / "cap.dat", planes=200)
    out = tmp_path / "out"
    for fmt in ("mp4", "png", "exr"):
        assert cli("reconstruct", dat, "-o", out / fmt, *GEOM, "--method", "tfp", "--format", fmt, "-q").returncode == 0
    np.save(tmp_path / "array.npy", np.zeros(20000, np.uint8))
    for path, what in ((out / "mp4" / "frames.mp4", "an MP4/MOV video"), (out / "png" / "frame_000000.png",
                       "a PNG image"), (out / "exr" / "frame_000000.exr", "an OpenEXR image"),
                       (tmp_path / "array.npy", "a NumPy array")):
        one_line_error(cli("reconstruct", path, "-o", tmp_path / "again", *GEOM), str(path), f"is {what}")
    video = out / "mp4" / "frames.mp4"
    one_line_error(cli("info", video, "--guess-geometry"), str(video), "is an MP4/MOV video")
    assert not (tmp_path / "again").exists()


def test_batch_reports_every_kind_of_broken_capture(tmp_path: Path) -> None:
    good = capture(tmp_path / "in" / "good.dat")
    (tmp_path / "in" / "empty.dat").write_bytes(b"")
    (tmp_path / "in" / "short.dat").write_bytes(b"\xff" * 100)
    (tmp_path / "in" / "folder.dat").mkdir()
    (tmp_path / "in" / "folder.dat" / "inner.dat").write_bytes(b"")
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["batch", str(tmp_path / "in"), str(tmp_path / "missing.dat"), "-o", str(out),
                                       *GEOM, "--format", "exr", "--jobs", "1", "-q"], catch_exceptions=False)
    assert result.exit_code == 1
    entries = {Path(c["input"]).name: c for c in json.loads((out / REPORT_NAME).read_text())["captures"]}
    assert entries["good.dat"]["status"] == "ok"
    assert "empty file" in entries["empty.dat"]["error"]
    assert "empty file" in entries["inner.dat"]["error"]
    assert "less than one" in entries["short.dat"]["error"]
    assert "no such file" in entries["missing.dat"]["error"]
    assert all(entries[n]["status"] == "failed" for n in ("empty.dat", "short.dat", "missing.dat", "inner.dat"))
    assert str(good) in result.stdout


# --- geometry guessing ---------------------------------------------------------------------------


def test_geometry_that_does_not_divide_the_file_and_the_guess(tmp_path: Path) -> None:
    dat = tmp_path / "cap.dat"
    write_dat(dat, moving_scene(48, 64, 96), DatGeometry(96, 64))
    proc = cli("info", dat)  # the default 400x250 does not divide a 96x64 capture: warned, not fatal
    assert proc.returncode == 0 and "wrong geometry" in proc.stderr
    one_line_error(cli("info", dat, "--width", "1000", "--height", "1000"), str(dat), "wrong geometry")
    proc = cli("info", dat, "--guess-geometry", "--json")
    assert proc.returncode == 0, proc.stderr
    best = json.loads(proc.stdout)["guesses"][0]
    assert (best["width"], best["height"], best["planes"]) == (96, 64, 48)
    assert best["score"] > CONVINCING_SCORE and best["options"] == "--width 96 --height 64"
    proc = cli("info", dat, "--guess-geometry")
    assert proc.returncode == 0 and "--width 96 --height 64" in proc.stdout


def test_a_geometry_the_data_cannot_tell_is_said_to_be_a_tie(tmp_path: Path) -> None:
    """A scene whose rows are all alike (a left-to-right ramp) fits every height that divides the file: the guess
    says the best candidates tie and asks for the geometry; a scene with structure both ways is not a tie."""
    width, height, planes = 96, 64, 60
    ramp = np.linspace(0.02, 0.9, width, dtype=np.float32)[None, :].repeat(height, 0)
    charge = np.random.default_rng(0).random(width)[None, :].repeat(height, 0)  # columns at their own phases
    spikes = []
    for _ in range(planes):
        charge += ramp
        spikes.append(charge >= 1.0)
        charge[spikes[-1]] -= 1.0
    flat = tmp_path / "ramp.dat"
    write_dat(flat, np.stack(spikes).astype(np.uint8), DatGeometry(width, height))
    report = json.loads(cli("info", flat, "--guess-geometry", "--json").stdout)
    assert report["ambiguous"] and report["guesses"][0]["score"] > CONVINCING_SCORE
    proc = cli("info", flat, "--guess-geometry")
    assert proc.returncode == 0 and "cannot tell them apart" in proc.stdout and "--height" in proc.stdout
    structured = tmp_path / "cap.dat"
    write_dat(structured, moving_scene(48, 64, 96), DatGeometry(96, 64))
    assert not json.loads(cli("info", structured, "--guess-geometry", "--json").stdout)["ambiguous"]
    assert "cannot tell" not in cli("info", structured, "--guess-geometry").stdout


def test_a_capture_read_at_the_default_size_that_fits_another_is_warned_of(tmp_path: Path) -> None:
    """A camera turned on its side (250x400 planes: the bytes of the default 400x250) or one whose rows end in a
    header, read with nothing giving their size: one warning names the geometry that fits, and the capture is read as
    before; the default's own captures and random spikes are not warned of, nor a capture whose size is given."""
    sideways = tmp_path / "sideways.dat"
    write_dat(sideways, block_scene(12, 400, 250), DatGeometry(250, 400))
    proc = cli("info", sideways)
    assert proc.returncode == 0 and "400x250" in proc.stdout, proc.stderr
    assert proc.stderr.count("look like planes of 250x400 (") == 1 and "give --width 250 --height 400 " in proc.stderr
    header = tmp_path / "header.dat"
    write_dat(header, block_scene(12, 250, 400), DatGeometry(416, 250, header_cols=16))
    assert "give --width 416 --height 250 --header-cols 16 " in cli("info", header).stderr
    upright, noise = tmp_path / "upright.dat", tmp_path / "noise.dat"
    write_dat(upright, block_scene(12, 250, 400), DatGeometry(400, 250))
    write_dat(noise, (np.random.default_rng(1).random((12, 250, 400)) < 0.3).astype(np.uint8), DatGeometry(400, 250))
    for path in (upright, noise):
        assert "look like" not in cli("info", path).stderr
    assert "look like" not in cli("info", sideways, "--width", "400", "--height", "250").stderr
    result = CliRunner().invoke(main, ["batch", str(sideways), str(upright), "-o", str(tmp_path / "out"),
                                       "--method", "tfp", "--jobs", "1"])
    assert result.exit_code == 0 and result.output.count("look like planes of 250x400 (") == 1, result.output
    proc = cli("batch", sideways, upright, "-o", tmp_path / "out2", "--method", "tfp", "--jobs", "2")
    assert proc.returncode == 0 and proc.stderr.count("look like planes of 250x400 (") == 1, proc.stderr
    for out in ("out", "out2"):  # the report keeps it with the capture it concerns, after the terminal has scrolled
        entries = {Path(e["input"]).name: e for e in
                   json.loads((tmp_path / out / "batch-report.json").read_text())["captures"]}
        assert [w for w in entries["sideways.dat"]["warnings"] if "look like planes of 250x400 (" in w], entries
        assert not [w for w in entries["upright.dat"]["warnings"] if "look like" in w], entries


def test_geometry_guess_of_a_real_capture(shared_data: Path) -> None:
    guesses = guess_geometry(shared_data / "real" / "car.dat")
    best = guesses[0]
    assert (best.geometry.width, best.geometry.height, best.geometry.header_cols) == (400, 250, 0)
    assert best.planes == 200 and best.score > guesses[1].score + 0.05
    assert tied_with_best(guesses) == [best]


# --- outputs that cannot be written -------------------------------------------------------------


def unwritable_folder(tmp_path: Path) -> Path:
    """A folder this process cannot write into (chmod, or a path under a regular file as root)."""
    if os.geteuid() == 0:  # root ignores permissions: a path under a file can never be created
        (tmp_path / "a-file").write_text("x")
        return tmp_path / "a-file" / "out"
    folder = tmp_path / "locked"
    folder.mkdir()
    folder.chmod(0o500)
    return folder / "out"


def test_unwritable_output_folder(tmp_path: Path) -> None:
    dat = capture(tmp_path / "cap.dat")
    out = unwritable_folder(tmp_path)
    one_line_error(cli("reconstruct", dat, "-o", out, *GEOM, "--format", "png"), str(out.parent))
    one_line_error(cli("batch", dat, "-o", out, *GEOM, "--format", "png", "-q"))
    assert not out.exists()


class FullDisk:
    """``open`` whose files refuse writes with ENOSPC when their path contains ``marker`` (a full disk)."""

    def __init__(self, marker: str) -> None:
        self.marker = marker
        self.refused = 0

    def __call__(self, file, mode="r", *args, **kwargs):
        handle = open(file, mode, *args, **kwargs)
        if self.marker not in str(file) or "w" not in mode:
            return handle
        disk = self

        class Refusing:
            def __enter__(self):
                return self

            def __exit__(self, *exc):
                handle.close()

            def write(self, data):
                disk.refused += 1
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(file))

        return Refusing()


def test_full_disk_fails_one_capture_and_keeps_earlier_outputs(tmp_path: Path, monkeypatch) -> None:
    for name in ("a", "b", "c"):
        capture(tmp_path / "in" / f"{name}.dat", seed=ord(name))
    out = tmp_path / "out"
    args = ["batch", str(tmp_path / "in"), "-o", str(out), *GEOM, "--format", "png", "--jobs", "1", "-q"]
    assert CliRunner().invoke(main, args, catch_exceptions=False).exit_code == 0
    before = {p: p.read_bytes() for p in sorted((out / "b").iterdir())}
    # Re-run with another tone map (so every capture is redone); the disk is full while b is written.
    disk = FullDisk(".b.partial-")
    monkeypatch.setattr(atomic, "open", disk, raising=False)
    result = CliRunner().invoke(main, args + ["--tonemap", "reinhard"], catch_exceptions=False)
    assert result.exit_code == 1 and disk.refused > 0
    entries = {Path(c["input"]).name: c for c in json.loads((out / REPORT_NAME).read_text())["captures"]}
    assert entries["a.dat"]["status"] == entries["c.dat"]["status"] == "ok"
    assert entries["b.dat"]["status"] == "failed" and "No space left on device" in entries["b.dat"]["error"]
    # named as the folder the user knows, not the hidden one it was written into (removed by now)
    assert entries["b.dat"]["error"].startswith(f"{out / 'b'}{os.sep}frame_") and ".partial-" not in result.output
    assert {p: p.read_bytes() for p in sorted((out / "b").iterdir())} == before  # earlier output intact
    assert not list(out.glob(".b.*"))
    # The old marker does not match the new options, so b is redone once the disk has room.
    monkeypatch.undo()
    result = CliRunner().invoke(main, args + ["--tonemap", "reinhard"], catch_exceptions=False)
    entries = {Path(c["input"]).name: c["status"] for c in json.loads((out / REPORT_NAME).read_text())["captures"]}
    assert entries == {"a.dat": "skipped", "b.dat": "ok", "c.dat": "skipped"}
    assert json.loads((out / "b" / MARKER_NAME).read_text())["fingerprint"]["options"]["tonemap"] == "reinhard"


# --- model files ---------------------------------------------------------------------------------


def rmbnet_cli_available() -> bool:
    from rmbvideo.cli.reconstruct import reconstruct

    names = {p.name for p in reconstruct.params}
    method = next(p for p in reconstruct.params if p.name == "method")
    return "model" in names and "rmbnet" in method.type.choices


def model_error(tmp_path: Path, weights: Path) -> str:
    """The one-line error of using ``weights`` (CLI when it has RMB-Net, else ``load_model``)."""
    if rmbnet_cli_available():
        dat = capture(tmp_path / "cap.dat")
        proc = cli("reconstruct", dat, "-o", tmp_path / "out", *GEOM, "--method", "rmbnet", "--model", weights)
        one_line_error(proc)
        assert not (tmp_path / "out").exists()
        return proc.stderr
    weights_module = pytest.importorskip("rmbvideo.net.weights")
    from rmbvideo.errors import ModelError

    with pytest.raises(ModelError) as info:
        weights_module.load_model(weights)
    return str(info.value)


def valid_card(tmp_path: Path) -> dict:
    weights = pytest.importorskip("rmbvideo.net.weights")
    from rmbvideo.net.config import RmbNetConfig
    from rmbvideo.net.model import RmbNet

    path = weights.save_model(tmp_path / "valid", RmbNet(RmbNetConfig(w=1, width=0.25)), weights.ModelCard(name="t"))
    return json.loads(path.with_suffix(".json").read_text())


@pytest.mark.parametrize("kind", ["corrupt", "foreign"])
def test_corrupt_or_foreign_model_is_refused(tmp_path: Path, kind: str) -> None:
    card = valid_card(tmp_path)
    weights = tmp_path / "m.safetensors"
    if kind == "corrupt":
        good = (tmp_path / "valid.safetensors").read_bytes()
        weights.write_bytes(good[: len(good) // 2])
        (tmp_path / "m.json").write_text(json.dumps(card))
    else:
        weights.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
        (tmp_path / "m.json").write_text(json.dumps({"format": "some-other-tool", "layers": 3}))
    message = model_error(tmp_path, weights)
    assert "m.safetensors" in message or "m.json" in message


class _Payload:
    """Unpickling this creates a file: proof that code from the model file ran."""

    def __init__(self, proof: Path) -> None:
        self.proof = proof

    def __reduce__(self):
        return (Path.touch, (self.proof,))


def test_model_file_carrying_pickled_code_is_refused_without_running_it(tmp_path: Path) -> None:
    card = valid_card(tmp_path)
    proof = tmp_path / "code-ran"
    weights = tmp_path / "m.safetensors"
    weights.write_bytes(pickle.dumps({"state_dict": _Payload(proof)}))
    (tmp_path / "m.json").write_text(json.dumps(card))
    message = model_error(tmp_path, weights)
    assert "refused" in message and "m.safetensors" in message
    assert not proof.exists()

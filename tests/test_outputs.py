"""Outputs: atomic writes, EXR files, and the MP4/EXR/PNG/null frame sinks with frames.csv."""

from __future__ import annotations

import csv
import errno
import importlib.abc
import logging
import sys
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np
import OpenEXR
import pytest
from click.testing import CliRunner

from rmbvideo.chunks import Frame
from rmbvideo.cli import main
from rmbvideo.errors import InputError, OutputError, RmbvideoError
from rmbvideo.io.atomic import (
    atomic_path,
    atomic_write_text,
    check_folder_creatable,
    output_folder,
    outputs_together,
    staged_folder,
)
from rmbvideo.io.exr import HALF_MAX, read_exr, read_exr_rgb, write_exr
from rmbvideo.io.ffmpeg import FfmpegEncoder
from rmbvideo.io.sinks import make_sink
from rmbvideo.io.tonemap import ToneMapConfig, ToneMapper

RATE_HZ = 20000.0


def _frames(n: int, shape: tuple[int, int], start: int = 0) -> list[Frame]:
    """A moving ramp with a bright spot: distinct, finite, HDR-ish frames."""
    height, width = shape
    ramp = np.add.outer(np.linspace(0.0, 1.0, height), np.linspace(0.0, 1.0, width)).astype(np.float32)
    frames = []
    for k in range(start, start + n):
        image = np.roll(ramp, k, axis=1) * (1.0 + 0.1 * k)
        image[height // 2, (k * 3) % width] = 500.0
        frames.append(Frame(index=k, time_s=(10 * k + 5) / RATE_HZ, image=image))
    return frames


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".tmp-" in p.name)


def _read_index(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        assert reader.fieldnames == ["index", "time_s", "file"]
        return list(reader)


def _decode_gray(path: Path) -> tuple[tuple[int, int], list[np.ndarray]]:
    """Decode a video with ffmpeg: ((width, height), frames as (H, W) uint8)."""
    reader = imageio_ffmpeg.read_frames(str(path), pix_fmt="gray", bpp=1)
    meta = next(reader)
    width, height = meta["size"]
    frames = [np.frombuffer(buffer, np.uint8).reshape(height, width) for buffer in reader]
    return (width, height), frames


# ---- atomic writes ----------------------------------------------------------------------------


def test_atomic_write_text_replaces_the_file(tmp_path: Path) -> None:
    target = tmp_path / "a.txt"
    target.write_text("old")
    atomic_write_text(target, "new ✓")
    assert target.read_text(encoding="utf-8") == "new ✓"
    assert _leftovers(tmp_path) == []


def test_atomic_path_failure_keeps_the_old_file_and_no_temp(tmp_path: Path) -> None:
    target = tmp_path / "a.txt"
    target.write_text("old")
    with pytest.raises(KeyError):
        with atomic_path(target) as temp:
            assert temp.parent == tmp_path and temp.name.startswith(".a.txt.tmp-")
            temp.write_text("half")
            raise KeyError("boom")
    assert target.read_text() == "old"
    assert _leftovers(tmp_path) == []


def test_atomic_path_turns_disk_full_into_output_error(tmp_path: Path) -> None:
    target = tmp_path / "a.bin"
    with pytest.raises(OutputError, match=str(target)):
        with atomic_path(target) as temp:
            temp.write_bytes(b"x")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert list(tmp_path.iterdir()) == []


def test_atomic_path_into_a_missing_folder_is_an_output_error(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="does not exist"):
        atomic_write_text(tmp_path / "missing" / "a.txt", "x")


# ---- EXR ----------------------------------------------------------------------------------------


def test_a_folder_another_run_filled_meanwhile_is_kept_without_overwrite(tmp_path: Path) -> None:
    """Two runs racing into one new folder: the one that finishes second, without --overwrite, fails with one
    line and leaves the first run's complete output as it was (it used to rename it aside and replace it)."""
    out = tmp_path / "out"
    is_output = lambda name: name.startswith("frames.")  # noqa: E731
    with pytest.raises(OutputError, match="another run") as caught:
        with staged_folder(out, is_output) as staging:
            (staging / "frames.csv").write_text("second run\n")
            out.mkdir()  # the first run's commit, while this one was still writing
            (out / "frames.csv").write_text("first run\n")
    assert str(out) in str(caught.value) and "partial" not in str(caught.value)
    assert (out / "frames.csv").read_text() == "first run\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging or set-aside folder left
    with staged_folder(out, is_output, overwrite=True) as staging:  # --overwrite still replaces it
        (staging / "frames.csv").write_text("third run\n")
    assert (out / "frames.csv").read_text() == "third run\n"
    empty = tmp_path / "empty"
    empty.mkdir()
    with staged_folder(empty, is_output) as staging:  # an empty folder is no one's output
        (staging / "frames.csv").write_text("run\n")
    assert (empty / "frames.csv").read_text() == "run\n"


def test_outputs_together_are_renamed_together_or_not_at_all(tmp_path: Path) -> None:
    """A report set is all of one run: held at temporary names until the block ends, then renamed together; a full
    disk at the second file, or a Ctrl-C, leaves the earlier set whole and no temporary; other files go as usual."""
    for name in ("report.md", "report.png"):
        (tmp_path / name).write_text("earlier run")
    cache = tmp_path / "cache"
    cache.mkdir()
    with pytest.raises(OutputError, match="report.png: cannot write: No space left on device"):
        with outputs_together(tmp_path, ("report.*",)):
            atomic_write_text(tmp_path / "report.md", "this run")
            atomic_write_text(tmp_path / "notes.txt", "not a report")  # not held
            atomic_write_text(cache / "report.md", "a cache the run reads back")  # another folder: not held
            assert (tmp_path / "report.md").read_text() == "earlier run"
            assert (cache / "report.md").read_text() == "a cache the run reads back"
            with atomic_path(tmp_path / "report.png"):
                raise OSError(errno.ENOSPC, "No space left on device")
    assert [(tmp_path / n).read_text() for n in ("report.md", "report.png")] == ["earlier run"] * 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "notes.txt", "report.md", "report.png"]
    with pytest.raises(KeyboardInterrupt):
        with outputs_together(tmp_path, ("report.*",)):
            atomic_write_text(tmp_path / "report.md", "this run")
            raise KeyboardInterrupt
    assert (tmp_path / "report.md").read_text() == "earlier run" and len(list(tmp_path.iterdir())) == 4
    with outputs_together(tmp_path, ("report.*",)):
        for name in ("report.md", "report.png"):
            atomic_write_text(tmp_path / name, "this run")
    assert [(tmp_path / n).read_text() for n in ("report.md", "report.png")] == ["this run"] * 2
    assert len(list(tmp_path.iterdir())) == 4
    with pytest.raises(KeyboardInterrupt):  # an inner block's files, done, still wait for the outer block's end
        with outputs_together(tmp_path, ("report.*",)):
            with outputs_together(tmp_path, ("report.md",)):
                atomic_write_text(tmp_path / "report.md", "third run")
            assert (tmp_path / "report.md").read_text() == "this run"
            raise KeyboardInterrupt
    assert (tmp_path / "report.md").read_text() == "this run" and len(list(tmp_path.iterdir())) == 4


def test_dynamic_range_figures_on_a_full_disk_keep_the_earlier_pair(tmp_path: Path) -> None:
    """The disk fills between the two figures of a rerun (RLIMIT_FSIZE between their sizes): the earlier pair stays,
    the same files (not replaced), where the first figure used to be replaced alone."""
    import subprocess
    import sys

    plots = tmp_path / "plots"
    args = [sys.executable, "-m", "rmbvideo", "dynamic-range", "--levels", "1", "--readouts", "1,10", "--plots",
            str(plots), "--quiet"]
    assert subprocess.run(args, capture_output=True).returncode == 0
    first, second = plots / "fig2_expectation_std.png", plots / "fig3_snr.png"
    if first.stat().st_size >= second.stat().st_size:  # the disk must fill at the second: only then is it a pair
        pytest.skip("this matplotlib draws the first figure larger than the second")
    inodes = {path: path.stat().st_ino for path in (first, second)}
    limit = (first.stat().st_size + second.stat().st_size) // 2

    def full_disk() -> None:
        import resource
        import signal

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    proc = subprocess.run(args, capture_output=True, text=True, preexec_fn=full_disk)
    assert proc.returncode == 2 and "File too large" in proc.stderr, proc.stderr
    assert {path: path.stat().st_ino for path in (first, second)} == inodes
    assert sorted(p.name for p in plots.iterdir()) == [first.name, second.name]


def test_atomic_outputs_get_a_plain_files_mode_whatever_wrote_them(tmp_path: Path) -> None:
    import os
    import stat

    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    target = tmp_path / "made.bin"
    with atomic_path(target) as temp:
        fd = os.open(temp, os.O_WRONLY | os.O_CREAT, 0o600)  # as safetensors creates its files
        os.close(fd)
    assert stat.S_IMODE(target.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)


def test_exr_half_round_trip_clips_above_half_max_and_keeps_time(tmp_path: Path) -> None:
    image = np.array([[0.0, 0.25, 1.5], [1000.0, 7e4, 1e9]], np.float32)
    path = tmp_path / "f.exr"
    write_exr(path, image, time_s=0.1 + 0.2, attrs={"rmbvideo:note": "hello"})
    back, header = read_exr(path)
    assert back.dtype == np.float32 and back.shape == (2, 3)
    assert np.all(np.isfinite(back))
    np.testing.assert_array_equal(back[0], [0.0, 0.25, 1.5])
    assert back[1, 0] == 1000.0
    assert back[1, 1] == HALF_MAX and back[1, 2] == HALF_MAX
    assert header["time_s"] == 0.1 + 0.2  # exact, from the string attribute
    assert header["captureTime"] == pytest.approx(0.3, rel=1e-6)
    assert header["rmbvideo:note"] == "hello"
    assert str(header["compression"]).endswith("ZIP_COMPRESSION")
    assert [c.name for c in header["channels"]] == ["Y"]
    exr = OpenEXR.File(str(path), separate_channels=True)
    assert exr.channels()["Y"].pixels.dtype == np.float16
    assert _leftovers(tmp_path) == []


def test_exr_float_round_trip_is_exact(tmp_path: Path) -> None:
    image = np.random.default_rng(1).lognormal(0.0, 4.0, (7, 9)).astype(np.float32)
    image[0, 0] = 7e4
    write_exr(tmp_path / "f.exr", image, time_s=2.5, dtype="float")
    back, header = read_exr(tmp_path / "f.exr")
    np.testing.assert_array_equal(back, image)
    assert header["time_s"] == 2.5


def test_exr_nonfinite_pixels_become_zero(tmp_path: Path) -> None:
    image = np.ones((3, 4), np.float32)
    image[0, 0], image[1, 1], image[2, 2] = np.nan, np.inf, -np.inf
    assert write_exr(tmp_path / "f.exr", image, time_s=0.0) == 3
    back, _ = read_exr(tmp_path / "f.exr")
    assert back[0, 0] == 0.0 and back[1, 1] == 0.0 and back[2, 2] == 0.0 and back[0, 1] == 1.0


def test_read_exr_rgb_of_a_written_rgb_file(tmp_path: Path) -> None:
    rgb = np.random.default_rng(2).uniform(0, 100, (5, 6, 3)).astype(np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {"R": rgb[..., 0].copy(), "G": rgb[..., 1].copy(), "B": rgb[..., 2].copy()}
    OpenEXR.File(header, channels).write(str(tmp_path / "rgb.exr"))
    np.testing.assert_array_equal(read_exr_rgb(tmp_path / "rgb.exr"), rgb)
    with pytest.raises(InputError, match="single-channel"):
        read_exr(tmp_path / "rgb.exr")


def test_read_exr_rgb_of_the_dwab_panoramas(shared_data: Path) -> None:
    rgb = read_exr_rgb(shared_data / "hdri" / "city.exr")
    assert rgb.shape == (512, 1024, 3) and rgb.dtype == np.float32
    assert np.all(np.isfinite(rgb)) and rgb.min() >= 0.0
    assert rgb.max() / max(float(np.percentile(rgb, 50)), 1e-6) > 100  # it is HDR


def test_reading_bad_exr_files_raises_input_error(tmp_path: Path) -> None:
    junk = tmp_path / "junk.exr"
    junk.write_bytes(b"not an exr" * 20)
    with pytest.raises(InputError, match="junk.exr"):
        read_exr(junk)
    with pytest.raises(InputError, match="no such file"):
        read_exr_rgb(tmp_path / "absent.exr")
    write_exr(tmp_path / "y.exr", np.zeros((2, 2), np.float32), time_s=0.0)
    with pytest.raises(InputError, match="not an RGB EXR"):
        read_exr_rgb(tmp_path / "y.exr")


def test_exr_without_openexr_installed_is_a_one_line_error_naming_the_file(tmp_path: Path,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """A partial install (the GPU image lacked the wheel) reads and writes no EXR, with an error, not a traceback."""
    monkeypatch.setitem(sys.modules, "OpenEXR", None)  # what `import OpenEXR` meets where it is not installed
    out = tmp_path / "frame.exr"
    with pytest.raises(RmbvideoError, match=r"frame\.exr: OpenEXR is not installed"):
        write_exr(out, np.zeros((2, 2), np.float32), time_s=0.0)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RmbvideoError, match=r"frame\.exr: OpenEXR is not installed"):
        read_exr(out)


class _FailingImport(importlib.abc.MetaPathFinder):
    """A finder whose OpenEXR fails to initialise with ``error`` (as a C extension's init reports an exception)."""

    def __init__(self, error: BaseException) -> None:
        self.error = error

    def find_spec(self, name, path=None, target=None):
        if name == "OpenEXR":
            raise ImportError("initialization failed") from self.error
        return None


@pytest.mark.parametrize("error, expected", [(KeyboardInterrupt(), KeyboardInterrupt),
                                             (RuntimeError("bad build"), RmbvideoError)])
def test_a_signal_while_openexr_loads_is_an_interruption_not_a_missing_module(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, error: BaseException, expected: type) -> None:
    """Ctrl-C during OpenEXR's first import (the fault matrix met it) ends the run as interrupted; a broken build is a
    one-line error that does not call it uninstalled."""
    monkeypatch.delitem(sys.modules, "OpenEXR")
    monkeypatch.setattr(sys, "meta_path", [_FailingImport(error), *sys.meta_path])
    with pytest.raises(expected) as caught:
        write_exr(tmp_path / "frame.exr", np.zeros((2, 2), np.float32), time_s=0.0)
    if expected is RmbvideoError:
        assert "cannot be loaded" in str(caught.value) and "not installed" not in str(caught.value)
    assert list(tmp_path.iterdir()) == []


# ---- sinks --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("shape", "pixel_format", "decoded_size"),
    [
        ((16, 24), "yuv420p", (24, 16)),
        ((17, 33), "yuv420p", (34, 18)),  # odd: padded by one row and column
        ((17, 33), "yuv444p", (33, 17)),  # odd: exact size
        ((17, 33), "auto", (33, 17)),  # default: odd size kept exact via yuv444p
        ((16, 24), "auto", (24, 16)),
    ],
)
def test_mp4_decodes_back_with_every_frame_at_the_expected_size(
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    shape: tuple[int, int],
    pixel_format: str,
    decoded_size: tuple[int, int],
) -> None:
    frames = _frames(7, shape, start=3)
    caplog.set_level(logging.INFO, logger="rmbvideo")
    with make_sink("mp4", tmp_path / "out", fps=25.0, mp4_pixel_format=pixel_format,
                   capture_rate_hz=RATE_HZ, frame_rate_hz=RATE_HZ / 10) as sink:
        for frame in frames:
            sink.write(frame)
    assert "80x slower than real time" in caplog.text  # 2000 frames/s of capture at 25 fps
    assert ("padding" in caplog.text) == (decoded_size != (shape[1], shape[0]))
    out = tmp_path / "out"
    assert sorted(p.name for p in out.iterdir()) == ["frames.csv", "frames.mp4"]
    size, decoded = _decode_gray(out / "frames.mp4")
    assert size == decoded_size
    assert len(decoded) == 7
    mapper = ToneMapper()
    height, width = shape
    for frame, video in zip(frames, decoded):
        expected = mapper(frame.image).astype(np.int16)
        error = np.abs(video[:height, :width].astype(np.int16) - expected)
        assert np.median(error) <= 3  # lossy, but the picture is the tone-mapped frame
    if decoded_size != (width, height):
        for video in decoded:  # padding repeats the edge pixels
            assert np.abs(video[-1].astype(int) - video[-2].astype(int)).mean() < 4
    rows = _read_index(out / "frames.csv")
    assert [int(r["index"]) for r in rows] == [f.index for f in frames]
    assert [float(r["time_s"]) for r in rows] == [f.time_s for f in frames]
    assert {r["file"] for r in rows} == {"frames.mp4"}


def test_exr_sink_writes_one_linear_file_per_frame_and_an_index(tmp_path: Path) -> None:
    frames = _frames(4, (9, 11))
    frames[2].image[0, 0] = np.nan
    with make_sink("exr", tmp_path, exr_dtype="float", capture_rate_hz=RATE_HZ,
                   frame_rate_hz=RATE_HZ / 10) as sink:
        for frame in frames:
            sink.write(frame)
    assert sink.frames_written == 4 and sink.nonfinite_pixels == 1
    rows = _read_index(tmp_path / "frames.csv")
    assert [r["file"] for r in rows] == [f"frame_{k:06d}.exr" for k in range(4)]
    for frame, row in zip(frames, rows):
        image, header = read_exr(tmp_path / row["file"])
        expected = np.nan_to_num(frame.image, nan=0.0)
        np.testing.assert_array_equal(image, expected)
        assert header["time_s"] == frame.time_s == float(row["time_s"])
        assert header["rmbvideo:frame_index"] == frame.index
        assert header["rmbvideo:capture_rate_hz"] == RATE_HZ
    assert _leftovers(tmp_path) == []


def test_png_sink_writes_the_tone_mapped_frames(tmp_path: Path) -> None:
    frames = _frames(3, (10, 15))
    config = ToneMapConfig(percentile=99.0)
    with make_sink("png", tmp_path, tonemap=config, stem="run1") as sink:
        for frame in frames:
            sink.write(frame)
    mapper = ToneMapper(config)
    rows = _read_index(tmp_path / "run1.csv")
    assert [r["file"] for r in rows] == [f"frame_{k:06d}.png" for k in range(3)]
    for frame, row in zip(frames, rows):
        png = cv2.imread(str(tmp_path / row["file"]), cv2.IMREAD_UNCHANGED)
        assert png.dtype == np.uint8 and png.shape == (10, 15)
        np.testing.assert_array_equal(png, mapper(frame.image))


def test_null_sink_counts_and_writes_nothing(tmp_path: Path) -> None:
    target = tmp_path / "never"
    with make_sink("null", target) as sink:
        for frame in _frames(5, (4, 4)):
            sink.write(frame)
    assert sink.frames_written == 5
    assert not target.exists()


@pytest.mark.parametrize("fmt", ["mp4", "exr", "png"])
def test_abort_removes_this_runs_partial_files_only(tmp_path: Path, fmt: str) -> None:
    (tmp_path / "keep.txt").write_text("mine")
    (tmp_path / "frame_000099.exr").write_bytes(b"earlier run")
    with pytest.raises(RuntimeError, match="pipeline failed"):
        with make_sink(fmt, tmp_path) as sink:
            for frame in _frames(3, (8, 10)):
                sink.write(frame)
            assert len(list(tmp_path.iterdir())) > 2  # something was being written
            raise RuntimeError("pipeline failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame_000099.exr", "keep.txt"]
    assert (tmp_path / "frame_000099.exr").read_bytes() == b"earlier run"


def test_ffmpegs_failure_is_its_reason_in_one_error_and_nothing_on_the_terminal(tmp_path: Path, capfd) -> None:
    """ffmpeg's own lines (it cannot open the file here) are kept out of stderr and its first, the cause, ends the
    error naming the file; a later stream is read to the end of what ffmpeg said."""
    target = tmp_path / "missing" / "v.mp4"
    encoder = FfmpegEncoder(target, (16, 16), pix_fmt_in="gray", pix_fmt_out="yuv420p", fps=30.0, codec="libx264",
                            output_params=["-f", "mp4"], display_path=tmp_path / "frames.mp4")
    with pytest.raises(OutputError) as failure:
        for _ in range(2000):  # ffmpeg exits at once; the pipe refuses frames then, or close reads its status
            encoder.send(bytes(256))
        encoder.close()
    message = str(failure.value)
    assert message.startswith(f"{tmp_path / 'frames.mp4'}: ffmpeg ") and message.endswith("No such file or directory")
    assert "Error opening output" in message and "\n" not in message
    assert capfd.readouterr().err == ""
    assert not target.parent.exists()


def test_sink_rejects_frames_of_changing_shape(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="differs"):
        with make_sink("exr", tmp_path) as sink:
            sink.write(Frame(0, 0.0, np.zeros((4, 5), np.float32)))
            sink.write(Frame(1, 0.1, np.zeros((5, 4), np.float32)))
    assert list(tmp_path.iterdir()) == []


def test_unwritable_output_folder_is_an_output_error(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OutputError, match="file"):
        make_sink("png", blocker / "out")


def test_sdr_outputs_carry_bt709_tags(tmp_path):
    """The MP4 stream says BT.709 (primaries, transfer, matrix) and limited range; PNGs carry cICP."""
    import subprocess

    import imageio_ffmpeg

    from rmbvideo.chunks import Frame
    from rmbvideo.io.sinks import write_frames

    frames = [Frame(i, i / 1000, np.full((16, 24), 0.1 * (i + 1), np.float32)) for i in range(4)]
    write_frames(frames, tmp_path / "mp4", fmt="mp4")
    probe = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(tmp_path / "mp4" / "frames.mp4")],
                           capture_output=True, text=True).stderr
    assert "yuv420p(tv, bt709, progressive)" in probe, probe
    write_frames(frames, tmp_path / "png", fmt="png")
    data = (tmp_path / "png" / "frame_000000.png").read_bytes()
    assert data[37:45] == b"cICP" + bytes([1, 1, 0, 1])


def test_an_output_folder_made_for_a_run_that_fails_is_removed_again(tmp_path: Path) -> None:
    """evaluate, bench and dynamic-range --plots make their folder for the reports: a run that fails or is stopped
    removes the folders it made while they are empty (an empty folder was left behind), never one that was there
    or holds a file; a folder that cannot be made is refused before the run."""
    with pytest.raises(KeyboardInterrupt), output_folder(tmp_path / "a" / "b" / "c"):
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError), output_folder(tmp_path / "kept" / "new") as folder:
        (tmp_path / "kept" / "mine.txt").write_text("mine")
        assert folder.is_dir()
        raise ValueError
    assert sorted(p.name for p in (tmp_path / "kept").iterdir()) == ["mine.txt"]
    with output_folder(tmp_path / "done"):
        pass
    assert (tmp_path / "done").is_dir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="is not a folder"):
        check_folder_creatable(tmp_path / "file" / "out")
    check_folder_creatable(tmp_path / "x" / "y")
    assert not (tmp_path / "x").exists()
    (tmp_path / "bad.safetensors").write_text("junk")  # a training run that fails before its first checkpoint
    result = CliRunner().invoke(main, ["train-detail", "-o", str(tmp_path / "new"), "--init",
                                       str(tmp_path / "bad.safetensors"), "--minutes", "0.01", "-q"])
    assert result.exit_code == 2 and "bad.json" in result.output and not (tmp_path / "new").exists()


def test_write_frames_replaces_a_folder_whole_and_only_when_told(tmp_path: Path) -> None:
    """``rmbvideo.write_frames`` wrote frame files one by one into the folder: a second, shorter run left the first
    run's extra frames beside its own. It now makes the folder whole, as ``reconstruct`` does: an earlier run's
    outputs are replaced only with ``overwrite``, and then as a whole."""
    from rmbvideo.io.sinks import write_frames

    def frames(count: int) -> list[Frame]:
        return [Frame(i, i / 1000, np.full((8, 8), 0.1 * (i + 1), np.float32)) for i in range(count)]

    out = tmp_path / "out"
    assert write_frames(frames(5), out, fmt="exr") == 5
    with pytest.raises(OutputError, match="holds earlier outputs; use --overwrite"):
        write_frames(frames(2), out, fmt="exr")
    assert len(list(out.glob("*.exr"))) == 5
    assert write_frames(frames(2), out, fmt="exr", overwrite=True) == 2
    assert sorted(p.name for p in out.iterdir()) == ["frame_000000.exr", "frame_000001.exr", "frames.csv"]

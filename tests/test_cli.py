"""End-to-end tests of the ``rmbvideo`` command on real files: reconstruct, info, preview, bad input."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import imageio_ffmpeg
import numpy as np
import pytest
from click.testing import CliRunner

from rmbvideo.cli import main
from rmbvideo.io.dat import DatGeometry, write_dat
from rmbvideo.io.exr import read_exr
from rmbvideo.io.tonemap import ToneMapConfig, ToneMapper


def small_capture(path: Path, planes: int = 80, width: int = 64, height: int = 48,
                  seed: int = 0) -> Path:
    """A random 1-bit capture with a horizontal brightness ramp, so frames have content."""
    rng = np.random.default_rng(seed)
    rate = np.linspace(0.02, 0.9, width)[None, None, :]
    spikes = (rng.random((planes, height, width)) < rate).astype(np.uint8)
    write_dat(path, spikes, DatGeometry(width=width, height=height))
    return path


def run(*args: str) -> "CliRunner.Result":
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


GEOM = ("--width", "64", "--height", "48")


def read_index(outdir: Path) -> list[dict[str, str]]:
    with open(outdir / "frames.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_reconstruct_mp4_decodes_back_with_exact_size_and_count(tmp_path: Path) -> None:
    """The default job: shipped RMB-Net on the binned stream with the raw stream's detail (the camera's
    size), H.264 decoded back; --resolution binned gives half the size."""
    dat = small_capture(tmp_path / "cap.dat")
    result = run("reconstruct", dat, "-o", tmp_path / "out", *GEOM, "--quiet")
    assert result.exit_code == 0, result.output
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "out" / "frames.mp4"))
    meta = next(reader)
    count = sum(1 for _ in reader)
    assert tuple(meta["size"]) == (64, 48)
    assert count == 80 // 20
    rows = read_index(tmp_path / "out")
    assert [r["index"] for r in rows] == ["0", "1", "2", "3"]
    assert {r["file"] for r in rows} == {"frames.mp4"}
    assert float(rows[1]["time_s"]) == pytest.approx(30 / 20000)
    result = run("reconstruct", dat, "-o", tmp_path / "binned", *GEOM, "--resolution", "binned", "--quiet")
    assert result.exit_code == 0, result.output
    assert tuple(next(imageio_ffmpeg.read_frames(str(tmp_path / "binned" / "frames.mp4")))["size"]) == (32, 24)


@pytest.mark.parametrize("method", ["tfp", "tfi", "tfw"])
def test_reconstruct_exr_linear_values_and_times(tmp_path: Path, method: str) -> None:
    dat = small_capture(tmp_path / "cap.dat")
    result = run("reconstruct", dat, "-o", tmp_path / "out", *GEOM, "--method", method,
                 "--format", "exr", "--exr-dtype", "float", "--quiet")
    assert result.exit_code == 0, result.output
    rows = read_index(tmp_path / "out")
    assert len(rows) == 4
    image, header = read_exr(tmp_path / "out" / rows[2]["file"])
    assert header["time_s"] == pytest.approx(float(rows[2]["time_s"]))
    assert image.shape[1] == 64  # tfw runs on the binned stream: full resolution by default, like the rest
    assert np.isfinite(image).all()
    # The ramp's firing rate rises left to right; the linear estimate must follow it.
    profile = image.mean(axis=0)
    assert profile[-4:].mean() > 5 * profile[:4].mean()
    if method == "tfp":
        assert profile[-4:].mean() == pytest.approx(0.88, abs=0.06)


def test_output_does_not_depend_on_chunk_size(tmp_path: Path) -> None:
    dat = small_capture(tmp_path / "cap.dat", planes=120)
    images = []
    for chunk in ("1", "7", "4096"):
        out = tmp_path / f"out{chunk}"
        assert run("reconstruct", dat, "-o", out, *GEOM, "--method", "tfw", "--format", "exr",
                   "--exr-dtype", "float", "--chunk-planes", chunk, "-q").exit_code == 0
        images.append(np.stack([read_exr(p)[0] for p in sorted(out.glob("*.exr"))]))
    np.testing.assert_array_equal(images[0], images[1])
    np.testing.assert_array_equal(images[0], images[2])


def test_a_huge_chunk_is_cut_to_the_memory_bound_of_the_plane_size(tmp_path: Path) -> None:
    """--chunk-planes 1000000 on a 1000x1000 camera would decode a terabyte at once: the chunk is cut to
    CHUNK_BYTES of planes, so memory stays bounded whatever the option, and a small plane keeps its chunk."""
    from rmbvideo.io.dat import DatReader
    from rmbvideo.recon.run import CHUNK_BYTES, bounded_chunk_planes
    big = tmp_path / "big.dat"
    big.write_bytes(bytes(3 * 1000 * 1000 // 8))
    reader = DatReader(big, DatGeometry(width=1000, height=1000))
    assert bounded_chunk_planes(10**6, reader) == CHUNK_BYTES // 10**6 < 1024
    small = DatReader(small_capture(tmp_path / "cap.dat"), DatGeometry(width=64, height=48))
    assert bounded_chunk_planes(1024, small) == 1024


def test_info_json_and_preview(tmp_path: Path) -> None:
    dat = small_capture(tmp_path / "cap.dat", planes=50)
    with open(dat, "ab") as f:
        f.write(b"\x01\x02\x03")
    result = run("info", dat, *GEOM, "--json")
    assert result.exit_code == 0
    record = json.loads(result.stdout)
    assert record["planes"] == 50 and record["trailing_bytes"] == 3
    assert record["pixel"] is None  # one 40-plane window of a sparse random capture: too little to tell
    png = tmp_path / "sheet.png"
    assert run("preview", dat, "-o", png, *GEOM).exit_code == 0
    sheet = iio.imread(png)
    assert sheet.shape == (2 * 48, 3 * 64)


def test_preview_reads_a_wide_window_in_blocks_and_lays_many_points_out_square(tmp_path: Path) -> None:
    """--window 10000 on a 1000x1000 camera decoded 10 GB of planes at once: a tile's mean is now summed
    ``MEAN_BLOCK`` planes at a time (the same mean); 64 points came as a sheet 3 tiles wide and 22 high."""
    from rmbvideo.cli.preview import MEAN_BLOCK, contact_sheet
    from rmbvideo.io.dat import DatReader

    class Reads(DatReader):
        """A real reader that remembers the most planes one read decoded."""
        most = 0

        def read(self, start: int, stop: int) -> np.ndarray:
            Reads.most = max(Reads.most, stop - start)
            return super().read(start, stop)

    dat = small_capture(tmp_path / "cap.dat", planes=3 * MEAN_BLOCK)
    reader = Reads(dat, DatGeometry(width=64, height=48))
    whole = ToneMapper(ToneMapConfig())(reader.read(0, 3 * MEAN_BLOCK).mean(axis=0, dtype=np.float32))
    Reads.most = 0
    sheet = contact_sheet(reader, count=1, window=3 * MEAN_BLOCK)
    assert Reads.most == MEAN_BLOCK
    np.testing.assert_array_equal(sheet[20:], whole[20:])  # below the label: the same tile
    assert contact_sheet(reader, count=64, window=2).shape == (8 * 48, 8 * 64)
    assert contact_sheet(reader, count=6, window=2).shape == (2 * 48, 3 * 64)


def test_preview_never_writes_over_a_capture_or_an_earlier_file_unasked(tmp_path: Path) -> None:
    """``-o`` must name a .png: naming the capture itself (or any other file) is refused before anything is read,
    the file kept byte for byte; an existing preview is replaced only with --overwrite."""
    dat = small_capture(tmp_path / "cap.dat", planes=50)
    before = dat.read_bytes()
    result = run("preview", dat, "-o", dat, *GEOM)
    assert result.exit_code == 2 and "writes .png" in result.output and dat.read_bytes() == before
    result = run("preview", dat, "-o", tmp_path / "sheet.jpg", *GEOM)
    assert result.exit_code == 2 and not (tmp_path / "sheet.jpg").exists()
    png = tmp_path / "Sheet.PNG"
    png.write_bytes(b"mine")
    result = run("preview", dat, "-o", png, *GEOM)
    assert result.exit_code == 2 and "exists; use --overwrite" in result.output and png.read_bytes() == b"mine"
    assert run("preview", dat, "-o", png, *GEOM, "--overwrite").exit_code == 0
    assert iio.imread(png).shape == (2 * 48, 3 * 64)
    result = run("preview", dat, "-o", tmp_path / "missing" / "sheet.png", *GEOM)
    assert result.exit_code == 2 and "folder" in result.output and "does not exist" in result.output


def test_info_counts_the_pixels_that_fire_every_plane(tmp_path: Path) -> None:
    """A lamp that fires every plane (an eighth of the frame) is reported as saturated; pixels bright enough to fire
    in 90 % of the planes are not; a capture too short to tell says so."""
    rng = np.random.default_rng(4)
    rates = np.full((48, 64), 0.9)
    rates[:, :8] = 1.0
    planes = (rng.random((200, 48, 64)) < rates).astype(np.uint8)
    write_dat(tmp_path / "lamp.dat", planes, DatGeometry(width=64, height=48))
    record = json.loads(run("info", tmp_path / "lamp.dat", *GEOM, "--json").stdout)
    assert record["saturated_fraction"] == pytest.approx(1 / 8, abs=0.01)
    write_dat(tmp_path / "short.dat", planes[:20], DatGeometry(width=64, height=48))
    result = run("info", tmp_path / "short.dat", *GEOM)
    assert result.exit_code == 0 and "too few planes" in result.stdout


def test_preview_is_exposed_as_the_video_is(tmp_path: Path) -> None:
    """A uniform scene at a middle level previews as a middle grey (reconstruct's exposure), not as white, and a
    scene that brightens tenfold shows it: the tiles share one exposure."""
    rng = np.random.default_rng(1)
    for name, rate in (("uniform", np.full((400, 1, 1), 0.18)),
                       ("steps", np.where(np.arange(400)[:, None, None] < 200, 0.02, 0.2))):
        dat = tmp_path / f"{name}.dat"
        write_dat(dat, (rng.random((400, 48, 64)) < rate).astype(np.uint8), DatGeometry(width=64, height=48))
        png = tmp_path / f"{name}.png"
        assert run("preview", dat, "-o", png, *GEOM, "--count", "2", "--window", "100").exit_code == 0
        sheet = iio.imread(png)[20:]  # below the labels
        first, second = np.median(sheet[:, :64]), np.median(sheet[:, 64:])
        if name == "uniform":
            assert 60 < first < 160 and 60 < second < 160  # the exposure's middle grey is about 100 of 255
        else:
            assert first < 0.6 * second


def test_sidecar_sets_geometry_and_options_override(tmp_path: Path) -> None:
    dat = small_capture(tmp_path / "cap.dat", planes=30)
    (tmp_path / "cap.capture.json").write_text(json.dumps({"width": 64, "height": 48, "rate_hz": 1000}))
    record = json.loads(run("info", dat, "--json").stdout)
    assert (record["width"], record["height"], record["rate_hz"]) == (64, 48, 1000)
    record = json.loads(run("info", dat, "--json", "--rate", "2000").stdout)
    assert record["rate_hz"] == 2000


BAD_INPUTS = {
    "missing": lambda p: p / "nope.dat",
    "directory": lambda p: (p / "adir.dat").mkdir() or p / "adir.dat",
    "empty": lambda p: (p / "empty.dat").write_bytes(b"") or p / "empty.dat",
    "short": lambda p: (p / "short.dat").write_bytes(b"\xff" * 100) or p / "short.dat",
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_one_line_error_no_output(tmp_path: Path, case: str) -> None:
    path = BAD_INPUTS[case](tmp_path)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "rmbvideo", "reconstruct", str(path), "-o", str(out)],
                          capture_output=True, text=True)
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert str(path) in lines[0] and "Traceback" not in proc.stderr
    assert not out.exists()


def test_geometry_that_cannot_divide_the_file(tmp_path: Path) -> None:
    dat = small_capture(tmp_path / "cap.dat", planes=10)
    proc = subprocess.run([sys.executable, "-m", "rmbvideo", "info", str(dat), "--width", "4000",
                           "--height", "4000"], capture_output=True, text=True)
    assert proc.returncode != 0 and str(dat) in proc.stderr and "Traceback" not in proc.stderr


def test_options_the_method_does_not_read_are_named(tmp_path: Path) -> None:
    dat = small_capture(tmp_path / "cap.dat", planes=40)
    result = run("reconstruct", dat, "-o", tmp_path / "tfp", *GEOM, "--method", "tfp", "--format", "null",
                 "--prime", "2", "--convention", "spikezoo", "--threads", "1")
    assert result.exit_code == 0 and "--convention, --prime: not read by --method tfp, ignored" in result.output
    result = run("reconstruct", dat, "-o", tmp_path / "mg20", *GEOM, "--method", "gc20", "--format", "null",
                 "--convention", "spikezoo", "--resolution", "binned")
    assert result.exit_code == 0 and "not read by" not in result.output  # GC20 reads the convention


def test_real_capture_end_to_end(tmp_path: Path, shared_data: Path) -> None:
    car = shared_data / "real" / "car.dat"
    out = tmp_path / "car"
    result = run("reconstruct", car, "-o", out, "--method", "tfp", "--format", "png", "-q")
    assert result.exit_code == 0, result.output
    rows = read_index(out)
    assert len(rows) == 10
    frame = iio.imread(out / rows[5]["file"])
    assert frame.shape == (250, 400) and frame.std() > 5


def test_native_rmb_capture_reconstructs_without_binning(tmp_path: Path) -> None:
    """A simulated native RMB sensor (.dat + .mbit) opens by itself and is not binned again."""
    scene = tmp_path / "native.toml"
    scene.write_text(
        'width = 48\nheight = 32\nrate_hz = 20000\nduration_s = 0.004\nexposure = 20.0\nseed = 3\n'
        'effects = []\n[readout]\ntype = "rmb"\n[background]\npanorama = "city"\ncenter = [300, 215]\n'
    )
    dat = tmp_path / "native.dat"
    assert run("simulate", scene, "-o", dat, "-q").exit_code == 0
    assert (tmp_path / "native.mbit").is_file()
    out = tmp_path / "out"
    result = run("reconstruct", dat, "-o", out, "--method", "tfw", "--format", "exr",
                 "--exr-dtype", "float", "-q")
    assert result.exit_code == 0, result.output
    rows = read_index(out)
    assert len(rows) == 80 // 10  # one frame per N = 10 native readouts, full resolution
    image, _ = read_exr(out / rows[3]["file"])
    assert image.shape == (32, 48) and np.isfinite(image).all() and image.max() > 0
    # its companions given for the capture (they were read as spikes: "2000 multi-bit readouts but native.mbit has
    # 96 planes (truncated capture?)") are refused naming the capture to give
    for companion, what in (("native.mbit", "the multi-bit readouts"), ("native.capture.json", "the sidecar")):
        result = run("reconstruct", tmp_path / companion, "-o", tmp_path / "again", "-q")
        assert result.exit_code == 2 and f"is {what} of the capture {dat}; give {dat}" in result.output
    assert not (tmp_path / "again").exists()
    record = json.loads(run("info", dat, "--json").stdout)  # info says what the .mbit holds
    assert record["multi_bit"] == {"file": str(tmp_path / "native.mbit"), "bits": 3, "level": 7, "band_rows": 4,
                                   "band_shift": 2}
    assert json.loads(run("info", small_capture(tmp_path / "plain.dat"), *GEOM, "--json").stdout)["multi_bit"] is None
    proc = subprocess.run([sys.executable, "-m", "rmbvideo", "info", str(dat), "--width", "64", "--height", "32"],
                          capture_output=True, text=True)  # the header fixes the geometry: a given one is not used
    assert proc.returncode == 0 and "--width ignored" in proc.stderr and "48x32" in proc.stdout


def test_rmbnet_window_selects_a_shipped_model_or_refuses(tmp_path: Path) -> None:
    dat = small_capture(tmp_path / "cap.dat")
    w0 = run("reconstruct", dat, "-o", tmp_path / "w0", *GEOM, "--window", "0", "--format", "null", "-q")
    assert w0.exit_code == 0, w0.output
    proc = subprocess.run([sys.executable, "-m", "rmbvideo", "reconstruct", str(dat), "-o", str(tmp_path / "w1"),
                           *GEOM, "--window", "1", "-q"], capture_output=True, text=True)
    assert proc.returncode == 2 and "w = 1" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "w1").exists()


def test_every_command_that_logs_takes_q_and_preview_is_then_silent(tmp_path: Path) -> None:
    """-q/--quiet means the same everywhere (bench, preview and dynamic-range refused -q, or knew only --quiet)."""
    ctx = main.make_context("rmbvideo", ["info", "x"])
    names = [name for name in main.list_commands(ctx) if name != "info"]  # info prints its facts and nothing else
    for name in names:
        assert "-q, --quiet" in run(name, "--help").output, name
    assert "-q, --quiet" in run("bench", "sizes", "--help").output
    dat = small_capture(tmp_path / "cap.dat")
    result = CliRunner().invoke(main, ["preview", str(dat), "-o", str(tmp_path / "p.png"), *GEOM, "-q"])
    assert result.exit_code == 0 and result.output == "" and (tmp_path / "p.png").is_file()


def test_an_output_named_as_a_video_file_is_refused_not_made_a_folder(tmp_path: Path) -> None:
    """`-o video.mp4` made a folder named video.mp4 holding frames.mp4; it is refused with the folder to give."""
    dat = small_capture(tmp_path / "cap.dat")
    result = CliRunner().invoke(main, ["reconstruct", str(dat), "-o", str(tmp_path / "video.mp4"), *GEOM,
                                       "--method", "tfp"])
    assert result.exit_code == 2
    assert "names a .mp4 file, but the output is a folder" in result.output
    assert f"give e.g. -o {tmp_path / 'video'}" in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cap.dat"]
    result = CliRunner().invoke(main, ["batch", str(dat), "-o", str(tmp_path / "b.mp4"), *GEOM, "--method", "tfp",
                                       "--jobs", "1", "-q"])
    assert result.exit_code == 2
    assert "names a .mp4 file, but the output is a folder (one output folder per capture" in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cap.dat"]

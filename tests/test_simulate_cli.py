"""``rmbvideo simulate``: bundled list, 1-bit and RMB outputs readable back, ground truth, errors."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rmbvideo.cli import main
from rmbvideo.io.dat import DatGeometry, DatReader
from rmbvideo.io.exr import read_exr
from rmbvideo.io.rmbfile import RmbFileReader
from rmbvideo.scenes.scene import load_scene
from rmbvideo.simulate.capture import CaptureSimulator

SCENE = """
description = "cli test"
width = 64
height = 48
rate_hz = 20000
duration_s = 0.004
exposure = 25.0
seed = 3
effects = ["shot_noise", "threshold_mismatch", "readout_rounding"]

[readout]
type = "{readout}"
level = 7
band = 4
shift = 2

[background]
panorama = "studio"
velocity = [800, 0]
"""


def write_scene(tmp_path: Path, readout: str) -> Path:
    path = tmp_path / f"{readout}.toml"
    path.write_text(SCENE.format(readout=readout))
    return path


def run(args: list[str]):
    return CliRunner().invoke(main, ["simulate", *args], catch_exceptions=False)


def test_list_prints_bundled_scenes() -> None:
    result = run(["--list"])
    assert result.exit_code == 0
    names = [line.split("\t")[0] for line in result.output.splitlines()]
    assert {"demo", "extreme-contrast", "fast-motion", "static-noise"} <= set(names)
    assert all(len(line.split("\t")) == 2 and line.split("\t")[1] for line in result.output.splitlines())


def test_one_bit_capture_reads_back_with_default_reader_and_sidecar(tmp_path: Path) -> None:
    scene_path = write_scene(tmp_path, "1bit")
    out = tmp_path / "cap.dat"
    result = run([str(scene_path), "-o", str(out), "--quiet", "--chunk", "13"])
    assert result.exit_code == 0, result.output
    sidecar = json.loads((tmp_path / "cap.capture.json").read_text())
    assert sidecar == {"width": 64, "height": 48, "rate_hz": 20000.0, "flip": True, "header_cols": 0,
                       "readout": "1bit", "scene": "1bit",
                       "effects": ["shot_noise", "threshold_mismatch", "readout_rounding"], "reset": "zero"}
    from rmbvideo.io.capture import open_capture

    planes = open_capture(out, None, None, None, None, None).read()  # defaults + sidecar
    expected = np.concatenate([c.planes for c in CaptureSimulator(load_scene(scene_path)).chunks(50)])
    np.testing.assert_array_equal(planes, expected)
    assert planes.shape == (80, 48, 64) and planes.any()
    assert not list(tmp_path.glob(".*"))  # no temporary files left behind


def test_rmb_capture_round_trips(tmp_path: Path) -> None:
    scene_path = write_scene(tmp_path, "rmb")
    out = tmp_path / "rmb.dat"
    assert run([str(scene_path), "-o", str(out), "-q", "--duration", "0.002"]).exit_code == 0
    read = list(RmbFileReader(out).rmb_chunks(17))
    expected = list(CaptureSimulator(load_scene(scene_path), 0.002).chunks(64))
    for name in ("single", "multi", "multi_rows"):
        np.testing.assert_array_equal(np.concatenate([getattr(c, name) for c in read]),
                                      np.concatenate([getattr(c, name) for c in expected]))
    multi = np.concatenate([c.multi for c in read])
    rows = np.concatenate([c.multi_rows for c in read])
    assert rows.sum(axis=1).tolist() == [4] * 40
    assert multi[rows].max() > 1 and multi[~rows].max() == 0
    # the .dat alone is an ordinary 1-bit capture
    single = DatReader(out, DatGeometry(width=64, height=48)).read()
    np.testing.assert_array_equal(single, np.concatenate([c.single for c in read]))


def test_lbit_capture_round_trips(tmp_path: Path) -> None:
    scene_path = write_scene(tmp_path, "Lbit")
    out = tmp_path / "l.dat"
    assert run([str(scene_path), "-o", str(out), "-q"]).exit_code == 0
    read = np.concatenate([c.multi for c in RmbFileReader(out).rmb_chunks(30)])
    expected = np.concatenate([c.multi for c in CaptureSimulator(load_scene(scene_path)).chunks(64)])
    np.testing.assert_array_equal(read, expected)
    assert set(np.unique(read)) > {0, 7}


def test_ground_truth_frames_flow_and_index(tmp_path: Path) -> None:
    scene_path = write_scene(tmp_path, "binned")
    gt = tmp_path / "gt"
    result = run([str(scene_path), "-o", str(tmp_path / "b.dat"), "--gt", str(gt), "-q"])
    assert result.exit_code == 0, result.output
    with open(gt / "index.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["index"]) for r in rows] == [0, 1, 2, 3]  # 80 readouts / 20
    assert np.isclose(float(rows[1]["time_s"]), 30 / 20000)
    image, header = read_exr(gt / rows[1]["file"])
    assert image.shape == (24, 32) and np.isfinite(image).all() and image.max() > 0
    assert np.isclose(header["time_s"], 30 / 20000)
    flow = np.load(gt / "flow_000001.npy")
    # studio pan of 800 px/s over 1 ms: -0.8 raw px = -0.4 binned px
    assert flow.shape == (24, 32, 2) and np.allclose(flow[..., 0], -0.4, atol=1e-4)


def test_bad_scene_is_a_one_line_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("width = -3\n")
    result = CliRunner().invoke(main, ["simulate", str(bad), "-o", str(tmp_path / "x.dat")])
    assert result.exit_code == 2
    assert "bad.toml" in result.output and "'width'" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "x.dat").exists()


def test_a_scene_shorter_than_one_readout_names_the_scene_not_an_option(tmp_path: Path) -> None:
    """A scene whose duration_s holds no readout at its rate_hz was reported as "--duration None s", an option the
    user never gave; it names the scene file and both fields, and --duration names itself."""
    scene = write_scene(tmp_path, "binned")
    scene.write_text(scene.read_text().replace("duration_s = 0.004", "duration_s = 1e-9"))
    result = CliRunner().invoke(main, ["simulate", str(scene), "-o", str(tmp_path / "x.dat")])
    assert result.exit_code == 2 and "None" not in result.output, result.output
    for needle in ("binned.toml", "duration_s = 1e-09", "rate_hz = 20000"):
        assert needle in result.output, result.output
    result = CliRunner().invoke(main, ["simulate", str(write_scene(tmp_path, "binned")), "-o", str(tmp_path / "x.dat"),
                                       "--duration", "1e-6"])
    assert result.exit_code == 2 and "--duration 1e-06 s" in result.output
    assert not (tmp_path / "x.dat").exists()


def test_a_simulated_capture_is_read_by_its_cameras_response_and_a_real_one_by_the_closed_form(tmp_path: Path) -> None:
    """``reconstruct --response auto`` (the default): the sidecar ``rmbvideo simulate`` writes names the effects that
    shape the emission model's response, so RMB-Net's box candidates read that capture by its table; a capture
    without them (a real camera's, or a scene without noise) by the closed form; an explicit choice wins."""
    from rmbvideo.io.sidecar import SimulatedCamera, simulated_camera
    from rmbvideo.recon.run import prepare_run

    scene_path = write_scene(tmp_path, "1bit")
    out = tmp_path / "cap.dat"
    assert run([str(scene_path), "-o", str(out), "-q"]).exit_code == 0
    assert simulated_camera(out) == SimulatedCamera(("shot_noise", "threshold_mismatch", "readout_rounding"), "zero")

    def tabulated(path: Path, **options) -> bool:
        recon = prepare_run(path, resolution="binned", raw_gate="off", extra_options={"threads": 1, **options}).method
        return recon.network is not None and recon._net.tabulated_response

    assert tabulated(out) and tabulated(out, response="auto") and not tabulated(out, response="closed-form")
    sidecar = tmp_path / "cap.capture.json"
    data = json.loads(sidecar.read_text())
    sidecar.write_text(json.dumps({**data, "effects": []}))  # a deterministic scene: the bare staircase
    assert not tabulated(out) and tabulated(out, response="emission-model")
    sidecar.write_text(json.dumps({k: v for k, v in data.items() if k != "effects"}))  # a camera's sidecar
    assert simulated_camera(out) is None and not tabulated(out)


def test_a_view_past_the_panoramas_top_or_bottom_is_warned_of_with_how_far(tmp_path: Path, caplog) -> None:
    """The panorama is mirrored beyond its top and bottom: a scene whose view reaches there is simulated, with a
    warning that says how far, which a view inside the panorama does not get."""
    scene = write_scene(tmp_path, "binned")
    result = CliRunner().invoke(main, ["simulate", str(scene), "-o", str(tmp_path / "in.dat")])
    assert result.exit_code == 0 and "mirrored" not in result.output, result.output
    scene.write_text(scene.read_text().replace("velocity = [800, 0]", "center = [512, 10]\nvelocity = [800, -1000]"))
    result = CliRunner().invoke(main, ["simulate", str(scene), "-o", str(tmp_path / "out.dat")])
    # rows 10 - 24 at t = 0 and 10 - 4 - 24 at the end (4 ms at -1000 px/s): 18 rows above, none below
    assert result.exit_code == 0 and "binned.toml: the view reaches 18 panorama rows above the top and 0 below the " \
                                     "bottom of studio" in result.output, result.output


def test_rows_past_the_panorama_are_the_extremes_over_the_whole_scene(tmp_path: Path) -> None:
    """A zooming, tilting camera: the reach found from the ends equals the densely sampled one."""
    from rmbvideo.scenes.render import SceneRenderer

    path = tmp_path / "tilt.toml"
    path.write_text(SCENE.format(readout="binned").replace(
        "velocity = [800, 0]", "center = [512, 30]\nvelocity = [0, 120000]\nzoom = 0.5\nzoom_rate = 300"))
    scene = load_scene(path)
    renderer = SceneRenderer(scene)
    t = np.linspace(0, 0.004, 4001)
    _, cy, zoom = renderer.camera(t)
    half = scene.height / 2 / zoom
    above, below = renderer.rows_past_panorama(0.004)
    assert above == pytest.approx(max(0.0, (half - cy).max()))
    assert below == pytest.approx(max(0.0, (cy + half - renderer.pano.shape[0]).max()))
    assert above > 0 and below > 0


def test_ground_truth_replaces_an_earlier_ground_truth_but_not_a_folder_of_other_files(tmp_path: Path) -> None:
    scene = str(write_scene(tmp_path, "binned"))
    gt = tmp_path / "gt"
    assert run([scene, "-o", str(tmp_path / "c.dat"), "--gt", str(gt), "--duration", "0.003"]).exit_code == 0
    again = CliRunner().invoke(main, ["simulate", scene, "-o", str(tmp_path / "e.dat"), "--gt", str(gt)])
    assert again.exit_code == 2 and "holds earlier outputs; use --overwrite" in again.output
    assert run([scene, "-o", str(tmp_path / "c.dat"), "--gt", str(gt), "--duration", "0.002", "--overwrite"]).exit_code == 0
    assert sorted(p.name for p in gt.iterdir()) == ["flow_000000.npy", "flow_000001.npy", "gt_000000.exr",
                                                    "gt_000001.exr", "index.csv"]
    (gt / "notes.txt").write_text("mine")
    result = CliRunner().invoke(main, ["simulate", scene, "-o", str(tmp_path / "d.dat"), "--gt", str(gt)])
    assert result.exit_code == 2 and "holds files this command does not write (notes.txt)" in result.output
    assert len(list(gt.iterdir())) == 6 and not (tmp_path / "d.dat").exists()


def test_an_existing_capture_is_replaced_only_with_overwrite(tmp_path: Path) -> None:
    """A real capture at -o is never replaced by a simulated one unasked (the .dat, or an RMB capture's .mbit);
    a missing folder is named."""
    capture = tmp_path / "real.dat"
    capture.write_bytes(b"\x01" * 4000)
    scene = str(write_scene(tmp_path, "binned"))
    refused = CliRunner().invoke(main, ["simulate", scene, "-o", str(capture), "-q"])
    assert refused.exit_code == 2 and f"{capture}: exists; use --overwrite to replace it" in refused.output
    assert capture.read_bytes() == b"\x01" * 4000 and not capture.with_suffix(".capture.json").exists()
    assert run([scene, "-o", str(capture), "-q", "--overwrite"]).exit_code == 0
    assert capture.stat().st_size != 4000 and capture.with_suffix(".capture.json").exists()

    rmb = str(write_scene(tmp_path, "rmb"))
    (tmp_path / "cam.mbit").write_bytes(b"mine")
    refused = CliRunner().invoke(main, ["simulate", rmb, "-o", str(tmp_path / "cam.dat"), "-q"])
    assert refused.exit_code == 2 and "cam.mbit: exists; use --overwrite" in refused.output
    assert (tmp_path / "cam.mbit").read_bytes() == b"mine" and not (tmp_path / "cam.dat").exists()

    missing = CliRunner().invoke(main, ["simulate", scene, "-o", str(tmp_path / "no" / "x.dat"), "-q"])
    assert missing.exit_code == 2 and f"folder {tmp_path / 'no'} does not exist" in missing.output
    from rmbvideo.errors import OutputError
    from rmbvideo.simulate.capture import simulate_capture

    with pytest.raises(OutputError, match=r"is a folder; name the file to write \(e.g. .*capture\.dat\)"):  # the library's callers: no click check
        simulate_capture(load_scene(Path(scene)), tmp_path, duration_s=0.001)


def test_a_capture_named_as_a_video_or_picture_is_refused(tmp_path: Path) -> None:
    """`simulate demo -o demo.mp4` wrote spikes into a file named as a video; it is refused up front, with the name to
    use and the command that makes the video."""
    scene = str(write_scene(tmp_path, "binned"))
    for name in ("demo.mp4", "demo.PNG", "demo.exr"):
        refused = CliRunner().invoke(main, ["simulate", scene, "-o", str(tmp_path / name), "-q"])
        dat = tmp_path / "demo.dat"
        assert refused.exit_code == 2, refused.output
        assert f"{tmp_path / name}: simulate writes a spike capture" in refused.output
        assert f"name it e.g. {dat}, then `rmbvideo reconstruct {dat}`" in refused.output
    assert not list(tmp_path.glob("demo*"))

"""Scenes: TOML parsing and validation, exact rendering at any time, exact flow, chunk invariance."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from rmbvideo.errors import InputError
from rmbvideo.scenes.render import SceneRenderer, ground_truth, ground_truth_flow
from rmbvideo.scenes.scene import bundled_scenes, load_scene, resolve_scene
from rmbvideo.simulate.capture import CaptureSimulator

TINY = """
description = "tiny test scene"
width = 64
height = 48
rate_hz = 20000
duration_s = 0.005
exposure = 20.0
seed = 7
effects = {effects}
subsamples = {subsamples}

[readout]
type = "{readout}"

[background]
panorama = "city"
center = [300, 230]
velocity = [{pan}, 0]

[[objects]]
shape = "rect"
size = [16, 12]
position = [20, 24]
velocity = [1500, 0]
texture = "checker"
radiance = 3.0
"""


def tiny(tmp_path: Path, effects=("shot_noise",), readout="1bit", pan=400.0, subsamples=1) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(TINY.format(effects=list(effects).__repr__().replace("'", '"'), readout=readout,
                                pan=pan, subsamples=subsamples))
    return path


def test_bundled_scenes_parse_and_cover_the_required_set() -> None:
    scenes = bundled_scenes()
    assert {"demo", "extreme-contrast", "fast-motion", "static-noise"} <= set(scenes)
    assert all(description for description in scenes.values())
    assert resolve_scene("extreme-contrast").readout.kind == "rmb"


@pytest.mark.parametrize("text, key", [
    ("width = 'big'", "'width'"),
    ("effects = ['shot_noise', 'gremlins']", "'effects'"),
    ("[readout]\ntype = 'holographic'", "'readout.type'"),
    ("[readout]\ntype = 'Lbit'\nlevel = 6", "'readout.level'"),
    ("colour = 3", "'colour'"),
    ("[[objects]]\nshape = 'star'", "'objects[0].shape'"),
    ("[[dark_regions]]\nattenuation = 0.1", "'dark_regions[0].rect'"),
    ("width = [", "not valid TOML"),
])
def test_invalid_scene_names_file_and_key(tmp_path: Path, text: str, key: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text + "\n")
    with pytest.raises(InputError) as info:
        load_scene(path)
    assert str(path) in str(info.value) and key in str(info.value)


def test_unknown_scene_name_lists_bundled() -> None:
    with pytest.raises(InputError, match="demo"):
        resolve_scene("no-such-scene")


def test_render_is_exact_at_any_time_and_rows_can_have_their_own_times(tmp_path: Path) -> None:
    renderer = SceneRenderer(load_scene(tiny(tmp_path)))
    a = renderer.render(0.0012345)
    np.testing.assert_array_equal(a, renderer.render(0.0012345))
    assert a.dtype == np.float32 and a.shape == (48, 64) and np.isfinite(a).all() and a.min() >= 0
    assert not np.array_equal(a, renderer.render(0.0013))
    rows = renderer.render(np.full((48, 1), 0.0012345))
    np.testing.assert_allclose(rows, a, rtol=1e-6, atol=1e-6)
    times = np.where(np.arange(48)[:, None] < 24, 0.001, 0.002)
    mixed = renderer.render(times)
    np.testing.assert_allclose(mixed[:24], renderer.render(0.001)[:24], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(mixed[24:], renderer.render(0.002)[24:], rtol=1e-6, atol=1e-6)


def test_flow_maps_content_to_where_it_is_later(tmp_path: Path) -> None:
    renderer = SceneRenderer(load_scene(tiny(tmp_path, pan=3000.0)))
    t0, t1 = 0.001, 0.002
    flow = renderer.flow(t0, t1)
    # background pans +3000 panorama px/s at zoom 1: content moves -3 px in x
    assert np.allclose(flow[0, 50], [-3.0, 0.0], atol=1e-4)
    # the object (centre x = 20 + 1500*t) moves +1.5 px
    obj_x = int(20 + 1500 * t0)
    assert np.allclose(flow[24, obj_x], [1.5, 0.0], atol=1e-4)
    # warping the later frame back along the flow reproduces the earlier frame (away from edges)
    grid_y, grid_x = np.mgrid[0:48, 0:64].astype(np.float32)
    later = renderer.render(t1)
    warped = cv2.remap(later, grid_x + flow[..., 0], grid_y + flow[..., 1], cv2.INTER_LINEAR)
    earlier = renderer.render(t0)
    inner = (slice(4, 44), slice(6, 58))
    mask = np.ones((48, 64), bool)
    mask[10:38, 8:42] = False  # object edges: occlusions are not masked in the flow
    err = np.abs(warped - earlier)[inner][mask[inner]]
    assert np.median(err) < 0.02 * np.median(earlier)


def test_zoom_flow_is_radial(tmp_path: Path) -> None:
    path = tiny(tmp_path)
    path.write_text(path.read_text().replace("velocity = [400.0, 0]", "velocity = [0, 0]\nzoom_rate = 10.0"))
    flow = SceneRenderer(load_scene(path)).flow(0.0, 0.01)
    growth = np.exp(0.1) - 1
    assert np.allclose(flow[0, 63], [(63.5 - 32) * growth, (0.5 - 24) * growth], atol=1e-3)


def test_ground_truth_units_and_binned_size(tmp_path: Path) -> None:
    scene = load_scene(tiny(tmp_path))
    renderer = SceneRenderer(scene)
    gt = ground_truth(renderer, 0.002)
    np.testing.assert_allclose(gt, renderer.render(0.002) * scene.exposure / scene.sensor.q_r, rtol=1e-6)
    binned = SceneRenderer(load_scene(tiny(tmp_path, readout="binned")))
    assert ground_truth(binned, 0.002).shape == (24, 32)
    assert ground_truth_flow(binned, 0.0, 0.001).shape == (24, 32, 2)


def test_capture_does_not_depend_on_chunk_size(tmp_path: Path) -> None:
    effects = ["shot_noise", "dark_current", "threshold_mismatch", "reset_noise", "thermal_noise",
               "readout_rounding", "rolling_readout"]
    sim = CaptureSimulator(load_scene(tiny(tmp_path, effects=effects, subsamples=2)))
    whole = np.concatenate([c.planes for c in sim.chunks(1000)])
    pieces = np.concatenate([c.planes for c in sim.chunks(7)])
    np.testing.assert_array_equal(whole, pieces)
    assert whole.shape == (100, 48, 64) and 0.01 < whole.mean() < 0.9


def test_rolling_readout_integrates_each_row_over_its_own_interval(tmp_path: Path) -> None:
    scene = load_scene(tiny(tmp_path, effects=["rolling_readout"], pan=3000.0))
    sim = CaptureSimulator(scene)
    k = 5
    expected = sim.expected_photo(k)
    r = 40
    delay = r / scene.height
    row = 0.5 * (sim.renderer.render((k + delay) / scene.rate_hz)[r]
                 + sim.renderer.render((k + 1 + delay) / scene.rate_hz)[r]) * scene.exposure
    np.testing.assert_allclose(expected[r], row, rtol=1e-5)
    global_shutter = CaptureSimulator(load_scene(tiny(tmp_path, effects=[], pan=3000.0)))
    assert not np.allclose(global_shutter.expected_photo(k)[r], row, rtol=1e-3)
    np.testing.assert_allclose(global_shutter.expected_photo(k)[0], expected[0], rtol=1e-5)


def test_a_scene_files_panorama_path_is_read_from_its_own_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``panorama = "mine.exr"`` (and ``panorama:mine.exr`` textures) name a file beside the scene file, whatever the
    folder the command runs in (it was looked for there); a name that is neither bundled nor a file is an error naming
    the scene file and the key when the scene is read, not later in the renderer without either."""
    from rmbvideo.scenes.scene import HDRI_DIR

    folder = tmp_path / "scenes"
    folder.mkdir()
    (folder / "mine.exr").write_bytes((HDRI_DIR / "city.exr").read_bytes())
    body = 'width = 48\nheight = 32\nduration_s = 0.002\n[background]\npanorama = "{}"\n'
    (folder / "s.toml").write_text(body.format("mine.exr") + '[[objects]]\ntexture = "panorama:mine.exr"\n')
    monkeypatch.chdir(tmp_path)
    scene = load_scene(Path("scenes/s.toml"))
    mine = (folder / "mine.exr").resolve()
    assert Path(scene.background.panorama) == mine and scene.objects[0].texture == f"panorama:{mine}"
    assert SceneRenderer(scene).render(0.0).shape == (32, 48)
    assert load_scene(folder / "s.toml").background.panorama == scene.background.panorama
    (folder / "bad.toml").write_text(body.format("nowhere"))
    with pytest.raises(InputError, match=r"bad.toml: 'background.panorama' names no bundled panorama \(city, "):
        load_scene(folder / "bad.toml")

"""Property-based fuzzing of the parsers a user's files reach: capture sidecars (JSON), scene files
(TOML) and .mbit headers. Whatever the bytes, the result is a value or an ``InputError`` (one line
naming the file), never another exception."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rmbvideo.errors import InputError
from rmbvideo.io.dat import DatGeometry, write_dat
from rmbvideo.io.rmbfile import RmbFileReader
from rmbvideo.io.sidecar import read_sidecar, simulated_camera
from rmbvideo.scenes.scene import load_scene

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**12, 10**12) | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=12)
sidecar_keys = st.sampled_from(["width", "height", "rate_hz", "flip", "header_cols", "effects", "reset", "other"])


def _returns_or_input_error(call) -> None:
    try:
        call()
    except InputError as exc:
        assert "\n" not in str(exc)


@SETTINGS
@given(st.dictionaries(sidecar_keys, json_values, max_size=6) | json_values)
def test_sidecars(tmp_path: Path, data) -> None:
    (tmp_path / "c.capture.json").write_text(json.dumps(data))
    _returns_or_input_error(lambda: read_sidecar(tmp_path / "c.dat"))
    _returns_or_input_error(lambda: simulated_camera(tmp_path / "c.dat"))


@SETTINGS
@given(st.binary(max_size=64))
def test_sidecar_bytes(tmp_path: Path, data: bytes) -> None:
    (tmp_path / "c.capture.json").write_bytes(data)
    _returns_or_input_error(lambda: read_sidecar(tmp_path / "c.dat"))


def test_deeply_nested_sidecar_and_scene(tmp_path: Path) -> None:
    (tmp_path / "c.capture.json").write_text("[" * 100_000 + "]" * 100_000)
    _returns_or_input_error(lambda: read_sidecar(tmp_path / "c.dat"))
    (tmp_path / "s.toml").write_text("a = " + "[" * 100_000 + "]" * 100_000)
    _returns_or_input_error(lambda: load_scene(tmp_path / "s.toml"))


scene_keys = st.sampled_from(["name", "width", "height", "rate_hz", "duration_s", "exposure", "effects", "seed",
                              "readout", "background", "objects", "subsamples", "sensor", "dark_regions"])
toml_scalars = st.booleans() | st.integers(-10**9, 10**9) | st.floats(allow_nan=True, allow_infinity=True) | \
    st.text(alphabet="abc_-0123456789.", max_size=8)


def _toml(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if value != value else ("inf" if value > 0 else "-inf") if abs(value) == float("inf") else repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return json.dumps(value)


@SETTINGS
@given(st.dictionaries(scene_keys, toml_scalars | st.lists(toml_scalars, max_size=3), max_size=8))
def test_scene_files(tmp_path: Path, data) -> None:
    text = "\n".join(f"{k} = {_toml(v)}" for k, v in data.items())
    (tmp_path / "s.toml").write_text(text)
    _returns_or_input_error(lambda: load_scene(tmp_path / "s.toml"))


@SETTINGS
@given(st.dictionaries(st.sampled_from(["version", "width", "height", "level", "bits", "rate_hz", "flip", "band",
                                        "shift", "rows"]), json_values, max_size=10))
def test_mbit_headers(tmp_path: Path, header) -> None:
    write_dat(tmp_path / "c.dat", np.zeros((2, 8, 8), np.uint8), DatGeometry(8, 8))
    text = json.dumps(header).encode()
    (tmp_path / "c.mbit").write_bytes(b"RMBMBIT1" + struct.pack("<I", len(text)) + text + bytes(64))
    _returns_or_input_error(lambda: RmbFileReader(tmp_path / "c.dat"))

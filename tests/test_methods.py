"""The method registry: every method's own window/step meaning, limits and defaults, in one place."""

from __future__ import annotations

import pytest

from rmbvideo.errors import OptionError
from rmbvideo.recon.methods import METHODS, get_method


def test_every_method_builds_with_its_defaults():
    for name, method in METHODS.items():
        recon = method.build(**method.options(None, 20))
        assert recon.input_kind == method.input_kind, name


@pytest.mark.parametrize("name, window, expected", [
    ("tfp", 41, {"window": 41, "step": 20}),
    ("tfi", None, {"step": 20}),
    ("tfi", 8, {"window": 8, "step": 20}),
    ("tfw", 70, {"window": 70, "step": 10}),
    ("gc20", 70, {"window": 70, "step": 10}),
    ("rmbnet", 0, {"w": 0}),
    ("rmbnet", None, {}),
])
def test_window_and_step_mean_what_the_method_says(name, window, expected):
    assert get_method(name).options(window, 20) == expected


def test_a_fixed_step_method_keeps_every_kth_frame_at_a_multiple_of_its_step():
    rmbnet = get_method("rmbnet")
    assert [rmbnet.frame_every(step) for step in (20, 40, 660)] == [1, 2, 33]
    assert rmbnet.frame_every(20, raw_per_readout=1) == 2 and rmbnet.options(None, 40) == {}
    assert get_method("tfp").frame_every(40) == 1  # its frames are made at any step


def test_native_streams_count_readouts_of_one_raw_plane():
    assert get_method("tfw").options(10, 10, raw_per_readout=1) == {"window": 10, "step": 10}
    assert get_method("rmbnet").options(None, 10, raw_per_readout=1) == {}


@pytest.mark.parametrize("name, window, step, message", [
    ("tfp", 100_000_000, 20, "--window: tfp takes 1..20000"),  # a typo cannot ask for gigabytes
    ("tfp", 0, 20, "--window"),
    ("tfi", -1, 20, "--window: tfi takes 0..20000"),
    ("rmbnet", 4, 20, "--window: rmbnet takes 0..3"),
    ("rmbnet", None, 30, "--step: rmbnet makes a frame every 20 raw planes"),
    ("tfw", 10, 21, "--step: methods on the binned stream need an even step"),
])
def test_values_a_method_cannot_take_are_refused(name, window, step, message):
    with pytest.raises(OptionError, match=message):
        get_method(name).options(window, step)


def test_extra_options_go_only_to_the_methods_that_declare_them():
    extra = {"model": "m.safetensors", "align": "dis", "threads": 1}
    assert get_method("rmbnet").select_extra(extra) == extra
    assert get_method("tfp").select_extra(extra) == {}
    with pytest.raises(OptionError, match="unknown method"):
        get_method("tfq")

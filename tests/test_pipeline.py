"""The streaming loop: reader -> reconstructor -> sink, chunk independence, the non-finite guard."""

from __future__ import annotations

import numpy as np
import pytest

from rmbvideo.chunks import Frame, SpikeChunk
from rmbvideo.io.dat import DatGeometry, DatReader, write_dat
from rmbvideo.recon.classical import Tfw
from rmbvideo.errors import OptionError
from rmbvideo.recon.methods import METHODS, Method, make_reconstructor, register_method
from rmbvideo.recon.pipeline import reconstruct_stream
from rmbvideo.sensor.readout import RmbReadout

GEOMETRY = DatGeometry(width=32, height=16)


class _Collect:
    def __init__(self) -> None:
        self.frames: list[Frame] = []

    def write(self, frame: Frame) -> None:
        self.frames.append(frame)


@pytest.fixture
def reader(tmp_path) -> DatReader:
    rng = np.random.default_rng(7)
    planes = (rng.random((130, 16, 32)) < rng.uniform(0.05, 0.8, (16, 32))).astype(np.uint8)
    write_dat(tmp_path / "s.dat", planes, GEOMETRY)
    return DatReader(tmp_path / "s.dat", GEOMETRY)


@pytest.mark.parametrize("method", ["tfp", "tfi", "tfw"])
def test_results_do_not_depend_on_chunk_size(reader, method):
    runs = []
    for chunk in (6, 1000):
        sink = _Collect()
        summary = reconstruct_stream(reader, make_reconstructor(method), sink, start=0, chunk_planes=chunk)
        assert summary.frames == len(sink.frames) == 6 and summary.planes == 130
        runs.append(sink.frames)
    for a, b in zip(*runs):
        assert a.index == b.index and np.array_equal(a.image, b.image)


def test_rmb_method_applies_readout_and_rounds_odd_start(reader):
    sink = _Collect()
    readout = RmbReadout(band=2, shift=1)
    summary = reconstruct_stream(reader, Tfw(), sink, start=21, stop=121, chunk_planes=9, readout=readout)
    direct = Tfw()
    chunk = readout.apply(reader.read_binned(22, 120))
    expected = direct.push(chunk) + direct.flush()
    assert summary.planes == 98
    assert [f.index for f in sink.frames] == [f.index for f in expected] == [1, 2, 3, 4, 5]
    for a, b in zip(sink.frames, expected):
        assert np.array_equal(a.image, b.image)


def test_nonfinite_pixels_never_reach_the_sink(reader):
    class Broken:
        input_kind = "spikes"

        def push(self, chunk: SpikeChunk) -> list[Frame]:
            image = np.ones(chunk.planes.shape[1:], np.float32)
            image[0, :3] = [np.nan, np.inf, -1.0]
            return [Frame(chunk.start, 0.0, image)]

        def flush(self) -> list[Frame]:
            return []

    register_method(Method("broken-test", Broken, "spikes", "emits NaN and Inf"))
    try:
        sink = _Collect()
        summary = reconstruct_stream(reader, make_reconstructor("broken-test"), sink, chunk_planes=50)
    finally:
        del METHODS["broken-test"]
    assert summary.frames == 3 and summary.nonfinite_pixels == 6
    for frame in sink.frames:
        assert np.isfinite(frame.image).all() and (frame.image >= 0).all()
        assert frame.image[0, 3] == 1.0


def test_bad_requests(reader):
    with pytest.raises(OptionError, match="unknown method"):
        make_reconstructor("nope")
    with pytest.raises(OptionError, match="method tfp: .*widow"):
        make_reconstructor("tfp", widow=3)
    with pytest.raises(ValueError, match="readout"):
        reconstruct_stream(reader, make_reconstructor("tfp"), _Collect(), readout=RmbReadout())


def test_every_run_is_timed_by_stage(reader):
    """One wiring for reconstruct, evaluate and bench: the run reports seconds per stage, and the
    RMB-Net engine adds its own parts, which lie within the method's time."""
    from rmbvideo.recon.pipeline import STAGES

    summary = reconstruct_stream(reader, make_reconstructor("tfp", window=21, step=20), _Collect())
    assert set(summary.stages) == set(STAGES)
    assert all(v >= 0 for v in summary.stages.values()) and sum(summary.stages.values()) <= summary.seconds
    rmbnet = make_reconstructor("rmbnet", device="cpu", threads=1)
    summary = reconstruct_stream(reader, rmbnet, _Collect(), readout=RmbReadout())
    assert summary.frames > 0
    inner = summary.stages["preliminary frames"] + summary.stages["network"]
    assert 0 < summary.stages["network"] and inner <= summary.stages["method"] + 1e-6


@pytest.mark.parametrize("special", [np.nan, -np.nan, np.inf, -np.inf, -1.0, -1e-45, np.float32(3.4e38), 0.0, -0.0, 1e-45])
def test_clean_image_on_every_kind_of_value(special):
    """Clean images come back as they are (the same object, -0.0 included); anything else is finite and >= 0,
    with the non-finite pixels counted."""
    from rmbvideo.chunks import clean_image

    image = np.linspace(0.0, 2.0, 24, dtype=np.float32).reshape(4, 6)[:, ::2]  # a strided view
    image[1, 2] = special
    cleaned, bad = clean_image(image)
    value = np.float32(special)
    if np.isfinite(value) and value >= 0:
        assert cleaned is image and bad == 0
    else:
        assert bad == int(not np.isfinite(value))
        assert np.isfinite(cleaned).all() and (cleaned >= 0).all() and cleaned[1, 2] == 0.0
        mask = np.ones(image.shape, bool)
        mask[1, 2] = False
        assert np.array_equal(cleaned[mask], image[mask])

"""TFP on packed bits: identical frames to the unpacked path for any chunking, start, orientation and
header columns; packed chunks from the reader; page release keeps total RSS flat."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from rmbvideo.bench.memory import write_random_capture
from rmbvideo.io.dat import DatGeometry, DatReader, PackedChunk, write_dat
from rmbvideo.recon.classical import Tfp, _bit_sliced_sum
from rmbvideo.recon.pipeline import reconstruct_stream

RATE = 20000.0


def _capture(tmp_path, geometry: DatGeometry, planes: int = 173, seed: int = 0) -> DatReader:
    rng = np.random.default_rng(seed)
    rate = rng.uniform(0.0, 1.0, (geometry.height, geometry.image_width))
    rate[0, :3] = (0.0, 1.0, 0.5)  # a dark, a saturated and a middling pixel, whatever the seed
    data = (rng.random((planes, geometry.height, geometry.image_width)) < rate).astype(np.uint8)
    write_dat(tmp_path / "c.dat", data, geometry)
    return DatReader(tmp_path / "c.dat", geometry, rate_hz=RATE)


def _run(tfp: Tfp, chunks) -> list:
    return [f for c in chunks for f in tfp.push(c)] + tfp.flush()


def _assert_same(expected: list, got: list) -> None:
    assert [f.index for f in got] == [f.index for f in expected]
    assert [f.time_s for f in got] == [f.time_s for f in expected]
    for x, y in zip(expected, got):
        assert y.image.dtype == np.float32 and y.image.shape == x.image.shape
        assert np.array_equal(x.image, y.image), (x.index, np.abs(x.image - y.image).max())


GEOMETRIES = [
    DatGeometry(32, 6),
    DatGeometry(32, 6, flip=False),
    DatGeometry(48, 5, header_cols=16),
    DatGeometry(12, 10),  # rows not byte aligned: the bits still add up per pixel
    DatGeometry(8, 3),  # 3-byte planes: counted in single bytes
]


@pytest.mark.parametrize("geometry", GEOMETRIES, ids=lambda g: f"{g.width}x{g.height}h{g.header_cols}f{int(g.flip)}")
@pytest.mark.parametrize(("window", "step"), [(41, 20), (7, 3), (1, 5), (300, 7)])
def test_packed_equals_unpacked(tmp_path, geometry, window, step):
    reader = _capture(tmp_path, geometry)
    for start, stop in ((0, None), (13, 160)):
        expected = _run(Tfp(window, step), reader.chunks(reader.n_planes, start, stop))
        assert expected
        for size in (1, 17, 64, 1000):
            _assert_same(expected, _run(Tfp(window, step), reader.packed_chunks(size, start, stop)))


def test_packed_values_are_the_window_means(tmp_path):
    """Independent of the running-sum machinery: frame i is the mean of its (clipped) window."""
    geometry = DatGeometry(24, 4, header_cols=8)
    reader = _capture(tmp_path, geometry, planes=90, seed=5)
    planes = reader.read()
    frames = _run(Tfp(9, 4), reader.packed_chunks(11))
    assert [f.index for f in frames] == list(range(22))  # centres 2, 6, .., 86 lie inside 90 planes
    for f in frames:
        centre2 = (2 * f.index + 1) * 4
        lo, hi = max((centre2 - 9 + 1) // 2, 0), min((centre2 - 9 + 1) // 2 + 9, 90)
        assert f.time_s == centre2 / 2 / RATE
        assert np.array_equal(f.image, planes[lo:hi].mean(axis=0, dtype=np.float64).astype(np.float32))
    assert frames[5].image[0, 0] == 0.0 and frames[5].image[0, 1] == 1.0  # the dark and the saturated pixel


@pytest.mark.parametrize("word", [np.uint8, np.uint32])
def test_bit_sliced_sum_counts_every_plane(word):
    """The carry-save tree's bit k, for every count of planes it meets (segments of 1 to a chunk): each
    pixel's count, in exactly ``m.bit_length()`` rows."""
    rng = np.random.default_rng(3)
    for m in [*range(1, 70), 255, 256, 1000]:
        planes = rng.integers(0, 256, (m, 8), dtype=np.uint8)
        bits = _bit_sliced_sum(planes.view(word))
        assert len(bits) == m.bit_length()
        counts = sum(np.unpackbits(b.view(np.uint8), bitorder="little").astype(np.int64) << k for k, b in enumerate(bits))
        assert np.array_equal(counts, np.unpackbits(planes, axis=1, bitorder="little").sum(axis=0)), m


def test_float32_quotient_matches_float64_rounding():
    """The packed path divides in float32: exhaustively the same value as the float64 path."""
    counts = np.arange(1, 1025)
    sums = np.arange(0, 1025)
    n, c = np.meshgrid(sums, counts)
    keep = n <= c
    direct = np.divide(n[keep].astype(np.uint16), c[keep].astype(np.float32), dtype=np.float32)
    assert np.array_equal(direct, (n[keep] / c[keep]).astype(np.float32))


def test_mixed_chunks(tmp_path):
    reader = _capture(tmp_path, DatGeometry(16, 4), planes=60)
    expected = _run(Tfp(), reader.chunks(60))
    unpacked_first = Tfp()
    got = unpacked_first.push(next(reader.chunks(30))) + unpacked_first.push(next(reader.packed_chunks(30, 30)))
    _assert_same(expected, got + unpacked_first.flush())
    packed_first = Tfp()
    packed_first.push(next(reader.packed_chunks(30)))
    with pytest.raises(ValueError, match="one kind"):
        packed_first.push(next(reader.chunks(30, 30)))


def test_packed_chunks_cover_the_range(tmp_path):
    geometry = DatGeometry(16, 4, header_cols=8)
    reader = _capture(tmp_path, geometry, planes=50)
    chunks = list(reader.packed_chunks(16, 3, 45))
    assert [(c.start, c.stop) for c in chunks] == [(3, 19), (19, 35), (35, 45)]
    assert all(isinstance(c, PackedChunk) and c.geometry == geometry and c.rate_hz == RATE for c in chunks)
    assert all(c.data.shape[1] == geometry.plane_bytes and not c.data.flags.writeable for c in chunks)
    assert np.array_equal(np.concatenate([c.unpack().planes for c in chunks]), reader.read(3, 45))
    raw = np.fromfile(tmp_path / "c.dat", np.uint8).reshape(50, -1)
    assert np.array_equal(np.concatenate([c.data for c in chunks]), raw[3:45])
    with pytest.raises(ValueError):
        next(reader.packed_chunks(0))


def test_pipeline_feeds_packed_chunks(tmp_path):
    reader = _capture(tmp_path, DatGeometry(32, 8), planes=120)
    expected = _run(Tfp(), reader.chunks(120))

    class Collect:
        def __init__(self) -> None:
            self.frames: list = []

        def write(self, frame) -> None:
            self.frames.append(frame)

    class Spy(Tfp):
        def __init__(self) -> None:
            super().__init__()
            self.kinds: set[str] = set()

        def push(self, chunk):
            self.kinds.add(type(chunk).__name__)
            return super().push(chunk)

    sink, spy = Collect(), Spy()
    summary = reconstruct_stream(reader, spy, sink, chunk_planes=25)
    assert spy.kinds == {"PackedChunk"} and summary.planes == 120 and summary.frames == len(expected)
    _assert_same(expected, sink.frames)


def test_pipeline_pushes_at_most_max_push_planes(tmp_path):
    """A read of many planes reaches TFP in consecutive pushes of at most its ``max_push_planes`` (so a push's
    frames stay few), with the same frames as one push of everything."""
    most = Tfp.max_push_planes
    reader = _capture(tmp_path, DatGeometry(16, 4), planes=3 * most + 37)
    spans: list[tuple[int, int]] = []

    class Spy(Tfp):
        def push(self, chunk):
            spans.append((chunk.start, chunk.stop))
            return super().push(chunk)

    class Collect:
        def __init__(self) -> None:
            self.frames: list = []

        def write(self, frame) -> None:
            self.frames.append(frame)

    sink = Collect()
    reconstruct_stream(reader, Spy(), sink, start=5, chunk_planes=2 * most + 1)
    assert spans[0][0] == 5 and spans[-1][1] == reader.n_planes
    assert all(a == b for (_, a), (b, _) in zip(spans, spans[1:])) and max(b - a for a, b in spans) == most
    _assert_same(_run(Tfp(), reader.chunks(reader.n_planes, 5)), sink.frames)


# Runs ``rmbvideo reconstruct`` in-process and prints the sampled peak of its total RSS (file pages of
# the input included). ru_maxrss cannot serve: Linux carries the parent's peak into it.
_CHILD = """
import sys, threading
from rmbvideo.bench.memory import current_rss_bytes
from rmbvideo.cli import main
peak = [current_rss_bytes()]
stop = threading.Event()
def sample():
    while not stop.wait(0.002):
        peak[0] = max(peak[0], current_rss_bytes())
thread = threading.Thread(target=sample, daemon=True)
thread.start()
main(sys.argv[1:], prog_name="rmbvideo", standalone_mode=False)
stop.set()
thread.join()
print(max(peak[0], current_rss_bytes()))
"""


@pytest.mark.parametrize("method", ["tfp", "tfw"])
def test_total_rss_flat_with_capture_length(tmp_path, method):
    """Peak total RSS of ``reconstruct`` does not grow with capture length (5x longer: < 10 % more). Binned
    output: the full-resolution stage's memory is checked by ``test_memory`` (anonymous RSS), and here it
    would make the test 7x slower."""
    peaks = []
    for count in (2048, 5 * 2048):  # 25 MB and 128 MB of input
        path = write_random_capture(tmp_path / f"c{count}.dat", count, 400, 250, seed=count)
        args = [str(path), "-o", str(tmp_path / "out"), "--format", "null", "-q", "--width", "400",
                "--height", "250", "--method", method, "--resolution", "binned"]
        run = subprocess.run([sys.executable, "-c", _CHILD, "reconstruct", *args], capture_output=True, text=True,
                             timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})
        assert run.returncode == 0, run.stderr[-2000:]
        peaks.append(int(run.stdout.split()[-1]))
    short, long = peaks
    assert long < 1.10 * short, (short, long)

"""The .dat reader and writer: layout, round trips, binned reading, bad inputs, real data."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from rmbvideo.errors import InputError, OutputError
from rmbvideo.image_pool import ImagePool
from rmbvideo.io.dat import DatGeometry, DatReader, DatWriter, unpack_planes, write_dat
from rmbvideo.sensor.binning import StreamBinner, bin_2x2x2


def random_planes(seed: int, shape: tuple[int, int, int], rate: float = 0.4) -> np.ndarray:
    return (np.random.default_rng(seed).random(shape) < rate).astype(np.uint8)


# --- geometry -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs",
    [
        {"width": 0},
        {"height": -250},
        {"width": 7, "height": 3},  # 21 bits: not whole bytes
        {"header_cols": 400},
        {"header_cols": -1},
        {"width": 400, "height": 2_500_000},
        {"width": 400.0},
        {"width": True},
    ],
)
def test_geometry_rejects_impossible_layouts(kwargs: dict) -> None:
    with pytest.raises(InputError, match="geometry"):
        DatGeometry(**kwargs)


def test_geometry_sizes() -> None:
    g = DatGeometry(416, 250, header_cols=16)
    assert (g.image_width, g.plane_bytes, g.byte_aligned) == (400, 13000, True)
    assert DatGeometry(12, 2).byte_aligned is False


# --- layout and round trips -----------------------------------------------------------------


def test_stored_layout_is_lsb_first_and_upside_down(tmp_path: Path) -> None:
    """Bytes written by hand from the format description decode to the expected pixels."""
    h, w = 4, 16
    raw = np.zeros((h * w) // 8, np.uint8)
    # stored row 3 is image row 0; stored pixel index 3*16 + 2 -> byte 6, bit 2
    raw[(3 * w + 2) >> 3] |= 1 << ((3 * w + 2) & 7)
    # stored row 0 column 9 is image row 3 column 9 -> byte 1, bit 1
    raw[9 >> 3] |= 1 << (9 & 7)
    path = tmp_path / "layout.dat"
    path.write_bytes(raw.tobytes())
    flipped = DatReader(path, DatGeometry(w, h)).read()[0]
    assert list(zip(*np.nonzero(flipped))) == [(0, 2), (3, 9)]
    unflipped = DatReader(path, DatGeometry(w, h, flip=False)).read()[0]
    assert list(zip(*np.nonzero(unflipped))) == [(0, 9), (3, 2)]


@pytest.mark.parametrize(
    "geometry",
    [
        DatGeometry(16, 6),
        DatGeometry(16, 6, flip=False),
        DatGeometry(32, 5, header_cols=16),
        DatGeometry(12, 2),  # rows not byte aligned
        DatGeometry(10, 4, header_cols=3),
    ],
)
def test_round_trip_with_odd_chunkings(tmp_path: Path, geometry: DatGeometry) -> None:
    planes = random_planes(1, (13, geometry.height, geometry.image_width))
    path = tmp_path / "rt.dat"
    with DatWriter(path, geometry) as writer:
        for s, e in [(0, 1), (1, 6), (6, 6), (6, 13)]:
            writer.write(planes[s:e])
        assert writer.n_written == 13
    assert path.stat().st_size == 13 * geometry.plane_bytes
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind
    reader = DatReader(path, geometry)
    assert reader.n_planes == 13 and reader.trailing_bytes == 0
    np.testing.assert_array_equal(reader.read(), planes)
    np.testing.assert_array_equal(reader.read(4, 9), planes[4:9])
    chunks = list(reader.chunks(chunk_planes=5, start=2))
    assert [c.start for c in chunks] == [2, 7, 12]
    np.testing.assert_array_equal(np.concatenate([c.planes for c in chunks]), planes[2:])


@pytest.mark.parametrize("geometry", [DatGeometry(16, 6), DatGeometry(32, 5, header_cols=16), DatGeometry(10, 4, 3)])
def test_decoded_chunks_are_reused_only_once_released(tmp_path: Path, geometry: DatGeometry) -> None:
    """Reading decodes into arrays reused once nothing holds them (no page faults per chunk): a chunk kept stays
    as it was while later ones are read, a released one's memory decodes the next; several of numpy's blocks."""
    planes = random_planes(2, (150, geometry.height, geometry.image_width))
    path = tmp_path / "reuse.dat"
    write_dat(path, planes, geometry)
    reader = DatReader(path, geometry)
    kept = [c.planes for c in reader.chunks(chunk_planes=70)]  # every chunk held: none may be written again
    for k, chunk in enumerate(kept):
        np.testing.assert_array_equal(chunk, planes[70 * k : 70 * (k + 1)])
    first = reader.read(0, 70)
    address = first.ctypes.data
    del first, kept
    again = reader.read(70, 140)
    np.testing.assert_array_equal(again, planes[70:140])
    assert again.ctypes.data == address  # the released chunk's memory, not a fresh allocation
    packed = next(reader.packed_chunks(70, 0, 70))
    pool = ImagePool()
    np.testing.assert_array_equal(packed.unpack(pool).planes, planes[:70])
    np.testing.assert_array_equal(packed.unpack().planes, planes[:70])


def test_unpack_planes_checks_its_output(tmp_path: Path) -> None:
    geometry = DatGeometry(16, 6)
    packed = np.zeros((3, geometry.plane_bytes), np.uint8)
    with pytest.raises(ValueError, match="contiguous"):
        unpack_planes(packed, geometry, np.zeros((3, 6, 8), np.uint8))
    with pytest.raises(ValueError, match="contiguous"):
        unpack_planes(packed, geometry, np.zeros((3, 6, 32), np.uint8)[:, :, ::2])


def test_header_columns_are_written_as_zeros(tmp_path: Path) -> None:
    planes = np.ones((2, 3, 16), np.uint8)
    path = tmp_path / "hdr.dat"
    write_dat(path, planes, DatGeometry(24, 3, header_cols=8))
    raw = DatReader(path, DatGeometry(24, 3)).read()
    assert (raw[:, :, 16:] == 0).all() and (raw[:, :, :16] == 1).all()


def test_writer_leaves_nothing_on_exception(tmp_path: Path) -> None:
    path = tmp_path / "fail.dat"
    with pytest.raises(RuntimeError):
        with DatWriter(path, DatGeometry(8, 2)) as writer:
            writer.write(np.ones((3, 2, 8), np.uint8))
            raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []


def test_writer_rejects_wrong_planes_and_unwritable_folder(tmp_path: Path) -> None:
    with pytest.raises(ValueError):
        write_dat(tmp_path / "a.dat", np.ones((2, 3, 8), np.uint8), DatGeometry(8, 2))
    with pytest.raises(ValueError):
        write_dat(tmp_path / "b.dat", np.full((1, 2, 8), 2, np.uint8), DatGeometry(8, 2))
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(OutputError, match="no-such-folder"):
        write_dat(tmp_path / "no-such-folder" / "c.dat", np.ones((1, 2, 8), np.uint8), DatGeometry(8, 2))


# --- binned reading -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "geometry", [DatGeometry(32, 7), DatGeometry(32, 6, flip=False), DatGeometry(48, 6, header_cols=16), DatGeometry(12, 6)]
)
def test_binned_reading_matches_stream_binning(tmp_path: Path, geometry: DatGeometry) -> None:
    planes = random_planes(2, (23, geometry.height, geometry.image_width), rate=0.6)
    path = tmp_path / "b.dat"
    write_dat(path, planes, geometry)
    reader = DatReader(path, geometry, rate_hz=1000.0)
    whole = reader.read_binned()
    ref_single, ref_multi = bin_2x2x2(planes)
    np.testing.assert_array_equal(whole.single, ref_single)
    np.testing.assert_array_equal(whole.multi, ref_multi)
    assert (whole.start, whole.rate_hz, whole.raw_per_readout, whole.level) == (0, 500.0, 2, 7)
    assert whole.multi_rows.all() and whole.multi_rows.shape == (11, geometry.height // 2)

    part = reader.read_binned(4, 15)  # odd length: plane 14 is dropped
    assert part.start == 2 and len(part.single) == 5
    np.testing.assert_array_equal(part.multi, ref_multi[2:7])

    binner = StreamBinner()
    streamed = [c for c in (binner.push(ch) for ch in reader.chunks(chunk_planes=5)) if c is not None]
    for chunk_planes in (2, 6, 1024):
        binned = list(reader.binned_chunks(chunk_planes=chunk_planes))
        assert [c.start for c in binned] == list(range(0, 11, chunk_planes // 2))
        for field in ("single", "multi"):
            expected = np.concatenate([getattr(c, field) for c in streamed])
            np.testing.assert_array_equal(np.concatenate([getattr(c, field) for c in binned]), expected)


def test_binned_reading_needs_an_even_start(tmp_path: Path) -> None:
    path = tmp_path / "e.dat"
    write_dat(path, np.zeros((6, 2, 8), np.uint8), DatGeometry(8, 2))
    reader = DatReader(path, DatGeometry(8, 2))
    with pytest.raises(ValueError):
        reader.read_binned(1, 5)
    with pytest.raises(ValueError):
        list(reader.binned_chunks(chunk_planes=3))


# --- time, rates, ranges --------------------------------------------------------------------


def test_time_to_plane_and_duration(tmp_path: Path) -> None:
    path = tmp_path / "t.dat"
    write_dat(path, random_planes(3, (40, 8, 16), rate=0.25), DatGeometry(16, 8))
    reader = DatReader(path, DatGeometry(16, 8), rate_hz=20000.0)
    assert reader.duration_s == pytest.approx(0.002)
    assert [reader.plane_index(t) for t in (0.0, 0.001, 0.00104, 0.0012999)] == [0, 20, 20, 25]
    assert all(reader.plane_index(k / 20000.0) == k for k in range(40))
    with pytest.raises(InputError):
        reader.plane_index(-1.0)
    with pytest.raises(InputError, match="outside"):
        reader.read(30, 41)
    assert 0.15 < reader.mean_firing_rate(max_planes=40) < 0.35


# --- bad inputs -----------------------------------------------------------------------------


def test_missing_directory_and_empty_files(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        DatReader(tmp_path / "absent.dat")
    with pytest.raises(InputError, match="directory"):
        DatReader(tmp_path)
    empty = tmp_path / "empty.dat"
    empty.touch()
    with pytest.raises(InputError, match="empty"):
        DatReader(empty)


def test_file_smaller_than_a_plane_names_the_file_and_a_fitting_geometry(tmp_path: Path) -> None:
    path = tmp_path / "small.dat"
    path.write_bytes(bytes(12500))  # one 400x250 plane read as 1000x1000
    with pytest.raises(InputError, match=r"small\.dat.*less than one 1000x1000.*fits 400x250"):
        DatReader(path, DatGeometry(1000, 1000))


def test_truncated_file_warns_and_keeps_whole_planes(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    geometry = DatGeometry(16, 4)
    planes = random_planes(4, (5, 4, 16))
    path = tmp_path / "cut.dat"
    write_dat(path, planes, geometry)
    with open(path, "ab") as f:
        f.write(b"\x01\x02\x03")
    with caplog.at_level(logging.WARNING, logger="rmbvideo.io.dat"):
        reader = DatReader(path, geometry)
    assert any("cut.dat" in r.getMessage() and "3 trailing bytes" in r.getMessage() for r in caplog.records)
    assert (reader.n_planes, reader.trailing_bytes) == (5, 3)
    np.testing.assert_array_equal(reader.read(), planes)
    assert sum(len(c.single) for c in reader.binned_chunks(chunk_planes=2)) == 2


def test_file_truncated_while_being_read_is_an_error_not_a_crash(tmp_path: Path) -> None:
    """A capture cut short under a running reader (still being copied) gives an InputError naming it;
    a memory map would have killed the process with SIGBUS."""
    geometry = DatGeometry(400, 250)
    path = tmp_path / "copying.dat"
    write_dat(path, random_planes(5, (64, 250, 400)), geometry)
    reader = DatReader(path, geometry)
    chunks = reader.binned_chunks(chunk_planes=16)
    next(chunks)
    os.truncate(path, 20 * geometry.plane_bytes)
    with pytest.raises(InputError, match=r"copying\.dat.*shrank while being read"):
        list(chunks)


def test_pipes_are_refused_rather_than_waited_on(tmp_path: Path) -> None:
    fifo = tmp_path / "stream.dat"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match=r"stream\.dat: not a regular file"):
        DatReader(fifo)


# --- real data ------------------------------------------------------------------------------


def test_orientation_and_bit_order_against_ground_truth(shared_data: Path) -> None:
    """A 41-plane mean of a spikezoo stream matches its ground-truth PNG (README: 28.9 dB)."""
    folder = shared_data / "spikezoo-base"
    reader = DatReader(folder / "200_part3_key_id151.dat")
    assert reader.n_planes == 301 and reader.trailing_bytes == 0
    mean = reader.read(130, 171).mean(axis=0).astype(np.float64)
    truth = cv2.imread(str(folder / "200_part3_key_id151.png"), cv2.IMREAD_GRAYSCALE).astype(np.float64)
    scale = (mean * truth).sum() / (mean * mean).sum()
    psnr = 10 * np.log10(255.0**2 / np.mean((scale * mean - truth) ** 2))
    assert psnr >= 28.0
    binned = reader.read_binned(130, 172)
    assert binned.multi.shape == (21, 125, 200) and binned.multi.max() <= 7

"""Frame images reused only once released: a held image or a view of it is never handed out again, a released one
is, and TFP frames and binned chunks a caller keeps stay as they were while later ones reuse the released memory."""

from __future__ import annotations

import numpy as np

from rmbvideo.bench.memory import write_random_capture
from rmbvideo.io.dat import DatGeometry, DatReader
from rmbvideo.recon.classical import Tfp
from rmbvideo.sensor.binning import StreamBinner, bin_2x2x2
from rmbvideo.image_pool import ImagePool


def test_held_images_are_not_reused_and_released_ones_are():
    pool = ImagePool()
    first, second = pool.take((4, 6)), pool.take((4, 6))
    assert first is not second and first.shape == (4, 6) and first.dtype == np.float32
    view = second[1:3]
    del second
    third = pool.take((4, 6))
    assert third is not first and third.base is None and view.base is not third  # the view still holds the second
    first_id = id(first)
    del first
    assert id(pool.take((4, 6))) == first_id  # released, so reused
    assert pool.take((2, 2)).shape == (2, 2) and len(pool._images) == 1  # another shape: a fresh pool


def test_the_pool_is_bounded_in_bytes():
    pool = ImagePool(max_bytes=3 * 4 * 100)
    held = [pool.take((10, 10)) for _ in range(5)]
    assert len({id(image) for image in held}) == 5
    assert len(pool._images) == 3  # the others were allocated outside the pool


def test_tfp_frames_kept_by_the_caller_stay_as_they_were(tmp_path):
    path = write_random_capture(tmp_path / "c.dat", 600, 64, 16, seed=3)
    reader = DatReader(path, DatGeometry(64, 16))
    first = Tfp(41, 5)
    reference = {f.index: f.image.copy() for c in reader.packed_chunks(50) for f in first.push(c)}
    kept, seen, tfp = {}, 0, Tfp(41, 5)
    for chunk in reader.packed_chunks(50):
        for frame in tfp.push(chunk):  # most frames are dropped at once, every seventh is kept
            seen += 1
            if frame.index % 7 == 0:
                kept[frame.index] = frame.image
            assert np.array_equal(frame.image, reference[frame.index])
    assert seen > 50 and kept
    for index, image in kept.items():
        assert np.array_equal(image, reference[index]), index
    assert len(tfp._images._images) < seen  # the released images were reused


def test_pooled_arrays_keep_their_type_and_a_new_type_starts_afresh():
    pool = ImagePool()
    first = pool.take((2, 3), np.uint8)
    assert first.dtype == np.uint8
    del first
    assert pool.take((2, 3), np.uint8).dtype == np.uint8 and pool.take((2, 3)).dtype == np.float32
    assert len(pool._images) == 1


def test_binned_chunks_kept_by_the_caller_stay_as_they_were(tmp_path):
    path = write_random_capture(tmp_path / "c.dat", 300, 64, 16, seed=4)
    reader = DatReader(path, DatGeometry(64, 16))
    reference = bin_2x2x2(reader.read(0, 300))
    kept, binner = [], StreamBinner()
    for k, (chunk, packed) in enumerate(zip(reader.binned_chunks(20), reader.packed_chunks(20))):
        stored = binner.push_stored(packed.data, packed.start, packed.rate_hz, 16, 64, True)
        for binned in (chunk, stored):
            s = slice(binned.start, binned.start + len(binned.single))
            assert np.array_equal(binned.single, reference[0][s]) and np.array_equal(binned.multi, reference[1][s])
            if k % 4 == 0:
                kept.append((binned.single[1:3], binned.multi, s))  # a view keeps its chunk's memory too
    for single, multi, s in kept:
        assert np.array_equal(single, reference[0][s][1:3]) and np.array_equal(multi, reference[1][s])
    assert len(reader._binned._images) < 15 and len(binner._outputs._images) < 15  # released chunks were reused

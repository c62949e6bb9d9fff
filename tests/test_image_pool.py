"""Frame images reused only once released: a held image or a view of it is never handed out again, a released one
is, and TFP frames a caller keeps stay as they were while later frames reuse the released ones."""

from __future__ import annotations

import numpy as np

from rmbvideo.bench.memory import write_random_capture
from rmbvideo.io.dat import DatGeometry, DatReader
from rmbvideo.recon.classical import Tfp
from rmbvideo.recon.image_pool import ImagePool


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

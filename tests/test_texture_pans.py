"""Development clips: spikezoo-format streams of textures panned at known speeds."""

from __future__ import annotations

import numpy as np

from rmbvideo.evaluate.real_video import find_streams, scaled_psnr
from rmbvideo.evaluate.texture_pans import (PLANES, REFERENCE_PLANE, SPIKEZOO_RATE, TEXTURE_PANS, texture,
                                            write_texture_pan)
from rmbvideo.io.dat import DatReader


def _reference(stream) -> np.ndarray:
    import cv2

    return cv2.imread(str(stream.reference), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0


def test_static_pan_fires_at_spikezoos_rate_of_its_reference(tmp_path):
    static = next(p for p in TEXTURE_PANS if p.speed == 0)
    write_texture_pan(static, tmp_path)
    (stream,) = find_streams(tmp_path)
    assert stream.plane == REFERENCE_PLANE
    planes = DatReader(stream.capture).read().astype(np.float32)
    assert len(planes) == PLANES
    reference = _reference(stream)
    rate = planes.mean(axis=0)
    # accumulate-and-subtract: the count over T planes is within one spike of T x rate
    assert np.abs(rate - SPIKEZOO_RATE * reference).max() < 1.0 / PLANES + SPIKEZOO_RATE / 255
    assert scaled_psnr(rate, reference) > 40.0


def test_moving_pan_shows_its_reference_at_the_reference_plane(tmp_path):
    moving = max(TEXTURE_PANS, key=lambda p: (p.contrast, p.speed))
    write_texture_pan(moving, tmp_path)
    (stream,) = find_streams(tmp_path)
    planes = DatReader(stream.capture).read().astype(np.float32)
    reference = _reference(stream)
    at = planes[REFERENCE_PLANE - 9 : REFERENCE_PLANE + 11].mean(axis=0)  # centred on the moment, time 151
    early = planes[:21].mean(axis=0)
    assert scaled_psnr(at, reference) > scaled_psnr(early, reference) + 3.0


def test_textures_are_reproducible_and_have_their_contrast():
    low, high = (next(p for p in TEXTURE_PANS if p.contrast == c) for c in (0.16, 0.32))
    a, b = texture(low, 64, 96), texture(low, 64, 96)
    assert np.array_equal(a, b)
    spread = [float(np.log(np.clip(texture(p, 128, 192), 1e-3, None)).std()) for p in (low, high)]
    assert spread[0] < spread[1] and abs(spread[0] - 0.16) < 0.05

"""The raw stream's TFP and TFI made by torch (``rmbvideo.recon.device_rates``, a GPU's path; here on the CPU) are
the numpy methods' frames bit for bit, whatever the chunks, packed or decoded, from any first plane (on a GPU too,
where there is one)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from rmbvideo.chunks import SpikeChunk
from rmbvideo.io.dat import DatGeometry, PackedChunk, unpack_planes
from rmbvideo.recon.classical import Tfi, Tfp
from rmbvideo.recon.device_rates import DeviceTfi, DeviceTfp, to_device, unpack_on

GEOMETRY = DatGeometry(48, 20, header_cols=8)
#: the CPU everywhere, and a GPU where there is one
DEVICES = ["cpu", *(["cuda"] if torch.cuda.is_available() else [])]


def _stream(planes: int = 403, seed: int = 0) -> np.ndarray:
    """Stored plane bytes of a stream whose pixels fire at rates from 0 to 0.3, some never."""
    rng = np.random.default_rng(seed)
    rates = rng.uniform(0.0, 0.3, (GEOMETRY.height, GEOMETRY.width))
    rates[:3] = 0.0
    stored = (rng.random((planes, GEOMETRY.height, GEOMETRY.width)) < rates).astype(np.uint8)
    return np.packbits(stored.reshape(planes, -1), axis=1, bitorder="little")


@pytest.mark.parametrize("device", DEVICES)
def test_planes_decoded_on_the_device_are_the_stored_planes(device):
    packed = _stream(9)
    for flip in (True, False):
        geometry = DatGeometry(48, 20, header_cols=8, flip=flip)
        decoded = unpack_on(packed, geometry, torch.device(device)).cpu().numpy()
        assert np.array_equal(decoded, unpack_planes(packed, geometry))


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("chunk,first,packed", [(37, 0, True), (128, 13, False), (500, 0, True), (64, 5, True)])
def test_device_tfp_and_tfi_give_the_numpy_frames_bit_for_bit(chunk, first, packed, device):
    stored = _stream()
    planes = unpack_planes(stored, GEOMETRY)
    # the last three keep their images on the device (for the detail stage there): the same values
    pairs = [(Tfp(6, 20), DeviceTfp(6, 20)), (Tfp(41, 20), DeviceTfp(41, 20)), (Tfi(20, 40), DeviceTfi(20, 40)),
             (Tfi(20, 7), DeviceTfi(20, 7)), (Tfp(41, 20), DeviceTfp(41, 20, on_device=True)),
             (Tfi(20, 40), DeviceTfi(20, 40, on_device=True)),
             (Tfi(20, 40, shorter=(7,)), DeviceTfi(20, 40, on_device=True, shorter=(7,))),
             (Tfi(20, 40, shorter=(7,), window=8), DeviceTfi(20, 40, on_device=True, shorter=(7,), window=8))]
    frames = [([], []) for _ in pairs]
    for a in range(first, len(stored), chunk):
        b = min(len(stored), a + chunk)
        source = PackedChunk(stored[a:b], a, 20000.0, GEOMETRY) if packed else SpikeChunk(planes[a:b], a, 20000.0)
        on_device = to_device(source, torch.device(device))
        for (numpy_method, device_method), (expected, got) in zip(pairs, frames):
            numpy_input = source.unpack() if packed and isinstance(numpy_method, Tfi) else source
            expected += numpy_method.push(numpy_input)
            got += device_method.push(on_device)
    for k, ((numpy_method, device_method), (expected, got)) in enumerate(zip(pairs, frames)):
        expected += numpy_method.flush()
        got += device_method.flush()
        assert len(expected) >= 19 and [f.index for f in got] == [f.index for f in expected]
        for e, g in zip(expected, got):
            image = g.image
            if k >= 4:
                assert isinstance(image, torch.Tensor) and image.device.type == torch.device(device).type
                image = image.cpu().numpy()
            assert g.time_s == e.time_s and image.dtype == np.float32 and np.array_equal(image, e.image)
    dark = frames[2][1][len(frames[2][1]) // 2].image[-3:]  # never firing (stored first, flipped): a finite bound
    assert np.allclose(dark, 1 / 81)


def test_a_chunk_out_of_order_is_refused():
    stored = _stream(60)
    tfi = DeviceTfi(20, 40)
    tfi.push(to_device(PackedChunk(stored[:30], 0, 20000.0, GEOMETRY), torch.device("cpu")))
    with pytest.raises(ValueError, match="expected 30"):
        tfi.push(to_device(PackedChunk(stored[31:], 31, 20000.0, GEOMETRY), torch.device("cpu")))

"""The aligned window means batched in torch (``recon.aligned_batched``, the GPU's way): the means of
``AlignedBox`` to float and OpenCV's 1/32-pixel rounding of sample positions, streamed and evicted as the engine
does; and through the engine, the frames of the OpenCV means to that precision."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from rmbvideo.recon.aligned_batched import BatchedAlignedWorker, _reflect_101, network_input_on_device, warp
from rmbvideo.recon.aligned_box import STATISTICS, AlignedBox, AlignedBoxConfig, aligned_window, network_input
from tests.test_aligned_box import noisy, texture


def test_warp_is_bilinear_sampling_with_the_border_replicated():
    image = torch.arange(12, dtype=torch.float32).reshape(1, 1, 3, 4)
    flow = torch.zeros(1, 2, 3, 4)
    assert torch.equal(warp(image, flow), image)
    flow[:, 0] = 0.5  # half a pixel right: the mean of each pair, the last column replicated
    expected = torch.tensor([[0.5, 1.5, 2.5, 3.0], [4.5, 5.5, 6.5, 7.0], [8.5, 9.5, 10.5, 11.0]])
    torch.testing.assert_close(warp(image, flow)[0, 0], expected)
    flow[:, 0], flow[:, 1] = -2.0, 5.0  # far outside: the nearest border pixel
    torch.testing.assert_close(warp(image, flow)[0, 0], torch.tensor([8.0, 8.0, 8.0, 9.0]).expand(3, 4))


DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def host(value):
    """A result kept on the device (``on_device``) as numpy, checking it is a tensor there."""
    if isinstance(value, tuple):
        return tuple(host(v) for v in value)
    assert isinstance(value, torch.Tensor)
    return value.cpu().numpy()


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("sharp, statistics, on_device", [(False, False, False), (True, False, False),
                                                          (True, True, False), (True, True, True)])
def test_batched_means_are_the_opencv_means_streamed_with_evictions(sharp, statistics, on_device, device):
    """A texture panned 2 px a frame (and a still stretch), its frames added one at a time and its means asked for in
    runs as the engine does, windows slid inwards at both ends; old frames evicted after each run. With
    ``statistics`` also each mean's ``STATISTICS``: the flow's to float (the same DIS flows), the merge's support and
    spread to the means' precision. ``on_device``: the same, kept as tensors on the device."""
    rng = np.random.default_rng(3)
    scene = texture(4, (48, 64 + 40))
    count, radius = 17, 3
    shifts = [min(2 * k, 20) for k in range(count)]
    frames = [noisy(scene[:, s : s + 64], rng) for s in shifts]
    sharps = [noisy(scene[:, s : s + 64], rng, 16) for s in shifts] if sharp else [None] * count
    config = AlignedBoxConfig.for_frames(10, 2 if sharp else 0)
    box = AlignedBox(config)
    for k in range(count):
        box.add(k, frames[k], sharps[k])
    expected = [box.mean(i, aligned_window(i, radius, count, shift=True), statistics) for i in range(count)]

    worker = BatchedAlignedWorker(config, device, workers=2, on_device=on_device)
    got, added = {}, 0
    for run in ([0, 1, 2, 3], [4, 5, 6, 7, 8, 9], [10, 11, 12, 13, 14, 15, 16]):
        while added < min(count, run[-1] + 2 * radius + 1):
            worker.add(added, frames[added], sharps[added])
            added += 1
        handles = {i: worker.mean(i, aligned_window(i, radius, count, shift=True), statistics) for i in run}
        got.update({i: host(h.result()) if on_device else h.result() for i, h in handles.items()})
        worker.evict(run[-1] + 1 - 2 * radius)
    worker.close()
    assert sorted(got) == list(range(count))
    if statistics:
        for i in range(count):
            (got[i], stats), (expected[i], opencv) = got[i], expected[i]
            assert stats.shape == opencv.shape == (len(STATISTICS), 48, 64) and stats.dtype == np.float32
            np.testing.assert_allclose(stats[:2], opencv[:2], rtol=1e-4, atol=1e-5)
            merged = np.abs(stats[2:] - opencv[2:])  # a pixel at the frame's edge may keep or drop a neighbour
            assert merged.mean() < 2e-3 and np.quantile(merged, 0.995) < 0.02, (i, merged.max())
        assert np.median(opencv_stats(box, 3)[1]) > 1.5 and opencv_stats(box, 3)[2].min() < 1  # a pan; cut windows
    for i in range(count):
        assert got[i].shape == expected[i].shape and got[i].dtype == np.float32 and np.isfinite(got[i]).all()
        difference = np.abs(got[i] - expected[i])
        assert difference.mean() < 1e-4 and np.quantile(difference, 0.999) < 2e-3, (i, difference.max())
    assert worker.busy_seconds > 0 and set(worker._images) == set(range(count - 2 * radius - 1, count)) - set(
        range(0, 16 + 1 - 2 * radius))


def opencv_stats(box: AlignedBox, i: int) -> np.ndarray:
    return box.mean(i, aligned_window(i, 3, 17, shift=True), statistics=True)[1]


def test_reflected_border_is_opencvs_default_for_any_size():
    import cv2

    for size, pad in ((1, 3), (2, 6), (5, 6), (13, 6)):
        expected = [cv2.borderInterpolate(p, size, cv2.BORDER_REFLECT_101) for p in range(-pad, size + pad)]
        assert _reflect_101(size, pad) == expected, (size, pad)


def test_black_and_saturated_frames_stay_finite():
    config = AlignedBoxConfig.for_frames(10)
    worker = BatchedAlignedWorker(config, "cpu", workers=1)
    frames = [np.zeros((16, 24), np.float32), np.ones((16, 24), np.float32), np.full((16, 24), np.nan, np.float32)]
    for k, frame in enumerate(frames):
        worker.add(k, frame)
    means = [worker.mean(i, range(3)).result() for i in range(3)]
    alone = worker.mean(1, [1]).result()  # a window of one frame (a clip of one): the frame itself
    worker.close()
    assert all(np.isfinite(m).all() and (m >= 0).all() and (m <= 1).all() for m in means)
    assert np.array_equal(alone, np.ones((16, 24), np.float32))


@pytest.mark.parametrize("evidence, on_device", [(False, False), (True, False), (True, True)])
def test_the_engine_with_batched_means_gives_the_frames_of_the_opencv_means(monkeypatch, evidence, on_device):
    """What a GPU runs, forced onto the CPU: batched aligned means (with their statistics for a model that reads
    them; kept on the device, as a GPU run keeps them, with ``on_device``) and batched passes of the network give
    the frames of the plain run to the means' precision."""
    import rmbvideo.recon.rmbnet as engine_module
    from tests.test_rmbnet_stream import aligned_model_and_stream, split, stream

    model, data = aligned_model_and_stream(8, evidence)
    plain, _ = stream(model, [data], threads=1)
    monkeypatch.setattr(engine_module, "aligned_worker_for",
                        lambda device, config, workers: BatchedAlignedWorker(config, device, 2, on_device))
    batched, engine = stream(model, split(data, 45), threads=1, frame_batch=8)
    assert isinstance(engine._aligned_box, BatchedAlignedWorker) and engine.stage_seconds["aligned mean"] > 0
    assert engine._aligned_box.on_device == on_device
    assert [f.index for f in batched] == [f.index for f in plain]
    images, reference = np.stack([f.image for f in batched]), np.stack([f.image for f in plain])
    assert np.isfinite(images).all()
    relative = np.abs(images - reference) / np.maximum(reference, 1e-3)  # random frames: the flows are noise, and
    assert relative.mean() < 1e-3 and np.quantile(relative, 0.99) < 5e-3  # a rounded position moves a mean most
    short = split(data, 45)[0]
    short = type(short)(short.single[:25], short.multi[:25], short.multi_rows[:25], 0, short.rate_hz)
    monkeypatch.undo()
    two, _ = stream(model, [short], threads=1)  # a clip of two frames, shorter than any window
    monkeypatch.setattr(engine_module, "aligned_worker_for",
                        lambda device, config, workers: BatchedAlignedWorker(config, device, 2, on_device))
    batched_two, _ = stream(model, [short], threads=1, frame_batch=8)
    assert [f.index for f in batched_two] == [f.index for f in two] == [0, 1]
    np.testing.assert_allclose(np.stack([f.image for f in batched_two]), np.stack([f.image for f in two]),
                               rtol=5e-3, atol=1e-4)


def test_means_kept_on_the_device_are_read_as_the_host_means_are():
    """``network_input_on_device`` is ``network_input`` on tensors, bit for bit: one mean or two, statistics or none."""
    rng = np.random.default_rng(5)
    statistics = rng.random((len(STATISTICS), 6, 7), dtype=np.float32)
    for mean in (rng.random((6, 7), dtype=np.float32), rng.random((2, 6, 7), dtype=np.float32)):
        for stats in (None, statistics):
            expected = network_input(mean, stats, 160.0)
            got = network_input_on_device(torch.from_numpy(mean), None if stats is None else torch.from_numpy(stats),
                                          160.0)
            assert got.dtype == torch.float32 and np.array_equal(got.numpy(), expected)

"""The motion-compensated window mean (``recon.aligned_box``): it averages where frames agree, follows
motion, drops evidence the flow maps outside the frame, and stays finite on black and saturated input."""

from __future__ import annotations

import numpy as np
import pytest

from rmbvideo.recon.aligned_box import (STATISTICS, AlignedBox, AlignedBoxConfig, _white, aligned_means,
                                        aligned_window, network_input)

H, W = 48, 64


def texture(seed: int = 0, size: tuple[int, int] = (H, W + 40)) -> np.ndarray:
    """A smooth random texture of rates in [0.1, 0.7] (flow needs structure at a few pixels' scale)."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.random(size).astype(np.float32), (0, 0), 2.0)
    noise = (noise - noise.min()) / (noise.max() - noise.min())
    return (0.1 + 0.6 * noise).astype(np.float32)


def noisy(rate: np.ndarray, rng: np.random.Generator, trials: int = 80) -> np.ndarray:
    """A frame's measured rate: binomial counts over ``trials`` raw pixel-planes."""
    return (rng.binomial(trials, rate) / trials).astype(np.float32)


def test_static_frames_average_like_the_plain_window():
    clean = texture()[:, :W]
    rng = np.random.default_rng(1)
    frames = np.stack([noisy(clean, rng) for _ in range(7)])
    out = aligned_means(frames, 3)[3]
    plain = frames.mean(axis=0)
    single_error = np.abs(frames[3] - clean).mean()
    assert np.abs(out - clean).mean() < 0.6 * single_error  # 7 frames of evidence, not 1
    assert np.abs(out - plain).mean() < 0.25 * single_error


def test_moving_texture_is_followed_not_blurred():
    wide = texture(2)
    speed = 3  # pixels per frame
    rng = np.random.default_rng(3)
    clean = [wide[:, 20 + speed * (k - 3): 20 + speed * (k - 3) + W] for k in range(7)]
    frames = np.stack([noisy(c, rng) for c in clean])
    out = aligned_means(frames, 3)[3]
    inner = (slice(6, -6), slice(12, -12))
    aligned_error = np.abs(out - clean[3])[inner].mean()
    assert aligned_error < 0.7 * np.abs(frames[3] - clean[3])[inner].mean()  # better than the frame alone
    assert aligned_error < 0.5 * np.abs(frames.mean(axis=0) - clean[3])[inner].mean()  # and than the blur


def test_statistics_say_where_the_mean_can_be_trusted():
    """``mean(statistics=True)``: the same mean, and per pixel the flow's gradient and magnitude, the robust test's
    support and the neighbours' spread. Two halves panned apart: a flow of their speed, smooth inside each half and
    steep where they meet, every neighbour kept inside them; a neighbour of other content: fewer kept, more spread."""
    left, right = texture(4), texture(5)
    speed, rng = 2, np.random.default_rng(6)
    clean = [np.concatenate([left[:, 20 + speed * (k - 3): 52 + speed * (k - 3)],
                             right[:, 40 - speed * (k - 3): 72 - speed * (k - 3)]], axis=1) for k in range(7)]
    box = AlignedBox(AlignedBoxConfig())
    for k, frame in enumerate(clean):
        box.add(k, noisy(frame, rng))
    mean, stats = box.mean(3, range(7), statistics=True)
    assert np.array_equal(mean, box.mean(3, range(7))) and stats.shape == (len(STATISTICS), H, W)
    assert stats.dtype == np.float32 and np.isfinite(stats).all()
    roughness, magnitude, support, spread = stats
    halves, seam = (slice(8, -8), np.r_[8:22, 42:56]), (slice(8, -8), slice(28, 36))
    assert abs(np.median(magnitude[halves]) - speed) < 0.3
    assert np.median(roughness[halves]) < 0.05 and np.median(roughness[seam]) > 2 * np.median(roughness[halves])
    assert np.median(support[halves]) > 0.95 and 0 < support.min() and support.max() <= 1
    other = AlignedBox(AlignedBoxConfig())
    for k, frame in enumerate(clean):
        other.add(k, noisy(texture(9)[:, :W] if k == 4 else frame, rng))
    _, mixed = other.mean(3, range(7), statistics=True)
    assert np.median(mixed[2][halves]) < np.median(support[halves]) - 0.05
    assert np.median(mixed[3][halves]) > np.median(spread[halves])


def test_statistics_of_a_clip_read_only_its_windows_flows_and_join_the_means_as_the_network_reads_them():
    """``aligned_means(statistics=True)``: each frame's statistics, the same whatever flows an earlier mean left
    cached (a window's own flows only: the last frame has no flow to a next one); ``network_input``: the means as
    sums, then the statistics unscaled."""
    rng = np.random.default_rng(8)
    frames = np.stack([noisy(texture(3)[:, 2 * k: 2 * k + W], rng) for k in range(6)])
    means, stats = aligned_means(frames, 2, statistics=True)
    assert np.array_equal(means, aligned_means(frames, 2)) and stats.shape == (6, len(STATISTICS), H, W)
    box = AlignedBox()
    for k, frame in enumerate(frames):
        box.add(k, frame)
    box.mean(3, range(1, 6))  # caches the flows from 3 to 4 and 4 to 5
    _, late = box.mean(5, range(3, 6), statistics=True)
    fresh = AlignedBox()
    for k, frame in enumerate(frames):
        fresh.add(k, frame)
    np.testing.assert_array_equal(late, fresh.mean(5, range(3, 6), statistics=True)[1])
    assert np.median(late[1]) > 1.5  # the pan's 2 px a frame, from the flow into the last frame
    alone, lone = box.mean(2, [2], statistics=True)  # a window of one frame: the frame, no flow, all kept, no spread
    assert np.array_equal(alone, frames[2]) and not lone[:2].any() and (lone[2] == 1).all() and not lone[3].any()
    joined = network_input(means[0], stats[0], 80.0)
    assert joined.shape == (1 + len(STATISTICS), H, W) and joined.dtype == np.float32
    np.testing.assert_allclose(joined[0], means[0] * 80.0, rtol=1e-6)
    np.testing.assert_array_equal(joined[1:], stats[0])
    assert np.array_equal(network_input(means[0], None, 80.0), means[0] * np.float32(80.0))


def test_window_cut_at_the_ends_and_neighbours_only_where_they_exist():
    clean = texture(4)[:, :W]
    rng = np.random.default_rng(5)
    frames = np.stack([noisy(clean, rng) for _ in range(5)])
    means = aligned_means(frames, 3)
    assert means.shape == frames.shape and np.isfinite(means).all()
    box = AlignedBox()
    for k, frame in enumerate(frames):
        box.add(k, frame)
    np.testing.assert_allclose(means[0], box.mean(0, range(0, 4)), rtol=1e-6)
    np.testing.assert_array_equal(box.mean(2, [2]), frames[2])  # no neighbours: the frame itself
    box.evict(2)
    with pytest.raises(KeyError):
        box.mean(1, [0, 1])


@pytest.mark.parametrize("level", [0.0, 1.0])
def test_black_and_saturated_frames_stay_finite_and_exact(level):
    frames = np.full((7, H, W), level, np.float32)
    frames[2, 0, 0] = np.nan  # a non-finite input pixel counts as 0
    means = aligned_means(frames, 3)
    assert np.isfinite(means).all() and (means >= 0).all() and (means <= 1).all()
    np.testing.assert_allclose(means[:, 5:, 5:], level, atol=1e-6)


def test_config_is_checked():
    with pytest.raises(ValueError, match="preset"):
        AlignedBoxConfig(preset="slow")
    with pytest.raises(ValueError, match="positive"):
        AlignedBoxConfig(tau=0.0)
    with pytest.raises(ValueError, match="stride"):
        AlignedBoxConfig(patch_stride=0)


def test_flow_settings_reach_dis_and_white_is_the_high_order_statistic():
    box = AlignedBox(AlignedBoxConfig(patch_stride=5, descent_iterations=7, refinement_iterations=1))
    dis = box._dis()
    settings = dis.getPatchStride(), dis.getGradientDescentIterations(), dis.getVariationalRefinementIterations()
    assert settings == (5, 7, 1)
    assert AlignedBox()._dis().getPatchStride() == 4
    rng = np.random.default_rng(3)
    image = rng.random((H, W)).astype(np.float32)
    ordered = np.sort(image.ravel())
    k = int(0.995 * (image.size - 1))
    assert _white(image) == ordered[k]  # the order statistic just below np.percentile's interpolated value
    assert ordered[k] <= np.percentile(image, 99.5) <= ordered[k + 1]
    assert _white(np.zeros((H, W), np.float32)) == 0.0


def test_aligned_window_is_cut_or_slides_inwards_at_the_clip_ends():
    assert list(aligned_window(5, 2, 20)) == [3, 4, 5, 6, 7]
    assert list(aligned_window(0, 2, 20)) == [0, 1, 2]
    assert list(aligned_window(0, 2, 20, shift=True)) == [0, 1, 2, 3, 4]
    assert list(aligned_window(19, 2, 20, shift=True)) == [15, 16, 17, 18, 19]
    assert list(aligned_window(19, 2, 20)) == [17, 18, 19]
    assert list(aligned_window(1, 2, 3, shift=True)) == [0, 1, 2]  # a clip shorter than the window
    assert list(aligned_window(1, 2, None, shift=True)) == [0, 1, 2, 3, 4]  # the end not known yet
    assert list(aligned_window(9, 2, None, shift=True)) == [7, 8, 9, 10, 11]
    with pytest.raises(ValueError, match="radius"):
        aligned_window(0, -1, 5)


def test_composed_flows_follow_motion_beyond_the_next_frame():
    """A texture panned 1 px a frame: the mean over radius 4 (flows composed over up to 4 steps) matches
    the clean reference better than the frame alone, as the radius-1 mean does, and better than it."""
    clean = texture(5, (H, W + 20))
    rng = np.random.default_rng(2)
    frames = np.stack([noisy(clean[:, k : k + W], rng) for k in range(9)])
    ref = clean[:, 4 : 4 + W]
    inner = (slice(6, -6), slice(12, -12))

    def error(image: np.ndarray) -> float:
        return float(np.abs(image - ref)[inner].mean())

    wide, narrow = aligned_means(frames, 4)[4], aligned_means(frames, 1)[4]
    assert error(wide) < error(narrow) < error(frames[4])


def test_sharp_images_follow_the_same_flows_and_are_merged_by_their_own_test():
    """Sharp images (a frame's central readouts) are moved by the flows of the whole-frame rates: a sharp
    image equal to the rate (and as many trials) gives the same mean, and a noisier one is averaged towards the clean reference."""
    clean = texture(7, (H, W + 20))
    rng = np.random.default_rng(3)
    frames = np.stack([noisy(clean[:, k : k + W], rng) for k in range(7)])
    both = aligned_means(frames, 3, AlignedBoxConfig(sharp_trials=80), sharp=frames)
    assert both.shape == (7, 2, H, W)
    np.testing.assert_array_equal(both[:, 1], aligned_means(frames, 3))
    np.testing.assert_array_equal(both[:, 0], both[:, 1])
    sharp = np.stack([noisy(clean[:, k : k + W], rng, trials=16) for k in range(7)])
    merged = aligned_means(frames, 3, AlignedBoxConfig(sharp_trials=16), sharp=sharp)[3, 1]
    inner = (slice(6, -6), slice(12, -12))
    ref = clean[:, 3 : 3 + W]
    assert np.abs(merged - ref)[inner].mean() < 0.6 * np.abs(sharp[3] - ref)[inner].mean()


def test_config_for_frames_counts_the_trials_of_whole_frames_and_sharp_images():
    config = AlignedBoxConfig.for_frames(10, 2)
    assert (config.trials, config.sharp_trials) == (80, 16) and AlignedBoxConfig.for_frames(4).trials == 32


@pytest.mark.parametrize("workers", [0, 1, 3])
def test_worker_gives_the_box_means_in_call_order_and_reports_a_failure_to_the_caller(workers):
    """Inline, one thread beside, or a pool: the box's means bit for bit (every flow and mean is a function of the
    frames alone, whichever thread makes it), and a failure reaches the caller."""
    from rmbvideo.recon.aligned_worker import AlignedWorker

    import cv2

    rng = np.random.default_rng(3)
    rates = rng.random((6, 24, 32)).astype(np.float32)
    cv_threads = cv2.getNumThreads()
    box, worker = AlignedBox(), AlignedWorker(AlignedBoxConfig(), workers=workers)
    assert cv2.getNumThreads() == (1 if workers >= 2 else cv_threads)  # a pool's threads each run OpenCV on one
    for k, rate in enumerate(rates):
        box.add(k, rate)
        worker.add(k, rate)
    queued = [worker.mean(i, aligned_window(i, 2, 6)) for i in range(6)]
    worker.evict(6)
    for i, handle in enumerate(queued):
        assert np.array_equal(handle.result(), box.mean(i, aligned_window(i, 2, 6)))
    with pytest.raises(KeyError):  # evicted: the error reaches the caller (inline: at once; beside: at result())
        worker.mean(2, [1, 2, 3]).result()
    assert worker.busy_seconds > 0
    worker.close()
    assert cv2.getNumThreads() == cv_threads

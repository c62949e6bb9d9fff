"""Metrics: known values, finiteness on degenerate frames, torch/NumPy SSIM agreement, PU21."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from rmbvideo.evaluate.metrics import (
    PSNR_CAP_DB,
    mu_law_psnr,
    mu_law_ssim,
    normalise_pair,
    psnr,
    pu21_encode,
    pu21_psnr,
    ssim,
    ssim_torch,
    temporal_mu_law_psnr,
)


def hdr_frame(seed: int, shape: tuple[int, int] = (32, 40)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.exp(rng.normal(0.0, 2.0, shape)).astype(np.float32)


def test_psnr_known_value_and_cap() -> None:
    assert psnr(np.full((4, 4), 0.5), np.full((4, 4), 0.6)) == pytest.approx(20.0)
    frame = hdr_frame(0)
    assert mu_law_psnr(frame, frame) == PSNR_CAP_DB
    assert mu_law_ssim(frame, frame) == pytest.approx(1.0)
    assert pu21_psnr(frame, frame) == PSNR_CAP_DB


def test_normalisation_uses_the_ground_truth_scale() -> None:
    gt = np.linspace(0.0, 2.0, 1001)
    pred, norm_gt = normalise_pair(gt * 3.0, gt, percentile=100.0)
    assert norm_gt.max() == pytest.approx(1.0) and pred.max() == 1.0
    # scale invariance: the metrics do not depend on the linear unit
    a, b = hdr_frame(1), hdr_frame(2)
    assert mu_law_psnr(a * 7.0, b * 7.0) == pytest.approx(mu_law_psnr(a, b))


def test_metrics_order_a_closer_prediction_higher() -> None:
    gt = hdr_frame(3)
    rng = np.random.default_rng(4)
    slight = gt * np.exp(rng.normal(0.0, 0.05, gt.shape))
    heavy = gt * np.exp(rng.normal(0.0, 0.8, gt.shape))
    assert mu_law_psnr(slight, gt) > mu_law_psnr(heavy, gt) + 5.0
    assert mu_law_ssim(slight, gt) > mu_law_ssim(heavy, gt) + 0.05
    assert pu21_psnr(slight, gt) > pu21_psnr(heavy, gt) + 5.0



def test_temporal_psnr_counts_what_changes_between_frames_not_a_steady_error() -> None:
    """A frame-to-frame flicker lowers the temporal score; the same error held still in every frame does not, though
    it costs the per-frame score; identical videos reach the cap; one frame has no pairs (NaN)."""
    rng = np.random.default_rng(5)
    truth = [hdr_frame(10) * (1.0 + 0.1 * k) for k in range(6)]
    steady_error = np.exp(rng.normal(0.0, 0.3, truth[0].shape))
    steady = [t * steady_error for t in truth]
    flicker = [t * np.exp(rng.normal(0.0, 0.3, t.shape)) for t in truth]
    assert temporal_mu_law_psnr(truth, truth) == PSNR_CAP_DB
    per_frame = [np.mean([mu_law_psnr(p, t) for p, t in zip(video, truth)]) for video in (steady, flicker)]
    assert abs(per_frame[0] - per_frame[1]) < 1.0  # the same error per frame ...
    assert temporal_mu_law_psnr(steady, truth) > temporal_mu_law_psnr(flicker, truth) + 10.0  # ... held still or not
    scaled = temporal_mu_law_psnr([f * 3 for f in flicker], [t * 3 for t in truth])
    assert scaled == pytest.approx(temporal_mu_law_psnr(flicker, truth))  # no dependence on the linear unit
    assert math.isnan(temporal_mu_law_psnr(truth[:1], truth[:1]))
    dark = [np.zeros((16, 16)), np.full((16, 16), np.nan), np.full((16, 16), np.inf)]
    assert math.isfinite(temporal_mu_law_psnr(dark, [np.zeros((16, 16))] * 3))
    with pytest.raises(ValueError, match="3 frames against 2"):
        temporal_mu_law_psnr(dark, dark[:2])


@pytest.mark.parametrize("pred_value", [0.0, 1.0, 1e30])
@pytest.mark.parametrize("gt_value", [0.0, 0.5, 1e30])
def test_metrics_finite_on_zero_constant_and_saturated_frames(pred_value: float, gt_value: float) -> None:
    pred = np.full((16, 16), pred_value, dtype=np.float32)
    gt = np.full((16, 16), gt_value, dtype=np.float32)
    for metric in (mu_law_psnr, mu_law_ssim, pu21_psnr):
        assert math.isfinite(metric(pred, gt))
    assert math.isfinite(mu_law_psnr(np.full((16, 16), np.nan), gt))


def test_ssim_torch_agrees_with_numpy_and_is_differentiable() -> None:
    rng = np.random.default_rng(5)
    a = rng.random((2, 24, 30))
    b = np.clip(a + rng.normal(0.0, 0.1, a.shape), 0.0, 1.0)
    expected = np.mean([ssim(a[k], b[k]) for k in range(2)])
    assert expected < 0.95
    x = torch.tensor(a, requires_grad=True)
    value = ssim_torch(x, torch.tensor(b))
    assert value.item() == pytest.approx(expected, abs=1e-6)
    value.backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
    with pytest.raises(ValueError):
        ssim(np.zeros((8, 8)), np.zeros((8, 8)))


def test_pu21_is_monotone_over_its_range() -> None:
    luminance = np.logspace(math.log10(0.005), 4, 500)
    encoded = pu21_encode(luminance)
    assert np.all(np.diff(encoded) > 0)
    assert abs(encoded[0]) < 1.0  # 0.005 cd/m^2 encodes to about 0
    assert 200.0 < pu21_encode(np.array(100.0)) < 300.0  # 100 cd/m^2 (SDR white) near 256
    assert pu21_encode(np.array(-1.0)) == encoded[0] and pu21_encode(np.array(1e9)) == encoded[-1]

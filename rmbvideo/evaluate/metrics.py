"""Image-quality metrics for linear HDR frames (paper Sec. 5.1, Table 2; DESIGN.md "Evaluation").

- ``mu_law_psnr`` / ``mu_law_ssim``: PSNR and SSIM on mu-law tone-mapped frames (paper Eqn. 13's
  T(G) = log(1 + mu G) / log(1 + mu)). Both frames are first divided by the same scale, a robust
  maximum of the *ground truth* (its ``percentile``-th percentile, 99.9 by default; its maximum when
  that percentile is 0; 1 for an all-zero ground truth) and clipped to [0, 1], so the ground truth
  spans the whole tone curve and the metrics do not depend on the linear unit.
- ``ssim`` (NumPy/OpenCV) and ``ssim_torch`` (differentiable, a training loss) are the same standard
  Gaussian-window SSIM (Wang et al. 2004: 11x11 window, sigma 1.5, K1 = 0.01, K2 = 0.03), computed on
  the "valid" region (pixels whose window lies inside the image), on values with a given data range.
- ``pu21_psnr``: PSNR on PU21-encoded absolute luminance (Mantiuk & Azimi 2021), standing in for the
  MATLAB-only HDR-VDP-3 / HDR-VQM of Table 2 as the perceptual HDR metric.
- ``temporal_mu_law_psnr``: PSNR of the mu-law frame-to-frame differences against the ground truth's, what a
  viewer sees as flicker, shimmer or a jumping source and a per-frame score barely counts.

PSNR of identical frames is capped at ``PSNR_CAP_DB`` (the mean squared error is floored), so every
metric is finite on all-zero, constant and saturated frames.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import cv2
import numpy as np

from rmbvideo.mulaw import mu_law

if TYPE_CHECKING:
    import torch

PSNR_CAP_DB = 100.0
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03

# PU21 "banding_glare" parameters p1..p7 (the recommended set), from the authors' reference code:
# gfxdisp/pu21, matlab/pu21_encoder.m ("The parameters were updated on 06/02/2020"):
# V = p7 * (((p1 + p2 * Y^p4) / (1 + p3 * Y^p4))^p5 - p6), for Y in cd/m^2 clamped to [0.005, 10000].
PU21_BANDING_GLARE = (0.353487901, 0.3734658629, 8.277049286e-05, 0.9062562627, 0.09150303166, 0.9099517204, 596.3148142)
PU21_MIN_LUMINANCE = 0.005
PU21_MAX_LUMINANCE = 10000.0


def robust_scale(gt: np.ndarray, percentile: float = 99.9) -> float:
    """The linear value mapped to 1 before tone mapping: a high percentile of ``gt`` (finite, > 0)."""
    values = np.asarray(gt, dtype=np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return 1.0
    scale = float(np.percentile(values, percentile))
    if scale <= 0.0:
        scale = float(values.max())
    return scale if scale > 0.0 else 1.0


def _normalised(frame: np.ndarray, scale: float) -> np.ndarray:
    """``frame / scale`` clipped to [0, 1]; NaN and -inf become 0, +inf 1."""
    array = np.nan_to_num(np.asarray(frame, dtype=np.float64), nan=0.0, posinf=scale, neginf=0.0)
    return np.clip(array / scale, 0.0, 1.0)


def normalise_pair(pred: np.ndarray, gt: np.ndarray, percentile: float = 99.9) -> tuple[np.ndarray, np.ndarray]:
    """Divide both frames by ``robust_scale(gt)`` and clip to [0, 1] (non-finite values become 0 or 1)."""
    scale = robust_scale(gt, percentile)
    return _normalised(pred, scale), _normalised(gt, scale)


def psnr(pred: np.ndarray, gt: np.ndarray, peak: float = 1.0) -> float:
    """PSNR in dB for a signal of the given peak; capped at ``PSNR_CAP_DB`` for identical inputs."""
    mse = float(np.mean((np.asarray(pred, dtype=np.float64) - np.asarray(gt, dtype=np.float64)) ** 2))
    floor = peak * peak * 10.0 ** (-PSNR_CAP_DB / 10.0)
    return 10.0 * math.log10(peak * peak / max(mse, floor))


def _check_ssim_size(shape: tuple[int, ...]) -> None:
    if shape[-1] < SSIM_WINDOW or shape[-2] < SSIM_WINDOW:
        raise ValueError(f"SSIM needs frames of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {shape[-2:]}")


def ssim(x: np.ndarray, y: np.ndarray, data_range: float = 1.0) -> float:
    """Mean Gaussian-window SSIM of two (H, W) images with values spanning ``data_range``."""
    a = np.asarray(x, dtype=np.float64)
    b = np.asarray(y, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"SSIM needs two (H, W) images of the same shape, got {a.shape} and {b.shape}")
    _check_ssim_size(a.shape)
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    r = SSIM_WINDOW // 2

    def blur(image: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(image, (SSIM_WINDOW, SSIM_WINDOW), SSIM_SIGMA)[r:-r, r:-r]

    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a * mu_a
    var_b = blur(b * b) - mu_b * mu_b
    cov = blur(a * b) - mu_a * mu_b
    ssim_map = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    return float(ssim_map.mean())


def _gaussian_window_torch(dtype: "torch.dtype", device: "torch.device") -> "torch.Tensor":
    import torch

    offsets = torch.arange(SSIM_WINDOW, dtype=torch.float64) - SSIM_WINDOW // 2
    kernel = torch.exp(-(offsets**2) / (2 * SSIM_SIGMA**2))
    kernel = kernel / kernel.sum()
    return torch.outer(kernel, kernel).to(dtype=dtype, device=device)[None, None]


def ssim_torch(x: "torch.Tensor", y: "torch.Tensor", data_range: float = 1.0) -> "torch.Tensor":
    """Differentiable mean SSIM of tensors shaped (H, W), (C, H, W) or (N, C, H, W); same as ``ssim``.

    Each channel is treated as a separate grey image; the result is the mean over all of them.
    """
    import torch.nn.functional as F

    if x.shape != y.shape or x.dim() < 2 or x.dim() > 4:
        raise ValueError(f"ssim_torch needs two tensors of the same 2-4D shape, got {tuple(x.shape)}, {tuple(y.shape)}")
    _check_ssim_size(tuple(x.shape))
    height, width = x.shape[-2:]
    a = x.reshape(-1, 1, height, width)
    b = y.reshape(-1, 1, height, width)
    window = _gaussian_window_torch(a.dtype, a.device)
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2

    def blur(image):
        return F.conv2d(image, window)

    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a * mu_a
    var_b = blur(b * b) - mu_b * mu_b
    cov = blur(a * b) - mu_a * mu_b
    ssim_map = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    return ssim_map.mean()


def mu_law_psnr(pred: np.ndarray, gt: np.ndarray, mu: float = 5000.0, percentile: float = 99.9) -> float:
    """PSNR (dB, peak 1) of the mu-law tone-mapped frames after ``normalise_pair``."""
    a, b = normalise_pair(pred, gt, percentile)
    return psnr(mu_law(a, mu), mu_law(b, mu), peak=1.0)


def temporal_mu_law_psnr(preds: Sequence[np.ndarray], gts: Sequence[np.ndarray], mu: float = 5000.0,
                         percentile: float = 99.9) -> float:
    """Mean over consecutive frame pairs of the PSNR (dB, peak 1) of the mu-law frame differences,
    T(pred_i) - T(pred_i-1) against T(gt_i) - T(gt_i-1), both frames of a pair divided by one scale (the
    ``robust_scale`` of the two ground-truth frames together) and clipped to [0, 1]. A constant error in every frame
    costs nothing here; an error that changes from frame to frame does. NaN for fewer than two frames."""
    if len(preds) != len(gts):
        raise ValueError(f"{len(preds)} frames against {len(gts)} ground-truth frames")
    scores = []
    for k in range(1, len(preds)):
        scale = robust_scale(np.stack([np.asarray(gts[k - 1]), np.asarray(gts[k])]), percentile)
        tone = [mu_law(_normalised(frame, scale), mu) for frame in (preds[k - 1], preds[k], gts[k - 1], gts[k])]
        scores.append(psnr(tone[1] - tone[0], tone[3] - tone[2], peak=1.0))
    return float(np.mean(scores)) if scores else math.nan


def mu_law_ssim(pred: np.ndarray, gt: np.ndarray, mu: float = 5000.0, percentile: float = 99.9) -> float:
    """SSIM of the mu-law tone-mapped frames after ``normalise_pair`` (data range 1)."""
    a, b = normalise_pair(pred, gt, percentile)
    return ssim(mu_law(a, mu), mu_law(b, mu), data_range=1.0)


def pu21_encode(luminance: np.ndarray) -> np.ndarray:
    """PU21 (banding + glare) encoding of absolute luminance in cd/m^2, clamped to [0.005, 10000]."""
    p1, p2, p3, p4, p5, p6, p7 = PU21_BANDING_GLARE
    y = np.clip(np.nan_to_num(np.asarray(luminance, dtype=np.float64), nan=0.0, posinf=PU21_MAX_LUMINANCE),
                PU21_MIN_LUMINANCE, PU21_MAX_LUMINANCE)
    y_p = y**p4
    return p7 * (((p1 + p2 * y_p) / (1.0 + p3 * y_p)) ** p5 - p6)


def pu21_psnr(pred: np.ndarray, gt: np.ndarray, peak_luminance: float = 4000.0, percentile: float = 99.9) -> float:
    """PSNR of PU21-encoded frames, peak = PU21(``peak_luminance``).

    Linear sensor units become cd/m^2 by one factor for both frames: the ground truth's robust max
    (``robust_scale``) maps to ``peak_luminance`` (4000 cd/m^2, a bright HDR display), so the scene's
    dynamic range is kept and its darkest parts fall towards PU21's 0.005 cd/m^2 floor.
    """
    if not 0.0 < peak_luminance <= PU21_MAX_LUMINANCE:
        raise ValueError(f"peak_luminance must be in (0, {PU21_MAX_LUMINANCE}], got {peak_luminance}")
    factor = peak_luminance / robust_scale(gt, percentile)
    encoded_pred = pu21_encode(np.asarray(pred, dtype=np.float64) * factor)
    encoded_gt = pu21_encode(np.asarray(gt, dtype=np.float64) * factor)
    return psnr(encoded_pred, encoded_gt, peak=float(pu21_encode(np.array(peak_luminance))))

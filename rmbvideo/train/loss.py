"""Training loss of RMB-Net (paper Eqn. 13) on mu-law tone-mapped frames.

L = beta_l2 L2(T(P), T(G)) + beta1 (1 - SSIM(T(P), T(G))) + beta_edge L1(grad T(P), grad T(G))
  + (beta_linear + beta_display d) |P - G|_1 / |G|_1 (per sample; d = 1 for display-referred samples)
  + beta_regional |B(P) - B(G)| / (B(G) + eps) (B: 8x8 block means)
  + beta_temporal L1(T(P_i) - T(P_i-1), T(G_i) - T(G_i-1)) (consecutive outputs; ``temporal_loss``),
with T(G) = log(1 + mu G) / log(1 + mu), mu = 5000. LPIPS (beta2 in the paper) needs pretrained
weights that cannot be downloaded here; the edge term (L1 between horizontal and vertical finite
differences) stands in for it as a cheap sharpness prior. The ground truth is clipped at
``saturation`` before tone mapping: above it (1 in the project's units, a pixel firing at every
readout) the sensor cannot tell radiances apart, so no model can learn them.

The regional term is there for tone bias: a pixel-wise L1 (or the mu-law domain) is minimised by the
median (or a log mean) of what the evidence allows, which at a few spikes per pixel sits well below
the mean; a block mean of 64 pixels is nearly Gaussian, so its L1 asks for the mean, relative to the
block's level so dark regions count as much as bright ones.

Display-referred samples (spikezoo's convention: the intensities are 8-bit video values, already
gamma-encoded for a viewer) are judged by their linear error, which the mu-law terms barely see in
bright regions: there a long box filter's motion blur of low-contrast texture costs little mu-law
error, and a model trained on the mu-law terms alone blurs real video's bright texture (measured:
200_part3, most of the blend's weight on 3- and 7-frame boxes over moving gravel). ``display_linear``
adds weight to their linear term.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from rmbvideo.evaluate.metrics import ssim_torch
from rmbvideo.mulaw import inverse_mu_law, mu_law


@dataclass(frozen=True)
class LossConfig:
    """Weights and constants of the loss: ``l2`` weighs the mu-law L2 (the evaluation's PSNR; at 1 its gradient is
    a small share of the whole for errors of a few hundredths), ``ssim`` is beta1, ``edge`` replaces LPIPS (0: off),
    ``linear`` weighs the relative linear-domain L1 (0: off), ``regional`` the relative L1 of 8x8 block
    means in linear units (0: off), ``display_linear`` the extra weight of the linear L1 on display-referred
    samples (0: off), ``temporal`` the L1 of consecutive frames' mu-law differences (0: off)."""

    mu: float = 5000.0
    l2: float = 1.0
    ssim: float = 1.0
    edge: float = 0.5
    saturation: float = 1.0
    linear: float = 0.0
    regional: float = 0.0
    display_linear: float = 0.0
    temporal: float = 0.0

#: Block size of the regional term and the floor of its denominator (the dark end of the targets).
REGION = 8
REGION_FLOOR = 1e-3


def tone_mapped_target(gt: torch.Tensor, config: LossConfig) -> torch.Tensor:
    """T(min(G, saturation)) of linear ground truth; non-finite values become 0."""
    clean = torch.nan_to_num(gt.float(), nan=0.0, posinf=0.0, neginf=0.0)
    return mu_law(clean.clamp(0.0, config.saturation), config.mu)


def _gradients(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    return x[..., :, 1:] - x[..., :, :-1], x[..., 1:, :] - x[..., :-1, :]


def reconstruction_loss(pred_t: torch.Tensor, gt: torch.Tensor, config: LossConfig,
                        display: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, float]]:
    """Loss of mu-law-domain predictions ``pred_t`` (B, H, W) against linear ``gt`` (B, H, W);
    ``display`` (B,): 1 for display-referred samples (spikezoo's convention), 0 (or None) for radiance.

    Returns the scalar loss and its parts as floats (``l2``, ``ssim`` = 1 - SSIM, ``edge``, ``linear``).
    """
    target = tone_mapped_target(gt, config)
    pred = pred_t.float()
    l2 = F.mse_loss(pred, target)
    ssim_term = 1.0 - ssim_torch(pred[:, None], target[:, None], data_range=1.0)
    total = config.l2 * l2 + config.ssim * ssim_term
    edge = torch.zeros((), device=pred.device)
    if config.edge > 0:
        gx_p, gy_p = _gradients(pred)
        gx_t, gy_t = _gradients(target)
        edge = F.l1_loss(gx_p, gx_t) + F.l1_loss(gy_p, gy_t)
        total = total + config.edge * edge
    linear = torch.zeros((), device=pred.device)
    regional = torch.zeros((), device=pred.device)
    weight_display = config.display_linear if display is not None else 0.0
    if config.linear > 0 or config.regional > 0 or weight_display > 0:  # linear-domain terms, vs the clipped truth
        truth = torch.nan_to_num(gt.float(), nan=0.0, posinf=0.0, neginf=0.0).clamp(0.0, config.saturation)
        guess = inverse_mu_law(pred, config.mu).clamp(max=config.saturation)
        if config.linear > 0 or weight_display > 0:
            scale = truth.flatten(1).mean(dim=1).clamp(min=1e-4)
            per_sample = (guess - truth).abs().flatten(1).mean(dim=1) / scale
            linear = per_sample.mean()
            total = total + config.linear * linear
            if display is not None and weight_display > 0:
                total = total + weight_display * (per_sample * display.to(per_sample.dtype)).mean()
        if config.regional > 0:
            block_p = F.avg_pool2d(guess[:, None], REGION, ceil_mode=True)
            block_g = F.avg_pool2d(truth[:, None], REGION, ceil_mode=True)
            regional = ((block_p - block_g).abs() / (block_g + REGION_FLOOR)).mean()
            total = total + config.regional * regional
    parts = {"l2": float(l2.detach()), "ssim": float(ssim_term.detach()), "edge": float(edge.detach()),
             "linear": float(linear.detach()), "regional": float(regional.detach())}
    return total, parts


def temporal_loss(pred_t: torch.Tensor, previous_t: torch.Tensor, gt: torch.Tensor, previous_gt: torch.Tensor,
                  config: LossConfig) -> torch.Tensor:
    """L1 between the mu-law change from the previous output to this one and the truth's change over the same
    frame step (B, H, W each). A frame that shows its neighbour's moment (a clip's edge frame averaged towards the
    inside, a ghost trailing a moving edge) changes too little and pays for it; the per-frame terms cannot see that,
    since the L2 optimum of a one-sided window is a blur towards the side that has evidence."""
    step_p = pred_t.float() - previous_t.float()
    step_g = tone_mapped_target(gt, config) - tone_mapped_target(previous_gt, config)
    return F.l1_loss(step_p, step_g)

"""Classical-candidate output of RMB-Net: the head weighs its own estimate against exact box filters.

Where the scene is bright and the spikes are many, the plain mean of the counts (TFP on the binned
stream) is already accurate to a fraction of a percent, and a network that re-derives it through
the mu-law output domain loses about 2 dB of linear PSNR to it (measured on spikezoo-convention
video). So the head also predicts per-pixel softmax weights over its own estimate and the box-filter
intensities of the reference frame, of each pooled window (valid frames only) and of each central
sub-window of the reference frame (``centre_windows``: its centre time, finer than N readouts); the
output is their weighted sum in linear units. It can pass an exact classical estimate through where that is
right (bright, or fast motion: the reference alone) and use its own where the counts are noisy.

Box-filter intensity from the mean multi-bit rate r per raw pixel-plane (bin count over its 8 trials):
- spikezoo's rate convention (accumulate and subtract): the intensity is r itself;
- a camera's reset-to-zero pixel: r = q / (1 + q/2) to within 1 % up to q = 0.5 (the charge wasted at
  each reset is half a plane's on average), so q = r / (1 - r/2); above that the response has
  plateaus (a pixel fires every 2nd plane over a range of charges) and the network's own estimate
  must do.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

#: Raw pixel-planes behind one binned multi-bit count (2 x 2 pixels x 2 planes).
BIN_TRIALS = 8  # = rmbvideo.sensor.binning.BIN_TRIALS (net/ imports torch and its siblings only; tested)
#: Initial logit of the network's own estimate (the box filters start at 0): a new blend head starts
#: close to the plain network's function.
OWN_LOGIT_INIT = 5.0
#: Initial logit of a central sub-window candidate: noisy, so a new one starts nearly unused.
CENTRE_LOGIT_INIT = -2.0
#: Rates above this are treated as this in the reset-to-zero inverse (it has a pole at r = 2).
_MAX_PHYSICAL_RATE = 0.98


def candidate_count(pooled_windows: Sequence[int], centre_windows: Sequence[int] = (), aligned: int = 0) -> int:
    """Box-filter candidates: the reference frame, each pooled window, each central sub-window and the
    ``aligned`` motion-compensated means (0, 1 or 2: the window's, and its central readouts')."""
    return 1 + len(pooled_windows) + len(centre_windows) + int(aligned)


def box_intensity(rate: torch.Tensor, convention: torch.Tensor | float) -> torch.Tensor:
    """Intensity (charge per raw plane / threshold) of mean rate ``rate`` under the sensor convention
    (0 = a camera's reset-to-zero pixel, 1 = spikezoo's rate convention; scalar or one per batch item)."""
    if isinstance(convention, (int, float)) and convention in (0, 1):  # one convention: no per-item mix
        return rate if convention == 1 else rate / (1.0 - 0.5 * rate.clamp(max=_MAX_PHYSICAL_RATE))
    code = torch.as_tensor(convention, dtype=rate.dtype, device=rate.device).reshape(-1, 1, 1, 1)
    physical = rate / (1.0 - 0.5 * rate.clamp(max=_MAX_PHYSICAL_RATE))
    return code * rate + (1.0 - code) * physical


def box_candidates(pooled: Sequence[torch.Tensor], level: int, convention: torch.Tensor | float,
                   centre: torch.Tensor | None = None, aligned: torch.Tensor | None = None) -> list[torch.Tensor]:
    """Box-filter intensities of the reference frame, of each pooled window, of each central
    sub-window and of the motion-compensated window mean, (B,1,Hp,Wp) each.

    ``pooled``: the reference frame's normalised multi-bit rate I_m/(level N), then its means over each
    pooled window (valid frames only), (B,1,Hp,Wp) each; ``centre``: the reference frame's central
    multi-bit rates I_c/(level k), (B,C,Hp,Wp), or None; ``aligned``: the aligned mean rates
    I_a/(level N), (B,A,Hp,Wp) (one candidate per channel), or None.
    """
    out = [box_intensity(rate.float() * (level / BIN_TRIALS), convention) for rate in pooled]
    if centre is not None:
        out += [box_intensity(c * (level / BIN_TRIALS), convention) for c in centre.float().split(1, dim=1)]
    if aligned is not None:
        out.append(box_intensity(aligned.float() * (level / BIN_TRIALS), convention))
    return out


def blend(own: torch.Tensor, candidates: Sequence[torch.Tensor], logits: torch.Tensor) -> torch.Tensor:
    """Per-pixel softmax(``logits``)-weighted sum of ``own`` and the ``candidates`` (linear units)."""
    weights = torch.softmax(logits.float(), dim=1)
    stacked = torch.cat([own.float(), *(c.float() for c in candidates)], dim=1)
    return (weights * stacked).sum(dim=1, keepdim=True)

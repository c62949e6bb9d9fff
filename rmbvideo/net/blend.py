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
- spikezoo's rate convention (accumulate and subtract; real cameras such as car.dat's): the intensity is r itself up
  to half a spike per plane; above, the inverse of the binned rate ``rate_convention_rate``, which the 3-bit clamp
  holds below the light (a bin of 8 spikes reads 7: a pixel firing every plane reads 7/8);
- a camera's reset-to-zero pixel of unknown response: q = r / (1 - r/2), the inverse of r = q / (1 + q/2) (the
  charge wasted at each reset is half a plane's on average), exact to about 1 % below half a threshold per
  plane; above that the response has a plateau and the network's own estimate must do. Smooth, whatever the
  camera: the default;
- the camera of rmbvideo's emission model (``tabulated=True``; ``rmbvideo.sensor.response``): the inverse of
  its measured response (``RESET_TO_ZERO_RATES``), piecewise linear. It has a plateau (every 2nd plane from
  about 0.6 to 0.8 of a threshold per plane) and then rises to the bin's ceiling of 7 of 8 near 1.3, where the
  closed form reads 0.9 as 0.77 and 0.95 as 0.87. Only for streams that model made: on a real camera whose
  response differs it draws contours across smooth bright surfaces (the inverse is steep in the plateau).
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
#: Rates above this are treated as this in the closed-form reset-to-zero inverse (it has a pole at r = 2).
_MAX_PHYSICAL_RATE = 0.98
#: Cells of the inverse's uniform lookup over the rates: each narrower than the table's closest knots (1.6e-4).
_LOOKUP_CELLS = 8192
#: Charge per raw plane (in firing thresholds) of the tabulated response: 0, 0.025, ..., 1.3.
RESET_TO_ZERO_STEP = 0.025
#: Mean binned rate per raw pixel-plane of a camera's reset-to-zero pixel at each level k * RESET_TO_ZERO_STEP,
#: measured on the emission model with a real camera's noise (``rmbvideo.sensor.response.tabulated_response``;
#: level 0 is dark); strictly increasing, so it inverts. Above 1.3 the bin fires 7 times in 8 whatever the light.
RESET_TO_ZERO_RATES = (
    0.0, 0.02476, 0.04890, 0.07247, 0.09546, 0.11791, 0.13984, 0.16127, 0.18224, 0.20253, 0.22295, 0.24248,
    0.25977, 0.27986, 0.30242, 0.32073, 0.33234, 0.34190, 0.35562, 0.37668, 0.40426, 0.43391, 0.46011, 0.47912,
    0.49055, 0.49630, 0.49880, 0.49980, 0.50032, 0.50092, 0.50202, 0.50403, 0.50754, 0.51335, 0.52229, 0.53537,
    0.55345, 0.57712, 0.60672, 0.64164, 0.68061, 0.72110, 0.76042, 0.79542, 0.82368, 0.84452, 0.85833, 0.86663,
    0.87115, 0.87336, 0.87435, 0.87476, 0.87492,
)


#: The binned mean rate's ceiling: a bin of 8 spikes is clamped to 7 (``MULTI_LEVEL``), so no rate reads above 7/8.
CLAMPED_CEILING = 1.0 - 1.0 / BIN_TRIALS
#: Cells of the rate convention's tabulated inverse, uniform in the binned rate from 0 to ``CLAMPED_CEILING``.
_RATE_INVERSE_CELLS = 4096


def rate_convention_rate(light: torch.Tensor) -> torch.Tensor:
    """Mean binned rate (clamped count / 8) of a rate-convention pixel of ``light`` spikes per raw plane (<= 1).

    Such a pixel fires at regular intervals, so it fires in both planes of a pair a fraction max(0, 2 light - 1) of
    the time; with the four pixels of a bin at independent phases all eight fire with probability (2 light - 1)^4,
    and the clamp takes one spike off each such bin. Exact for spikezoo's pixel and within 0.002 of a noisy camera's
    pixel reset by subtraction (``tests/test_response.py``)."""
    light = light.clamp(0.0, 1.0)
    return light - (2.0 * light - 1.0).clamp(min=0.0) ** 4 / BIN_TRIALS


def rate_convention_intensity(rate: torch.Tensor) -> torch.Tensor:
    """Light (spikes per raw plane) of a rate-convention pixel with mean binned rate ``rate``: the rate itself up to
    a half, then the inverse of ``rate_convention_rate`` (tabulated, linear between cells), so a pixel that fires
    every plane (every bin clamped to 7) reads 1, not 7/8. Rates at or above the ceiling read 1."""
    table = _rate_inverse_table(rate.device)
    r = rate.float().clamp(0.0, CLAMPED_CEILING)
    position = (r * (_RATE_INVERSE_CELLS / CLAMPED_CEILING)).reshape(-1)
    cell = position.long().clamp_(0, _RATE_INVERSE_CELLS - 1)
    low, high = torch.index_select(table, 0, cell), torch.index_select(table, 0, cell + 1)
    inverted = (low + (position - cell.float()) * (high - low)).view(r.shape)
    return torch.where(r > 0.5, inverted, r).to(rate.dtype)


def _rate_inverse_table(device: torch.device) -> torch.Tensor:
    """The light at each cell edge of the binned rates 0 .. ``CLAMPED_CEILING``, by bisection in float64 (made once)."""
    if device not in _RATE_INVERSES:
        target = torch.linspace(0.0, CLAMPED_CEILING, _RATE_INVERSE_CELLS + 1, dtype=torch.float64)
        low, high = torch.zeros_like(target), torch.ones_like(target)
        for _ in range(60):  # the rate rises monotonically from 0 to the ceiling as the light goes from 0 to 1
            middle = 0.5 * (low + high)
            below = rate_convention_rate(middle) < target
            low, high = torch.where(below, middle, low), torch.where(below, high, middle)
        _RATE_INVERSES[device] = (0.5 * (low + high)).float().to(device)
    return _RATE_INVERSES[device]


_RATE_INVERSES: dict[torch.device, torch.Tensor] = {}


def candidate_count(pooled_windows: Sequence[int], centre_windows: Sequence[int] = (), aligned: int = 0) -> int:
    """Box-filter candidates: the reference frame, each pooled window, each central sub-window and the
    ``aligned`` motion-compensated means (0, 1 or 2: the window's, and its central readouts')."""
    return 1 + len(pooled_windows) + len(centre_windows) + int(aligned)


def reset_to_zero_intensity(rate: torch.Tensor) -> torch.Tensor:
    """Charge per raw plane (in thresholds) of a reset-to-zero pixel with mean binned rate ``rate``: the tabulated
    response inverted piecewise linearly, float32; rates past the table's ends read its end levels (0 and 1.3).
    The segment comes from a uniform lookup over the rates (2.4x faster than ``torch.searchsorted`` on a CPU), and
    every lookup is an ``index_select`` on the flattened rates (1.9x faster than indexing with a tensor, the same
    values: this runs for each of a frame's seven box candidates)."""
    table, segment = _inverse_lookup(rate.device)
    last = len(RESET_TO_ZERO_RATES) - 2
    r = rate.float().clamp(0.0, RESET_TO_ZERO_RATES[-1])
    flat = r.reshape(-1)
    cell = (flat * (_LOOKUP_CELLS / RESET_TO_ZERO_RATES[-1])).long().clamp_(0, _LOOKUP_CELLS - 1)
    j = torch.index_select(segment, 0, cell)
    # a cell holds at most one knot, and rounding may put r one cell off: one step up or down finds its segment
    above = flat >= torch.index_select(table, 0, (j + 1).clamp_(max=last + 1))
    below = flat < torch.index_select(table, 0, j)
    j = (j + above.long() - below.long()).clamp_(0, last)
    low, high = torch.index_select(table, 0, j), torch.index_select(table, 0, j + 1)
    return ((j.float() + (flat - low) / (high - low)) * RESET_TO_ZERO_STEP).view(r.shape)


def _inverse_lookup(device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """The table on ``device`` and, per lookup cell of the rates, the segment its left edge lies in (made once)."""
    if device not in _LOOKUPS:
        table = torch.tensor(RESET_TO_ZERO_RATES, dtype=torch.float64)
        edges = torch.arange(_LOOKUP_CELLS, dtype=torch.float64) * (RESET_TO_ZERO_RATES[-1] / _LOOKUP_CELLS)
        segment = (torch.searchsorted(table, edges, right=True) - 1).clamp(0, len(RESET_TO_ZERO_RATES) - 2)
        _LOOKUPS[device] = (table.float().to(device), segment.to(device))
    return _LOOKUPS[device]


_LOOKUPS: dict[torch.device, tuple[torch.Tensor, torch.Tensor]] = {}


def box_intensity(rate: torch.Tensor, convention: torch.Tensor | float, tabulated: bool = False) -> torch.Tensor:
    """Intensity (charge per raw plane / threshold) of mean rate ``rate`` under the sensor convention
    (0 = a camera's reset-to-zero pixel, 1 = spikezoo's rate convention; scalar or one per batch item); a camera's
    by the closed form, or by the emission model's tabulated response when ``tabulated``."""
    if isinstance(convention, (int, float)) and convention == 1:
        return rate_convention_intensity(rate)
    physical = (reset_to_zero_intensity(rate).to(rate.dtype) if tabulated
                else rate / (1.0 - 0.5 * rate.clamp(max=_MAX_PHYSICAL_RATE)))
    if isinstance(convention, (int, float)) and convention == 0:  # one convention: no per-item mix
        return physical
    code = torch.as_tensor(convention, dtype=rate.dtype, device=rate.device).reshape(-1, 1, 1, 1)
    return code * rate_convention_intensity(rate) + (1.0 - code) * physical


def box_candidates(pooled: Sequence[torch.Tensor], level: int, convention: torch.Tensor | float,
                   centre: torch.Tensor | None = None, aligned: torch.Tensor | None = None,
                   tabulated: bool = False) -> list[torch.Tensor]:
    """Box-filter intensities of the reference frame, of each pooled window, of each central
    sub-window and of the motion-compensated window mean, (B,1,Hp,Wp) each.

    ``pooled``: the reference frame's normalised multi-bit rate I_m/(level N), then its means over each
    pooled window (valid frames only), (B,1,Hp,Wp) each; ``centre``: the reference frame's central
    multi-bit rates I_c/(level k), (B,C,Hp,Wp), or None; ``aligned``: the aligned mean rates
    I_a/(level N), (B,A,Hp,Wp) (one candidate per channel), or None. ``tabulated``: see ``box_intensity``.
    """
    out = [box_intensity(rate.float() * (level / BIN_TRIALS), convention, tabulated) for rate in pooled]
    if centre is not None:
        out += [box_intensity(c * (level / BIN_TRIALS), convention, tabulated) for c in centre.float().split(1, dim=1)]
    if aligned is not None:
        out.append(box_intensity(aligned.float() * (level / BIN_TRIALS), convention, tabulated))
    return out


def blend(own: torch.Tensor, candidates: Sequence[torch.Tensor], logits: torch.Tensor) -> torch.Tensor:
    """Per-pixel softmax(``logits``)-weighted sum of ``own`` and the ``candidates`` (linear units)."""
    weights = torch.softmax(logits.float(), dim=1)
    stacked = torch.cat([own.float(), *(c.float() for c in candidates)], dim=1)
    return (weights * stacked).sum(dim=1, keepdim=True)

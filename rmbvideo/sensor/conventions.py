"""The sensor conventions a spike stream can come from.

"physical": a real camera's pixel (``emission.SpikeEmitter``: charge reset to zero at a spike, the
camera's noise). "spikezoo": the rate convention of simulators such as spikezoo's
(``emission.RateIntegrateFire``: accumulate and subtract, no noise). The same spikes mean different
intensities under the two, so a network is told which one made a stream (its index here).

A capture shows which: a pixel reset to zero at a spike fires every second plane for every light from about 0.6
to 0.8 of its threshold per plane, so its spike counts pile up at exactly half the planes; a pixel that keeps the
charge past its threshold (the rate convention; real spiking cameras such as the one behind ``car.dat``) does not
(``convention_from_spikes``).
"""

from collections.abc import Iterable

import numpy as np

CONVENTIONS = ("physical", "spikezoo")
#: Planes per window of the pile-up test, the windows read from a capture's start (200 planes), and the
#: pixel-windows near half of them it needs to decide.
PILE_UP_WINDOW = 40
PILE_UP_WINDOWS = 5
PILE_UP_EVIDENCE = 1000
#: Pixel-windows at exactly half the planes over the mean of their two neighbours (19 and 21 of 40): the
#: emission model's pixel reads about 6 on a ramp of light, the rate convention about 1 (``car.dat`` 0.99).
PILE_UP_PHYSICAL, PILE_UP_RATE = 2.0, 1.5

#: How a camera's rates are read back as light where the model reads them exactly (the blend's box candidates,
#: ``rmbvideo.net.blend``): "closed-form" for any camera (r / (1 - r/2): smooth, biased above half a threshold per
#: plane), "emission-model" for streams rmbvideo's emission model made (its tabulated response, exact there).
RESPONSES = ("closed-form", "emission-model")
#: The effects that shape the emission model's tabulated response (with them, the demo's three effects and all six
#: of a real camera give the same rates to 1e-4 up to 0.9 of a threshold per plane; without, it is a bare staircase).
RESPONSE_EFFECTS = ("shot_noise", "threshold_mismatch")


def response_for(effects: tuple[str, ...] | None) -> str:
    """The reading for a stream the emission model made with ``effects`` ("emission-model" when they shape its
    tabulated response), or for a camera of unknown response (``effects`` None: "closed-form")."""
    return "emission-model" if effects is not None and set(RESPONSE_EFFECTS) <= set(effects) else "closed-form"


def convention_from_spikes(windows: Iterable[np.ndarray]) -> str | None:
    """The convention a camera's raw 1-bit planes show: ``windows`` of ``PILE_UP_WINDOW`` planes each (T, H, W);
    "physical" where the pixels' spike counts pile up at half the planes, "spikezoo" where they do not, None when
    too few pixel-windows lie near half to tell (a dark scene) or the pile-up is in between."""
    counts = np.zeros(PILE_UP_WINDOW + 1, dtype=np.int64)
    for planes in windows:
        if len(planes) != PILE_UP_WINDOW:
            raise ValueError(f"windows must hold {PILE_UP_WINDOW} planes, got {len(planes)}")
        counts += np.bincount(planes.sum(axis=0, dtype=np.int16).ravel(), minlength=PILE_UP_WINDOW + 1)
    half = PILE_UP_WINDOW // 2
    below, at, above = counts[half - 1 : half + 2]
    if below + at + above < PILE_UP_EVIDENCE:
        return None
    pile_up = at / max((below + above) / 2, 1)
    return "physical" if pile_up >= PILE_UP_PHYSICAL else "spikezoo" if pile_up <= PILE_UP_RATE else None

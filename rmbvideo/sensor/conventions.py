"""The sensor conventions a spike stream can come from.

"physical": a real camera's pixel (``emission.SpikeEmitter``: charge reset to zero at a spike, the
camera's noise). "spikezoo": the rate convention of simulators such as spikezoo's
(``emission.RateIntegrateFire``: accumulate and subtract, no noise). The same spikes mean different
intensities under the two, so a network is told which one made a stream (its index here).
"""

CONVENTIONS = ("physical", "spikezoo")

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

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

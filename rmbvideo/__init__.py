"""rmbvideo: HDR, high-frame-rate video from spiking-camera captures.

The package is laid out along the data flow:

- ``rmbvideo.io``       reading/writing ``.dat`` spike streams and frame outputs (MP4, EXR, PNG)
- ``rmbvideo.sensor``   sensor physics: 2x2x2 binning, RMB readout, emission simulator, theory
- ``rmbvideo.scenes``   HDR scenes rendered at any time, with exact ground truth
- ``rmbvideo.recon``    streaming reconstruction: preliminary frames, classical methods, tone mapping
- ``rmbvideo.net``      RMB-Net (encoders, cross-bit/cross-time attention, ConvLSTM decoder)
- ``rmbvideo.train``    training data and the training loop
- ``rmbvideo.evaluate`` metrics, baselines and the evaluation table
- ``rmbvideo.bench``    benchmarks (what accuracy costs in time)
- ``rmbvideo.cli``      the ``rmbvideo`` command, a thin layer over the above
"""

__version__ = "0.1.0"

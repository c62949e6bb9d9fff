"""rmbvideo: HDR, high-frame-rate video from spiking-camera captures.

For notebooks and scripts (the same defaults and sidecars as the command line)::

    import rmbvideo
    for frame in rmbvideo.reconstruct("capture.dat", method="tfp"):
        ...  # frame.index, frame.time_s, frame.image (linear float32)

``reconstruct``, ``open_capture``, ``simulate_capture``, ``load_scene`` and ``write_frames`` are imported on
first use, so ``import rmbvideo`` is cheap. The layers are described in the README ("Architecture").
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name -> "module:attribute", imported on first use
_API = {
    "reconstruct": "rmbvideo.recon.run:reconstruct_frames",
    "open_capture": "rmbvideo.io.capture:open_capture",
    "simulate_capture": "rmbvideo.simulate.capture:simulate_capture",
    "load_scene": "rmbvideo.scenes.scene:resolve_scene",
    "write_frames": "rmbvideo.io.sinks:write_frames",
}
__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    if name not in _API:
        raise AttributeError(f"module 'rmbvideo' has no attribute {name!r}")
    module, attribute = _API[name].split(":")
    return getattr(importlib.import_module(module), attribute)

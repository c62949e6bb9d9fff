"""The reconstruction methods, one registry line each, with the settings that belong to the method:
which stream it reads, what its window and step mean, its defaults and limits.

A new method is one new module with a factory (keyword options -> an object with ``push``/``flush``
and ``input_kind``, see ``rmbvideo.recon.classical.Reconstructor``) plus one ``Method`` line in
``METHODS``; ``reconstruct``, ``batch``, ``evaluate`` and ``bench`` take it from here. Factories are
named as "module:attribute" and imported on first use, so listing the methods (``--help``) imports
neither torch, scipy nor OpenCV.

Units: ``--step`` is always in raw planes (a frame every ``step`` planes, centred in its interval);
methods on the mixed-bit stream count readouts, each ``raw_per_readout`` raw planes (2 for
2x2x2-binned data, 1 for a native RMB sensor).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rmbvideo.errors import OptionError

DEFAULT_METHOD = "rmbnet"


@dataclass(frozen=True)
class Method:
    """A reconstruction method and its settings.

    ``input_kind``: "spikes" (raw 1-bit planes, full resolution) or "rmb" (the binned or native
    mixed-bit stream). ``window``: what ``--window`` counts ("raw planes", "readouts", "half-width w")
    or None when the method has no window; ``window_range``: the values accepted (memory and time
    stay bounded whatever a user types). ``factory``: "module:attribute" (imported on first use) or a
    callable. ``fixed_readouts``: readouts per frame fixed by the method
    (RMB-Net's N), else the frame step is free. ``extra_options``: further factory keywords the
    command line offers (e.g. RMB-Net's ``model``); ``select_extra`` keeps only these. ``help``: one
    line for ``--help`` and the README.
    """

    name: str
    factory: str | Callable[..., Any]
    input_kind: str
    help: str
    window: str | None = None
    window_default: int | None = None
    window_range: tuple[int, int] = (1, 1)
    fixed_readouts: int | None = None
    extra_options: tuple[str, ...] = ()

    def build(self, **options: Any) -> Any:
        """The reconstructor, from keyword options (see ``options``)."""
        factory = self.factory
        if isinstance(factory, str):
            module, attribute = factory.split(":")
            factory = getattr(importlib.import_module(module), attribute)
        try:
            return factory(**options)
        except TypeError as exc:
            raise OptionError(f"method {self.name}: {exc}") from None

    def select_extra(self, extra: dict[str, Any]) -> dict[str, Any]:
        """The entries of ``extra`` (command-line option values) that this method's factory takes."""
        return {k: v for k, v in extra.items() if k in self.extra_options}

    def frame_every(self, step: int, raw_per_readout: int = 2) -> int:
        """How many of its frames a method with a fixed frame step makes for each frame ``step`` asks (1: all)."""
        return 1 if self.fixed_readouts is None else step // (self.fixed_readouts * raw_per_readout)

    def options(self, window: int | None, step: int, raw_per_readout: int = 2) -> dict[str, Any]:
        """Keyword options of the factory for ``--window``/``--step`` (step in raw planes).

        Raises ``OptionError`` naming the option for a value this method cannot take."""
        options: dict[str, Any] = {}
        if window is not None:
            low, high = self.window_range
            if self.window is None:
                raise OptionError(f"--window: {self.name} has no window")
            if not low <= window <= high:
                raise OptionError(f"--window: {self.name} takes {low}..{high} {self.window}, got {window}")
            options["w" if self.window == "half-width w" else "window"] = window
        if self.input_kind == "spikes":
            return {**options, "step": step}
        if step % raw_per_readout:
            raise OptionError(f"--step: methods on the binned stream need an even step, got {step}")
        if self.fixed_readouts is not None:
            fixed = self.fixed_readouts * raw_per_readout
            if step % fixed:
                raise OptionError(f"--step: {self.name} makes a frame every {fixed} raw planes (its model's N = "
                                  f"{self.fixed_readouts} readouts); give {fixed}, or a multiple of it to keep every "
                                  f"k-th frame, got {step}")
            return options
        return {**options, "step": step // raw_per_readout}


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("rmbnet", "rmbvideo.recon.rmbnet:make_rmbnet", "rmb",
           "RMB-Net on the binned RMB stream (shipped model); from a 1-bit capture at the camera's resolution, "
           "the raw stream's detail added (--resolution binned: half)", "half-width w", 3, (0, 3),
           fixed_readouts=10,
           extra_options=("model", "align", "device", "upsampling", "precision", "threads", "input_mode",
                          "convention", "readout", "frame_batch", "prime", "cuda_graphs", "response", "edges")),
    Method("tfp", "rmbvideo.recon.classical:Tfp", "spikes",
           "mean of --window raw planes, full resolution", "raw planes", 41, (1, 20000)),
    Method("tfi", "rmbvideo.recon.classical:Tfi", "spikes",
           "1 / inter-spike interval around the frame time; with --window M, the rate over the whole intervals "
           "that cover the central M raw planes (TFI-M), full resolution", "raw planes", 0, (0, 20000)),
    Method("tfw", "rmbvideo.recon.classical:Tfw", "rmb",
           "pooled 1-bit and multi-bit rate over --window readouts (10 = TFW-S, 70 = TFW-L)", "readouts", 10,
           (1, 10000)),
    Method("gc20", "rmbvideo.recon.gc20:make_gc20", "rmb",
           "maximum-likelihood exposure from the readings read out (Gnanasambandam & Chan 2020)", "readouts", 70,
           (10, 10000), extra_options=("convention",)),
    Method("mg20", "rmbvideo.recon.mg20:make_mg20", "rmb",
           "blocks aligned with DIS flow, robust merge, then the GC20 likelihood (Ma et al. 2020)", "readouts", 70,
           (10, 10000), extra_options=("convention",)),
)}


def register_method(method: Method) -> None:
    """Add (or replace) a method at run time, e.g. from a plugin or a test."""
    METHODS[method.name] = method


def get_method(name: str) -> Method:
    """The registered method ``name``; ``OptionError`` listing the known ones otherwise."""
    method = METHODS.get(name)
    if method is None:
        raise OptionError(f"--method: unknown method {name!r} (known: {', '.join(sorted(METHODS))})")
    return method


def make_reconstructor(name: str, **options: Any) -> Any:
    """Build method ``name`` with keyword ``options`` (the factory's own keywords)."""
    return get_method(name).build(**options)

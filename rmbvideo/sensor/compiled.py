"""The compiled kernels on stored ``.dat`` bytes (``_packed.c``: decode+bin, decode), or ``None`` where the
install built none (no C compiler): callers then run the numpy forms of the same kernels, bit for bit the same."""

from __future__ import annotations

from types import ModuleType

KERNELS: ModuleType | None
try:
    from rmbvideo.sensor import _packed as KERNELS
except ImportError:  # pragma: no cover - depends on the install
    KERNELS = None

#: whether this install runs the compiled kernels
COMPILED = KERNELS is not None

"""The compiled kernels over spike planes (``_packed.c``: decode+bin of stored ``.dat`` bytes, TFI's block scan), or
``None`` where the install built none (no C compiler) or a build of another version is found (a source tree updated
without reinstalling): callers then run the numpy forms of the same kernels, bit for bit the same."""

from __future__ import annotations

import logging
from types import ModuleType

logger = logging.getLogger(__name__)

#: the kernels' version this code calls (``KERNELS_VERSION`` in ``_packed.c``)
KERNELS_VERSION = 2


def _load() -> ModuleType | None:
    """The built module if it is this version's."""
    try:
        from rmbvideo.sensor import _packed
    except ImportError:  # pragma: no cover - depends on the install
        return None
    if getattr(_packed, "VERSION", None) != KERNELS_VERSION:
        logger.warning("the compiled kernels (%s) are of another version than this code: running their numpy "
                       "forms; reinstall (pip install -e .) to rebuild them", _packed.__file__)
        return None
    return _packed


KERNELS = _load()
#: whether this install runs the compiled kernels
COMPILED = KERNELS is not None

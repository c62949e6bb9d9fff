"""Figures as PNG files: encoded at zlib's highest (still lossless) compression, written atomically.

The evaluation's and benchmark's picture sheets are large flat-coloured panels: at OpenCV's default
level they took 2-3x the bytes (10 MB for the project's figures, 3.5 MB at level 9). Frame sinks keep their
own, faster, setting: they write a file per frame.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from rmbvideo.errors import OutputError
from rmbvideo.io.atomic import atomic_path, atomic_write_bytes

#: zlib level 9: the smallest files; a figure is encoded once
FIGURE_COMPRESSION = 9


def encode_png(image: np.ndarray, what: str) -> bytes:
    """``image`` (H, W) or (H, W, 3) BGR uint8/uint16 as PNG bytes; ``what`` names it in the error."""
    ok, encoded = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, FIGURE_COMPRESSION])
    if not ok:
        raise OutputError(f"{what}: cannot encode the image as PNG")
    return encoded.tobytes()


def write_png(path: Path, image: np.ndarray) -> Path:
    """Encode ``image`` as PNG and write it atomically to ``path``."""
    atomic_write_bytes(Path(path), encode_png(image, str(path)))
    return Path(path)


def write_figure(fig: Any, path: Path, dpi: float | None = None) -> Path:
    """Render the matplotlib figure ``fig`` as PNG atomically to ``path`` and close it (an interrupted or failed
    render leaves neither a half-written ``path`` nor a temporary file)."""
    import matplotlib.pyplot as plt

    try:
        with atomic_path(Path(path)) as temp:
            fig.savefig(temp, format="png", **({} if dpi is None else {"dpi": dpi}))
    finally:
        plt.close(fig)
    return Path(path)

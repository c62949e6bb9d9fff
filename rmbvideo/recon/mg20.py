"""MG20 baseline (Ma et al. 2020, "Quanta burst photography"): align blocks of readings to the
frame's own block, merge them robustly, and invert the merged counts with GC20's likelihood.

Per output frame (same timing and window as GC20):

1. Blocks: the window's readings summed per ``block`` readouts (GC20's sufficient statistics).
2. Alignment: each block's fired/observed jot ratio, Gaussian-smoothed and square-root tone-mapped
   to 8 bits, is matched to the reference block (the frame's own) with OpenCV DIS optical flow
   (coarse-to-fine); the block's statistics are warped onto the reference grid (bilinear; pixels
   that map outside the frame carry no evidence).
3. Robust merge (Wiener-like): per pixel, the local (``patch`` x ``patch``) jot ratios of the warped
   block and of the reference are compared on the variance-stabilised arcsine-sqrt scale; the block's
   weight is ``min(1, tau / z^2)`` with z^2 the squared difference over its expected variance
   (1 / n_block + 1 / n_reference), so well-aligned blocks count fully and misaligned ones fade out.
4. The weighted sum of statistics is inverted by ``gc20.solve_exposure`` (a weighted likelihood).

``align=False`` skips steps 2-3 (plain sum over the window): the no-alignment merge, i.e. GC20.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from rmbvideo.errors import OptionError
from rmbvideo.recon.flow import dis_flow
from rmbvideo.recon.gc20 import (BlockWindowReconstructor, JotModel, ReadingStats, Response, config_options,
                                 solve_exposure, tiling_block)


@dataclass(frozen=True)
class Mg20Config:
    """MG20 settings: timing as GC20 (``window``, ``step`` and ``block`` in readouts),
    alignment on/off, pre-blur of the alignment images, robust-merge patch size and threshold."""

    window: int = 70
    step: int = 10
    block: int = 10
    response: Response = "poisson"
    align: bool = True
    align_sigma: float = 1.5
    patch: int = 5
    tau: float = 4.0


class Mg20Reconstructor(BlockWindowReconstructor):
    """MG20: align-and-merge of block statistics, then the GC20 maximum-likelihood inversion."""

    def __init__(self, config: Mg20Config | None = None) -> None:
        config = config or Mg20Config()
        if config.patch < 1 or config.tau <= 0 or config.align_sigma < 0:
            raise ValueError(f"patch must be >= 1, tau > 0 and align_sigma >= 0, got {config}")
        if tiling_block(config.window, config.step, config.block) < config.block:
            # its blocks are what it aligns and merges: smaller ones would be another method (and many more flows)
            raise OptionError(f"mg20 aligns and merges blocks of {config.block} readouts, which must tile each frame's "
                              f"window: --step {2 * config.step} raw planes ({config.step} readouts) with --window "
                              f"{config.window} readouts do not; give a --step that is a multiple of "
                              f"{2 * config.block} and a --window that differs from the step's readouts by a multiple "
                              f"of {2 * config.block} (with the default --step 20: 30, 50, 70, ...)")
        super().__init__(config.window, config.step, config.block, config.response)
        self.config = config
        self._flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)

    def _frame_image(self, blocks: list[ReadingStats], reference: int, model: JotModel) -> np.ndarray:
        ref = blocks[reference]
        merged = ReadingStats.zeros(ref.single_ones.shape)
        merged.add(ref)
        if not self.config.align:
            for k, stats in enumerate(blocks):
                if k != reference:
                    merged.add(stats)
            return solve_exposure(merged, model)
        ref_fires, ref_jots = self._local(ref.fires(model)), self._local(ref.jots(model))
        ref_angle = _arcsine_sqrt(ref_fires, ref_jots)
        scale = _alignment_scale(ref.fires(model), ref.jots(model))
        ref_image = self._alignment_image(ref, model, scale)
        height, width = ref_image.shape
        grid_x, grid_y = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
        for k, stats in enumerate(blocks):
            if k == reference:
                continue
            flow = dis_flow(self._flow, ref_image, self._alignment_image(stats, model, scale))
            map_x, map_y = grid_x + flow[..., 0], grid_y + flow[..., 1]
            warped = ReadingStats(*(
                cv2.remap(a, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
                for a in stats.arrays()
            ))
            fires, jots = self._local(warped.fires(model)), self._local(warped.jots(model))
            variance = 1.0 / np.maximum(jots, 1.0) + 1.0 / np.maximum(ref_jots, 1.0)
            z2 = (_arcsine_sqrt(fires, jots) - ref_angle) ** 2 / variance
            weight = np.minimum(1.0, self.config.tau / np.maximum(z2, 1e-12)).astype(np.float32)
            merged.add(warped, weight)
        return solve_exposure(merged, model)

    def _local(self, values: np.ndarray) -> np.ndarray:
        """Sum over a ``patch`` x ``patch`` neighbourhood (evidence pooled for the robust test)."""
        size = self.config.patch
        return cv2.boxFilter(values.astype(np.float32), -1, (size, size), normalize=False,
                             borderType=cv2.BORDER_REPLICATE)

    def _alignment_image(self, stats: ReadingStats, model: JotModel, scale: float) -> np.ndarray:
        """8-bit square-root tone-mapped jot ratio of one block, smoothed: the image DIS aligns."""
        ratio = stats.fires(model) / np.maximum(stats.jots(model), 1.0)
        if self.config.align_sigma > 0:
            ratio = cv2.GaussianBlur(ratio, (0, 0), self.config.align_sigma)
        return np.clip(np.sqrt(np.maximum(ratio, 0.0) / scale) * 255.0, 0, 255).astype(np.uint8)


def _alignment_scale(fires: np.ndarray, jots: np.ndarray) -> float:
    """The jot ratio mapped to white in alignment images: the reference's 99th percentile (> 0)."""
    ratio = fires / np.maximum(jots, 1.0)
    return max(float(np.percentile(ratio, 99.0)), 1e-3)


def _arcsine_sqrt(fires: np.ndarray, jots: np.ndarray) -> np.ndarray:
    """Variance-stabilised binomial proportion: 2 asin(sqrt(f / n)) has variance ~ 1 / n."""
    return 2.0 * np.arcsin(np.sqrt(np.clip(fires / np.maximum(jots, 1.0), 0.0, 1.0)))


def make_mg20(convention: str | None = None, **options: object) -> Mg20Reconstructor:
    """Method "mg20": keyword options are ``Mg20Config`` fields; ``convention`` (what made the spikes) picks the
    response when none is given."""
    return Mg20Reconstructor(Mg20Config(**config_options(options, convention)))  # type: ignore[arg-type]

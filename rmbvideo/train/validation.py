"""Held-out validation during training: the model's mu-law PSNR/SSIM and TFW's on the same samples."""

from __future__ import annotations

import numpy as np
import torch

from rmbvideo.evaluate.metrics import mu_law_psnr, mu_law_ssim
from rmbvideo.net.model import RmbNet, window_indices, window_valid
from rmbvideo.train.batch import Batch, output_range
from rmbvideo.train.dataset import Sample


def tfw_prediction(sample: Sample, i: int, w: int, n: int, quanta: int | None) -> np.ndarray:
    """TFW over the window of frame ``i``: pooled spike rate (sum I_s + I_m) / (N (2w+1) (1 + q)),
    with q = ``quanta`` trials per multi-bit value; rows without multi-bit evidence, and all rows
    when ``quanta`` is None (multi-bit values are not rates), use I_s alone."""
    frames = slice(max(i - w, 0), min(i + w + 1, len(sample.i_s)))
    valid = sample.m_valid[frames].all(axis=0)[:, None] & (quanta is not None)
    quanta = quanta or 0
    readouts = n * (frames.stop - frames.start)
    sum_s = sample.i_s[frames].sum(axis=0, dtype=np.float64)
    sum_m = sample.i_m[frames].sum(axis=0, dtype=np.float64)
    pooled = np.where(valid, (sum_s + sum_m) / (readouts * (1 + quanta)), sum_s / readouts)
    return pooled.astype(np.float32)


@torch.no_grad()
def validate(model: RmbNet, samples: list[Sample], quanta: int | None, saturation: float,
             device: torch.device, edges: bool = False) -> dict[str, float]:
    """Mean mu-law PSNR/SSIM of the model and mu-law PSNR of TFW over the supervised outputs of
    the held-out ``samples`` (``output_range``), against ground truth clipped at ``saturation``."""
    model.eval()
    w, n = model.config.w, model.config.n
    psnr, ssim, tfw = [], [], []
    for sample in samples:
        batch = Batch.from_samples([sample], device, centre=model.config.centre_windows, n=n,
                                   aligned=model.config)
        count = batch.i_s.shape[1]
        frames = model.encode(batch.i_s[0], batch.i_m[0], range(count), None if batch.i_c is None else batch.i_c[0])
        state = None
        for i in output_range(count, w, edges):
            window = [frames[j] for j in window_indices(i, w, count, model.config.edge_slide)]
            t, state = model.step(window, state, valid=window_valid(i, w, count, model.config.edge_slide),
                                  convention=batch.convention,
                                  aligned=None if batch.i_a is None else batch.i_a[:, i])
            pred = model.to_linear(t)[0, 0].float().cpu().numpy()
            gt = np.clip(sample.gt[i], 0.0, saturation)
            psnr.append(mu_law_psnr(pred, gt))
            ssim.append(mu_law_ssim(pred, gt))
            tfw.append(mu_law_psnr(np.clip(tfw_prediction(sample, i, w, n, quanta), 0, saturation), gt))
    return {"val_mu_psnr": float(np.mean(psnr)), "val_mu_ssim": float(np.mean(ssim)),
            "val_tfw_mu_psnr": float(np.mean(tfw))}

"""How much fixed pattern a camera's pixels put inside each 2x2 block: a flat field of the emission model with its
realistic effects, with and without threshold mismatch, each pixel's rate over 2,000 planes (its count noise averages
out, a pixel's own threshold does not); the spread of the pixels about their block's mean, relative to the level.
Run from the repository root (seconds):

    python models/experiments/tfi-detail/fixed_pattern.py
"""
import numpy as np
from rmbvideo.sensor.params import SensorParams
from rmbvideo.sensor.emission import SpikeEmitter
from rmbvideo.sensor.effects import REALISTIC_EFFECTS
H, W, T = 64, 64, 2000
for effects in (REALISTIC_EFFECTS, tuple(e for e in REALISTIC_EFFECTS if e != "threshold_mismatch")):
    for level in (0.05, 0.3):
        params = SensorParams(reset="zero")
        em = SpikeEmitter(H, W, params, effects, 7); em.settle(7)
        value = np.full((H, W), level, np.float32)
        counts = sum(em.emit_one(value * params.q_r, 1).astype(np.int64) for _ in range(T))
        rate = counts / T
        blocks = rate.reshape(H // 2, 2, W // 2, 2)
        resid = blocks - blocks.mean(axis=(1, 3), keepdims=True)
        shot = np.sqrt(rate.mean() / T) / rate.mean()   # Poisson-count std of a pixel's rate, relative
        print(f"{'with' if 'threshold_mismatch' in effects else 'without'} threshold mismatch, light {level}: "
              f"rate {rate.mean():.3f}, intra-block relative std {resid.std() / rate.mean() * 100:.2f} % (count noise alone at most {shot * 100:.2f} %)")

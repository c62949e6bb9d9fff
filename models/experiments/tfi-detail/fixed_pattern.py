"""How much fixed pattern a camera's pixels put inside each 2x2 block: a flat field of the emission model with its
realistic effects, with and without threshold mismatch, each pixel's rate over 2,000 planes (its count noise averages
out, a pixel's own threshold does not); the spread of the pixels about their block's mean, relative to the level.
Run from the repository root (seconds):

    python models/experiments/tfi-detail/fixed_pattern.py
"""

import numpy as np

from rmbvideo.sensor.effects import REALISTIC_EFFECTS
from rmbvideo.sensor.emission import SpikeEmitter
from rmbvideo.sensor.params import SensorParams

HEIGHT, WIDTH, PLANES = 64, 64, 2000


def main() -> None:
    for effects in (REALISTIC_EFFECTS, tuple(e for e in REALISTIC_EFFECTS if e != "threshold_mismatch")):
        for level in (0.05, 0.3):
            params = SensorParams(reset="zero")
            emitter = SpikeEmitter(HEIGHT, WIDTH, params, effects, 7)
            emitter.settle(7)
            value = np.full((HEIGHT, WIDTH), level * params.q_r, np.float32)
            rate = sum(emitter.emit_one(value, 1).astype(np.int64) for _ in range(PLANES)) / PLANES
            blocks = rate.reshape(HEIGHT // 2, 2, WIDTH // 2, 2)
            spread = (blocks - blocks.mean(axis=(1, 3), keepdims=True)).std() / rate.mean()
            poisson = np.sqrt(rate.mean() / PLANES) / rate.mean()  # a Poisson count's over the planes (an upper bound)
            print(f"{'with' if 'threshold_mismatch' in effects else 'without'} threshold mismatch, light {level}: "
                  f"rate {rate.mean():.3f}, spread about the block mean {spread * 100:.2f} % of the level "
                  f"(a Poisson count's: {poisson * 100:.2f} %)")


if __name__ == "__main__":
    main()

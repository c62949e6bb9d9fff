"""The shipped binned RMB-Net, run through the streaming engine on an independent simulator's
streams (spikezoo, REDS), beats TFW over the same 70 readouts against the 8-bit reference frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rmbvideo.evaluate.reference_frame import scaled_psnr, score_reference_frame


def test_scaled_psnr_ignores_scale_and_sees_noise() -> None:
    rng = np.random.default_rng(0)
    reference = rng.random((20, 30))
    assert scaled_psnr(7.0 * reference, reference) > 100
    assert scaled_psnr(reference + rng.normal(0, 0.1, reference.shape), reference) < 25


@pytest.mark.parametrize("name", ["200_part3_key_id151", "203_part2_key_id151"])
def test_shipped_model_beats_tfw_on_spikezoo(shared_data: Path, name: str) -> None:
    base = shared_data / "spikezoo-base" / name
    scores = score_reference_frame(base.with_suffix(".dat"), base.with_suffix(".png"), plane=150)
    assert scores["rmbnet"] > scores["tfw-l"] + 2.0, scores

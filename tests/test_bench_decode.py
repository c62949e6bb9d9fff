"""The decode benchmark runs end to end on a small capture and reports consistent figures."""

from __future__ import annotations

from rmbvideo.bench.decode import GOAL_PLANES_PER_S, TARGET_PLANES_PER_S, bench_decode, main
from rmbvideo.sensor.compiled import COMPILED


def test_bench_decode_small_run(capsys) -> None:
    result = bench_decode(n_planes=66)
    assert result["bit_exact"] is True
    assert 0.25 < result["firing_rate"] < 0.35
    assert result["fused"]["planes"] == 66 and result["plain"]["planes"] == 66
    for name in ("fused", "fused_numpy", "plain", "per_plane_loop"):
        assert result[name]["planes_per_s"] > 0
    assert result["fused_numpy"]["planes"] == 66 and result["kernel"] == ("compiled" if COMPILED else "numpy")
    assert result["fused_vs_numpy"] == result["fused"]["planes_per_s"] / result["fused_numpy"]["planes_per_s"]
    assert result["fused_vs_plain"] == result["fused"]["planes_per_s"] / result["plain"]["planes_per_s"]
    assert result["meets_target"] == (result["fused"]["planes_per_s"] >= TARGET_PLANES_PER_S)
    assert result["meets_goal"] == (result["fused"]["planes_per_s"] >= GOAL_PLANES_PER_S)
    main(["--planes", "8"])
    assert "planes/s" in capsys.readouterr().out

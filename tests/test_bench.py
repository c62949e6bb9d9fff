"""``rmbvideo bench`` on a tiny configuration: record fields, finiteness, Pareto marking, files."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from rmbvideo.bench.configs import BASELINES, BenchConfig, default_configs, rmbnet_config
from rmbvideo.bench.models import find_model
from rmbvideo.bench.pareto import pareto_front
from rmbvideo.bench.report import mark_pareto, markdown_table, write_csv, write_plot
from rmbvideo.bench.runner import BenchRecord, run_config
from rmbvideo.cli import main
from rmbvideo.evaluate.heldout import Sequence
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import ModelCard, save_model
from rmbvideo.sensor.binning import bin_2x2x2

H, W, READOUTS = 16, 24, 80


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def tiny_sequence(seed: int = 0) -> Sequence:
    """A static scene of firing probabilities 0.05..0.6 seen by a 1-bit camera, binned."""
    rng = np.random.default_rng(seed)
    light = np.linspace(0.05, 0.6, 2 * W, dtype=np.float32)[None, :].repeat(2 * H, axis=0)
    raw = (rng.random((2 * READOUTS, 2 * H, 2 * W)) < light).astype(np.uint8)
    single, multi = bin_2x2x2(raw)
    gt = light.reshape(H, 2, W, 2).mean(axis=(1, 3))
    return Sequence(name=f"tiny{seed}", seed=seed, rate_hz=10_000.0, single=single, multi=multi,
                    raw_packed=np.packbits(raw, axis=-1, bitorder="little"),
                    gt=np.repeat(gt[None], READOUTS // 10, axis=0), edge_readouts=20)


def test_pareto_front_marks_only_undominated_points():
    points = [(1.0, 30.0), (2.0, 35.0), (3.0, 34.0), (0.5, 20.0), (1.0, 30.0), (None, 40.0), (4.0, math.nan)]
    assert pareto_front(points) == [True, True, False, True, True, False, False]
    assert pareto_front([]) == []
    # equal to the shown 0.01 dB: the slower one is dominated however the floats fall
    assert pareto_front([(1.0, 30.001), (2.0, 30.004)], resolution=0.01) == [True, False]
    assert pareto_front([(1.0, 30.001), (2.0, 30.004)]) == [True, True]


def test_default_configs_cover_the_issue():
    names = [c.name for c in default_configs(("cpu",))]
    assert names[:len(BASELINES)] == list(BASELINES)
    assert {"TFW-S", "TFW-L", "GC20", "MG20", "TFP-41 (raw)", "TFI (raw)"} <= set(BASELINES)
    rmb = [c for c in default_configs(("cpu", "cuda")) if c.is_rmbnet]
    for device in ("cpu", "cuda"):
        mine = [c for c in rmb if c.device == device]
        assert {c.w for c in mine} == {0, 1, 2, 3} and {c.align for c in mine} == {"none", "dis", "tvl1"}
        assert {c.width for c in mine} == {0.5, 1.0} and {c.precision for c in mine} == {"auto", "fp32", "bf16"}
    assert len(set(names)) == len(names)
    assert len([c for c in default_configs(("cpu",), full_grid=True) if c.is_rmbnet]) == 48
    full = [c for c in rmb if c.resolution == "full"]  # reconstruct's default output, on the CPU
    assert len(full) == 1 and full[0].device == "cpu" and full[0].name.endswith("full res")
    for beside, other in ((False, 2), (True, 1)):  # the default row the other way (aligned means inline/beside), once
        own = [c for c in default_configs(("cpu",), beside=beside) if c.threads is not None]
        assert [(c.threads, c.w, c.precision, c.name.endswith(f"{other} threads")) for c in own] == [(other, 3, "auto", True)]


def test_full_resolution_row_scores_its_2x2_average_which_is_the_binned_output(tmp_path, monkeypatch):
    """The full-resolution row times the default job (binned network, raw-interval gate, raw detail) and is scored
    after 2x2 averaging: without the gate that gives the binned output back, the same accuracy as the binned row;
    with it (the default) the gated frame, which scores otherwise."""
    import rmbvideo.recon.full_resolution as full_module

    models = tmp_path / "models"
    (models / "ablations").mkdir(parents=True)
    torch.manual_seed(1)
    save_model(models / "ablations" / "tiny-w1", RmbNet(RmbNetConfig(w=1, width=0.25)), ModelCard(name="tiny"))
    sequences = [tiny_sequence(0)]
    binned, gated = (run_config(rmbnet_config(w=1, width=0.25, resolution=r), sequences, tmp_path, models,
                                memory=False) for r in ("binned", "full"))
    monkeypatch.setattr(full_module, "raw_gate_stage", lambda kind="auto": None)
    full = run_config(rmbnet_config(w=1, width=0.25, resolution="full"), sequences, tmp_path, models, memory=False)
    assert full.name.endswith("full res") and full.frames == binned.frames and full.net_fps > 0
    assert full.psnr == pytest.approx(binned.psnr, abs=0.02) and full.ssim == pytest.approx(binned.ssim, abs=1e-3)
    assert gated.frames == binned.frames and abs(gated.psnr - full.psnr) > 1e-3  # the gate mixed


def test_run_config_records_are_complete_and_finite(tmp_path):
    models = tmp_path / "models"
    (models / "ablations").mkdir(parents=True)
    torch.manual_seed(1)
    save_model(models / "ablations" / "tiny-w1", RmbNet(RmbNetConfig(w=1, width=0.25)), ModelCard(name="tiny"))
    assert find_model(1, 0.25, models).trained and not find_model(2, 0.25, models).trained
    sequences = [tiny_sequence(0), tiny_sequence(1)]
    configs = [BenchConfig("TFW-S", "tfw", {"window": 10, "step": 10}), BenchConfig("TFI", "tfi", {"step": 20}),
               rmbnet_config(w=1, width=0.25), rmbnet_config(w=2, width=0.25)]
    records = [run_config(c, sequences, tmp_path, models, memory=c.name != "TFI") for c in configs]
    tfw, tfi, trained, untrained = records
    for r in records:
        assert r.frames == 2 * READOUTS // 10
        assert math.isfinite(r.fps) and r.fps > 0 and r.realtime_factor > 0
        if r is tfi:
            assert r.peak_rss_mib is None and r.peak_anon_mib is None
        else:
            assert 0 < r.peak_anon_mib <= r.peak_rss_mib
    for r in (tfw, tfi, trained):
        assert r.trained and r.scored_frames == 2 * len(sequences[0].scored_frames)
        assert math.isfinite(r.psnr) and 0 <= r.ssim <= 1
    assert tfw.net_fps is None and trained.net_fps > 0 and untrained.net_fps > 0
    assert tfw.psnr > 20  # a static scene: the 10-readout mean is close to the truth
    assert untrained.model == "random-init" and untrained.psnr is None and untrained.ssim is None
    assert trained.model == "tiny-w1.safetensors"

    mark_pareto(records)
    assert not untrained.pareto and any(r.pareto for r in records)
    best = max((r for r in records if r.psnr is not None), key=lambda r: r.psnr)
    assert best.pareto
    table = markdown_table(records)
    assert table.count("\n") == len(records) + 2 and "n/a" in table
    write_csv(records, tmp_path / "bench.csv")
    rows = list(csv.DictReader((tmp_path / "bench.csv").open()))
    assert [r["name"] for r in rows] == [c.name for c in configs] and rows[3]["psnr"] == ""
    assert rows[1]["peak_rss_mib"] == "" and float(rows[0]["peak_rss_mib"]) == tfw.peak_rss_mib
    write_plot(records, tmp_path / "bench.png")
    assert (tmp_path / "bench.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_rows_peak_memory_is_its_own_not_the_benchmark_processes(tmp_path):
    """Each row's peak is measured in a fresh process running it: memory this process holds (here 800 MB, as earlier
    rows' high-water mark would be) is not in it, and an RMB-Net row reads its model and torch, which a baseline's does
    not load (nor does its ``reconstruct`` run): its peak is under half the network row's."""
    models = tmp_path / "models"
    (models / "ablations").mkdir(parents=True)
    save_model(models / "ablations" / "tiny-w1", RmbNet(RmbNetConfig(w=1, width=0.25)), ModelCard(name="tiny"))
    held = np.ones(800 * 2**20, dtype=np.uint8)  # touched: resident in this process
    sequences = [tiny_sequence(0)]
    tfw = run_config(BenchConfig("TFW-S", "tfw", {"window": 10, "step": 10}), sequences, tmp_path, models, runs=1)
    net = run_config(rmbnet_config(w=1, width=0.25), sequences, tmp_path, models, runs=1)
    assert held.sum() == held.size
    for record in (tfw, net):
        assert 20 < record.peak_rss_mib < 700 and 0 < record.peak_anon_mib <= record.peak_rss_mib
    assert tfw.peak_rss_mib < 0.5 * net.peak_rss_mib, (tfw.peak_rss_mib, net.peak_rss_mib)


def test_timing_runs_repeat_each_scene_and_count_its_frames_once(tmp_path):
    """Each scene runs ``runs`` times and the fastest is timed: the frames and scores are those of one run."""
    sequences = [tiny_sequence(0)]
    config = BenchConfig("TFW-S", "tfw", {"window": 10, "step": 10})
    once, thrice = (run_config(config, sequences, tmp_path, tmp_path, runs=r, memory=False) for r in (1, 3))
    assert once.frames == thrice.frames == READOUTS // 10 and once.psnr == thrice.psnr
    with pytest.raises(ValueError, match="runs"):
        run_config(config, sequences, tmp_path, tmp_path, runs=0, memory=False)


def test_names_of_rows_at_one_point_go_to_separate_spots_in_both_plots(tmp_path):
    """Rows of equal accuracy and time (the w = 3 rows at one PSNR) get their names at spots that do not overlap, and
    the OpenCV plot a plain install draws (no matplotlib) is a PNG."""
    from rmbvideo.bench.report import _free_spot, _overlap, _write_plot_opencv

    def box_at(spot):  # a 60x10 name beside a point at (100, 100), lines 12 apart
        side, k = spot
        x = 106 if side > 0 else 34
        return x, 90 - 12 * k, x + 60, 100 - 12 * k

    placed = []
    for _ in range(5):
        placed.append(box_at(_free_spot(box_at, placed, 0, 1000)))
    assert all(not _overlap(a, b) for i, a in enumerate(placed) for b in placed[i + 1:])
    assert _free_spot(box_at, [], 100, 1000) == (1, 0)  # level, right of the point, when free
    points = [(30.0, 38.7, f"RMB-Net row {i}", i == 0) for i in range(4)] + [(1.0, 30.0, "TFP-80 (raw)", True)]
    png = _write_plot_opencv(points, tmp_path / "plot.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_record_json_roundtrip():
    record = BenchRecord(name="x", method="tfw", w=None, align=None, width=None, precision=None, device="cpu",
                         threads=1, model="-", trained=True, frames=3, scored_frames=2, psnr=30.0, ssim=0.9,
                         fps=0.0, net_fps=None, realtime_factor=0.0, peak_rss_mib=1.0, peak_anon_mib=None)
    assert json.loads(json.dumps(record.to_dict()))["name"] == "x" and record.seconds_per_frame == math.inf


def test_cli_help_and_decode():
    runner = CliRunner()
    result = runner.invoke(main, ["bench", "--help"])
    assert result.exit_code == 0 and "--quick" in result.output and "decode" in result.output
    result = runner.invoke(main, ["bench", "decode", "--planes", "64", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["bit_exact"] is True


def test_bench_simulate_reports_both_rates_on_the_same_work() -> None:
    from rmbvideo.bench.simulate import bench_simulate, reference_emission, summary

    result = bench_simulate("demo", 0.002, repeats=2)
    assert result["readouts"] == 40 and result["width"] * result["height"] == 320 * 200 and result["repeats"] == 2
    assert result["simulator_pixel_readouts_per_s"] > 0 and result["reference_pixel_readouts_per_s"] > 0
    assert "simulator / reference" in summary(result)
    # the reference is a real emitter: its firing rate follows the expected charge
    rates = reference_emission(np.array([[1.0, 30.0, 300.0]]), 400, 105.0) / 400
    assert rates[0, 0] < 0.02 < rates[0, 1] < rates[0, 2] <= 1.0


def test_bench_sizes_times_each_size_and_precision_with_the_network_inside_the_run() -> None:
    runner = CliRunner()
    result = runner.invoke(main, ["bench", "sizes", "--size", "64x48", "--frames", "10", "--no-cli", "--json"])
    assert result.exit_code == 0, result.output
    rows = json.loads(result.output)
    assert [(r["binned"], r["precision"]) for r in rows] == [("32x24", "fp32"), ("32x24", "bf16")]
    for row in rows:
        assert row["frames"] == 10 and row["cli_fps"] is None
        assert 0 < row["fps"] <= row["network_fps"]  # the network is part of the end-to-end run
        assert set(row["stage_ms"]) >= {"read", "preliminary frames", "network", "detail"}
    batched = runner.invoke(main, ["bench", "sizes", "--size", "64x48", "--frames", "10", "--no-cli", "--json",
                                   "--precision", "fp32", "--frame-batch", "1", "--frame-batch", "4", "--threads", "1"])
    assert batched.exit_code == 0, batched.output
    rows = json.loads(batched.output)
    assert [(r["precision"], r["frame_batch"], r["threads"], r["frames"]) for r in rows] == [
        ("fp32", 1, 1, 10), ("fp32", 4, 1, 10)]
    bad = runner.invoke(main, ["bench", "sizes", "--size", "65x48"])
    assert bad.exit_code != 0 and "even raw size" in bad.output


def test_bench_network_times_the_encoders_and_the_batched_pass_alone() -> None:
    """Each run is timed as one batched pass and, on a CPU, frame by frame as the engine runs there."""
    runner = CliRunner()
    result = runner.invoke(main, ["bench", "network", "--run", "32x24x4", "--run", "16x16x2", "--precision", "fp32",
                                  "--json"])
    assert result.exit_code == 0, result.output
    rows = json.loads(result.output)
    assert [(r["binned"], r["frame_batch"], r["cuda_graphs"], r["frame_by_frame"]) for r in rows] == [
        ("32x24", 4, False, False), ("32x24", 4, False, True), ("16x16", 2, False, False), ("16x16", 2, False, True)]
    for row in rows:
        assert row["encode_ms"] > 0 and row["step_run_ms"] > 0
        assert abs(row["fps"] - 1e3 / (row["encode_ms"] + row["step_run_ms"])) < 1e-6 * row["fps"]
    table = runner.invoke(main, ["bench", "network", "--run", "16x16x2", "--precision", "bf16"])
    assert table.exit_code == 0 and "| 16x16 | cpu | bf16 | 2 | no |" in table.output
    assert "| 16x16 | cpu | bf16 | 1 (step, 2 frames) | no |" in table.output
    bad = runner.invoke(main, ["bench", "network", "--run", "200x125"])
    assert bad.exit_code != 0 and "WIDTHxHEIGHTxFRAMES" in bad.output


def test_bench_profile_writes_the_engine_profile_of_a_real_run(tmp_path) -> None:
    """The profile covers the profiled run's frames: its per-frame CPU time is the tables' total over the frames, and
    the network's convolutions are among the operations (the run went through RMB-Net)."""
    out = tmp_path / "profile.md"
    result = CliRunner().invoke(main, ["bench", "profile", "--size", "32x32", "--frames", "10", "--threads", "1",
                                       "-o", str(out)])
    assert result.exit_code == 0, result.output
    text = out.read_text()
    assert text.startswith("# Engine profile: CPU, 32x32 raw, fp32, full resolution, 10 frames")
    assert "conv" in text and "## by self cpu time total" in text
    per_frame = float(text.split("torch's operations: ")[1].split(" ms")[0])
    total = text.split("Self CPU time total: ")[1].split("\n")[0]
    unit = next(u for u in ("ms", "us", "s") if total.endswith(u))
    total_ms = float(total[: -len(unit)]) * {"ms": 1.0, "us": 1e-3, "s": 1e3}[unit]
    assert per_frame * 10 == pytest.approx(total_ms, rel=0.02)
    assert "end to end, unprofiled" in result.output
    bad = CliRunner().invoke(main, ["bench", "profile", "--size", "33x32"])
    assert bad.exit_code != 0 and "even raw size" in bad.output
    again = CliRunner().invoke(main, ["bench", "profile", "--size", "32x32", "-o", str(out)])  # refused up front
    assert again.exit_code == 2 and "exists; use --overwrite" in again.output and out.read_text() == text
    capture = tmp_path / "cap.dat"
    capture.write_bytes(b"\x01" * 64)
    wrong = CliRunner().invoke(main, ["bench", "profile", "--size", "32x32", "-o", str(capture), "--overwrite"])
    assert wrong.exit_code == 2 and "writes .md" in wrong.output and capture.read_bytes() == b"\x01" * 64

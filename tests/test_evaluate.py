"""Held-out set, evaluation harness and Table 2 outputs on a tiny sequence (48x40 binned, 60 readouts)."""

from __future__ import annotations

import csv
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from rmbvideo.chunks import Frame
from rmbvideo.evaluate.harness import (
    MethodSpec,
    BEST_RAW,
    CLOSED_FORM_ROW,
    GATED_ROW,
    evaluate_rows,
    run_method,
    score_frames,
    table2_specs,
    with_best_raw,
)
from rmbvideo.evaluate.heldout import HeldoutConfig, load_heldout_config
from rmbvideo.evaluate.metrics import PSNR_CAP_DB
from rmbvideo.evaluate.table import csv_table, pick_moving_region, pick_regions, write_comparison_png, write_tables
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import ModelCard, save_model
from rmbvideo.recon.methods import METHODS, Method, register_method

TINY = HeldoutConfig(count=1, width=48, height=40, readouts=60, edge_readouts=20)


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("heldout")


@pytest.fixture(scope="module")
def sequence(cache):
    return load_heldout_config(TINY, cache)[0]


@pytest.fixture(scope="module")
def models_dir(tmp_path_factory) -> Path:
    """A models folder with a random-init tiny RMB-Net as the main model and one ablation (w/o XBA)."""
    folder = tmp_path_factory.mktemp("models")
    torch.manual_seed(0)
    tiny = dict(w=1, width=0.25)
    save_model(folder / "rmbnet-binned.safetensors", RmbNet(RmbNetConfig(**tiny)), ModelCard(name="tiny"))
    (folder / "ablations").mkdir()
    save_model(folder / "ablations" / "rmbnet-binned-no-xba.safetensors", RmbNet(RmbNetConfig(use_xba=False, **tiny)),
               ModelCard(name="tiny-no-xba"))
    return folder


@pytest.fixture(scope="module")
def rows(sequence, models_dir):
    torch.set_num_threads(1)
    return with_best_raw(evaluate_rows(table2_specs(models_dir, device="cpu"), [sequence]))


def test_heldout_sequence_is_cached_and_consistent(sequence, cache):
    files = list(cache.glob("*.npz"))
    assert len(files) == 1 and "seed1000000" in files[0].name  # an evaluation seed, cached as npz
    again = load_heldout_config(TINY, cache)[0]  # read back from the cache
    for name in ("single", "multi", "raw_packed", "gt"):
        assert np.array_equal(getattr(again, name), getattr(sequence, name))
    assert sequence.single.shape == sequence.multi.shape == (60, 40, 48)
    assert sequence.gt.shape == (6, 40, 48) and np.isfinite(sequence.gt).all() and sequence.gt.min() >= 0
    assert sequence.multi.max() <= 7 and sequence.single.max() <= 1
    # binned multi-bit value = spike count of the 2x2x2 raw bin (clamped at 7)
    raw = np.concatenate([c.planes for c in sequence.raw_chunks(32)])
    assert raw.shape == (120, 80, 96)
    counts = raw.reshape(60, 2, 40, 2, 48, 2).sum(axis=(1, 3, 5))
    assert np.array_equal(np.minimum(counts, 7), sequence.multi)
    # edge policy: frames whose +-20 readouts lie inside 60 readouts: centres 25 and 35
    assert sequence.scored_frames == [2, 3]
    assert sequence.frame_time(2) == pytest.approx(25 / 10000)


def test_table2_rows_scores_and_not_trained(rows):
    names = [r.name for r in rows]
    raw = ["TFP-20 (raw)", "TFP-41 (raw)", "TFP-80 (raw)", "TFP-140 (raw)", "TFI (raw)", "TFI-4 (raw)", "TFI-8 (raw)",
           "TFI-16 (raw)", BEST_RAW]
    assert names == ["TFW-S", "TFW-L", "TFI", "GC20", "MG20", "RMB-Net", GATED_ROW, CLOSED_FORM_ROW, *raw,
                     "RMB-Net (ablation budget)", "w = 0", "Pure-S", "Pure-M", "Full-M", "w/o XBA", "w/o XTA"]
    status = {r.name: r.status for r in rows}
    assert all(status[n] == "not trained" for n in ("RMB-Net (ablation budget)", "w = 0", "Pure-S", "Pure-M", "Full-M", "w/o XTA"))
    ok = [r for r in rows if r.status == "ok"]
    assert [r.name for r in ok] == ["TFW-S", "TFW-L", "TFI", "GC20", "MG20", "RMB-Net", GATED_ROW, CLOSED_FORM_ROW, *raw,
                                    "w/o XBA"]
    for row in ok:
        assert row.per_sequence.keys() == row.middle_frames.keys() == {"random-1000000"}
        if row.name == BEST_RAW:  # per sequence the best raw row, with that row's frames
            assert row.per_sequence["random-1000000"] == max(r.psnr for r in ok if r.name in raw[:-1])
            continue
        values = (row.psnr, row.ssim, row.pu21, row.fps)
        assert all(math.isfinite(v) for v in values), row
        assert 0 < row.psnr < PSNR_CAP_DB and -1 <= row.ssim < 1 and row.fps > 0
        assert sorted(row.figure_frames) == [2, 3]
        assert all(img.shape == (40, 48) and np.isfinite(img).all() for img in row.figure_frames.values())
    rmbnet = next(r for r in rows if r.name == "RMB-Net")
    assert math.isfinite(rmbnet.network_fps) and rmbnet.network_fps >= rmbnet.fps
    # the default job on a 1-bit capture: the same network's frames, mixed with the raw intervals by the gate
    gated = next(r for r in rows if r.name == GATED_ROW)
    from rmbvideo.cli.evaluate import FIGURE_COLUMNS

    assert GATED_ROW in FIGURE_COLUMNS  # and the evaluation's pictures show it
    assert not np.array_equal(gated.figure_frames[2], rmbnet.figure_frames[2])
    assert np.abs(gated.figure_frames[2] - rmbnet.figure_frames[2]).mean() < 0.2 * rmbnet.figure_frames[2].mean()
    # the longer window averages more evidence: TFW-L beats TFW-S on a noisy binned stream
    by_name = {r.name: r for r in ok}
    assert by_name["TFW-L"].psnr > by_name["TFW-S"].psnr
    # the raw full-resolution capture holds 8x the samples of the RMB stream's 1-bit plane
    assert by_name["TFI (raw)"].psnr > by_name["TFI"].psnr


def test_outputs_written(rows, sequence, tmp_path):
    md, table = write_tables(rows, tmp_path, notes="notes here\n")
    text = md.read_text()
    assert "| RMB-Net |" in text and "| Pure-S | — | — | — | — | — | — | not trained |" in text
    assert text.rstrip().endswith("notes here")
    with open(table, newline="") as fh:
        records = list(csv.DictReader(fh))
    assert [r["method"] for r in records] == [r.name for r in rows]
    for record in records:
        if record["status"] == "ok":
            assert math.isfinite(float(record["mu_psnr_db"])) and float(record["fps"]) > 0
            # every row that made frames has its frame-to-frame score; an oracle pick of rows per sequence has none
            assert (record["temporal_mu_psnr_db"] == "") == (record["method"] == BEST_RAW)
        else:
            assert record["mu_psnr_db"] == "" and record["status"] == "not trained"
    assert csv_table(rows) == table.read_text()
    png = write_comparison_png(rows, sequence.gt[2], 2, tmp_path / "evaluation.png")
    image = cv2.imread(str(png))
    assert image is not None and image.ndim == 3
    columns = 1 + sum(r.status == "ok" for r in rows)  # GT + every method with frames
    assert image.shape[1] >= columns * 160  # each column at least one zoom wide
    assert not list(tmp_path.glob(".*tmp*"))  # no temporary files left behind


def test_regions_are_darkest_and_brightest_textured():
    rng = np.random.default_rng(1)
    gt = np.full((64, 64), 1.0, np.float32) + rng.uniform(0, 0.5, (64, 64)).astype(np.float32)
    gt[:16, :16] = 0.01 * (1 + rng.uniform(0, 0.5, (16, 16)))  # dark textured corner
    gt[48:, 48:] = 100.0 * (1 + rng.uniform(0, 0.5, (16, 16)))  # bright textured corner
    dark, bright = pick_regions(gt)
    assert dark.crop(gt).mean() < 1.0 < 50.0 < bright.crop(gt).mean()


class _GroundTruthMethod:
    """A perfect "method": emits the held-out ground truth on the binned frame schedule."""

    input_kind = "rmb"

    def __init__(self, gt: np.ndarray) -> None:
        self.gt = gt
        self.readouts = 0

    def push(self, chunk) -> list[Frame]:
        self.readouts = chunk.stop
        return []

    def flush(self) -> list[Frame]:
        return [Frame(i, (10 * i + 5) / 10000, self.gt[i].copy()) for i in range(self.readouts // 10)]


def test_perfect_method_scores_maximal(sequence):
    scored = {i: sequence.gt[i] for i in sequence.scored_frames}
    psnr, ssim, pu21 = score_frames(scored, sequence)
    assert psnr == PSNR_CAP_DB and pu21 == PSNR_CAP_DB and ssim == pytest.approx(1.0, abs=1e-6)
    register_method(Method("test-ground-truth", lambda: _GroundTruthMethod(sequence.gt), "rmb", "ground truth"))
    try:
        result = run_method(MethodSpec("GT", "test-ground-truth"), sequence)
        tfw = run_method(MethodSpec("TFW-L", "tfw", {"window": 70, "step": 10}), sequence)
    finally:
        METHODS.pop("test-ground-truth")
    assert result.psnr == PSNR_CAP_DB and result.pu21 == PSNR_CAP_DB and result.ssim == pytest.approx(1.0, abs=1e-6)
    assert result.frames_emitted == 6 and sorted(result.frames) == [2, 3]
    assert tfw.psnr < result.psnr and tfw.ssim < result.ssim


def test_missing_scored_frame_is_an_error(sequence):
    class Late(_GroundTruthMethod):
        def flush(self) -> list[Frame]:
            return super().flush()[3:]  # no frame 2

    register_method(Method("test-late", lambda: Late(sequence.gt), "rmb", "late"))
    try:
        with pytest.raises(ValueError, match="no frame 2"):
            run_method(MethodSpec("late", "test-late"), sequence)
    finally:
        METHODS.pop("test-late")


def test_ablation_weights_found_flat_or_nested(tmp_path):
    save_model(tmp_path / "rmbnet-binned-w0.safetensors", RmbNet(RmbNetConfig(w=0, width=0.25)), ModelCard(name="w0"))
    specs = {s.name: s for s in table2_specs(tmp_path, device="cpu")}
    assert specs["w = 0"].available and specs["w = 0"].model_path == tmp_path / "rmbnet-binned-w0.safetensors"
    assert not specs["Pure-S"].available and specs["Pure-S"].readout == "pure-s"
    assert specs["Pure-S"].model_path == tmp_path / "ablations" / "rmbnet-binned-pure-s.safetensors"


def test_development_sequences_use_other_seeds_than_the_validation_set():
    """Candidates are chosen on the development sequences, so none of their seeds may be a held-out one."""
    from dataclasses import replace

    from rmbvideo.evaluate.heldout import (DEVELOPMENT_RANDOM_OFFSET, DEVELOPMENT_VIDEO_FIRST, FULL, VIDEO_KINDS,
                                           VIDEO_SEED_START, heldout_seeds)
    from rmbvideo.scenes.random_scenes import is_eval_seed

    development = heldout_seeds(replace(FULL, count=2, first_seed_offset=DEVELOPMENT_RANDOM_OFFSET))
    assert not set(development) & set(heldout_seeds(FULL)) and all(is_eval_seed(s) for s in development)
    video = {VIDEO_SEED_START + 100 * k + DEVELOPMENT_VIDEO_FIRST for k in range(len(VIDEO_KINDS))}
    validation = {VIDEO_SEED_START + 100 * k for k in range(len(VIDEO_KINDS))}
    assert DEVELOPMENT_VIDEO_FIRST >= 1 and not video & validation and not video & set(development)


def test_development_scores_candidates_on_the_given_sets(sequence, models_dir, tmp_path):
    """Each candidate gets finite scores on every development sequence, edge-frame deltas, a dark-end
    bias, and one table row; two different models score differently. The pictured frames and each real stream's
    scored frame are kept, and the figure sets every model beside the truth and the reference."""
    from rmbvideo.evaluate.development import LONG_SEED, development_figure, markdown, score_candidates
    from rmbvideo.evaluate.real_video import find_streams
    from rmbvideo.evaluate.texture_pans import TEXTURE_PANS, write_texture_pan
    from rmbvideo.evaluate.video_checks import band_sequence
    from rmbvideo.io.dat import DatGeometry

    torch.set_num_threads(1)
    (tmp_path / "other").mkdir()
    other = tmp_path / "other" / "rmbnet-binned.safetensors"
    torch.manual_seed(1)
    save_model(other, RmbNet(RmbNetConfig(w=1, width=0.25)), ModelCard(name="other"))
    models = [models_dir / "rmbnet-binned.safetensors", other]
    done = []
    still = band_sequence(32, 24, 12, static=True, seed=LONG_SEED, convention="spikezoo")
    camera = load_heldout_config(replace(TINY, reset="subtract"), tmp_path / "cache")[0]
    geometry = DatGeometry(64, 40)
    (tmp_path / "real").mkdir()
    write_texture_pan(TEXTURE_PANS[-1], tmp_path / "real", geometry)
    (stream,) = find_streams(tmp_path / "real", geometry)
    kind = sequence.name.rsplit("-", 1)[0]
    scores = score_candidates(models, [sequence], clips=[], real=[stream], done=lambda: done.append(1), long=[still],
                              camera=[camera], pictured={kind: ("first", "last")})
    assert len(done) == 2 and [s.name for s in scores] == [f"{models_dir.name}/rmbnet-binned", "other/rmbnet-binned"]
    for s in scores:
        assert list(s.sequences) == [sequence.name] and math.isfinite(s.sequence_mean)
        assert list(s.camera) == [f"{camera.name}/subtract"] and math.isfinite(s.camera[f"{camera.name}/subtract"])
        assert s.camera[f"{camera.name}/subtract"] != s.sequences[sequence.name]  # another pixel, another stream
        assert math.isfinite(s.first_frame_db) and math.isfinite(s.last_frame_db) and math.isfinite(s.dark_bias)
        assert not s.clips and list(s.real) == [stream.name] and math.isfinite(s.real[stream.name])
        assert s.real_frames[stream.name].image.shape == (20, 32)
        assert list(s.state_age) == [still.name] and math.isfinite(s.state_age[still.name])
        assert list(s.pictures) == [(sequence.name, 0), (sequence.name, len(sequence.gt) - 1)]
        assert all(image.shape == sequence.shape and np.isfinite(image).all() for image in s.pictures.values())
    assert scores[0].sequences != scores[1].sequences
    assert not np.array_equal(scores[0].pictures[sequence.name, 0], scores[1].pictures[sequence.name, 0])
    table = markdown(scores, models)
    assert table.count("| other/rmbnet-binned |") == 2 and "—" in table and f"{camera.name}/subtract" in table
    one, both = development_figure(scores[:1], [sequence], [stream]), development_figure(scores, [sequence], [stream])
    assert one.ndim == 3 and one.dtype == np.uint8 and both.shape[0] == one.shape[0] and both.shape[1] > one.shape[1]
    rows = development_figure(scores, [sequence])  # two pictured frames, no real stream: a shorter figure
    assert rows.shape[0] < both.shape[0]
    assert development_figure([replace(s, pictures={}) for s in scores], [sequence]) is None


def test_candidate_needs_development(models_dir, tmp_path):
    from click.testing import CliRunner

    from rmbvideo.cli import main

    result = CliRunner().invoke(main, ["evaluate", "--candidate", str(models_dir / "rmbnet-binned.safetensors"),
                                       "-o", str(tmp_path / "out")])
    assert result.exit_code == 2 and "--development" in result.output
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"not a model")
    result = CliRunner().invoke(main, ["evaluate", "--development", "--candidate", str(junk), "-o", str(tmp_path / "out")])
    assert result.exit_code == 2 and "junk" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "out" / "development.md").exists()


def test_a_users_own_streams_alone(tmp_path):
    """`evaluate --no-heldout --real-video DIR` scores only that folder's pairs (RMB-Net alone and with the raw gate
    among the rows) and writes no held-out table; a wrong folder fails at once, and --no-heldout with nothing else to
    score is a usage error; a rerun with other options names the earlier run's reports it left beside its own."""
    from click.testing import CliRunner

    from rmbvideo.cli import main
    from rmbvideo.evaluate.texture_pans import TEXTURE_PANS, write_texture_pan
    from rmbvideo.io.dat import DatGeometry

    (tmp_path / "mine").mkdir()
    write_texture_pan(TEXTURE_PANS[-1], tmp_path / "mine", DatGeometry(64, 40))
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["evaluate", "--no-heldout", "--real-video", str(tmp_path / "mine"), "-o",
                                       str(out), "--device", "cpu", "--full-resolution", "--quiet"])
    assert result.exit_code == 0, result.output
    table = (out / "real_video.md").read_text()
    assert "| **RMB-Net** |" in table and f"| **{GATED_ROW}** |" in table and TEXTURE_PANS[-1].name in table
    assert (out / "real_video.png").is_file() and not (out / "evaluation.md").exists()
    full = (out / "full_resolution.md").read_text()  # the stream alone: no synthetic mean
    assert TEXTURE_PANS[-1].name in full and "| — |" in full and "nan" not in full
    again = CliRunner().invoke(main, ["evaluate", "--no-heldout", "--real-video", str(tmp_path / "mine"), "-o",
                                      str(out), "--device", "cpu", "--quiet"])  # a rerun without --full-resolution
    assert again.exit_code == 0, again.output
    assert "full_resolution.md, full_resolution.png are from an earlier run" in again.output
    assert "real_video" not in again.output.split("earlier run")[0]
    result = CliRunner().invoke(main, ["evaluate", "--real-video", str(tmp_path / "nowhere"), "-o", str(out)])
    assert result.exit_code != 0 and "nowhere" in result.output and "Traceback" not in result.output
    result = CliRunner().invoke(main, ["evaluate", "--no-heldout", "-o", str(tmp_path / "none")])
    assert result.exit_code == 2 and "--real-video" in result.output
    assert not (tmp_path / "none").exists()  # a usage error leaves no output folder behind
    (tmp_path / "torn").mkdir()  # a stream whose reference is cut short: found, then unreadable mid-run
    (tmp_path / "torn" / "a.dat").write_bytes(next((tmp_path / "mine").glob("*.dat")).read_bytes())
    (tmp_path / "torn" / "a.png").write_bytes(next((tmp_path / "mine").glob("*.png")).read_bytes()[:100])
    result = CliRunner().invoke(main, ["evaluate", "--no-heldout", "--real-video", str(tmp_path / "torn"), "-o",
                                       str(tmp_path / "new" / "out"), "--device", "cpu", "--quiet"])
    assert result.exit_code == 2 and "a.png" in result.output, result.output
    assert not (tmp_path / "new").exists()  # a failed run leaves no empty output folder behind either


def test_rate_methods_are_scored_as_light_on_a_camera_stream_only():
    """TFP/TFI/TFW frames are spike rates: on a physical-convention stream the harness reads them through the same
    response RMB-Net is given (a rate of 0.5 is about 0.7 of a threshold per plane); spikezoo's rates are the light
    itself, and GC20/MG20 already estimate light."""
    import torch

    from rmbvideo.evaluate.harness import rate_as_light
    from rmbvideo.net.blend import reset_to_zero_intensity

    rate = np.array([[0.0, 0.1], [0.5, 0.87]], np.float32)
    light = rate_as_light("tfi", rate, "physical")
    np.testing.assert_allclose(light, reset_to_zero_intensity(torch.from_numpy(rate)).numpy())
    assert light[0, 0] == 0 and 0.1 < light[0, 1] < 0.11 and 0.6 < light[1, 0] < 0.8 and light[1, 1] > 1.0
    assert rate_as_light("tfi", rate, "spikezoo") is rate and rate_as_light("mg20", rate, "physical") is rate
    binned = rate_as_light("tfw", rate, "spikezoo", binned=True)  # the clamp's ceiling of 7/8 read as 1
    np.testing.assert_array_equal(binned[0], rate[0])
    assert binned[1, 0] == 0.5 and binned[1, 1] > 0.92
    assert rate_as_light("tfi", rate, "spikezoo", binned=True) is rate  # the binned stream's 1-bit plane: unclamped


def test_moving_region_is_where_the_frames_differ():
    rng = np.random.default_rng(2)
    before = (1.0 + rng.uniform(0, 0.2, (64, 96))).astype(np.float32)
    after = before.copy()
    after[40:56, 60:80] = 20.0  # a bright object arrived here
    moving = pick_moving_region(before, after)
    assert moving.size == 16 and moving.crop(after).mean() > 10.0


def test_real_capture_comparison_at_the_first_and_last_frame(tmp_path):
    """The real-capture figure: RMB-Net, TFP and TFI side by side at a clip's edge frames, three regions zoomed."""
    import cv2

    from rmbvideo.bench.memory import write_random_capture
    from rmbvideo.errors import InputError
    from rmbvideo.evaluate.table import real_capture_comparison

    capture = write_random_capture(tmp_path / "c.dat", 200, 400, 250, seed=4)
    for frame in ("first", "last"):
        png = real_capture_comparison(capture, tmp_path / f"{frame}.png", device="cpu", frame=frame)
        image = cv2.imread(str(png))
        assert image.shape[1] >= 3 * 200 and image.shape[0] >= 125 + 3 * 160  # 3 binned columns: frame, 3 zooms
    with pytest.raises(InputError, match="no frame 99"):
        real_capture_comparison(capture, tmp_path / "x.png", device="cpu", frame=99)
    assert not (tmp_path / "x.png").exists()


def test_full_resolution_table_has_the_synthetic_frame_to_frame_column():
    """The full-resolution table's "synthetic temporal" column is the mean of the synthetic sequences' temporal scores
    (real streams have one reference frame, so none), and a dash where no sequence has one."""
    from rmbvideo.evaluate.full_resolution import FullScores, markdown

    scores = FullScores(psnr={"a": {"TFI": 30.0}, "b": {"TFI": 32.0}, "real": {"TFI": 28.0}},
                        temporal={"a": {"TFI": 20.0}, "b": {"TFI": 24.0}}, fps={"TFI": [100.0]})
    table = markdown(scores, ["a", "b"], ["real"])
    assert "| synthetic temporal |" in table and "| TFI | 30.00 | 32.00 | 28.00 | 31.00 | 28.00 | 22.00 | 100.0 |" in table
    assert "| TFI | 28.00 | — | 28.00 | — | 100.0 |" in markdown(FullScores(psnr={"real": {"TFI": 28.0}},
                                                                       fps={"TFI": [100.0]}), [], ["real"])


def test_evaluate_precision_reaches_every_rmbnet_row(tmp_path):
    """`evaluate --precision` is the network's precision in every table's RMB-Net rows: forced bf16 moves their
    frames against fp32 and leaves the classical rows as they were; the CLI takes the option, and refuses it with
    --development, which would not use it."""
    from click.testing import CliRunner

    from rmbvideo.cli import main
    from rmbvideo.evaluate.full_resolution import full_rows
    from rmbvideo.evaluate.real_video import evaluate_streams, find_streams, real_video_rows
    from rmbvideo.evaluate.texture_pans import TEXTURE_PANS, write_texture_pan
    from rmbvideo.io.dat import DatGeometry
    from rmbvideo.net.weights import MODELS_DIR

    specs = table2_specs(MODELS_DIR, "cpu", "fp32")
    assert all(s.options["precision"] == "fp32" for s in specs if s.method == "rmbnet")
    assert all(r.options["precision"] == "bf16" for r in full_rows(precision="bf16") if r.method == "rmbnet")
    write_texture_pan(TEXTURE_PANS[-1], tmp_path, DatGeometry(64, 40))
    streams = find_streams(tmp_path)
    scores = {p: evaluate_streams(streams, real_video_rows(device="cpu", precision=p))[streams[0].name]
              for p in ("fp32", "bf16")}
    assert not np.array_equal(scores["fp32"]["RMB-Net"].image, scores["bf16"]["RMB-Net"].image)
    assert np.array_equal(scores["fp32"]["MG20"].image, scores["bf16"]["MG20"].image)
    result = CliRunner().invoke(main, ["evaluate", "--no-heldout", "--real-video", str(tmp_path), "-o",
                                       str(tmp_path / "out"), "--device", "cpu", "--precision", "fp32", "--quiet"])
    assert result.exit_code == 0, result.output
    refused = CliRunner().invoke(main, ["evaluate", "--development", "--precision", "bf16", "-o", str(tmp_path / "dev")])
    assert refused.exit_code == 2 and "--precision" in refused.output and not (tmp_path / "dev").exists()


def test_development_table_has_the_frame_to_frame_mean():
    """The candidates' table puts each model's mean frame-to-frame score beside its per-frame mean (a dash when the
    sequences gave none)."""
    from rmbvideo.evaluate.development import DevelopmentScore, markdown

    score = DevelopmentScore("a", {"s1": 30.0, "s2": 32.0}, -1.0, 0.5, {}, {}, 0.01, {}, temporal={"s1": 27.0, "s2": 29.0})
    table = markdown([score, DevelopmentScore("b", {"s1": 30.0, "s2": 30.0}, 0.0, 0.0, {}, {}, 0.0, {})],
                     [Path("a"), Path("b")])
    assert "| frame to frame (temporal mu-PSNR) |" in table
    assert "| a | 31.00 | 28.00 | -1.00 / +0.50 |" in table and "| b | 30.00 | — | +0.00 / +0.00 |" in table


def test_a_stream_unlike_its_reference_is_warned_of(tmp_path, caplog):
    """A pair whose .dat is not laid out as its PNG says (the spikes read as garbage) scores near nothing; the
    evaluation says so, naming the capture and the layout, where a right pair is scored without a word."""
    import cv2

    from rmbvideo.evaluate.real_video import RAW_STEP, RealRow, find_streams, score_stream
    from rmbvideo.evaluate.texture_pans import TEXTURE_PANS, write_texture_pan
    from rmbvideo.io.dat import DatGeometry

    rows = [RealRow("TFP-41 (raw, 2x2-avg)", "tfp", {"window": 41, "step": RAW_STEP}, raw=True)]
    write_texture_pan(TEXTURE_PANS[-1], tmp_path, DatGeometry(64, 40))
    (stream,) = find_streams(tmp_path)
    with caplog.at_level("WARNING", logger="rmbvideo.evaluate.real_video"):
        right = score_stream(stream, rows)
    assert not caplog.records and right[rows[0].name].ssim > 0.5
    png = cv2.imread(str(stream.reference), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(stream.reference), cv2.resize(png, (80, 32)))  # the same pixels a plane, laid out 80x32
    (wrong,) = find_streams(tmp_path)
    with caplog.at_level("WARNING", logger="rmbvideo.evaluate.real_video"):
        scores = score_stream(wrong, rows)
    assert scores[rows[0].name].ssim < 0.3
    (record,) = caplog.records
    assert wrong.capture.name in record.getMessage() and "80x32" in record.getMessage()


def test_a_users_folder_pairs_either_case_and_names_the_captures_it_leaves_out(tmp_path, caplog):
    """A folder of a user's pairs: `.DAT`/`.PNG` pair as `.dat`/`.png` do, and a capture without a reference is named
    in one warning rather than quietly left out of the table."""
    from rmbvideo.evaluate.real_video import find_streams
    from rmbvideo.evaluate.texture_pans import TEXTURE_PANS, write_texture_pan
    from rmbvideo.io.dat import DatGeometry

    write_texture_pan(TEXTURE_PANS[-1], tmp_path, DatGeometry(64, 40))
    (stream,) = find_streams(tmp_path)
    stream.capture.rename(tmp_path / "LOUD.DAT")
    stream.reference.rename(tmp_path / "LOUD.PNG")
    (tmp_path / "orphan.dat").write_bytes((tmp_path / "LOUD.DAT").read_bytes())
    with caplog.at_level("WARNING", logger="rmbvideo.evaluate.real_video"):
        (found,) = find_streams(tmp_path)
    assert found.name == "LOUD" and found.reference.name == "LOUD.PNG"
    (record,) = caplog.records
    assert "orphan.dat" in record.getMessage() and "LOUD" not in record.getMessage()

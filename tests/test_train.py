"""Training: random scenes, cached samples, loss, TBPTT, resumable CLI runs, shipped models."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from rmbvideo.cli import main
from rmbvideo.errors import InputError
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.model import RmbNet
from rmbvideo.train.checkpoint import CHECKPOINT_FORMAT, checkpoint_paths, load_checkpoint
from rmbvideo.train.config import RECIPES_DIR, load_recipe
from rmbvideo.train.dataset import SampleCache, SampleSpec, simulate_sample
from rmbvideo.train.batch import Batch
from rmbvideo.net.model import window_indices
from rmbvideo.train.loop import Trainer, segment_losses, train_batch
from rmbvideo.train.validation import tfw_prediction
from rmbvideo.train.loss import LossConfig
from rmbvideo.scenes.random_scenes import (EVAL_SEED_START, HELD_OUT_PANORAMA, TRAIN_PANORAMAS,
                                          random_scene)

MODELS_DIR = Path(__file__).resolve().parents[1] / "models"
TINY_SPEC = SampleSpec(mode="binned", crop=16, frames=5, n=4, warmup_frames=1)

TINY_RECIPE = """
name = "tiny"
seed = 3
minutes = 5

[data]
mode = "binned"
count = 2
crop = 16
steps = 3
n = 4
warmup_frames = 1
val_count = 1

[model]
w = 1
width = 0.25

[optim]
lr = 3e-3
steps = {steps}
batch = 1
tbptt = 2
threads = 1
val_every = 2
checkpoint_every = 1
"""


@pytest.fixture(autouse=True)
def one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def _panoramas(scene) -> set[str]:
    names = {scene.background.panorama}
    names |= {o.texture.split(":", 1)[1] for o in scene.objects if o.texture.startswith("panorama:")}
    return names


def test_random_scenes_are_reproducible_and_hold_out_a_panorama():
    assert random_scene(7, 64, 64, 0.01) == random_scene(7, 64, 64, 0.01)
    assert random_scene(7, 64, 64, 0.01) != random_scene(8, 64, 64, 0.01)
    train = set().union(*(_panoramas(random_scene(s, 64, 64, 0.01)) for s in range(60)))
    held = set().union(*(_panoramas(random_scene(EVAL_SEED_START + s, 64, 64, 0.01)) for s in range(60)))
    assert train <= set(TRAIN_PANORAMAS) and HELD_OUT_PANORAMA not in train
    assert HELD_OUT_PANORAMA in held
    lights = [o.radiance for s in range(60) for o in random_scene(s, 64, 64, 0.01).objects if o.radiance >= 10]
    assert lights and max(lights) > 100


@pytest.mark.parametrize("mode", ["binned", "native"])
def test_sample_shapes_ranges_and_units(mode):
    spec = SampleSpec(mode=mode, crop=16, frames=4, n=5, warmup_frames=1)
    sample = simulate_sample(spec, 11)
    assert sample.i_s.shape == sample.i_m.shape == sample.gt.shape == (4, 16, 16)
    assert sample.m_valid.shape == (4, 16) and sample.m_valid.all()
    assert 0 <= sample.i_s.min() and sample.i_s.max() <= 5
    assert 0 <= sample.i_m.min() and sample.i_m.max() <= 7 * 5
    assert np.isfinite(sample.gt).all() and sample.gt.min() >= 0
    assert np.all(np.diff(sample.times_s) > 0)
    # TFW from the same frames estimates the ground truth where it is below saturation.
    tfw = tfw_prediction(sample, 1, 1, 5, spec.quanta)
    gt = sample.gt[1]
    assert np.isfinite(tfw).all() and tfw.min() >= 0
    if mode == "binned":  # native RMB band values are not per-readout rates (see tfw_prediction)
        mid = (gt > 0.05) & (gt < 0.6)
        assert mid.sum() > 10
        assert 0.6 < np.median(tfw[mid] / gt[mid]) < 1.5


def test_cache_hit_does_not_resimulate(tmp_path):
    first = SampleCache(tmp_path, TINY_SPEC)
    a = first.get(5)
    assert first.simulated == 1 and first.path(5).is_file()
    with np.load(first.path(5), allow_pickle=False) as data:
        assert set(data.files) == {"i_s", "i_m", "gt", "m_valid", "times_s", "i_c", "convention"}
    second = SampleCache(tmp_path, TINY_SPEC)
    b = second.get(5)
    assert second.simulated == 0
    np.testing.assert_array_equal(a.i_m, b.i_m)
    np.testing.assert_array_equal(a.gt, b.gt)
    first.path(5).write_bytes(b"not an npz")  # a damaged file is simulated again, identically
    c = second.get(5)
    assert second.simulated == 1
    np.testing.assert_array_equal(a.i_s, c.i_s)
    other = SampleCache(tmp_path, SampleSpec(mode="binned", readout="pure-s", crop=16, frames=5, n=4))
    assert other.dir != first.dir


def _tiny_model(w: int = 1) -> RmbNet:
    torch.manual_seed(0)
    return RmbNet(RmbNetConfig(w=w, width=0.25, n=4))


def test_loss_is_finite_and_decreases_on_a_fixed_batch(tmp_path):
    cache = SampleCache(tmp_path, TINY_SPEC)
    batch = Batch.from_samples([cache.get(0), cache.get(1)], torch.device("cpu"))
    model = _tiny_model()
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(8):
        optimizer.zero_grad()
        parts = train_batch(model, batch, tbptt=2, loss_config=LossConfig())
        assert all(np.isfinite(v) for v in parts.values())
        optimizer.step()
        losses.append(parts["loss"])
    assert losses[-1] < 0.9 * losses[0]


def test_aligned_model_trains_on_batches_with_their_aligned_means(tmp_path):
    """A model that reads the aligned window mean gets it from the batch (computed on the mirrored
    counts, with the model's radius and edge policy) and trains with a finite loss and gradients on the head."""
    from rmbvideo.recon.aligned_box import AlignedBoxConfig, aligned_means
    from rmbvideo.recon.prelim import select_centre

    samples = [SampleCache(tmp_path, TINY_SPEC).get(k) for k in (0, 1)]
    config = RmbNetConfig(w=1, width=0.25, n=4, readout="pure-m", blend=True, aligned=True, aligned_radius=2,
                          aligned_shift=True, aligned_centre=2)
    batch = Batch.from_samples(samples, torch.device("cpu"), flips=[True, False], n=4, aligned=config)
    scale = 8 * 4
    sharp = select_centre(samples[0].i_c, 4, (2,))[:, 0, :, ::-1] / (8 * 2)
    expected = aligned_means(samples[0].i_m[..., ::-1] / scale, 2, AlignedBoxConfig.for_frames(4, 2), True, sharp) * scale
    assert batch.i_a.shape[2] == 2
    np.testing.assert_allclose(batch.i_a[0].numpy(), expected, rtol=1e-5, atol=1e-5)
    assert Batch.from_samples(samples, torch.device("cpu"), n=4).i_a is None
    torch.manual_seed(0)
    model = RmbNet(config)
    parts = train_batch(model, batch, tbptt=2, loss_config=LossConfig())
    assert all(np.isfinite(v) for v in parts.values())
    assert model.decoder.head[-1].weight.grad is not None and model.decoder.head[-1].weight.grad.abs().sum() > 0


def test_evidence_model_trains_on_batches_with_the_means_statistics(tmp_path):
    """A model that reads the aligned mean's statistics (``aligned_evidence``) gets them after the means in ``i_a``,
    unscaled (the means in sums), and its head's new inputs get gradients."""
    from rmbvideo.recon.aligned_box import STATISTICS, AlignedBoxConfig, aligned_means

    samples = [SampleCache(tmp_path, TINY_SPEC).get(k) for k in (0, 1)]
    config = RmbNetConfig(w=1, width=0.25, n=4, readout="pure-m", blend=True, aligned=True, aligned_radius=2,
                          aligned_evidence=True)
    batch = Batch.from_samples(samples, torch.device("cpu"), flips=[False, True], n=4, aligned=config)
    scale = 8 * 4
    means, statistics = aligned_means(samples[1].i_m[..., ::-1] / scale, 2, AlignedBoxConfig.for_frames(4), False,
                                      statistics=True)
    assert batch.i_a.shape[2] == 1 + len(STATISTICS)
    np.testing.assert_allclose(batch.i_a[1, :, 0].numpy(), means * scale, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(batch.i_a[1, :, 1:].numpy(), statistics, rtol=1e-6, atol=1e-7)
    torch.manual_seed(0)
    model = RmbNet(config)
    parts = train_batch(model, batch, tbptt=2, loss_config=LossConfig())
    assert all(np.isfinite(v) for v in parts.values())
    assert model.decoder.head[0][0].weight.grad[:, -len(STATISTICS):].abs().sum() > 0


def _graph_size(tensor: torch.Tensor) -> int:
    seen, stack = set(), [tensor.grad_fn]
    while stack:
        node = stack.pop()
        if node is None or node in seen:
            continue
        seen.add(node)
        stack.extend(n for n, _ in node.next_functions)
    return len(seen)


def test_tbptt_cuts_the_graph_between_segments(tmp_path):
    sample = SampleCache(tmp_path, SampleSpec(mode="binned", crop=16, frames=7, n=4, warmup_frames=1)).get(0)
    batch = Batch.from_samples([sample], torch.device("cpu"))
    model = _tiny_model()
    sizes = []
    segments = []
    for segment in segment_losses(model, batch, tbptt=1, loss_config=LossConfig()):
        if segment.state_in is not None:
            assert all(not t.requires_grad and t.grad_fn is None for pair in segment.state_in for t in pair)
        sizes.append(_graph_size(segment.loss))
        segment.loss.backward()
        segments.append(segment)
    assert len(segments) == 5  # K = 7 - 2w outputs, one per segment
    assert segments[0].state_in is None and segments[1].state_in is not None
    assert len(set(sizes[1:])) == 1  # later segments do not grow: the graph is bounded
    whole = next(segment_losses(model, batch, tbptt=5, loss_config=LossConfig()))
    assert _graph_size(whole.loss) > 3 * sizes[1]


def test_aged_passes_start_the_supervised_run_from_a_state_run_over_the_outputs_without_gradients(tmp_path):
    """One pass is the engine's priming (backwards over the outputs after the first); three passes go back, forth and
    back; the state carries no graph, and the supervised losses change with it."""
    from rmbvideo.train.loop import aged_state

    sample = SampleCache(tmp_path, SampleSpec(mode="binned", crop=16, frames=8, n=4, warmup_frames=1)).get(0)
    batch = Batch.from_samples([sample], torch.device("cpu"))
    model = _tiny_model()
    w, count = model.config.w, batch.i_s.shape[1]
    outputs = range(w, count - w)
    assert aged_state(model, batch, outputs, 0) is None
    with torch.no_grad():
        frames = model.encode(batch.i_s[0], batch.i_m[0], range(count))
        state = None
        for i in reversed(outputs[1:]):
            state = model.step_backward([frames[j] for j in window_indices(i, w, count)], state)
        primed = state
        for i in outputs[:-1]:
            state = model.step([frames[j] for j in window_indices(i, w, count)], state)[1]
        for i in reversed(outputs[1:]):
            state = model.step_backward([frames[j] for j in window_indices(i, w, count)], state)
    for passes, expected in ((1, primed), (3, state)):
        aged = aged_state(model, batch, outputs, passes)
        for (h, c), (h_ref, c_ref) in zip(aged, expected):
            assert not h.requires_grad and h.grad_fn is None
            torch.testing.assert_close(h, h_ref)
            torch.testing.assert_close(c, c_ref)
    fresh = next(segment_losses(model, batch, tbptt=1, loss_config=LossConfig()))
    old = next(segment_losses(model, batch, tbptt=1, loss_config=LossConfig(), aged_passes=3))
    assert fresh.state_in is None and old.state_in is not None
    assert not torch.isclose(fresh.loss, old.loss)


def _csv_steps(path: Path) -> list[int]:
    with path.open(newline="") as fh:
        return [int(r["step"]) for r in csv.DictReader(fh)]


def test_ctrl_c_of_a_training_run_with_simulation_workers_ends_in_one_line(tmp_path):
    """A terminal's Ctrl-C reaches the prefetching workers too: the run still ends in one line, exit 130, no worker
    traceback, with its checkpoint kept for --resume."""
    recipe = tmp_path / "tiny.toml"
    recipe.write_text(TINY_RECIPE.format(steps=100000).replace('mode = "binned"', 'mode = "binned"\nscenes = "video"')
                      .replace("val_every = 2", "val_every = 100000"))
    out = tmp_path / "out"
    proc, stderr = _stopped_when_logged([sys.executable, "-m", "rmbvideo", "train", str(recipe), "--out", str(out),
                                         "--workers", "2", "-q"], out / "loss.csv", 4, lambda p: os.killpg(
                                             p.pid, signal.SIGINT))
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    model = RmbNet(load_recipe(recipe).model)
    step = load_checkpoint(out, model, torch.optim.Adam(model.parameters())).step
    assert stderr.strip().splitlines()[-1] == (f"rmbvideo: interrupted; the checkpoint of step {step} is saved in "
                                               f"{out}; --resume continues from it")
    assert all(path.is_file() for path in checkpoint_paths(out))


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads signal dispositions from /proc")
def test_simulation_workers_ignore_ctrl_c_from_birth():
    """The workers start when the prefetcher does, SIGINT already ignored while they import: a Ctrl-C then reached a
    worker before its initializer and printed its traceback (seen in CI under load)."""
    from rmbvideo.train.dataset import SamplePrefetcher

    prefetcher = SamplePrefetcher(None, lambda step: [], workers=2)
    try:
        pids = list(prefetcher._pool._processes)
        assert len(pids) == 2 and signal.getsignal(signal.SIGINT) is signal.default_int_handler
        for pid in pids:
            line = next(l for l in Path(f"/proc/{pid}/status").read_text().splitlines() if l.startswith("SigIgn"))
            assert int(line.split()[1], 16) & (1 << (signal.SIGINT - 1)), line
    finally:
        prefetcher.close()


def test_a_stopped_run_saves_the_step_it_stood_at_and_resumes_from_it(tmp_path):
    """A SIGTERM (a scheduler's, say) between checkpoints used to lose every step since the last one; the run now
    saves the checkpoint of its last whole step, says so in its one line, and --resume continues from that step."""
    recipe = tmp_path / "tiny.toml"
    text = TINY_RECIPE.replace("checkpoint_every = 1", "checkpoint_every = 100000").replace("val_every = 2",
                                                                                          "val_every = 100000")
    recipe.write_text(text.format(steps=100000))
    out, cache = tmp_path / "out", tmp_path / "cache"
    args = [sys.executable, "-m", "rmbvideo", "train", str(recipe), "--out", str(out), "--cache", str(cache), "-q"]
    proc, stderr = _stopped_when_logged(args, out / "loss.csv", 5, lambda p: p.send_signal(signal.SIGTERM))
    assert proc.returncode == 143, stderr
    model = RmbNet(load_recipe(recipe).model)
    step = load_checkpoint(out, model, torch.optim.Adam(model.parameters())).step
    logged = _csv_steps(out / "loss.csv")
    assert step >= 4 and step in (logged[-1], logged[-1] + 1)  # the stop may land between a step and its row
    assert stderr.strip().splitlines() == [f"rmbvideo: stopped by SIGTERM; the checkpoint of step {step} is saved in "
                                           f"{out}; --resume continues from it"]
    recipe.write_text(text.format(steps=step + 1))
    result = CliRunner().invoke(main, ["train", str(recipe), "--out", str(out), "--cache", str(cache), "--resume",
                                       "-q"])
    assert result.exit_code == 0, result.output
    assert _csv_steps(out / "loss.csv")[-1] == step + 1
    assert load_checkpoint(out, model, torch.optim.Adam(model.parameters())).step == step + 1


def test_a_checkpoint_cut_between_its_two_writes_resumes_from_its_tensors(tmp_path):
    """The tensors' header holds the whole state, so a stale or missing checkpoint.json (a crash between the two
    writes) no longer makes a checkpoint unresumable; one from before the header held it still needs the JSON to
    agree."""
    from safetensors.torch import load_file, save_file

    recipe = tmp_path / "tiny.toml"
    recipe.write_text(TINY_RECIPE.format(steps=1))
    out = tmp_path / "out"
    Trainer(load_recipe(recipe), out, cache_dir=tmp_path / "cache").run()
    tensors, meta = checkpoint_paths(out)
    stale = json.loads(meta.read_text())
    recipe.write_text(TINY_RECIPE.format(steps=3))
    Trainer(load_recipe(recipe), out, cache_dir=tmp_path / "cache", resume=True).run()
    meta.write_text(json.dumps(stale))  # the step-1 JSON beside the step-3 tensors
    model = RmbNet(load_recipe(recipe).model)
    optimizer = torch.optim.Adam(model.parameters())
    assert load_checkpoint(out, model, optimizer).step == 3
    assert all(float(s["step"]) == 3 for s in optimizer.state_dict()["state"].values())
    meta.unlink()
    assert load_checkpoint(out, model, torch.optim.Adam(model.parameters())).step == 3
    save_file(load_file(str(tensors)), str(tensors), metadata={"format": CHECKPOINT_FORMAT, "step": "3"})  # older
    meta.write_text(json.dumps(stale))
    with pytest.raises(InputError, match="checkpoint files disagree"):
        load_checkpoint(out, model, torch.optim.Adam(model.parameters()))
    meta.write_text(json.dumps({**stale, "step": 3}))
    assert load_checkpoint(out, model, torch.optim.Adam(model.parameters())).step == 3


def _stopped_when_logged(args: list[str], log: Path, lines: int, stop) -> tuple[subprocess.Popen, str]:
    """Run ``args`` in a session of its own, ``stop(process)`` once ``log`` has ``lines`` lines; (process, stderr)."""
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and proc.poll() is None and len(_lines(log)) < lines:
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()[1]
        stop(proc)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc, stderr


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines() if path.exists() else []


def test_cli_train_resume_and_card(tmp_path):
    recipe = tmp_path / "tiny.toml"
    recipe.write_text(TINY_RECIPE.format(steps=2))
    out, cache = tmp_path / "out", tmp_path / "cache"
    runner = CliRunner()
    result = runner.invoke(main, ["train", str(recipe), "--out", str(out), "--cache", str(cache), "-q"])
    assert result.exit_code == 0, result.output
    assert _csv_steps(out / "loss.csv") == [1, 2]
    model = RmbNet(load_recipe(recipe).model)
    optimizer = torch.optim.Adam(model.parameters())
    state = load_checkpoint(out, model, optimizer)
    assert state.step == 2
    assert all(float(s["step"]) == 2 for s in optimizer.state_dict()["state"].values())
    saved = {k: v.clone() for k, v in model.state_dict().items()}

    recipe.write_text(TINY_RECIPE.format(steps=4))
    result = runner.invoke(main, ["train", str(recipe), "--out", str(out), "--cache", str(cache), "--resume", "-q"])
    assert result.exit_code == 0, result.output
    assert _csv_steps(out / "loss.csv") == [1, 2, 3, 4]
    resumed = RmbNet(load_recipe(recipe).model)
    assert load_checkpoint(out, resumed, torch.optim.Adam(resumed.parameters())).step == 4
    changed = [k for k in saved if not torch.equal(saved[k], resumed.state_dict()[k])]
    assert changed  # training went on from the checkpoint

    card = json.loads((out / "tiny.json").read_text())
    assert card["training"]["steps_done"] == 4 and "gradient L1" in card["training"]["lpips"]
    assert card["training"]["recipe"] == recipe.read_text()
    assert card["data"]["held_out_panorama"] == HELD_OUT_PANORAMA
    assert np.isfinite(card["metrics"]["val_mu_psnr"])
    from rmbvideo.net.weights import load_model

    loaded, _ = load_model(out / "tiny.safetensors", expect_input_mode="binned")
    assert loaded.config.w == 1 and loaded.config.n == 4


def test_trainable_prefixes_freeze_the_rest_batchnorm_included(tmp_path):
    recipe = tmp_path / "tiny.toml"
    recipe.write_text(TINY_RECIPE.format(steps=2).replace("threads = 1", 'threads = 1\ntrainable = ["decoder.head"]'))
    config = load_recipe(recipe)
    trainer = Trainer(config, tmp_path / "out", cache_dir=tmp_path / "cache")
    before = {k: v.clone() for k, v in trainer.model.state_dict().items()}
    trainer.run()
    changed = {k for k, v in trainer.model.state_dict().items() if not torch.equal(before[k], v)}
    assert changed and all(k.startswith("decoder.head.") for k in changed)  # BN running stats included
    card = json.loads((tmp_path / "out" / "tiny.json").read_text())
    assert "trained only decoder.head" in card["training"]["optimizer"]
    recipe.write_text(TINY_RECIPE.format(steps=2).replace("threads = 1", 'threads = 1\ntrainable = ["decoder.nothing"]'))
    with pytest.raises(InputError, match="decoder.nothing"):
        Trainer(load_recipe(recipe), tmp_path / "out2", cache_dir=tmp_path / "cache")


def test_warm_start_widens_the_head_and_starts_new_logits_where_the_recipe_says(tmp_path):
    """A warm start into a model with one more blend candidate keeps the old head outputs and
    input weights, zeroes the new input channel, and starts the new logit's bias at init_new_logit."""
    from rmbvideo.net.weights import ModelCard, save_model

    old = RmbNet(RmbNetConfig(w=1, width=0.25, n=4, readout="pure-m", blend=True))
    torch.nn.init.normal_(old.decoder.head[-1].weight, std=0.1)
    source = save_model(tmp_path / "old.safetensors", old, ModelCard("old"))
    recipe = tmp_path / "tiny.toml"
    text = TINY_RECIPE.format(steps=1).replace("width = 0.25", 'width = 0.25\nblend = true\naligned = true')
    text = text.replace('minutes = 5', f'minutes = 5\ninit = "{source}"\ninit_new_logit = 3.5')
    recipe.write_text(text.replace('mode = "binned"', 'mode = "binned"\nreadout = "pure-m"'))
    trainer = Trainer(load_recipe(recipe), tmp_path / "out", cache_dir=tmp_path / "cache")
    last_old, last_new = old.decoder.head[-1], trainer.model.decoder.head[-1]
    outputs = last_old.bias.shape[0]
    assert last_new.bias.shape[0] == outputs + 1
    torch.testing.assert_close(last_new.bias[:outputs], last_old.bias)
    assert float(last_new.bias[-1].detach()) == 3.5
    first_old, first_new = old.decoder.head[0][0], trainer.model.decoder.head[0][0]
    inputs = first_old.weight.shape[1]
    torch.testing.assert_close(first_new.weight[:, :inputs], first_old.weight)
    assert not first_new.weight[:, inputs:].any()
    recipe.write_text(text.replace(f'init = "{source}"\n', ""))
    with pytest.raises(InputError, match="init_new_logit"):
        load_recipe(recipe)
    narrower = tmp_path / "narrower.toml"  # a recipe without the old model's inputs: an error, not fresh weights
    narrower.write_text(TINY_RECIPE.format(steps=1).replace('minutes = 5', f'minutes = 5\ninit = "{source}"'))
    with pytest.raises(InputError, match="cannot widen decoder.head"):
        Trainer(load_recipe(narrower), tmp_path / "out2", cache_dir=tmp_path / "cache")


def test_time_budget_stops_cleanly_and_still_saves(tmp_path):
    recipe = tmp_path / "tiny.toml"
    recipe.write_text(TINY_RECIPE.format(steps=100))
    config = load_recipe(recipe).with_minutes(1e-9)
    result = Trainer(config, tmp_path / "out", cache_dir=tmp_path / "cache").run()
    assert result.stopped_by == "time budget" and result.steps == 0
    assert result.weights.is_file() and np.isfinite(result.metrics["val_mu_psnr"])


def test_a_run_without_resume_is_refused_over_an_earlier_checkpoint(tmp_path):
    """A forgotten --resume replaced the checkpoint (and the days of training it held) at its first save; now it is
    refused with the step named, and --overwrite starts afresh over it."""
    recipe = tmp_path / "tiny.toml"
    recipe.write_text(TINY_RECIPE.format(steps=2))
    out, cache = tmp_path / "out", tmp_path / "cache"
    args = ["train", str(recipe), "--out", str(out), "--cache", str(cache), "-q"]
    assert CliRunner().invoke(main, args).exit_code == 0
    kept = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2 and f"{out}: holds the checkpoint of an earlier run at step 2" in result.output
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == kept
    assert CliRunner().invoke(main, [*args, "--resume", "--overwrite"]).exit_code == 2
    recipe.write_text(TINY_RECIPE.format(steps=1))
    assert CliRunner().invoke(main, [*args, "--overwrite"]).exit_code == 0
    assert _csv_steps(out / "loss.csv") == [1]


def test_resume_without_checkpoint_is_an_input_error(tmp_path):
    recipe = tmp_path / "tiny.toml"
    recipe.write_text(TINY_RECIPE.format(steps=1))
    result = CliRunner().invoke(main, ["train", str(recipe), "--out", str(tmp_path / "none"), "--resume"])
    assert result.exit_code == 2 and "no checkpoint" in result.output


def test_bundled_recipes_parse_and_bad_keys_are_refused(tmp_path):
    names = {p.stem for p in RECIPES_DIR.glob("*.toml")}
    assert {"cpu", "gpu", "native-cpu", "ablation-w0", "ablation-pure-s", "ablation-pure-m",
            "ablation-full-m", "ablation-no-xba", "ablation-no-xta"} <= names
    configs = {name: load_recipe(RECIPES_DIR / f"{name}.toml") for name in names}
    assert configs["cpu"].model.input_mode == "binned" and configs["native-cpu"].model.input_mode == "native"
    assert configs["ablation-w0"].model.w == 0 and not configs["ablation-no-xba"].model.use_xba
    assert configs["ablation-pure-s"].data.readout == "pure-s"
    wide = configs["video-aligned-wide-cpu"].model
    assert wide.aligned_half_width == 5 and wide.aligned_shift and configs["video-aligned-cpu"].model.aligned_half_width == 3
    repo = RECIPES_DIR.parents[2]
    for name, config in configs.items():  # a stage's start is a file kept in the repository
        assert not config.init or not config.init.endswith(".safetensors") or (repo / config.init).is_file(), name
    floor = configs["video-aligned-sharp-floor-cpu"].sample_spec()
    dark = configs["video-aligned-sharp-dark-cpu"].sample_spec()
    assert floor.flat_min_rate == 1e-4 and dark.flat_min_rate == 1e-3 and floor.key() != dark.key()
    assert configs["cpu"].source == "rmbvideo/train/recipes/cpu.toml"  # the same in every card, on every machine
    other = configs["ablation-w0"].with_seed(3)  # a comparison's spread: other weights and scenes, same recipe
    assert other.seed == 3 and other.sample_spec() == configs["ablation-w0"].sample_spec()
    gpu = configs["video-gpu"].with_workers(15)
    assert gpu.data.workers == 15 and gpu.sample_spec() == configs["video-gpu"].sample_spec()
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\n[optim]\nlearning_rate = 1.0\n')
    with pytest.raises(InputError, match="learning_rate"):
        load_recipe(bad)
    bad.write_text('name = "x"\n[model]\naligned_radius = 2.5\n')
    with pytest.raises(InputError, match="aligned_radius"):
        load_recipe(bad)


@pytest.mark.parametrize("mode", ["binned", "native"])
def test_shipped_models_load_and_match_their_cards(mode):
    from rmbvideo.net.weights import load_model

    weights = MODELS_DIR / f"rmbnet-{mode}.safetensors"
    assert weights.stat().st_size < 5 * 1024 * 1024
    model, card = load_model(weights, expect_input_mode=mode)
    assert model.config.input_mode == mode and model.config.n == 10 and model.config.w == 3
    document = json.loads(weights.with_suffix(".json").read_text())
    assert document["architecture"] == model.config.to_dict()
    assert card.metrics["val_mu_psnr"] > card.metrics["val_tfw_mu_psnr"]
    recipe_text = card.training["recipe"]
    assert f'mode = "{mode}"' in recipe_text
    windows = model.config.centre_windows  # central sums at the frame's mean rate
    with torch.no_grad():
        i_s = torch.full((1, 7, 16, 16), 3.0)
        i_c = torch.stack([i_s * 8 * k / 10 for k in windows], dim=2) if windows else None
        # a still scene: each aligned mean (whole frame, central readouts) is the frame's own rate; its evidence: no
        # flow, every neighbour kept, no spread (aligned_box.STATISTICS)
        channels = model.config.aligned_channels
        evidence = torch.tensor([0.0, 0.0, 1.0, 0.0])[: model.config.evidence_channels].reshape(1, 1, -1, 1, 1)
        i_a = (torch.cat([torch.stack([i_s * 8] * channels, dim=2), evidence.expand(1, 7, -1, 16, 16)], dim=2)
               if channels else None)
        out, _ = model.forward_sequence(i_s, i_s * 8, i_c=i_c, i_a=i_a)
    assert torch.isfinite(out).all()


def test_l2_weight_scales_only_the_mu_law_l2():
    """``loss.l2`` weighs the mu-law L2 (the evaluation's PSNR) against the other terms, and only it."""
    from rmbvideo.mulaw import mu_law
    from rmbvideo.train.loss import reconstruction_loss

    rng = np.random.default_rng(1)
    truth = torch.from_numpy(rng.uniform(0.0, 0.5, (2, 24, 24)).astype(np.float32))
    guess = mu_law(truth * torch.from_numpy(rng.uniform(0.8, 1.2, (2, 24, 24)).astype(np.float32)), 5000.0)
    one, parts = reconstruction_loss(guess, truth, LossConfig(linear=1.0, regional=1.0))
    fifty, again = reconstruction_loss(guess, truth, LossConfig(l2=50.0, linear=1.0, regional=1.0))
    assert parts == again and parts["l2"] > 0
    assert float(fifty - one) == pytest.approx(49 * parts["l2"], rel=1e-4)


def test_regional_loss_asks_for_the_mean_not_the_median():
    """On a sparse field (a few spikes per pixel: the pixel values' median sits below their mean) the
    regional term is smallest for a prediction at the block means; the pixel-wise linear L1 prefers the
    median, which is why the regional term is there."""
    from rmbvideo.mulaw import mu_law
    from rmbvideo.train.loss import reconstruction_loss

    rng = np.random.default_rng(0)
    truth = torch.from_numpy((rng.poisson(0.5, (2, 32, 32)) * 0.01).astype(np.float32))  # median 0, mean 0.005
    config = LossConfig(ssim=0.0, edge=0.0, linear=1.0, regional=1.0)

    def parts(level: float) -> dict[str, float]:
        return reconstruction_loss(mu_law(torch.full_like(truth, level), config.mu), truth, config)[1]

    levels = [0.0005, 0.0025, 0.005, 0.0075]
    regional = [parts(v)["regional"] for v in levels]
    linear = [parts(v)["linear"] for v in levels]
    assert int(np.argmin(regional)) == 2 and int(np.argmin(linear)) == 0
    assert reconstruction_loss(mu_law(truth, config.mu), truth, config)[1]["regional"] < 1e-3


def test_temporal_loss_charges_a_frame_that_shows_its_neighbours_moment():
    """A frame that repeats the previous moment (a lagging edge frame, a ghost) pays the truth's whole change; the
    right moment pays nothing, and a uniform level error (no change) pays nothing either."""
    from rmbvideo.mulaw import mu_law
    from rmbvideo.train.loss import temporal_loss, tone_mapped_target

    config = LossConfig()
    before = torch.zeros(1, 8, 8)
    before[..., :3] = 0.5
    after = torch.roll(before, 1, dims=-1)  # an edge moved by one pixel
    change = (tone_mapped_target(after, config) - tone_mapped_target(before, config)).abs().mean()
    lagging = temporal_loss(mu_law(before, config.mu), mu_law(before, config.mu), after, before, config)
    assert float(lagging) == pytest.approx(float(change)) and float(change) > 0
    assert float(temporal_loss(mu_law(after, config.mu), mu_law(before, config.mu), after, before, config)) < 1e-6
    level, truth = torch.full((1, 8, 8), 0.05), torch.full((1, 8, 8), 0.2)
    assert float(temporal_loss(level, level, truth, truth, config)) == 0.0


def test_temporal_weight_adds_its_term_across_segments(tmp_path):
    """With ``loss.temporal`` the training loss grows by that weight times the mean change error over every output
    after the first, segment boundaries included (the previous output carried without its graph): cut into segments
    of 2 or run as one, the term is the same, where restarting it at each segment would drop two of its four pairs."""
    sample = SampleCache(tmp_path, SampleSpec(mode="binned", crop=16, frames=7, n=4, warmup_frames=1)).get(0)
    batch = Batch.from_samples([sample], torch.device("cpu"))
    model = _tiny_model()
    plain = train_batch(model, batch, tbptt=2, loss_config=LossConfig())
    model.zero_grad()
    weighted = train_batch(model, batch, tbptt=2, loss_config=LossConfig(temporal=2.0))
    assert plain["temporal"] == 0.0 and weighted["temporal"] > 0
    assert weighted["loss"] == pytest.approx(plain["loss"] + 2.0 * weighted["temporal"], rel=1e-5)
    model.zero_grad()
    whole = train_batch(model, batch, tbptt=5, loss_config=LossConfig(temporal=2.0))
    assert weighted["temporal"] == pytest.approx(whole["temporal"], rel=1e-3)  # frames encoded in other batches


def test_display_referred_samples_weigh_their_linear_error_more():
    """The extra linear weight applies to display-referred samples only: the loss of a batch grows by
    display_linear x (that sample's relative L1) / B, and radiance samples are unchanged."""
    from rmbvideo.mulaw import mu_law
    from rmbvideo.train.loss import reconstruction_loss

    rng = np.random.default_rng(1)
    truth = torch.from_numpy(rng.uniform(0.1, 0.6, (2, 16, 16)).astype(np.float32))
    pred = mu_law(truth * 1.1, 5000.0)  # 10 % too bright everywhere: relative L1 = 0.1 per sample
    base = LossConfig(ssim=0.0, edge=0.0, linear=1.0)
    weighted = LossConfig(ssim=0.0, edge=0.0, linear=1.0, display_linear=3.0)
    plain = float(reconstruction_loss(pred, truth, base)[0])
    assert float(reconstruction_loss(pred, truth, weighted, torch.tensor([0.0, 0.0]))[0]) == pytest.approx(plain)
    one = float(reconstruction_loss(pred, truth, weighted, torch.tensor([1.0, 0.0]))[0])
    assert one - plain == pytest.approx(3.0 * 0.1 / 2, rel=1e-3)


def _per_frame_loss(model: RmbNet, batch: Batch, prime: int) -> torch.Tensor:
    """The mean reconstruction loss over every frame of the engine's run of the batch (``forward_sequence``)."""
    from rmbvideo.train.loss import reconstruction_loss

    with torch.no_grad():
        out, _ = model.forward_sequence(batch.i_s, batch.i_m, linear=False, prime=prime)
    return torch.stack([reconstruction_loss(out[:, i], batch.gt[:, i], LossConfig())[0]
                        for i in range(out.shape[1])]).mean()


def test_edge_frames_train_from_the_state_the_engine_primes_a_clip_with(tmp_path):
    """With ``prime``, a sample supervised from its first frame starts from the state the engine gives a clip's first
    frame (backwards over ``prime`` frames): the training losses are those of ``forward_sequence(prime=...)``'s frames,
    and differ from a fresh state's."""
    sample = SampleCache(tmp_path, SampleSpec(mode="binned", crop=16, frames=6, n=4, warmup_frames=1)).get(0)
    batch = Batch.from_samples([sample], torch.device("cpu"))
    model = _tiny_model().eval()
    with torch.no_grad():
        for prime in (0, 1, 3):
            losses = list(segment_losses(model, batch, tbptt=2, loss_config=LossConfig(), edges=True, prime=prime))
            assert (losses[0].state_in is None) == (prime == 0)
            trained = sum(segment.loss for segment in losses)
            torch.testing.assert_close(trained, _per_frame_loss(model, batch, prime), rtol=1e-5, atol=1e-6)
        primed = sum(s.loss for s in segment_losses(model, batch, 2, LossConfig(), edges=True, prime=1))
        assert not torch.isclose(primed, _per_frame_loss(model, batch, 0))
        inner = next(segment_losses(model, batch, 2, LossConfig(), edges=False, prime=1))
        assert inner.state_in is None  # a sample supervised from frame w is a piece of mid-clip, not a clip's start


def test_held_targets_keep_the_truth_at_the_edges_and_the_teachers_output_inside(tmp_path):
    """``held_targets``: the first and last w frames keep the truth, every frame with a whole window gets the
    teacher's linear output of the engine's run (primed as the sample is trained)."""
    from rmbvideo.train.loop import held_targets

    sample = SampleCache(tmp_path, SampleSpec(mode="binned", crop=16, frames=6, n=4, warmup_frames=1)).get(1)
    batch = Batch.from_samples([sample], torch.device("cpu"))
    teacher = _tiny_model().eval()
    targets = held_targets(teacher, batch, edges=True, prime=1)
    with torch.no_grad():
        engine, _ = teacher.forward_sequence(batch.i_s, batch.i_m, prime=1)
    w = teacher.config.w
    torch.testing.assert_close(targets[:, :w], batch.gt[:, :w], rtol=0, atol=0)
    torch.testing.assert_close(targets[:, -w:], batch.gt[:, -w:], rtol=0, atol=0)
    torch.testing.assert_close(targets[:, w:-w], engine[:, w:-w], rtol=1e-5, atol=1e-6)
    assert not torch.allclose(targets[:, w:-w], batch.gt[:, w:-w])
    inner = held_targets(teacher, batch, edges=False, prime=1)  # no edge frames: the teacher's run from frame w
    with torch.no_grad():
        fresh, _ = teacher.forward_sequence(batch.i_s, batch.i_m, prime=0)
    assert not torch.allclose(inner[:, w:-w], fresh[:, w:-w])  # started at frame w, not at frame 0


def test_edge_only_scores_the_edge_frames_alone(tmp_path):
    """``optim.edge_only``: the loss and its gradients are the first and last w frames' alone (a whole-window frame's
    truth changed moves neither), while an edge frame's truth moves both; without it the whole-window frame counts."""
    sample = SampleCache(tmp_path, SampleSpec(mode="binned", crop=16, frames=6, n=4, warmup_frames=1)).get(1)
    batch = Batch.from_samples([sample], torch.device("cpu"))
    model, w = _tiny_model(), 1

    def run(gt: torch.Tensor, edge_only: bool) -> tuple[float, torch.Tensor]:
        model.zero_grad()
        parts = train_batch(model, replace(batch, gt=gt), tbptt=2, loss_config=LossConfig(temporal=1.0), edges=True,
                            prime=1, edge_only=edge_only)
        return parts["loss"], torch.cat([p.grad.flatten() for p in model.parameters() if p.grad is not None])

    inner, edge = batch.gt.clone(), batch.gt.clone()
    inner[:, w + 1] = inner[:, w + 1] * 0.3 + 0.5
    edge[:, 0] = edge[:, 0] * 0.3 + 0.5
    loss, grad = run(batch.gt, True)
    inner_loss, inner_grad = run(inner, True)
    assert inner_loss == pytest.approx(loss, rel=1e-6)
    torch.testing.assert_close(inner_grad, grad)
    edge_loss, edge_grad = run(edge, True)
    assert edge_loss != pytest.approx(loss, rel=1e-3) and not torch.allclose(edge_grad, grad)
    assert run(inner, False)[0] != pytest.approx(run(batch.gt, False)[0], rel=1e-3)
    recipe = tmp_path / "tiny.toml"
    for bad in ("edge_only = true", "edges = 0.5\nedge_only = true"):  # not every step's edge frames
        recipe.write_text(TINY_RECIPE.format(steps=2).replace("threads = 1", f"threads = 1\n{bad}"))
        with pytest.raises(InputError, match="edge_only"):
            load_recipe(recipe)


def test_held_whole_windows_train_against_the_init_model_also_after_resume(tmp_path):
    """``hold_whole_windows`` holds whole-window outputs to the ``init`` weights (frozen, rebuilt from the file on
    resume, not from the checkpoint) and is refused without init or edge frames."""
    from rmbvideo.net.weights import ModelCard, save_model

    torch.manual_seed(5)
    source = save_model(tmp_path / "init.safetensors", RmbNet(RmbNetConfig(w=1, width=0.25, n=4)), ModelCard("init"))
    recipe = tmp_path / "tiny.toml"
    text = TINY_RECIPE.format(steps=2).replace("minutes = 5", f'minutes = 5\ninit = "{source}"')
    recipe.write_text(text.replace("threads = 1", "threads = 1\nedges = 1.0\nprime = 1\nhold_whole_windows = true"))
    trainer = Trainer(load_recipe(recipe), tmp_path / "out", cache_dir=tmp_path / "cache")
    init = trainer.teacher.state_dict()
    trainer.run()
    resumed = Trainer(load_recipe(recipe).with_steps(4), tmp_path / "out", cache_dir=tmp_path / "cache", resume=True)
    assert not resumed.teacher.training and not any(p.requires_grad for p in resumed.teacher.parameters())
    assert all(torch.equal(init[k], v) for k, v in resumed.teacher.state_dict().items())
    resumed.run()
    assert any(not torch.equal(init[k], v) for k, v in resumed.model.state_dict().items())
    card = json.loads((tmp_path / "out" / "tiny.json").read_text())
    assert "held" in card["training"]["tbptt"] and "primed backwards over 1" in card["training"]["tbptt"]
    no_init = text.replace(f'init = "{source}"\n', "").replace("threads = 1", "threads = 1\nedges = 1.0")
    aged = text.replace("threads = 1", "threads = 1\nedges = 1.0\naged_passes = 2")
    for bad in (no_init, text, aged):  # without init; with init but no edge frames; from an aged state
        recipe.write_text(bad.replace("threads = 1", "threads = 1\nhold_whole_windows = true"))
        with pytest.raises(InputError, match="hold_whole_windows"):
            load_recipe(recipe)


def test_train_lists_every_bundled_recipe_with_what_it_is_for():
    listed = CliRunner().invoke(main, ["train", "--list"], catch_exceptions=False)
    assert listed.exit_code == 0
    lines = {line.split()[0]: line for line in listed.output.splitlines()}
    assert set(lines) == {p.stem for p in RECIPES_DIR.glob("*.toml")}
    assert "the head told where a clip's edges cut the window" in lines["video-edge-input-head-cpu"]
    missing = CliRunner().invoke(main, ["train"])
    assert missing.exit_code == 2 and "--list" in missing.output


def test_a_model_whose_edge_windows_slide_trains_on_the_frames_the_engine_gives_it(tmp_path):
    """``edge_slide``: the TBPTT segments read the frames a slid edge window reaches (beyond a segment's own), so the
    training losses are those of ``forward_sequence``'s frames, primed or not; the hold keeps an edge frame's truth."""
    from dataclasses import replace

    from rmbvideo.train.loop import held_targets

    sample = SampleCache(tmp_path, SampleSpec(mode="binned", crop=16, frames=6, n=4, warmup_frames=1)).get(0)
    batch = Batch.from_samples([sample], torch.device("cpu"))
    cut = _tiny_model(w=2).eval()  # a first frame's slid window reads frame 4, past the first segment's own reach
    model = RmbNet(replace(cut.config, edge_slide=True)).eval()
    model.load_state_dict(cut.state_dict())
    with torch.no_grad():
        for prime in (0, 1):
            losses = list(segment_losses(model, batch, tbptt=2, loss_config=LossConfig(), edges=True, prime=prime))
            trained = sum(segment.loss for segment in losses)
            torch.testing.assert_close(trained, _per_frame_loss(model, batch, prime), rtol=1e-5, atol=1e-6)
    targets = held_targets(model, batch, edges=True, prime=1)
    w = model.config.w
    torch.testing.assert_close(targets[:, :w], batch.gt[:, :w], rtol=0, atol=0)
    torch.testing.assert_close(targets[:, -w:], batch.gt[:, -w:], rtol=0, atol=0)


def test_bf16_training_runs_the_network_under_autocast_and_the_losses_in_fp32(tmp_path, monkeypatch):
    """``optim.precision`` bf16: the forward passes under bf16 autocast (the loss differs from fp32's by bf16's
    rounding only), every loss term computed outside it (in bf16 SSIM's sums lose what they measure: a trained
    model's loss doubled), and the backward pass gives finite gradients to every weight fp32's reaches."""
    import rmbvideo.train.loop as loop

    cache = SampleCache(tmp_path, TINY_SPEC)
    batch = Batch.from_samples([cache.get(0), cache.get(1)], torch.device("cpu"))
    model = _tiny_model()
    fp32 = train_batch(model, batch, tbptt=2, loss_config=LossConfig())
    reached = {name for name, p in model.named_parameters() if p.grad is not None and p.grad.abs().sum() > 0}
    model.zero_grad(set_to_none=True)
    autocast_in_loss = []
    loss = loop.reconstruction_loss

    def recorded(pred, *args, **kwargs):
        autocast_in_loss.append(torch.is_autocast_enabled("cpu") or pred.dtype != torch.float32)
        return loss(pred, *args, **kwargs)

    monkeypatch.setattr(loop, "reconstruction_loss", recorded)
    bf16 = train_batch(model, batch, tbptt=2, loss_config=LossConfig(), bf16=True)
    assert autocast_in_loss and not any(autocast_in_loss)
    assert bf16["loss"] == pytest.approx(fp32["loss"], rel=0.05) and bf16["loss"] != fp32["loss"]
    grads = {name: p.grad for name, p in model.named_parameters() if p.grad is not None}
    assert reached <= set(grads) and all(torch.isfinite(g).all() and g.dtype == torch.float32 for g in grads.values())
    assert load_recipe(RECIPES_DIR / "cpu.toml").optim.precision == "fp32"
    assert load_recipe(RECIPES_DIR / "cpu.toml").with_precision("auto").optim.precision == "auto"

"""Safe weight files: round trip, mismatched cards, and refusal of foreign or unsafe files."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import pytest
import torch

from rmbvideo.errors import ModelError
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import (
    ModelCard,
    average_models,
    load_model,
    merge_aligned_candidates,
    save_model,
    without_window,
)


def tiny(**kw) -> RmbNet:
    torch.manual_seed(0)
    return RmbNet(RmbNetConfig(w=1, width=0.25, **kw)).eval()


CARD = ModelCard(name="tiny", training={"loss": "mu-law L2 + SSIM"}, data={"scenes": "none"}, metrics={"psnr": 1.5})


def test_round_trip_same_outputs_and_card(tmp_path):
    model = tiny(input_mode="native")
    with torch.no_grad():  # make BN statistics non-default so they must travel too
        model.encoder_s.blocks[0][1].running_mean.fill_(0.3)
    path = save_model(tmp_path / "m", model, CARD)
    assert path.name == "m.safetensors" and (tmp_path / "m.json").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    loaded, card = load_model(path, expect_input_mode="native")
    assert card == CARD and loaded.config == model.config
    x = torch.rand(1, 3, 16, 16) * 10
    with torch.inference_mode():
        torch.testing.assert_close(loaded.forward_sequence(x, x * 7)[0], model.forward_sequence(x, x * 7)[0])


def _card(tmp_path) -> dict:
    return json.loads((tmp_path / "m.json").read_text())


def test_weight_files_are_as_readable_as_their_cards(tmp_path):
    import stat

    path = save_model(tmp_path / "m", tiny(), CARD)
    assert stat.S_IMODE(path.stat().st_mode) == stat.S_IMODE((tmp_path / "m.json").stat().st_mode)


def test_a_model_whose_card_cannot_be_written_leaves_the_earlier_pair(tmp_path, monkeypatch):
    """Weights and card are renamed together: a full disk at the card (after the weights) used to leave new weights
    beside the earlier model's card, which then described another training."""
    import errno

    import rmbvideo.net.weights as weights_module

    earlier = {p.name: p.read_bytes() for p in (save_model(tmp_path / "m", tiny(), CARD), tmp_path / "m.json")}

    def full_disk(path, text):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(weights_module, "atomic_write_text", full_disk)
    with pytest.raises(OSError):
        save_model(tmp_path / "m", tiny(input_mode="native"), ModelCard(name="another"))
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == earlier


def test_mismatched_cards_are_refused(tmp_path):
    path = save_model(tmp_path / "m", tiny(), CARD)
    with pytest.raises(ModelError, match="'binned'.*'native'"):
        load_model(path, expect_input_mode="native")
    original = _card(tmp_path)
    cases = {
        "unknown config keys": {**original, "architecture": {**original["architecture"], "heads": 8}},
        "shape mismatch": {**original, "architecture": {**original["architecture"], "width": 0.5}},
        "missing tensors": {**original, "architecture": {**original["architecture"], "use_xba": True,
                                                         "use_xta": True, "w": 1}},
        "unknown model card keys": {**original, "extra": 1},
    }
    # a weight file without XTA tensors, described by a card that promises XTA
    save_model(tmp_path / "noxta", tiny(use_xta=False), CARD)
    for problem, document in cases.items():
        target = "noxta" if problem == "missing tensors" else "m"
        (tmp_path / f"{target}.json").write_text(json.dumps(document))
        with pytest.raises(ModelError, match=problem):
            load_model(tmp_path / f"{target}.safetensors")
    (tmp_path / "m.json").write_text("{not json")
    with pytest.raises(ModelError, match="not valid JSON"):
        load_model(path)
    (tmp_path / "m.json").unlink()
    with pytest.raises(ModelError, match="model card not found"):
        load_model(path)


class _Marker:
    """Unpickling this would create a file: proof that code ran."""

    def __init__(self, target: str) -> None:
        self.target = target

    def __reduce__(self):
        return (open, (self.target, "w"))


@pytest.mark.parametrize("kind", ["random", "pickle", "torch_save", "empty"])
def test_foreign_files_are_refused_without_running_code(tmp_path, kind):
    save_model(tmp_path / "m", tiny(), CARD)
    path = tmp_path / "m.safetensors"
    marker = tmp_path / "marker"
    if kind == "random":
        path.write_bytes(torch.randint(0, 256, (4096,), generator=torch.Generator().manual_seed(3),
                                       dtype=torch.uint8).numpy().tobytes())
    elif kind == "pickle":
        path.write_bytes(pickle.dumps(_Marker(str(marker))))
    elif kind == "torch_save":
        torch.save({"x": _Marker(str(marker))}, path)
    else:
        path.write_bytes(b"")
    assert not marker.exists()
    with pytest.raises(ModelError, match="refused: not a safetensors file"):
        load_model(path)
    assert not marker.exists()


def test_average_models_is_the_weighted_sum_and_refuses_other_architectures():
    torch.manual_seed(0)
    first, second = RmbNet(RmbNetConfig(w=1, width=0.25)), RmbNet(RmbNetConfig(w=1, width=0.25))
    for alpha in (0.0, 0.7, 1.0):
        mixed = average_models(first, second, alpha).state_dict()
        for key, a in first.state_dict().items():
            b = second.state_dict()[key]
            expected = alpha * a.float() + (1 - alpha) * b.float() if a.is_floating_point() else a
            assert torch.allclose(mixed[key].float(), expected.float(), atol=1e-7), key
    assert not torch.equal(average_models(first, second, 0.5).state_dict()["decoder.head.1.weight"],
                           first.state_dict()["decoder.head.1.weight"])
    with pytest.raises(ModelError, match="different architectures"):
        average_models(first, RmbNet(RmbNetConfig(w=2, width=0.25)), 0.5)
    with pytest.raises(ValueError, match="alpha"):
        average_models(first, second, 1.5)


def test_merging_the_aligned_candidates_is_exact_where_their_logits_differ_by_the_linearisation_point():
    model = tiny(blend=True, readout="pure-m", aligned=True, aligned_centre=2)
    difference = -3.0
    with torch.no_grad():  # give both aligned candidates real weight, their logits apart by exactly `difference`
        last = model.decoder.head[-1]
        last.weight.normal_(0.0, 0.1)
        last.weight[-1] = last.weight[-2]
        last.bias[-2] = 2.0
        last.bias[-1] = 2.0 + difference
    torch.manual_seed(1)
    i_s, i_m = torch.rand(1, 4, 16, 24) * 10, torch.rand(1, 4, 16, 24) * 70
    i_a = torch.rand(1, 4, 16, 24) * 70
    with torch.inference_mode():
        both = model.forward_sequence(i_s, i_m, i_a=torch.stack([i_a, i_a], dim=2))[0]
        merged = merge_aligned_candidates(model, difference)
        assert merged.config.aligned_centre == 0 and merged.config.aligned_channels == 1
        torch.testing.assert_close(merged.forward_sequence(i_s, i_m, i_a=i_a)[0], both, rtol=1e-4, atol=1e-6)
        # linearised elsewhere, the merge is only close: the check above can tell
        assert not torch.allclose(merge_aligned_candidates(model, 0.0).forward_sequence(i_s, i_m, i_a=i_a)[0], both,
                                  rtol=1e-4, atol=1e-6)
    with pytest.raises(ValueError, match="no second aligned mean"):
        merge_aligned_candidates(merged, difference)


def test_without_the_window_a_model_computes_what_it_does_on_a_lone_frame_where_the_dropped_weights_are_zero():
    model = tiny(blend=True, readout="pure-m", pooled_windows=(3,), convention_input=True, centre_windows=(2,),
                 aligned=True, edge_input=True)
    first, last = model.decoder.head[0][0], model.decoder.head[-1]
    features = first.out_channels
    # head inputs: features, the reference's 2, the pooled window's 2, convention, centre, aligned, the 2 edge planes
    dropped_inputs = [features + 2, features + 3, first.in_channels - 2, first.in_channels - 1]
    with torch.no_grad():
        last.weight.normal_(0.0, 0.1)
        last.bias.normal_(0.0, 1.0)
        first.weight[:, dropped_inputs] = 0.0
        last.weight[3] = 0.0  # the pooled window's blend logit: far below the rest
        last.bias[3] = -1e4
    torch.manual_seed(2)
    i_s, i_m, i_c = torch.rand(1, 1, 16, 24) * 10, torch.rand(1, 1, 16, 24) * 70, torch.rand(1, 1, 1, 16, 24) * 14
    i_a = torch.rand(1, 1, 16, 24) * 70
    narrow = without_window(model)
    assert narrow.config.w == 0 and not narrow.config.pooled_windows and not narrow.config.edge_input
    with torch.inference_mode():  # a one-frame clip: the w = 1 window's other positions are missing
        expected = model.forward_sequence(i_s, i_m, i_c=i_c, i_a=i_a, convention=1.0)[0]
        torch.testing.assert_close(narrow.forward_sequence(i_s, i_m, i_c=i_c, i_a=i_a, convention=1.0)[0], expected)
        with torch.no_grad():  # the weights it drops are the pooled window's and the edge planes', no others
            model.decoder.head[0][0].weight[:, features + 4] += 1.0
        assert not torch.allclose(without_window(model).forward_sequence(i_s, i_m, i_c=i_c, i_a=i_a, convention=1.0)[0],
                                  expected)


def test_a_recipes_init_path_is_found_from_any_folder(tmp_path, monkeypatch):
    """Bundled recipes name their init weights from the repository root ("models/training/..."); run from another
    folder, `rmbvideo train RECIPE` said "model file not found". A relative path that does not exist here is looked
    for beside the shipped models' folder; one that exists here, an absolute one and a missing one stay as given."""
    from rmbvideo.net.weights import MODELS_DIR, bundled_path

    monkeypatch.chdir(tmp_path)
    shipped = Path("models") / "rmbnet-binned.safetensors"
    assert not shipped.exists()
    found = bundled_path(shipped)
    assert found.is_file() and found.resolve() == (MODELS_DIR / "rmbnet-binned.safetensors").resolve()
    (tmp_path / "models").mkdir()
    (tmp_path / shipped).write_bytes(b"mine")
    assert bundled_path(shipped) == shipped  # the user's own file, here, wins
    missing = Path("models") / "no-such.safetensors"
    assert bundled_path(missing) == missing and bundled_path(tmp_path / "x") == tmp_path / "x"

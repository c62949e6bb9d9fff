"""The shipped model (stage 19) without its window: the same network at w = 0, the start of the window-worth pair's
w = 0 run (``rmbvideo train window-worth-w0-cpu``). Run from the repository root (a second):

    python models/experiments/window-worth/narrow.py

At w = 0 the attention reads the reference frame alone and nothing else changes shape but the head: its inputs lose
the means over the pooled windows of 3 and 7 frames and the two edge planes, and its blend logits lose the two pooled
windows' box candidates. Those weights are dropped, every other weight is stage 19's, so the w = 0 run starts from
everything stage 19 learned and the pair differs only in the window. The aligned mean over 11 frames (its own flows,
not the network's window) stays in both. Writes ``stage19-w0.safetensors`` here.
"""

from dataclasses import replace
from pathlib import Path

import torch

from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import ModelCard, default_model_path, load_model, save_model

HERE = Path(__file__).parent


def without_window(model: RmbNet) -> RmbNet:
    """``model`` at w = 0: its head's weights for the pooled means and the edge planes, and the pooled candidates'
    blend logits, dropped."""
    cfg = model.config
    narrow = RmbNet(replace(cfg, w=0, pooled_windows=(), edge_input=False))
    state = model.state_dict()
    decoder_channels = model.decoder.head[0][0].in_channels - (
        2 + 2 * len(cfg.pooled_windows) + int(cfg.convention_input) + len(cfg.centre_windows)
        + cfg.aligned_channels + cfg.evidence_channels + 2 * int(cfg.edge_input))
    # head inputs: decoder features, the reference's 2 inputs, 2 per pooled window, ..., the 2 edge planes last
    pooled = range(decoder_channels + 2, decoder_channels + 2 + 2 * len(cfg.pooled_windows))
    edge = range(model.decoder.head[0][0].in_channels - 2 * int(cfg.edge_input), model.decoder.head[0][0].in_channels)
    keep_in = [c for c in range(model.decoder.head[0][0].in_channels) if c not in pooled and c not in edge]
    state["decoder.head.0.0.weight"] = state["decoder.head.0.0.weight"][:, keep_in]
    # head outputs: t, then the blend logits of (own, reference box, each pooled window, centre windows, aligned)
    last = len(model.decoder.head) - 1
    dropped = range(3, 3 + len(cfg.pooled_windows))
    keep_out = [c for c in range(model.decoder.head[last].out_channels) if c not in dropped]
    for name in ("weight", "bias"):
        state[f"decoder.head.{last}.{name}"] = state[f"decoder.head.{last}.{name}"][keep_out]
    narrow.load_state_dict(state)
    return narrow.eval()


def main() -> None:
    model, card = load_model(default_model_path("binned"))
    narrow = without_window(model)
    with torch.no_grad():
        save_model(HERE / "stage19-w0.safetensors", narrow, ModelCard(
            name="stage19-w0", description="stage 19 at w = 0 (models/experiments/window-worth/narrow.py): the "
            "start of the window-worth pair's w = 0 run, not a model to use", training={"from": card.name}))


if __name__ == "__main__":
    main()

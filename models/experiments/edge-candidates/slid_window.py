"""A clip's edge frames with the network's window slid inwards, training-free, on the development video clips only:
where the window of frame i reaches past the clip's start (or end), its missing positions hold the next frames beyond
the window's other end (i + w + 1, ...; at the end i - w - 1, ...), marked valid for the attention (cross-bit and
cross-time attention have no positional code: they read their keys as a set), while the pooled means and the edge
planes still read the window as the engine cuts it. So an edge frame's own estimate reads 2w + 1 frames, all from its
one side, as its aligned mean already does (``aligned_shift``). Mid-clip frames are unchanged. Prints, per clip, the
edge check (``edge_report``) without and with the slide. Run from the repository root (about two minutes, one core):

    python models/experiments/edge-candidates/slid_window.py
"""

import math

import rmbvideo.net.model as model_module
import rmbvideo.recon.rmbnet as engine_module
from rmbvideo.evaluate.heldout import DEVELOPMENT_VIDEO_FIRST, load_video_heldout
from rmbvideo.evaluate.video_checks import edge_report

_indices, _valid = engine_module.window_indices, engine_module.window_valid
_prepare = model_module.RmbNet._prepare
_evict = engine_module.RmbNetReconstructor._evict


def slid_indices(i: int, w: int, count: int | None) -> list[int]:
    """``window_indices`` with positions past an edge holding the frames beyond the window's other end (when the
    clip has them), else the placeholders as before."""
    last = math.inf if count is None else count - 1
    ids = _indices(i, w, count)
    before = [p for p in range(2 * w + 1) if i - w + p < 0]
    after = [p for p in range(2 * w + 1) if i - w + p > last]
    for n, p in enumerate(before):
        if i + w + 1 + n <= last:
            ids[p] = i + w + 1 + n
    for n, p in enumerate(reversed(after)):
        if i - w - 1 - n >= 0:
            ids[p] = i - w - 1 - n
    return ids


def slid_valid(i: int, w: int, count: int | None) -> list[bool]:
    ids, plain = slid_indices(i, w, count), _indices(i, w, count)
    return [ok or a != b for ok, a, b in zip(_valid(i, w, count), ids, plain)]


def prepare(self, window, cache, valid, convention, aligned):
    """``RmbNet._prepare`` with the slid positions in the attention only: the pooled means and edge planes read the
    positions that hold the window's own frames."""
    w, ref = self.config.w, window[self.config.w].index
    own = [v and frame.index == ref - w + p for p, (v, frame) in enumerate(zip(valid, window))]
    pooled_rates, head_inputs = self._pooled_rates, self._head_inputs
    self._pooled_rates = lambda win, _valid: pooled_rates(win, own)
    self._head_inputs = lambda win, _valid, *args: head_inputs(win, own, *args)
    try:
        return _prepare(self, window, cache, valid, convention, aligned)
    finally:
        del self._pooled_rates, self._head_inputs


def evict(self, next_out: int) -> None:
    _evict(self, next_out - self._w)  # the slid window at a clip's end reads 2w frames back


def main() -> None:
    print("| clip | window | first below median (dB) | last below median | first offset (ms) | last offset "
          "| edge cost, first (dB) | edge cost, last |")
    print("|---|---|" + "---:|" * 6)
    for seq in load_video_heldout(False, first=DEVELOPMENT_VIDEO_FIRST):
        for label in ("cut (shipped)", "slid inwards"):
            slide = label != "cut (shipped)"
            engine_module.window_indices = slid_indices if slide else _indices
            engine_module.window_valid = slid_valid if slide else _valid
            model_module.RmbNet._prepare = prepare if slide else _prepare
            engine_module.RmbNetReconstructor._evict = evict if slide else _evict
            r = edge_report(seq, "rmbnet", {"threads": 1, "input_mode": "binned", "precision": "fp32"})
            print(f"| {seq.name} | {label} | {r.first_drop_db:+.2f} | {r.last_drop_db:+.2f} | {r.first_offset_ms:+.2f} "
                  f"| {r.last_offset_ms:+.2f} | {r.first_edge_cost_db:+.2f} | {r.last_edge_cost_db:+.2f} |", flush=True)


if __name__ == "__main__":
    main()

"""RMB-Net (paper Sec. 4.2, Fig. 6): two encoders, cross-bit and cross-time attention, and a
recurrent decoder, composed step by step so a streaming engine can reuse per-frame work.

Choices where the paper and supplement are silent:

- Inputs: I_s/N and I_m/(level*N), clipped to [0, 1] and mu-law compressed
  (``config.input_mu``) so the dark end of the HDR range is not lost in the first conv.
  Each encoder takes one channel.
- Sizes not divisible by 8: inputs are padded on the right/bottom by edge replication and the
  output is cropped back.
- XBA runs at all three encoder scales (1/2, 1/4, 1/8). The decoder's skip links need F_ms only
  of the reference frame at 1/2 and 1/4; XTA (or the temporal mean) runs at 1/8 over the whole
  window, and F_ms(i) at 1/8 joins F_bar_ms(i) there as the residual link.
- Output: the decoder's head z becomes t = min(softplus(z), output_max), the mu-law domain
  T(G) = log(1 + mu G)/log(1 + mu) the loss uses (mu = ``output_mu``); the linear HDR image is
  the exact inverse (expm1(t log(1+mu))/mu), so it is >= 0 and finite by construction.
- Window edges: a window reaching before the first or past the last frame holds the nearest frame
  in those positions only as a placeholder (``window_indices``); ``window_valid`` marks them and
  attention, temporal means and pooled inputs leave them out, so a clip's first and last frames use
  only the evidence that exists on their side.
- Pooled inputs (``config.pooled_windows``): the head also sees the reference pixel's mean rates
  over the central 3, 5 or 7 frames of the window (the classical TFW estimates, mu-law compressed),
  so it can pick per pixel between low noise (static regions) and the reference alone (motion).
- Convention input (``config.convention_input``): one more constant head channel, 0 for a real
  camera's pixel (reset to zero at a spike) and 1 for the rate convention of simulators that keep the
  charge above threshold (spikezoo): the same rates mean different intensities near saturation.
- Blend output (``config.blend``): the head also predicts softmax weights over its own estimate and
  exact box-filter intensities (``rmbvideo.net.blend``); the output is their linear blend.
- Centre windows (``config.centre_windows``): the reference frame's multi-bit rates over its central
  2/4/6 readouts (``I_c``) join the head inputs (mu-law compressed) and the blend candidates, so a
  pixel in fast motion can be read at the frame's centre time instead of over all N readouts.
- Aligned window mean (``config.aligned``): the reference's mean multi-bit rate over the window with
  the neighbours warped onto it by optical flow and merged where they agree (computed outside the
  network, ``rmbvideo.recon.aligned_box``; ``step(aligned=...)``) joins the head inputs (mu-law
  compressed) and the blend candidates (last of each).
- Edge input (``config.edge_input``): two constant head planes, the fractions of the window's past and future
  positions outside the clip (``edge_planes``; 0 mid-clip), after every other input.
- Aligned evidence (``config.aligned_evidence``): the aligned mean's per-pixel statistics (``config.EVIDENCE``), given
  after the means in ``step(aligned=...)``, join the head inputs last, each squashed to [0, 1) (``evidence_inputs``),
  so the head can tell where the aligned mean is nearly exact; they are not blend candidates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from rmbvideo.net.attention import CrossBitAttention, CrossTimeAttention, PlainBitFusion, TemporalMean
from rmbvideo.net.blend import CENTRE_LOGIT_INIT, OWN_LOGIT_INIT, blend, box_candidates, candidate_count
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.decoder import Decoder, DecoderState
from rmbvideo.net.encoder import Encoder
from rmbvideo.mulaw import inverse_mu_law, mu_law

PAD_MULTIPLE = 8
#: Per-pixel statistics of the aligned mean -> head inputs: x / (x + scale) for the flow's gradient (pixels per pixel),
#: its magnitude (pixels per frame) and the neighbours' spread (log units), so the heavy tails stay in [0, 1) with the
#: typical values (medians 0.01-0.25, 0.1-4 and 0.07-0.2 on the development sets) mid-range; the support, already in
#: [0, 1], as it is (None).
EVIDENCE_SCALES: tuple[float | None, ...] = (0.1, 2.0, None, 0.25)
# (scale, query frame index, key frame index) -> XBA mask logits of that pair, (B, C, h, w)
PairCache = dict[tuple[int, int, int], torch.Tensor]


def evict_pairs(cache: PairCache, oldest_needed: int) -> None:
    """Forget the pair logits of ``cache`` whose query or key frame is older than ``oldest_needed``."""
    for key in [k for k in cache if min(k[1], k[2]) < oldest_needed]:
        del cache[key]


@dataclass
class EncodedFrame:
    """Everything RMB-Net derives from one preliminary frame alone, computed once per frame.

    ``rates``: normalised (I_s/N, I_m/(level N)) clipped to [0, 1], padded, (B,2,Hp,Wp); ``inputs``:
    their mu-law compression; ``f_s``/``f_m``: encoder features per
    scale; ``query_parts``/``key_parts``: first-layer XBA terms per scale (empty without XBA);
    ``f_ms``: per-scale F_ms when there is no XBA (it then depends on the frame only).
    ``size``: the unpadded (H, W); ``centre``: the central multi-bit rates I_c/(level k) clipped to
    [0, 1], padded, (B,C,Hp,Wp), or None when the config has no centre windows.
    """

    index: int
    size: tuple[int, int]
    rates: torch.Tensor
    inputs: torch.Tensor
    f_s: list[torch.Tensor]
    f_m: list[torch.Tensor]
    query_parts: list[torch.Tensor]
    key_parts: list[torch.Tensor]
    f_ms: list[torch.Tensor]
    centre: torch.Tensor | None = None


def window_indices(i: int, w: int, count: int | None, slide: bool = False) -> list[int]:
    """Frame indices of the window around ``i``; positions past the clip's edges hold frame 0 /
    frame ``count-1`` as placeholders (``window_valid`` says which positions are real). With ``slide``
    (``RmbNetConfig.edge_slide``) they hold the frames beyond the window's other end instead, nearest first, where the
    clip has them."""
    last = math.inf if count is None else count - 1
    ids = [int(min(max(j, 0), last)) for j in range(i - w, i + w + 1)]
    if slide:
        before = [p for p in range(2 * w + 1) if i - w + p < 0]
        after = [p for p in range(2 * w + 1) if i - w + p > last]
        for n, p in enumerate(reversed(before)):
            if i + w + 1 + n <= last:
                ids[p] = i + w + 1 + n
        for n, p in enumerate(after):
            if i - w - 1 - n >= 0:
                ids[p] = i - w - 1 - n
    return ids


def window_valid(i: int, w: int, count: int | None, slide: bool = False) -> list[bool]:
    """Which positions of the window around ``i`` hold a real frame (inside 0..count-1, or with ``slide`` a frame
    from beyond the window's other end)."""
    last = math.inf if count is None else count - 1
    own = [0 <= j <= last for j in range(i - w, i + w + 1)]
    if not slide:
        return own
    ids, cut = window_indices(i, w, count, slide=True), window_indices(i, w, count)
    return [ok or a != b for ok, a, b in zip(own, ids, cut)]


def window_reach(i: int, w: int, count: int | None, slide: bool = False) -> range:
    """The frames the window around ``i`` reads (placeholders included)."""
    ids = window_indices(i, w, count, slide)
    return range(min(ids), max(ids) + 1)


def priming_frames(prime: int, count: int | None) -> range:
    """The frames a clip's first state is primed over, in the order the backward run takes them: ``prime`` .. 1,
    those inside a clip of ``count`` frames (None: not known, all)."""
    return range(prime if count is None else min(prime, count - 1), 0, -1)


def edge_planes(valid: Sequence[bool], w: int, like: torch.Tensor) -> torch.Tensor:
    """(B, 2, H, W) like ``like``: the fractions of the window's w past and w future positions outside the clip
    (``valid`` False), constant over the frame; both 0 for a window inside the clip."""
    missing = (sum(not v for v in valid[:w]) / w, sum(not v for v in valid[w + 1:]) / w)
    planes = torch.tensor(missing, dtype=like.dtype, device=like.device).reshape(1, 2, 1, 1)
    return planes.expand(like.shape[0], 2, *like.shape[2:])


def canonical_batch(t: torch.Tensor) -> torch.Tensor:
    """``t`` (B,C,H,W) as a view whose batch stride is C*H*W when B = 1: indexing an unflattened stack can leave
    a size-1 batch dim with stride C, and cat/conv then no longer read a channels-last tensor as one (they
    copy it to NCHW and back: the head's input alone cost 2.4 ms of a frame on a loaded machine)."""
    if t.dim() == 4 and t.shape[0] == 1 and t.stride(0) != t.numel():
        return t.as_strided(t.shape, (t.numel(), *t.stride()[1:]))
    return t


def _stack(tensors: Sequence[torch.Tensor]) -> torch.Tensor:
    """``torch.stack`` along a new dim 0, a view (no copy) for a single tensor."""
    return tensors[0].unsqueeze(0) if len(tensors) == 1 else torch.stack(list(tensors))


def _consecutive_view(tensors: Sequence[torch.Tensor]) -> torch.Tensor | None:
    """``torch.cat(tensors)`` as a view, when the tensors are consecutive batch slices of one tensor (the frames of one
    ``encode`` call are): a run's 2w + 1 stacked windows would otherwise copy every feature map 2w + 1 times. None
    when they are not."""
    first = tensors[0]
    step = first.shape[0] * first.stride(0)
    base = first.untyped_storage().data_ptr()
    for j, t in enumerate(tensors):
        if (t.shape != first.shape or t.stride() != first.stride() or t.dtype != first.dtype
                or t.untyped_storage().data_ptr() != base or t.storage_offset() != first.storage_offset() + j * step):
            return None
    return first.as_strided((len(tensors) * first.shape[0], *first.shape[1:]), first.stride(), first.storage_offset())


def _stack_frames(frames: Sequence[EncodedFrame], index: int) -> EncodedFrame:
    """Frames of batch size 1 as one frame whose batch holds them in order (``index`` names it in pair caches): a view
    where the frames come from one ``encode`` call, else a copy."""
    first = frames[0]

    def cat(tensors: Sequence[torch.Tensor]) -> torch.Tensor:
        if len(tensors) == 1:
            return tensors[0]
        view = _consecutive_view(tensors)
        return torch.cat(list(tensors)) if view is None else view

    def per_scale(name: str) -> list[torch.Tensor]:
        return [cat([getattr(f, name)[s] for f in frames]) for s in range(len(getattr(first, name)))]

    return EncodedFrame(
        index=index, size=first.size, rates=cat([f.rates for f in frames]), inputs=cat([f.inputs for f in frames]),
        f_s=per_scale("f_s"), f_m=per_scale("f_m"), query_parts=per_scale("query_parts"),
        key_parts=per_scale("key_parts"), f_ms=per_scale("f_ms"),
        centre=None if first.centre is None else cat([f.centre for f in frames]),
    )


@dataclass
class _Prepared:
    """A step's work before the decoder: its reference frame, the decoder's inputs (fused, reference features,
    head inputs), and what the blend reads (the pooled rates, the aligned rate)."""

    reference: EncodedFrame
    decoder_inputs: tuple[torch.Tensor, list[torch.Tensor], torch.Tensor]
    pooled: list[torch.Tensor]
    aligned_rate: torch.Tensor | None


def evidence_inputs(statistics: torch.Tensor) -> torch.Tensor:
    """The aligned mean's statistics (B, len(EVIDENCE), H, W) -> head inputs in [0, 1) (``EVIDENCE_SCALES``;
    NaN and negative values read as 0)."""
    parts = []
    for channel, scale in zip(statistics.float().split(1, dim=1), EVIDENCE_SCALES):
        x = torch.nan_to_num(channel, nan=0.0, posinf=1e6).clamp(0.0, 1e6)
        parts.append(x.clamp(max=1.0) if scale is None else x / (x + scale))
    return torch.cat(parts, dim=1)


class RmbNet(nn.Module):
    """The whole network; ``forward_sequence`` is the plain, non-streaming reference path."""

    def __init__(self, config: RmbNetConfig) -> None:
        super().__init__()
        self.config = config
        # how the blend's box candidates read a camera's rates: by the closed form (any camera), or by the tabulated
        # response of rmbvideo's emission model (streams it made; ``rmbvideo.net.blend``). Not a weight: a reader's
        # knowledge of the camera, set by whoever runs the network.
        self.tabulated_response = False
        channels = config.channels
        self.encoder_s = Encoder(1, channels, config.encoder_kernel)
        self.encoder_m = Encoder(1, channels, config.encoder_kernel)
        if config.use_xba:
            self.xba = nn.ModuleList(
                CrossBitAttention(c, max(1, round(c * config.attention_hidden)), config.attention_kernel)
                for c in channels
            )
        else:
            self.bit_fusion = nn.ModuleList(PlainBitFusion(c) for c in channels)
        if config.use_xta:
            self.time_fusion: nn.Module = CrossTimeAttention(
                channels[2], max(1, round(channels[2] * config.attention_hidden)), config.attention_kernel
            )
        else:
            self.time_fusion = TemporalMean()
        outputs = (2 + candidate_count(config.pooled_windows, config.centre_windows, config.aligned_channels)
                   if config.blend else 1)
        head_inputs = (2 + 2 * len(config.pooled_windows) + int(config.convention_input) + len(config.centre_windows)
                       + config.aligned_channels + config.evidence_channels + 2 * int(config.edge_input))
        self.decoder = Decoder(channels, config.lstm_kernel, input_channels=head_inputs, outputs=outputs,
                               cell_decay=config.cell_decay)
        if config.blend:  # start from the network's own estimate (weight ~0.98), whatever the input
            last = self.decoder.head[-1]
            with torch.no_grad():
                last.weight[1:].zero_()
                last.bias[1:].zero_()
                last.bias[1] = OWN_LOGIT_INIT
                extra = len(config.centre_windows) + config.aligned_channels
                if extra:  # noisy or possibly misaligned candidates start nearly unused
                    last.bias[-extra:] = CENTRE_LOGIT_INIT

    def normalise_inputs(self, i_s: torch.Tensor, i_m: torch.Tensor) -> torch.Tensor:
        """(B,H,W) preliminary sums -> (B,2,H,W) rates I_s/N and I_m/(level N), clipped to [0, 1]."""
        cfg = self.config
        v_s = torch.nan_to_num(i_s.float() / cfg.n, nan=0.0).clamp(0.0, 1.0)
        v_m = torch.nan_to_num(i_m.float() / (cfg.level * cfg.n), nan=0.0).clamp(0.0, 1.0)
        return torch.stack([v_s, v_m], dim=1)

    def compress_inputs(self, i_s: torch.Tensor, i_m: torch.Tensor) -> torch.Tensor:
        """(B,H,W) preliminary sums -> (B,2,H,W) normalised, clipped, mu-law compressed inputs."""
        return mu_law(self.normalise_inputs(i_s, i_m), self.config.input_mu)

    def normalise_centre(self, i_c: torch.Tensor | None) -> torch.Tensor | None:
        """(B,C,H,W) central sums over ``config.centre_windows`` -> rates I_c/(level k) in [0, 1]
        (None without centre windows; missing sums are an error when the config has them)."""
        windows = self.config.centre_windows
        if not windows:
            return None
        if i_c is None or i_c.shape[1] != len(windows):
            found = "none" if i_c is None else f"{i_c.shape[1]} channels"
            raise ValueError(f"the model reads central sums over {list(windows)} readouts, got {found}")
        scale = torch.tensor([self.config.level * k for k in windows], dtype=torch.float32, device=i_c.device)
        return torch.nan_to_num(i_c.float() / scale.reshape(1, -1, 1, 1), nan=0.0).clamp(0.0, 1.0)

    def normalise_aligned(self, i_a: torch.Tensor | None,
                          size: tuple[int, int]) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """(B,H,W) aligned window mean of the multi-bit sums, or (B,C,H,W): the means (the central readouts' second with
        ``config.aligned_centre``; in sums per N readouts too), then their statistics with ``config.aligned_evidence``
        -> the rates I_a/(level N) in [0, 1] (B,A,Hp,Wp) and the evidence inputs (``evidence_inputs``, (B,E,Hp,Wp), or
        None), padded like the inputs ((None, None) without ``config.aligned``; missing or wrong ones are an error)."""
        cfg = self.config
        channels, evidence = cfg.aligned_channels, cfg.evidence_channels
        if not channels:
            return None, None
        if i_a is None:
            raise ValueError("the model reads the aligned window mean (aligned=...), got none")
        i_a = i_a.unsqueeze(1) if i_a.dim() == 3 else i_a
        if i_a.shape[1] != channels + evidence:
            raise ValueError(f"the model reads {channels} aligned means and {evidence} statistics, "
                             f"got {i_a.shape[1]} channels")
        rate = torch.nan_to_num(i_a[:, :channels].float() / (cfg.level * cfg.n), nan=0.0).clamp(0.0, 1.0)
        statistics = evidence_inputs(i_a[:, channels:]) if evidence else None
        pad_h, pad_w = (-size[0]) % PAD_MULTIPLE, (-size[1]) % PAD_MULTIPLE
        if pad_h or pad_w:
            rate = F.pad(rate, (0, pad_w, 0, pad_h), mode="replicate")
            statistics = None if statistics is None else F.pad(statistics, (0, pad_w, 0, pad_h), mode="replicate")
        return rate, statistics

    def encode(self, i_s: torch.Tensor, i_m: torch.Tensor, indices: Sequence[int],
               i_c: torch.Tensor | None = None) -> list[EncodedFrame]:
        """Encode a batch of frames (F,H,W) each belonging to a batch of size B = 1 per index.

        ``i_s``/``i_m`` are (F*B, H, W) ordered frame-major; ``indices`` has F entries; ``i_c``
        (F*B, C, H, W): central sums over ``config.centre_windows`` (needed only when it names some).
        """
        count = len(indices)
        size = (int(i_s.shape[-2]), int(i_s.shape[-1]))
        rates = self.normalise_inputs(i_s, i_m)
        centre = self.normalise_centre(i_c)
        pad_h, pad_w = (-size[0]) % PAD_MULTIPLE, (-size[1]) % PAD_MULTIPLE
        if pad_h or pad_w:
            rates = F.pad(rates, (0, pad_w, 0, pad_h), mode="replicate")
            if centre is not None:
                centre = F.pad(centre, (0, pad_w, 0, pad_h), mode="replicate")
        x = mu_law(rates, self.config.input_mu)
        f_s_all = self.encoder_s(x[:, :1])
        f_m_all = self.encoder_m(x[:, 1:])
        if self.config.use_xba:
            q_all = [xba.query_part(f) for xba, f in zip(self.xba, f_s_all)]
            k_all = [xba.key_part(f) for xba, f in zip(self.xba, f_m_all)]
            ms_all: list[torch.Tensor] = []
        else:
            q_all, k_all = [], []
            ms_all = [fuse(fs, fm) for fuse, fs, fm in zip(self.bit_fusion, f_s_all, f_m_all)]

        def split(t: torch.Tensor) -> tuple[torch.Tensor, ...]:
            # slices along dim 0 keep the batch stride of a channels-last tensor (an unflattened size-1 batch
            # dim gets stride C, which stack/cat no longer read as channels-last: ~2x slower 1x1 convs after)
            return t.split(t.shape[0] // count)

        per = {name: [split(t) for t in ts] for name, ts in
               (("f_s", f_s_all), ("f_m", f_m_all), ("q", q_all), ("k", k_all), ("ms", ms_all))}
        inputs, rates_split = split(x), split(rates)
        centre_split = split(centre) if centre is not None else [None] * count
        return [
            EncodedFrame(
                index=int(index),
                size=size,
                rates=rates_split[j],
                inputs=inputs[j],
                f_s=[t[j] for t in per["f_s"]],
                f_m=[t[j] for t in per["f_m"]],
                query_parts=[t[j] for t in per["q"]],
                key_parts=[t[j] for t in per["k"]],
                f_ms=[t[j] for t in per["ms"]],
                centre=centre_split[j],
            )
            for j, index in enumerate(indices)
        ]

    def _xba_logits(
        self, scale: int, queries: Sequence[EncodedFrame], keys: Sequence[EncodedFrame], cache: PairCache
    ) -> list[torch.Tensor]:
        """XBA logits per key, (Q,B,C,h,w) each; pairs missing from ``cache`` are computed in one batched call."""
        missing: dict[tuple[int, int, int], tuple[int, EncodedFrame]] = {}
        query_parts = []
        for q in queries:
            part = q.query_parts[scale]
            for k in keys:
                key = (scale, q.index, k.index)
                if key not in cache and key not in missing:
                    if not query_parts or query_parts[-1] is not part:
                        query_parts.append(part)
                    missing[key] = (len(query_parts) - 1, k)
        if missing:
            if len(query_parts) == 1:  # one new query (the usual streaming step): broadcast its part, in the
                q_parts = torch.stack(query_parts)  # stacked keys' memory layout (a mismatch is 4x slower)
            else:
                q_parts = torch.stack([query_parts[j] for j, _ in missing.values()])
            k_parts = torch.stack([k.key_parts[scale] for _, k in missing.values()])
            for key, logits in zip(missing, self.xba[scale].pair_logits(q_parts, k_parts).unbind(0)):
                cache[key] = logits
        return [_stack([cache[(scale, q.index, k.index)] for q in queries]) for k in keys]

    def _bit_fused(
        self, scale: int, queries: Sequence[EncodedFrame], window: Sequence[EncodedFrame], cache: PairCache,
        valid: Sequence[bool] | None = None,
    ) -> torch.Tensor:
        """F_ms(q) at ``scale`` for each query over the window's valid keys, (Q,B,C,h,w)."""
        if not self.config.use_xba:
            return _stack([q.f_ms[scale] for q in queries])
        logits = self._xba_logits(scale, queries, window, cache)
        f_s = _stack([q.f_s[scale] for q in queries])
        return self.xba[scale].fuse(f_s, [k.f_m[scale] for k in window], logits, valid)

    def _pooled_rates(self, window: Sequence[EncodedFrame], valid: Sequence[bool]) -> list[torch.Tensor]:
        """The reference's rates, then their means over each pooled window (valid frames only), (B,2,Hp,Wp)
        each: one running sum grows from the narrowest window to the widest, shared by the head's
        inputs and the blend's box candidates."""
        w = self.config.w
        total, count, half = window[w].rates, 1, 0
        means = {1: total}
        for size in sorted(set(self.config.pooled_windows)):
            for j in [*range(w - size // 2, w - half), *range(w + half + 1, w + size // 2 + 1)]:
                if valid[j]:
                    total, count = total + window[j].rates, count + 1
            half = size // 2
            means[size] = total / count
        return [means[size] for size in (1, *self.config.pooled_windows)]

    def _head_inputs(self, window: Sequence[EncodedFrame], valid: Sequence[bool],
                     convention: torch.Tensor | float, pooled: Sequence[torch.Tensor] | None = None,
                     aligned: torch.Tensor | None = None, evidence: torch.Tensor | None = None) -> torch.Tensor:
        """The reference's compressed inputs plus its mean rates over each pooled window (valid
        frames only; ``pooled``, from ``_pooled_rates`` when None), mu-law compressed, plus the
        convention plane when the config has it: then the reference's central rates (mu-law
        compressed) when the config has centre windows, then the aligned mean rates (mu-law compressed)
        and the aligned mean's evidence inputs when given, then the edge planes when the config has them:
        (B, 2 + 2 len(pooled_windows) [+ 1] + len(centre_windows) [+ A] [+ E] [+ 2], Hp, Wp)."""
        w = self.config.w
        inputs = window[w].inputs
        pooled = self._pooled_rates(window, valid) if pooled is None else pooled
        parts = [inputs, *(mu_law(mean, self.config.input_mu) for mean in pooled[1:])]
        if self.config.convention_input:
            code = torch.as_tensor(convention, dtype=inputs.dtype, device=inputs.device).reshape(-1, 1, 1, 1)
            parts.append(code.expand(inputs.shape[0], 1, *inputs.shape[2:]))
        if window[w].centre is not None:
            parts.append(mu_law(window[w].centre, self.config.input_mu))
        if aligned is not None:
            parts.append(mu_law(aligned, self.config.input_mu).to(inputs.dtype))
        if evidence is not None:
            parts.append(evidence.to(inputs.dtype))
        if self.config.edge_input:
            parts.append(edge_planes(valid, w, inputs))
        return torch.cat(parts, dim=1) if len(parts) > 1 else parts[0]

    def step(
        self, window: Sequence[EncodedFrame], state: DecoderState | None, cache: PairCache | None = None,
        valid: Sequence[bool] | None = None, convention: torch.Tensor | float = 0.0,
        aligned: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, DecoderState]:
        """One output step for the window of 2w+1 encoded frames centred on the reference.

        Returns t = T(G) in the mu-law domain, (B,1,H,W) at the unpadded size, and the new state.
        ``cache`` holds XBA pair logits reused across overlapping windows (the caller evicts).
        ``valid`` marks the positions that hold real frames (default: all; see ``window_valid``).
        ``convention``: 0 (a camera) or 1 (the rate convention), a scalar or one per batch item; used
        only when ``config.convention_input``. ``aligned``: the reference's aligned window mean of the
        multi-bit sums (B,H,W), or (B,C,H,W): the means, then their statistics (``normalise_aligned``); needed when
        ``config.aligned``.
        """
        if len(window) != self.config.window:
            raise ValueError(f"window has {len(window)} frames, the model needs {self.config.window}")
        valid = [True] * len(window) if valid is None else list(valid)
        if not valid[self.config.w]:
            raise ValueError("the reference frame of a window must be valid")
        prepared = self._prepare(window, {} if cache is None else cache, valid, convention, aligned)
        z, state = self.decoder(*prepared.decoder_inputs, state)
        return self._finish(z, prepared, convention), state

    def advance(
        self, window: Sequence[EncodedFrame], state: DecoderState | None, cache: PairCache | None = None,
        valid: Sequence[bool] | None = None,
    ) -> DecoderState:
        """The state after ``step`` on ``window``, without the frame: the attention and the decoder's ConvLSTMs, not
        the layers after them nor the head's inputs (the pooled means, the aligned mean), which feed only the output.
        For frames made for the state alone (RMB-Net at a multiple of its step keeps one in k)."""
        valid = [True] * len(window) if valid is None else list(valid)
        if not valid[self.config.w]:
            raise ValueError("the reference frame of a window must be valid")
        fused, reference = self._fused(window, {} if cache is None else cache, valid)
        return self.decoder(fused, reference, None, state)[1]

    def step_backward(
        self, window: Sequence[EncodedFrame], state: DecoderState | None, valid: Sequence[bool] | None = None,
        convention: torch.Tensor | float = 0.0, aligned: torch.Tensor | None = None,
    ) -> DecoderState:
        """The state after one step of the network run backwards in time: ``step`` on the window (in time order,
        with its ``valid``) reversed. A clip's first frames have no past; a state primed backwards over the frames
        after them (``priming_frames``) gives them their future as later frames get their past."""
        valid = [True] * len(window) if valid is None else list(valid)
        return self.step(window[::-1], state, valid=valid[::-1], convention=convention, aligned=aligned)[1]

    def step_run(
        self, frames: Sequence[EncodedFrame], state: DecoderState | None, convention: torch.Tensor | float = 0.0,
        aligned: torch.Tensor | None = None, graphed: bool = False,
    ) -> tuple[torch.Tensor, DecoderState]:
        """K consecutive output steps in one batched pass: ``frames`` are 2w+K consecutive encoded frames (every
        window position real, each frame of batch size 1), the outputs are for frames[w .. w+K-1].

        The same as K calls of ``step`` (to float rounding): everything but the decoder's ConvLSTM recurrences
        runs on the K windows at once, and the recurrences step through them in order
        (``Decoder.forward`` with ``run``). On a GPU this turns hundreds of tiny launches per frame into a few per run.
        ``aligned``: the K references' aligned means, (K,H,W) or (K,C,H,W) (``step``). ``graphed``: on a GPU without autograd the
        recurrences replay as CUDA graphs (``ConvLSTMCell.run``). Returns t (K,1,H,W) and the state.
        """
        count = len(frames) - 2 * self.config.w
        if count < 1:
            raise ValueError(f"a run needs at least {self.config.window} frames, got {len(frames)}")
        if any(frame.rates.shape[0] != 1 for frame in frames):
            raise ValueError("step_run reads frames of batch size 1")
        window = [_stack_frames(frames[p : p + count], p) for p in range(self.config.window)]
        cache = self._run_pair_logits(frames, count) if self.config.use_xba else {}
        prepared = self._prepare(window, cache, [True] * len(window), convention, aligned)
        z, state = self.decoder(*prepared.decoder_inputs, state, run=True, graphed=graphed)
        return self._finish(z, prepared, convention), state

    def _run_pair_logits(self, frames: Sequence[EncodedFrame], count: int) -> PairCache:
        """A run's 1/8-scale XBA logits for every pair of window positions (p, p + d), keyed as ``_prepare`` asks for
        them: one batched call per offset d over the distinct frame pairs, each position pair a view of it. The run's
        stacked windows hold the same frame pair at up to 2w + 1 position pairs, which would compute it that often."""
        last_position = 2 * self.config.w
        queries = torch.cat([f.query_parts[2] for f in frames])
        keys = torch.cat([f.key_parts[2] for f in frames])
        cache: PairCache = {}
        for d in range(-last_position, last_position + 1):
            first, last = max(0, -d), min(last_position, last_position - d)  # positions p with p + d in the window
            logits = self.xba[2].pair_logits(queries[None, first : last + count],
                                             keys[None, first + d : last + d + count])[0]
            for p in range(first, last + 1):
                cache[(2, p, p + d)] = logits[p - first : p - first + count]
        return cache

    def _prepare(self, window: Sequence[EncodedFrame], cache: PairCache, valid: list[bool],
                 convention: torch.Tensor | float, aligned: torch.Tensor | None) -> "_Prepared":
        """Everything of a step before the decoder: the attention, the temporal fusion and the head's inputs."""
        w = self.config.w
        ref = window[w]
        fused, reference = self._fused(window, cache, valid)
        # the pooled means and the edge planes read the window's own frames, not those a slid edge window brought in
        # (from further than w frames away, either way: ``step_backward`` reverses a window)
        own = [v and abs(frame.index - ref.index) <= w for v, frame in zip(valid, window)] \
            if self.config.edge_slide else valid
        pooled = self._pooled_rates(window, own)
        aligned_rate, evidence = self.normalise_aligned(aligned, ref.size)
        inputs = self._head_inputs(window, own, convention, pooled, aligned_rate, evidence)
        return _Prepared(ref, (fused, reference, inputs), pooled, aligned_rate)

    def _fused(self, window: Sequence[EncodedFrame], cache: PairCache, valid: list[bool]
               ) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """The decoder's inputs from the attention: the window's temporal fusion at 1/8 and the reference frame's
        bit-fused features at each scale."""
        w = self.config.w
        mask = None if all(valid) else valid
        reference = [canonical_batch(self._bit_fused(s, [window[w]], window, cache, mask)[0]) for s in range(2)]
        f_ms_coarse = self._bit_fused(2, window, window, cache, mask)
        reference.append(canonical_batch(f_ms_coarse[w]))
        return self.time_fusion(f_ms_coarse, mask).contiguous(memory_format=torch.channels_last), reference

    def _finish(self, z: torch.Tensor, prepared: "_Prepared", convention: torch.Tensor | float) -> torch.Tensor:
        """The head's output z -> t = T(G) (the blend of the candidates when the config has it), unpadded."""
        t = F.softplus(z[:, :1].float()).clamp(max=self.config.output_max)
        ref = prepared.reference
        if self.config.blend:
            cfg = self.config
            candidates = box_candidates([mean[:, 1:2] for mean in prepared.pooled], cfg.level, convention,
                                        ref.centre, prepared.aligned_rate, self.tabulated_response)
            mixed = blend(self.to_linear(t), candidates, z[:, 1:])
            t = mu_law(mixed, cfg.output_mu).clamp(max=cfg.output_max)
        h, w = ref.size
        return t[..., :h, :w]

    def to_linear(self, t: torch.Tensor) -> torch.Tensor:
        """Mu-law-domain output -> linear HDR (>= 0, finite)."""
        return inverse_mu_law(t.float(), self.config.output_mu)

    def forward_sequence(
        self,
        i_s: torch.Tensor,
        i_m: torch.Tensor,
        state: DecoderState | None = None,
        linear: bool = True,
        convention: torch.Tensor | float = 0.0,
        i_c: torch.Tensor | None = None,
        i_a: torch.Tensor | None = None,
        prime: int = 0,
    ) -> tuple[torch.Tensor, DecoderState | None]:
        """Reconstruct a whole sequence (B,K,H,W) of preliminary sums -> (B,K,H,W) and final state.

        Linear HDR by default; ``linear=False`` returns the mu-law domain (the training loss domain).
        ``i_c`` (B,K,C,H,W): central sums, when the config has centre windows; ``i_a`` (B,K,H,W) or
        (B,K,C,H,W): each frame's aligned mean(s) of the multi-bit sums (and their statistics: ``step``), when the
        config has ``aligned``.
        Without a ``state``, the first frame's is primed backwards over frames ``prime`` .. 1 (``step_backward``;
        the streaming engine's default is w).
        """
        batch, count = i_s.shape[:2]
        frames = self.encode(
            i_s.transpose(0, 1).flatten(0, 1), i_m.transpose(0, 1).flatten(0, 1), range(count),
            None if i_c is None else i_c.transpose(0, 1).flatten(0, 1),
        )
        w, slide = self.config.w, self.config.edge_slide
        for i in priming_frames(prime, count) if state is None else ():
            state = self.step_backward([frames[j] for j in window_indices(i, w, count, slide)], state,
                                       window_valid(i, w, count, slide), convention,
                                       None if i_a is None else i_a[:, i])
        outputs = []
        for i in range(count):
            window = [frames[j] for j in window_indices(i, w, count, slide)]
            t, state = self.step(window, state, valid=window_valid(i, w, count, slide), convention=convention,
                                 aligned=None if i_a is None else i_a[:, i])
            outputs.append(t[:, 0])
        out = torch.stack(outputs, dim=1)
        return (self.to_linear(out) if linear else out), state

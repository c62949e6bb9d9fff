"""Configuration of RMB-Net (paper Sec. 4.2, supplement Sec. 11) as one plain dataclass.

Every architectural choice the paper leaves open is a field here, so a model card can record it
and ``load_model`` can rebuild exactly the network that produced a weight file.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

INPUT_MODES = ("binned", "native")
#: Readout designs a model can be trained on (``rmbvideo.sensor.readout.ReadoutMode`` values).
READOUTS = ("rmb", "pure-s", "pure-m", "full-m")
#: Largest half-width of the aligned window mean (frames): its flows compose one step per frame.
MAX_ALIGNED_RADIUS = 12
#: What ``aligned_evidence`` reads of each pixel's aligned mean, in this order (``rmbvideo.recon.aligned_box.STATISTICS``
#: makes them; net/ imports torch and its siblings only, so the names are repeated here and tested equal).
EVIDENCE = ("flow gradient", "flow magnitude", "support", "spread")


@dataclass(frozen=True)
class RmbNetConfig:
    """Architecture of RMB-Net; defaults follow the paper (w = 3, channels 24/32/48, N = 10).

    ``input_mode``: "binned" (2x2x2-binned real 1-bit data) or "native" (a native RMB sensor);
    the graph is the same, the weights are not interchangeable. ``input_mu``: mu of the mu-law
    that compresses the normalised inputs I_s/N and I_m/(level*N) before the encoders (HDR range).
    ``pooled_windows``: odd window lengths (3..2w+1) whose mean input rates the head also sees.
    ``readout``: the readout design of the training data (binned input: the design reconstruct applies
    to the binned stream for this model, unless told otherwise).
    ``convention_input``: the head also sees which sensor convention made the stream (a constant
    plane: 0 a real camera's reset-to-zero pixel, 1 the accumulate-and-subtract rate convention of
    simulators such as spikezoo's), because the same spikes mean different intensities under the two.
    ``blend``: the output is a per-pixel softmax blend of the network's own estimate and the exact
    box-filter intensities of the reference frame and each pooled window (``rmbvideo.net.blend``);
    needs every bin count (binned input, pure-M readout).
    ``centre_windows``: even readout counts (< N, N - k even) of central sub-windows of each frame
    whose multi-bit rates the head also sees and blends as box filters: fast motion, where a frame's N
    readouts already blur, is read at the reference frame's centre time more finely; needs ``blend``.
    ``aligned``: the head also sees and blends the window's motion-compensated mean multi-bit rate
    (``rmbvideo.recon.aligned_box``, given to ``RmbNet.step``): a long average where the flow is right,
    so moving texture need not choose between noise (one frame) and blur (the plain window); needs ``blend``.
    ``aligned_radius``: its window's half-width (None: w; flow-compensated evidence stays usable further
    out than the network's window); ``aligned_shift``: at a clip's ends its window slides inwards rather
    than being cut (``rmbvideo.recon.aligned_box.aligned_window``), so edge frames keep as much evidence.
    ``aligned_centre``: k > 0 adds a second aligned mean, of each frame's central k readouts (sharp where fast
    motion blurs a whole frame), moved by the same flows: one more head input and blend candidate.
    ``output_mu``/``output_max``: the decoder predicts the mu-law domain T(G) (the training loss
    domain, mu = 5000) through a softplus, capped at ``output_max`` so the inverse cannot overflow.
    ``aligned_evidence``: the head also sees how far the aligned mean can be trusted per pixel (``EVIDENCE``: the flow's
    local gradient and magnitude, the robust merge's support and the kept neighbours' spread; given after the means
    in ``RmbNet.step``'s ``aligned``), inputs only, not blend candidates: the flow tells a pan that moves as one piece,
    where the aligned mean is nearly exact, from a scene of independent movers (models/experiments/blend-hedging).
    ``cell_decay``: each ConvLSTM's cell state is scaled by it before each step (``ConvLSTMCell``): 1 keeps the
    state as trained; below 1 it forgets old evidence it would otherwise carry through a long still capture.
    ``edge_input``: the head also sees where the clip's edges cut the window (two constant planes, the fractions of
    its w past and w future positions that lie outside the clip; both 0 mid-clip), last of its inputs, so a clip's
    edge frames can be read differently from the rest without changing it.
    ``edge_slide``: where a clip's edge cuts a frame's window, its missing positions hold the frames beyond the window's
    other end instead (``window_indices``), real evidence for both attentions, which read their keys as a set, so an
    edge frame's attention fuses 2w + 1 frames, all from its one side, as its aligned mean does with
    ``aligned_shift``; the pooled means and the edge planes still read the window as the edge cuts it.
    """

    w: int = 3
    width: float = 1.0
    n: int = 10
    level: int = 7
    use_xba: bool = True
    use_xta: bool = True
    input_mode: str = "binned"
    base_channels: tuple[int, int, int] = (24, 32, 48)
    encoder_kernel: int = 5
    attention_hidden: float = 1.0   # hidden channels of the mask projection, x feature channels
    attention_kernel: int = 3
    lstm_kernel: int = 3
    input_mu: float = 255.0
    output_mu: float = 5000.0
    output_max: float = 2.0
    pooled_windows: tuple[int, ...] = ()
    convention_input: bool = False
    readout: str = "rmb"
    blend: bool = False
    centre_windows: tuple[int, ...] = ()
    aligned: bool = False
    aligned_radius: int | None = None
    aligned_shift: bool = False
    aligned_centre: int = 0
    aligned_evidence: bool = False
    cell_decay: float = 1.0
    edge_input: bool = False
    edge_slide: bool = False

    def __post_init__(self) -> None:
        if not 0 <= self.w <= 3:
            raise ValueError(f"w must be in 0..3, got {self.w}")
        if self.width <= 0:
            raise ValueError(f"width must be positive, got {self.width}")
        if self.n < 1 or self.level < 1:
            raise ValueError("n and level must be >= 1")
        if self.input_mode not in INPUT_MODES:
            raise ValueError(f"input_mode must be one of {INPUT_MODES}, got {self.input_mode!r}")
        if self.readout not in READOUTS:
            raise ValueError(f"readout must be one of {READOUTS}, got {self.readout!r}")
        if len(self.base_channels) != 3:
            raise ValueError("base_channels must name three encoder blocks")
        object.__setattr__(self, "base_channels", tuple(int(c) for c in self.base_channels))
        object.__setattr__(self, "pooled_windows", tuple(int(p) for p in self.pooled_windows))
        for size in self.pooled_windows:
            if size % 2 == 0 or not 3 <= size <= self.window:
                raise ValueError(f"pooled_windows must be odd lengths in 3..{self.window}, got {size}")
        object.__setattr__(self, "centre_windows", tuple(int(k) for k in self.centre_windows))
        for k in self.centre_windows:
            if not 0 < k < self.n or (self.n - k) % 2:
                raise ValueError(f"centre_windows must be lengths in 1..{self.n - 1} of the parity of n, got {k}")
        if self.centre_windows and not self.blend:
            raise ValueError("centre_windows need the blend output")
        if self.aligned and not self.blend:
            raise ValueError("aligned needs the blend output")
        if (self.aligned_radius is not None or self.aligned_shift or self.aligned_centre or self.aligned_evidence) \
                and not self.aligned:
            raise ValueError("aligned_radius, aligned_shift, aligned_centre and aligned_evidence need aligned")
        if self.aligned_centre and (not 0 < self.aligned_centre < self.n or (self.n - self.aligned_centre) % 2):
            raise ValueError(f"aligned_centre must be a length in 1..{self.n - 1} of the parity of n, got {self.aligned_centre}")
        if self.aligned_radius is not None and not 0 <= self.aligned_radius <= MAX_ALIGNED_RADIUS:
            raise ValueError(f"aligned_radius must be in 0..{MAX_ALIGNED_RADIUS}, got {self.aligned_radius}")
        if self.edge_input and self.w < 1:
            raise ValueError("edge_input needs a window (w >= 1)")
        if self.edge_slide and self.w < 1:
            raise ValueError("edge_slide needs a window (w >= 1)")
        if not 0.0 < self.cell_decay <= 1.0:
            raise ValueError(f"cell_decay must be in (0, 1], got {self.cell_decay}")
        if self.blend and (self.input_mode != "binned" or self.readout != "pure-m"):
            raise ValueError("blend needs every bin count: input_mode \"binned\" and readout \"pure-m\"")

    @property
    def window(self) -> int:
        """Frames per window, 2w+1."""
        return 2 * self.w + 1

    @property
    def aligned_half_width(self) -> int:
        """Half-width of the aligned mean's window (``aligned_radius``, else w)."""
        return self.w if self.aligned_radius is None else self.aligned_radius

    @property
    def aligned_channels(self) -> int:
        """Aligned means the model reads: 0, 1 (the window's) or 2 (also its central readouts')."""
        return int(self.aligned) + int(self.aligned_centre > 0)

    @property
    def evidence_channels(self) -> int:
        """Per-pixel statistics of the aligned mean the head reads (``aligned_evidence``): 0 or len(EVIDENCE)."""
        return len(EVIDENCE) if self.aligned_evidence else 0

    @property
    def channels(self) -> tuple[int, int, int]:
        """Encoder channels per block after the width multiplier."""
        return tuple(max(1, round(c * self.width)) for c in self.base_channels)  # type: ignore[return-value]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (tuples become lists; no ``pooled_windows`` key when there are none, no
        ``convention_input`` key when it is off, no ``readout`` key for the RMB design, no ``blend`` key
        when it is off, no ``centre_windows`` key when there are none, no ``aligned*`` key when off or unset, no ``edge_input``,
        ``edge_slide`` or ``cell_decay`` key at their defaults)."""
        out = asdict(self)
        out["base_channels"] = list(self.base_channels)
        out["pooled_windows"] = list(self.pooled_windows)
        if not self.pooled_windows:  # cards written before pooled inputs existed stay as they are
            del out["pooled_windows"]
        if not self.convention_input:  # likewise for the convention input and the readout
            del out["convention_input"]
        if self.readout == "rmb":
            del out["readout"]
        if not self.blend:
            del out["blend"]
        out["centre_windows"] = list(self.centre_windows)
        if not self.centre_windows:
            del out["centre_windows"]
        for name in ("aligned", "aligned_shift", "aligned_centre", "aligned_evidence"):
            if not out[name]:
                del out[name]
        if self.aligned_radius is None:
            del out["aligned_radius"]
        if self.cell_decay == 1.0:
            del out["cell_decay"]
        for name in ("edge_input", "edge_slide"):
            if not out[name]:
                del out[name]
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "RmbNetConfig":
        """Rebuild from ``to_dict`` output; unknown keys raise ``KeyError`` naming them."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise KeyError(f"unknown config keys {unknown}")
        kwargs = dict(data)
        if "base_channels" in kwargs:
            kwargs["base_channels"] = tuple(kwargs["base_channels"])
        for key in ("pooled_windows", "centre_windows"):
            if key in kwargs:
                kwargs[key] = tuple(kwargs[key])
        return cls(**kwargs)

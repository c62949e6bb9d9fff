"""RMB-Net parts and the whole network: shapes, ablations, hard inputs, precision."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from rmbvideo.net import layout
from rmbvideo.net.activations import relu_
from rmbvideo.net.attention import PairProjection, attend
from rmbvideo.net.convlstm import ConvLSTMCell
from rmbvideo.net.decoder import upsample2x
from rmbvideo.net.encoder import MaxPool2x2
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.model import RmbNet, canonical_batch, window_indices, window_reach, window_valid
from rmbvideo.mulaw import inverse_mu_law, mu_law


def small(**kw) -> RmbNet:
    torch.manual_seed(0)
    return RmbNet(RmbNetConfig(width=0.25, **{"w": 1, **kw})).eval()


def run(model: RmbNet, i_s: torch.Tensor, i_m: torch.Tensor) -> torch.Tensor:
    with torch.inference_mode():
        return model.forward_sequence(i_s, i_m)[0]


def random_inputs(k: int = 4, h: int = 20, w: int = 13, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return (torch.randint(0, 11, (1, k, h, w), generator=g).float(),
            torch.randint(0, 71, (1, k, h, w), generator=g).float())


def test_output_shape_odd_size_finite_nonnegative():
    model = small()
    out = run(model, *random_inputs(h=20, w=13))
    assert out.shape == (1, 4, 20, 13)
    assert torch.isfinite(out).all() and (out >= 0).all()


def test_split_projection_equals_conv_on_concatenation():
    torch.manual_seed(1)
    proj = PairProjection((3, 5), hidden=4, out_channels=2, kernel=3)
    a, b = torch.randn(2, 3, 8, 8), torch.randn(2, 5, 8, 8)
    whole = torch.nn.Conv2d(8, 4, 3, padding=1)
    with torch.no_grad():
        whole.weight.copy_(torch.cat([proj.parts[0].weight, proj.parts[1].weight], dim=1))
        whole.bias.copy_(proj.parts[0].bias)
        expected = proj.out(torch.relu(whole(torch.cat([a, b], dim=1))))
        got = proj.combine(proj.part(0, a) + proj.part(1, b))
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("valid", [None, [True, True, False, True, False]])
def test_attend_equals_softmax_over_the_valid_keys(valid):
    """The key-at-a-time SoftMax equals a plain SoftMax over the stacked keys, invalid keys left out,
    also for logits large enough to overflow a naive exp."""
    torch.manual_seed(0)
    logits = torch.randn(3, 5, 2, 4, 6, 7) * 30 + 80
    values = torch.randn(5, 2, 4, 6, 7)
    keep = list(range(5)) if valid is None else [k for k, ok in enumerate(valid) if ok]
    weights = torch.softmax(logits[:, keep].double(), dim=1)
    expected = (weights * values[keep].double().unsqueeze(0)).sum(dim=1)
    got = attend(logits.unbind(1), values.unbind(0), valid)
    assert got.shape == (3, 2, 4, 6, 7) and torch.isfinite(got).all()
    torch.testing.assert_close(got.double(), expected, rtol=1e-5, atol=1e-5)


def test_convlstm_cell_is_the_textbook_cell_in_value_and_gradient():
    """The cell's tanh (computed through the sigmoid, faster on CPU) gives the textbook ConvLSTM to float
    rounding, for pre-activations from tiny to saturating, and the same gradients."""
    torch.manual_seed(0)
    cell = ConvLSTMCell(3, 4, 3)
    x = (torch.randn(2, 3, 6, 5) * torch.tensor([1e-4, 1.0, 300.0]).reshape(1, 3, 1, 1)).requires_grad_(True)
    h0, c0 = torch.randn(2, 4, 6, 5), torch.randn(2, 4, 6, 5) * 50

    def textbook(x):
        i, f, o, g = cell.gates(torch.cat([x, h0], dim=1)).chunk(4, dim=1)
        c = torch.sigmoid(f) * c0 + torch.sigmoid(i) * torch.tanh(g)
        return torch.sigmoid(o) * torch.tanh(c), c

    (h, (_, c)), (h_ref, c_ref) = cell(x, (h0, c0)), textbook(x)
    torch.testing.assert_close(h, h_ref, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(c, c_ref, rtol=1e-5, atol=1e-5)
    grad, = torch.autograd.grad((h * h_ref.detach()).sum() + c.sum(), x)
    grad_ref, = torch.autograd.grad((h_ref * h_ref.detach()).sum() + c_ref.sum(), x)
    torch.testing.assert_close(grad, grad_ref, rtol=1e-4, atol=1e-5)
    with torch.inference_mode():  # the in-place path gives the same values
        torch.testing.assert_close(cell(x.detach(), (h0, c0))[0], h_ref.detach(), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("channels_last", [False, True])
def test_convlstm_recurrence_from_a_zero_state_is_the_run_from_none(channels_last):
    """What a CUDA graph replays (the hidden part from an explicit state) gives ``run``'s values: from zeros those
    of a run from no state, from a carried state those of the steps one by one; ``graphed`` off a GPU is ``run``."""
    torch.manual_seed(1)
    cell = ConvLSTMCell(3, 4, 3)
    layout = torch.channels_last if channels_last else torch.contiguous_format
    x = torch.randn(5, 3, 6, 7).contiguous(memory_format=layout)
    with torch.inference_mode():
        gates_x = torch.nn.functional.conv2d(x, cell.gates.weight[:, :3], cell.gates.bias, padding=1)
        zeros = torch.zeros(1, 4, 6, 7)
        hs, h, c = cell._recurrence(gates_x, zeros, zeros)
        ref, (h_ref, c_ref) = cell.run(x, None)
        torch.testing.assert_close(hs, ref, rtol=1e-6, atol=1e-7)
        torch.testing.assert_close((h, c), (h_ref, c_ref), rtol=1e-6, atol=1e-7)
        state, steps = None, []
        for k in range(5):
            out, state = cell(x[k : k + 1], state)
            steps.append(out)
        carried = cell._recurrence(gates_x[2:], *cell.run(x[:2], None)[1])
        torch.testing.assert_close(carried[0], torch.cat(steps[2:]), rtol=1e-5, atol=1e-6)
        graphed, _ = cell.run(x, None, graphed=True)
        assert torch.equal(graphed, ref)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a GPU")
def test_cuda_graphs_replay_the_eager_recurrence():
    """On a GPU, runs through the graph cache (eager the first time a shape is seen, captured the second, replayed
    after) give the eager values, from a carried state, and return copies rather than the graph's memory."""
    from rmbvideo.recon.rmbnet import inference_copy

    torch.manual_seed(0)
    net = inference_copy(RmbNet(RmbNetConfig(w=2, width=0.25)).eval().cuda())
    frames = [torch.randint(0, 81, (14, 19, 26)).float().cuda(), torch.randint(0, 7 * 81, (14, 19, 26)).float().cuda()]
    with torch.inference_mode():
        encoded = net.encode(*frames, range(14))
        for graphed in (False, True, True, True):
            state, outputs = None, []
            for start in (0, 5):
                t, state = net.step_run(encoded[start : start + 9], state, graphed=graphed)
                outputs.append(t)
            if not graphed:
                eager = outputs
            first = outputs[0]
            for got, expected in zip(outputs, eager):
                torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
        net.step_run(encoded[5:14], state, graphed=True)
        torch.testing.assert_close(first, eager[0], rtol=1e-5, atol=1e-6)
    assert net.decoder.lstm1._graphs._graphs


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
@pytest.mark.parametrize("channels_last", [False, True])
def test_strided_max_pool_equals_max_pool_2d(dtype, channels_last):
    x = torch.randn(2, 3, 9, 14).to(dtype)
    if channels_last:
        x = x.contiguous(memory_format=torch.channels_last)
    assert torch.equal(MaxPool2x2()(x), torch.nn.functional.max_pool2d(x, 2))


@pytest.mark.parametrize("shape", [(1, 48, 16, 25), (1, 24, 63, 100), (3, 8, 32, 50)])
def test_float32_upsampling_feeds_a_bf16_conv_the_values_of_bf16_upsampling(shape):
    """The decoder upsamples bf16 features in float32 (faster on CPUs): once the next conv's autocast rounds them,
    they are bf16 upsampling's values bit for bit, and so is the conv's output."""
    torch.manual_seed(0)
    x = (torch.randn(shape) * 4).to(torch.bfloat16).contiguous(memory_format=torch.channels_last)
    bf16 = torch.nn.functional.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
    assert torch.equal(upsample2x(x).to(torch.bfloat16), bf16)
    conv = torch.nn.Conv2d(shape[1], 5, 3, padding=1).to(torch.bfloat16).to(memory_format=torch.channels_last)
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        assert torch.equal(conv(upsample2x(x)), conv(bf16))


@pytest.mark.parametrize("channels_last", [False, True])
def test_bf16_relu_through_the_bit_pattern_is_torch_relu(channels_last):
    """``relu_`` clamps bf16 as int16: the values of ``torch.relu`` for signed zeros, infinities, the smallest and
    largest magnitudes and random values, in place; float32 and tensors needing gradients go through torch."""
    special = torch.tensor([0.0, -0.0, float("inf"), float("-inf"), 1e-40, -1e-40, 3e38, -3e38, 1.0, -1.0])
    x = torch.cat([special, torch.randn(4 * 5 * 6 * 7 - special.numel()) * 10]).reshape(4, 5, 6, 7).to(torch.bfloat16)
    if channels_last:
        x = x.contiguous(memory_format=torch.channels_last)
    expected = torch.relu(x)
    out = relu_(x)
    assert out.data_ptr() == x.data_ptr() and torch.equal(out, expected)
    assert not torch.signbit(out).any()  # -0 and the negatives read +0, as torch.relu makes them
    y = torch.randn(3, 4, requires_grad=True)
    z = relu_(y * 1.0)
    z.sum().backward()
    assert torch.equal(y.grad, (y > 0).float())


def test_bf16_layout_moves_as_int16_keep_values_layouts_and_gradients():
    """``layout.cat`` and ``layout.contiguous`` give torch's tensors bit for bit, in the layout asked for; with a
    gradient needed they are torch's ops, and the gradient flows."""
    cl = torch.channels_last
    a = torch.randn(2, 5, 6, 7).to(torch.bfloat16).contiguous(memory_format=cl)
    b = torch.randn(2, 3, 6, 7).to(torch.bfloat16).contiguous(memory_format=cl)
    joined = layout.cat([a, b], dim=1)
    assert joined.dtype == torch.bfloat16 and torch.equal(joined, torch.cat([a, b], dim=1))
    assert joined.is_contiguous(memory_format=cl)
    plain = torch.randn(2, 5, 6, 7).to(torch.bfloat16)
    moved = layout.contiguous(plain, cl)
    assert torch.equal(moved, plain) and moved.is_contiguous(memory_format=cl) and moved.dtype == torch.bfloat16
    assert torch.equal(layout.cat([a.float(), b.float()], dim=1), torch.cat([a.float(), b.float()], dim=1))
    w = torch.randn(2, 3, requires_grad=True)
    layout.cat([w.to(torch.bfloat16), w.to(torch.bfloat16)], dim=1).float().sum().backward()
    assert torch.equal(w.grad, torch.full((2, 3), 2.0))


def test_ablations_change_the_graph():
    names = lambda m: {n for n, _ in m.named_parameters()}  # noqa: E731
    full, no_xba, no_xta = small(), small(use_xba=False), small(use_xta=False)
    assert any(n.startswith("xba.") for n in names(full))
    assert not any(n.startswith("xba.") for n in names(no_xba))
    assert any(n.startswith("time_fusion.") for n in names(full))
    assert not any(n.startswith("time_fusion.") for n in names(no_xta))
    inputs = random_inputs()
    for model in (no_xba, no_xta, small(w=0)):
        out = run(model, *inputs)
        assert torch.isfinite(out).all() and (out >= 0).all()


@pytest.mark.parametrize("case", ["dark", "saturated", "single_spike"])
def test_hard_inputs_stay_finite(case):
    model = small()
    i_s = torch.zeros(1, 3, 16, 16)
    i_m = torch.zeros(1, 3, 16, 16)
    if case == "saturated":
        i_s += 10
        i_m += 70
    elif case == "single_spike":
        i_s[0, 1, 7, 9] = 1
    out = run(model, i_s, i_m)
    assert torch.isfinite(out).all() and (out >= 0).all()
    assert out.max() <= inverse_mu_law(torch.tensor(model.config.output_max), model.config.output_mu) + 1e-3


def test_bf16_autocast_close_to_fp32():
    model = small()
    inputs = random_inputs(k=3, h=16, w=16)
    with torch.inference_mode():
        ref = model.forward_sequence(*inputs, linear=False)[0]
        with torch.autocast("cpu", dtype=torch.bfloat16):
            low = model.forward_sequence(*inputs, linear=False)[0]
    assert low.dtype == torch.float32
    assert (low - ref).abs().max() < 0.05 * ref.abs().max()


def test_mu_law_round_trip_and_window_edges():
    x = torch.tensor([0.0, 1e-4, 0.5, 1.0, 30.0])
    torch.testing.assert_close(inverse_mu_law(mu_law(x, 5000.0), 5000.0), x, rtol=1e-4, atol=1e-7)
    assert window_indices(0, 2, 3) == [0, 0, 0, 1, 2]
    assert window_indices(2, 2, 3) == [0, 1, 2, 2, 2]
    assert window_indices(5, 1, None) == [4, 5, 6]


def test_config_validation_and_dict_round_trip():
    cfg = RmbNetConfig(w=2, width=0.5, input_mode="native", use_xta=False)
    assert RmbNetConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(KeyError):
        RmbNetConfig.from_dict({**cfg.to_dict(), "heads": 4})
    with pytest.raises(ValueError):
        RmbNetConfig(w=4)
    with pytest.raises(ValueError):
        RmbNetConfig(input_mode="raw")


def test_gradients_reach_every_parameter():
    model = small()
    model.train()
    out = model.forward_sequence(*random_inputs(k=3, h=16, w=16), linear=False)[0]
    out.mean().backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not torch.isfinite(p.grad).all()]
    assert not missing


@pytest.mark.parametrize("kw", [{}, {"use_xba": False, "use_xta": False}, {"pooled_windows": (3,)}])
def test_clip_edges_use_only_the_frames_that_exist(kw):
    """At a clip's edges the positions past the edge are placeholders: what they hold cannot change
    the output (they are neither attended to, nor averaged, nor pooled)."""
    model = small(**kw)
    i_s, i_m = random_inputs(k=3, h=16, w=16)
    with torch.inference_mode():
        frames = model.encode(i_s[0], i_m[0], range(3))
        junk = model.encode(torch.full((1, 16, 16), 10.0), torch.full((1, 16, 16), 70.0), [99])[0]
        valid = [False, True, True]
        t_edge, _ = model.step([frames[0], frames[0], frames[1]], None, valid=valid)
        t_junk, _ = model.step([junk, frames[0], frames[1]], None, valid=valid)
        t_full, _ = model.step([junk, frames[0], frames[1]], None)
        window = [junk, frames[0], frames[1]]
        coarse = model._bit_fused(2, window, window, {}, None)
        fused_full, fused_edge = model.time_fusion(coarse, None), model.time_fusion(coarse, valid)
    torch.testing.assert_close(t_edge, t_junk)
    # the same junk does change what is fused where it is marked valid (the output itself may not show it:
    # a random-init decoder can all but ignore the fused features, and at one thread on some CPUs it does)
    assert not torch.equal(fused_full, fused_edge) and t_full.shape == t_edge.shape
    assert window_valid(0, 2, 3) == [False, False, True, True, True]
    assert window_valid(2, 2, 3) == [True, True, True, False, False]
    with pytest.raises(ValueError):
        model.step([frames[0], frames[0], frames[1]], None, valid=[True, False, True])


def test_pooled_windows_config_and_head_inputs():
    cfg = RmbNetConfig(w=3, pooled_windows=(3, 7))
    assert RmbNetConfig.from_dict(cfg.to_dict()) == cfg
    assert "pooled_windows" not in RmbNetConfig().to_dict()  # older cards stay as they were written
    for bad in ((2,), (9,), (1,)):
        with pytest.raises(ValueError):
            RmbNetConfig(w=3, pooled_windows=bad)
    model = small(pooled_windows=(3,))
    assert model.decoder.head[0][0].in_channels == model.config.channels[0] + 4
    # a static scene: the pooled mean over 3 frames equals each frame's rate
    i_s = torch.full((1, 3, 16, 16), 4.0)
    i_m = torch.full((1, 3, 16, 16), 28.0)
    with torch.inference_mode():
        frames = model.encode(i_s[0], i_m[0], range(3))
        inputs = model._head_inputs(frames, [True, True, True], 0.0)
    torch.testing.assert_close(inputs[:, 2:], inputs[:, :2])


def test_convention_input_is_one_head_plane_that_changes_the_output():
    assert "convention_input" not in RmbNetConfig().to_dict()  # older cards stay as they were written
    cfg = RmbNetConfig(w=1, width=0.25, convention_input=True)
    assert RmbNetConfig.from_dict(cfg.to_dict()) == cfg
    torch.manual_seed(0)
    model = RmbNet(cfg).eval()
    assert model.decoder.head[0][0].in_channels == cfg.channels[0] + 3
    i_s, i_m = torch.rand(2, 3, 16, 16) * 10, torch.rand(2, 3, 16, 16) * 70
    with torch.inference_mode():
        frames = model.encode(i_s.transpose(0, 1).flatten(0, 1), i_m.transpose(0, 1).flatten(0, 1), range(3))
        planes = model._head_inputs(frames, [True] * 3, torch.tensor([0.0, 1.0]))[:, -1]
        assert torch.equal(planes[0], torch.zeros_like(planes[0])) and torch.equal(planes[1], torch.ones_like(planes[1]))
        camera, _ = model.forward_sequence(i_s, i_m, convention=0.0)
        simulated, _ = model.forward_sequence(i_s, i_m, convention=1.0)
        mixed, _ = model.forward_sequence(i_s, i_m, convention=torch.tensor([0.0, 1.0]))
    assert not torch.allclose(camera, simulated)
    torch.testing.assert_close(mixed[0], camera[0])
    torch.testing.assert_close(mixed[1], simulated[1])


def blend_model(**kw) -> RmbNet:
    return small(w=3, pooled_windows=(3, 7), convention_input=True, readout="pure-m", blend=True, **kw)


def test_blend_config_needs_every_bin_count_and_round_trips():
    assert "blend" not in RmbNetConfig().to_dict()  # older cards stay as they were written
    cfg = RmbNetConfig(w=3, pooled_windows=(3, 7), readout="pure-m", blend=True)
    assert RmbNetConfig.from_dict(cfg.to_dict()) == cfg
    for bad in ({"readout": "rmb"}, {"readout": "pure-m", "input_mode": "native"}):
        with pytest.raises(ValueError, match="blend"):
            RmbNetConfig(blend=True, **bad)


def test_blend_starts_near_the_own_estimate_and_can_pass_a_box_filter_through_exactly():
    """A new blend head weighs its own estimate ~0.98; with the logits forced to one box candidate the
    output is that box filter's intensity: the mean rate read through the clamp's inverse under the rate convention
    (the rate itself up to a half), and
    r / (1 - r/2) for a camera's reset-to-zero pixel (the inverse of the emission model's tabulated response
    when the network is told the stream is that model's)."""
    from rmbvideo.net.blend import BIN_TRIALS, OWN_LOGIT_INIT, rate_convention_intensity, reset_to_zero_intensity

    model = blend_model()
    plain = small(w=3, pooled_windows=(3, 7), convention_input=True, readout="pure-m")
    head, plain_head = model.decoder.head[-1], plain.decoder.head[-1]
    with torch.no_grad():
        for name, tensor in plain.state_dict().items():
            target = model.state_dict()[name]
            if tensor.dim() == 0:
                target.copy_(tensor)
            else:
                target[: tensor.shape[0]] = tensor  # the plain model's function in the blend model
    i_s, i_m = random_inputs(k=9, h=16, w=16)
    with torch.inference_mode():
        own = plain.forward_sequence(i_s, i_m, convention=1.0)[0]
        mixed = model.forward_sequence(i_s, i_m, convention=1.0)[0]
    boxes = (i_m / (7 * 10)).clamp(0, 1) * (7 / BIN_TRIALS)  # reference-frame box rate, per frame
    others = 1 - math.exp(OWN_LOGIT_INIT) / (math.exp(OWN_LOGIT_INIT) + 3)  # weight of the 3 box candidates
    assert others < 0.02
    bound = others * torch.maximum(own, torch.tensor(1.0))  # box intensities are <= 1 here
    assert ((mixed - own).abs() <= bound + 1e-6).all()
    with torch.no_grad():
        head.bias[1:] = torch.tensor([-50.0, 50.0, -50.0, -50.0])  # all weight on the reference frame's box
    with torch.inference_mode():
        spikezoo = model.forward_sequence(i_s, i_m, convention=1.0)[0]
        camera = model.forward_sequence(i_s, i_m, convention=0.0)[0]
    torch.testing.assert_close(spikezoo, rate_convention_intensity(boxes), rtol=2e-5, atol=1e-6)
    assert (boxes > 0.6).any()  # where the clamp's inverse differs from the rate
    torch.testing.assert_close(camera, boxes / (1 - boxes / 2), rtol=2e-5, atol=1e-6)
    model.tabulated_response = True
    with torch.inference_mode():
        simulated = model.forward_sequence(i_s, i_m, convention=0.0)[0]
        mixed_codes = model.forward_sequence(torch.cat([i_s, i_s]), torch.cat([i_m, i_m]),
                                             convention=torch.tensor([0.0, 1.0]))[0]
    torch.testing.assert_close(simulated, reset_to_zero_intensity(boxes), rtol=2e-5, atol=1e-6)
    torch.testing.assert_close(mixed_codes, torch.cat([simulated, spikezoo]), rtol=2e-5, atol=1e-6)
    assert (simulated - camera).abs().max() > 0.01  # the two inverses differ above half a threshold per plane
    assert plain_head.out_channels == 1 and head.out_channels == 5


@pytest.mark.parametrize("case", ["dark", "saturated"])
def test_blend_hard_inputs_stay_finite(case):
    model = blend_model()
    k, h, w = 9, 16, 16
    i_s = torch.zeros(1, k, h, w) if case == "dark" else torch.full((1, k, h, w), 10.0)
    i_m = torch.zeros(1, k, h, w) if case == "dark" else torch.full((1, k, h, w), 70.0)
    with torch.inference_mode():
        for convention in (0.0, 1.0):
            out = model.forward_sequence(i_s, i_m, convention=convention)[0]
            assert torch.isfinite(out).all() and (out >= 0).all()


def test_centre_windows_config_is_checked_and_round_trips():
    assert "centre_windows" not in blend_model().config.to_dict()
    cfg = blend_model(centre_windows=(2, 4, 6)).config
    assert RmbNetConfig.from_dict(cfg.to_dict()) == cfg
    for bad, match in (({"centre_windows": (3,)}, "parity"), ({"centre_windows": (10,)}, "parity")):
        with pytest.raises(ValueError, match=match):
            blend_model(**bad)
    with pytest.raises(ValueError, match="blend"):
        RmbNetConfig(readout="pure-m", centre_windows=(2,))


def test_centre_candidate_passes_the_frame_centre_through_exactly():
    """With the logits forced onto the central-4 candidate, the output is the box intensity of the
    reference frame's central 4 readouts, not of its 10; without the central sums the model refuses."""
    from rmbvideo.net.blend import BIN_TRIALS, rate_convention_intensity

    model = blend_model(centre_windows=(2, 4))
    head = model.decoder.head[-1]
    assert head.out_channels == 1 + 1 + 3 + 2 and head.bias[-1] < 0  # new candidates start little used
    g = torch.Generator().manual_seed(3)
    i_s, i_m = random_inputs(k=9, h=16, w=16)
    i_c = torch.stack([torch.randint(0, 15, (1, 9, 16, 16), generator=g).float(),
                       torch.randint(0, 29, (1, 9, 16, 16), generator=g).float()], dim=2)
    with torch.no_grad():
        head.weight[1:].zero_()
        head.bias[1:] = torch.tensor([-50.0, -50.0, -50.0, -50.0, -50.0, 50.0])  # own, box 1/3/7, centre 2, centre 4
    with torch.inference_mode():
        spikezoo = model.forward_sequence(i_s, i_m, convention=1.0, i_c=i_c)[0]
        camera = model.forward_sequence(i_s, i_m, convention=0.0, i_c=i_c)[0]
        with pytest.raises(ValueError, match="central sums over \\[2, 4\\]"):
            model.forward_sequence(i_s, i_m, convention=1.0)
    rate = (i_c[:, :, 1] / (7 * 4)).clamp(0, 1) * (7 / BIN_TRIALS)
    torch.testing.assert_close(spikezoo, rate_convention_intensity(rate), rtol=2e-5, atol=1e-6)
    torch.testing.assert_close(camera, rate / (1 - rate / 2), rtol=2e-5, atol=1e-6)


def test_canonical_batch_keeps_a_sliced_channels_last_frame_channels_last_through_cat():
    """A frame taken from an unflattened channels-last batch (stride C on its size-1 batch dim) is not
    read as channels-last by cat, which then writes NCHW (and the next conv copies it back)."""
    batch = torch.rand(3, 4, 6, 5).contiguous(memory_format=torch.channels_last)
    frame = batch.unflatten(0, (3, -1))[1, :]  # (1, 4, 6, 5)
    other = torch.rand(1, 2, 6, 5).contiguous(memory_format=torch.channels_last)
    fixed = canonical_batch(frame)
    assert torch.equal(fixed, frame) and fixed.data_ptr() == frame.data_ptr()
    assert torch.cat([fixed, other], dim=1).is_contiguous(memory_format=torch.channels_last)
    assert canonical_batch(batch) is batch


@pytest.mark.parametrize("valid", [[True] * 7, [False, False, True, True, True, True, True],
                                   [True, True, True, True, False, False, False]])
def test_pooled_rates_are_the_means_over_the_valid_frames_of_each_window(valid):
    model = small(w=3, pooled_windows=(7, 3, 5))
    with torch.inference_mode():
        frames = model.encode(torch.rand(7, 16, 16) * 10, torch.rand(7, 16, 16) * 70, range(7))
        pooled = model._pooled_rates(frames, valid)
    for size, got in zip((1, 7, 3, 5), pooled):
        half = size // 2
        expected = torch.stack([frames[j].rates for j in range(3 - half, 4 + half) if valid[j]]).mean(dim=0)
        torch.testing.assert_close(got, expected)


def test_aligned_candidate_is_checked_round_trips_and_passes_through_exactly():
    """``aligned``: one more head input and the last blend candidate; with the logits forced onto it the
    output is the box intensity of the aligned mean the caller gives, not of the frame's own counts."""
    from rmbvideo.net.blend import BIN_TRIALS, rate_convention_intensity

    assert "aligned" not in blend_model().config.to_dict()
    model = blend_model(aligned=True)
    assert RmbNetConfig.from_dict(model.config.to_dict()) == model.config
    with pytest.raises(ValueError, match="blend"):
        RmbNetConfig(readout="pure-m", aligned=True)
    head = model.decoder.head[-1]
    assert head.out_channels == 1 + 1 + 3 + 1 and head.bias[-1] < 0  # starts little used
    i_s, i_m = random_inputs(k=9, h=16, w=16)
    i_a = torch.rand(1, 9, 16, 16, generator=torch.Generator().manual_seed(5)) * 50
    with torch.no_grad():
        head.weight[1:].zero_()
        head.bias[1:] = torch.tensor([-50.0, -50.0, -50.0, -50.0, 50.0])  # own, box 1/3/7, aligned
    with torch.inference_mode():
        out = model.forward_sequence(i_s, i_m, convention=1.0, i_a=i_a)[0]
        with pytest.raises(ValueError, match="aligned window mean"):
            model.forward_sequence(i_s, i_m, convention=1.0)
    torch.testing.assert_close(out, rate_convention_intensity((i_a / (7 * 10)).clamp(0, 1) * (7 / BIN_TRIALS)),
                               rtol=2e-5, atol=1e-6)


def test_aligned_evidence_is_head_inputs_only_named_as_the_aligned_box_makes_them():
    """``aligned_evidence``: the aligned mean's statistics follow the means in ``aligned`` and join the head's inputs
    (squashed into [0, 1), NaN-safe), not its blend candidates; a stage that gains them (new inputs at zero weight,
    ``widen_model``) computes what it did; with weights on them, they change the output; a wrong channel count is an
    error naming both."""
    from rmbvideo.net.config import EVIDENCE
    from rmbvideo.net.model import evidence_inputs
    from rmbvideo.net.weights import widen_model
    from rmbvideo.recon.aligned_box import STATISTICS

    assert EVIDENCE == STATISTICS
    with pytest.raises(ValueError, match="aligned_evidence need aligned"):
        RmbNetConfig(readout="pure-m", blend=True, aligned_evidence=True)
    old = blend_model(aligned=True)
    model = widen_model(old, replace(old.config, aligned_evidence=True))
    assert "aligned_evidence" not in old.config.to_dict() and RmbNetConfig.from_dict(model.config.to_dict()) == model.config
    first, last = model.decoder.head[0][0], model.decoder.head[-1]
    assert first.in_channels == old.decoder.head[0][0].in_channels + len(EVIDENCE)
    assert last.out_channels == old.decoder.head[-1].out_channels  # no new blend candidate
    i_s, i_m = random_inputs(k=9, h=16, w=16)
    g = torch.Generator().manual_seed(5)
    i_a = torch.rand(1, 9, 1, 16, 16, generator=g) * 50
    statistics = torch.rand(1, 9, len(EVIDENCE), 16, 16, generator=g) * 3
    with torch.inference_mode():
        before = old.forward_sequence(i_s, i_m, i_a=i_a[:, :, 0])[0]
        widened = model.forward_sequence(i_s, i_m, i_a=torch.cat([i_a, statistics], dim=2))[0]
        torch.testing.assert_close(widened, before)
        first.weight[:, -len(EVIDENCE):] = 0.5
        moved = model.forward_sequence(i_s, i_m, i_a=torch.cat([i_a, statistics], dim=2))[0]
        assert (moved - before).abs().max() > 1e-3 and torch.isfinite(moved).all()
        with pytest.raises(ValueError, match="1 aligned means and 4 statistics, got 1 channels"):
            model.forward_sequence(i_s, i_m, i_a=i_a[:, :, 0])
    odd = torch.tensor([0.0, 0.1, 1e9, float("nan"), -1.0, float("inf")]).reshape(1, 1, 1, 6).expand(1, 4, 1, 6)
    squashed = evidence_inputs(odd)
    assert torch.isfinite(squashed).all() and (squashed >= 0).all() and (squashed <= 1).all()
    assert squashed[0, 0, 0, 1] == pytest.approx(0.5) and squashed[0, 2, 0, 2] == 1.0 and squashed[0, 1, 0, 3] == 0


@pytest.mark.parametrize("kw", [dict(), dict(readout="pure-m", blend=True, centre_windows=(2, 4), aligned=True),
                                dict(readout="pure-m", blend=True, centre_windows=(2, 4), aligned=True, edge_input=True)])
def test_step_run_is_the_steps_one_by_one(kw):
    """A run of K windows in one batched pass (the ConvLSTMs stepping through it in order) gives what K calls of
    ``step`` give, from a carried state, to float rounding; a run of one is a step. With ``edge_input`` (the shipped
    default's head, whose edge planes a GPU's runs of whole windows must read as zeros) too."""
    from rmbvideo.recon.rmbnet import inference_copy

    torch.manual_seed(0)
    model = RmbNet(RmbNetConfig(w=2, width=0.25, **kw)).eval()
    net = inference_copy(model)  # channels-last, as the engine runs it
    frames, h, w = 12, 19, 26
    i_s = torch.randint(0, 81, (frames, h, w)).float()
    i_m = torch.randint(0, 7 * 81, (frames, h, w)).float()
    i_c = torch.randint(0, 7 * 8 * 4, (frames, 2, h, w)).float() if kw else None
    aligned = torch.rand(frames, h, w) * 7 * 80 if kw else None
    with torch.inference_mode():
        encoded = net.encode(i_s, i_m, range(frames), i_c)
        state, steps = None, []
        for i in range(frames):
            window = [encoded[j] for j in window_indices(i, 2, frames)]
            t, state = net.step(window, state, {}, valid=window_valid(i, 2, frames),
                                aligned=None if aligned is None else aligned[i : i + 1])
            steps.append(t)
            if i == 2:
                carried = state
        t, last = net.step_run(encoded[1:11], carried, aligned=None if aligned is None else aligned[3:9])
        one, _ = net.step_run(encoded[1:6], carried, aligned=None if aligned is None else aligned[3:4])
        after, _ = net.step([encoded[j] for j in window_indices(9, 2, frames)], last, {},
                            aligned=None if aligned is None else aligned[9:10])
    expected = torch.cat(steps[3:9])
    assert t.shape == expected.shape == (6, 1, h, w) and torch.isfinite(t).all()
    torch.testing.assert_close(t, expected, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(one, steps[3], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(after, steps[9], rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="at least 5 frames"):
        net.step_run(encoded[:4], None)


def test_step_run_reads_one_encode_call_as_views_and_several_as_copies():
    """A run's stacked windows are views of the features when its frames come from one ``encode`` call and copies
    when they come from several (the streaming engine's batches); both give the same frames."""
    from rmbvideo.net.model import _consecutive_view
    from rmbvideo.recon.rmbnet import inference_copy

    torch.manual_seed(0)
    net = inference_copy(RmbNet(RmbNetConfig(w=2, width=0.25)).eval())
    i_s = torch.randint(0, 81, (10, 19, 26)).float()
    i_m = torch.randint(0, 7 * 81, (10, 19, 26)).float()
    with torch.inference_mode():
        whole = net.encode(i_s, i_m, range(10))
        parts = net.encode(i_s[:4], i_m[:4], range(4)) + net.encode(i_s[4:], i_m[4:], range(4, 10))
        one, _ = net.step_run(whole, None)
        several, _ = net.step_run(parts, None)
    view = _consecutive_view([f.f_s[0] for f in whole[2:6]])
    assert view is not None and view.data_ptr() == whole[2].f_s[0].data_ptr() and view.shape[0] == 4
    torch.testing.assert_close(view, torch.cat([f.f_s[0] for f in whole[2:6]]), rtol=0, atol=0)
    assert _consecutive_view([f.f_s[0] for f in parts[2:6]]) is None  # frames 2, 3 | 4, 5: two encode calls
    assert _consecutive_view([whole[3].f_s[0], whole[2].f_s[0]]) is None  # out of order
    torch.testing.assert_close(one, several, rtol=1e-5, atol=1e-6)


def test_evict_pairs_forgets_every_pair_with_a_frame_older_than_needed():
    """The pair cache keeps a pair only while both its frames are still needed (the engine and `bench network`)."""
    from rmbvideo.net.model import evict_pairs

    cache = {(s, q, k): torch.zeros(1) for s in (0, 2) for q in range(3, 7) for k in range(3, 7)}
    evict_pairs(cache, 5)
    assert cache and all(q >= 5 and k >= 5 for _, q, k in cache) and len(cache) == 2 * 2 * 2


def test_cell_decay_scales_the_carried_cell_state_and_round_trips():
    """``cell_decay`` a: each step starts from a * c (the textbook cell at a = 1, the default, which old cards keep
    by omitting it); the batched run and the graphed recurrence apply it as the step does."""
    torch.manual_seed(2)
    cell = ConvLSTMCell(3, 4, 3, decay=0.9)
    x, h0, c0 = torch.randn(1, 3, 6, 5), torch.randn(1, 4, 6, 5), torch.randn(1, 4, 6, 5) * 3
    with torch.inference_mode():
        plain = ConvLSTMCell(3, 4, 3)
        plain.load_state_dict(cell.state_dict())
        _, (_, c_decayed) = cell(x, (h0, c0))
        _, (_, c_scaled) = plain(x, (h0, 0.9 * c0))
        torch.testing.assert_close(c_decayed, c_scaled)
        xs = torch.randn(5, 3, 6, 5)
        steps, state = [], None
        for k in range(5):
            out, state = cell(xs[k : k + 1], state)
            steps.append(out)
        run, _ = cell.run(xs, None)
        torch.testing.assert_close(run, torch.cat(steps), rtol=1e-5, atol=1e-6)
        gates_x = torch.nn.functional.conv2d(xs, cell.gates.weight[:, :3], cell.gates.bias, padding=1)
        zeros = torch.zeros(1, 4, 6, 5)
        torch.testing.assert_close(cell._recurrence(gates_x, zeros, zeros)[0], run, rtol=1e-5, atol=1e-6)
    config = RmbNetConfig(w=1, width=0.25, cell_decay=0.95)
    assert RmbNetConfig.from_dict(config.to_dict()) == config and RmbNet(config).decoder.lstm1.decay == 0.95
    assert "cell_decay" not in RmbNetConfig(w=1).to_dict()
    for bad in (0.0, 1.5):
        with pytest.raises(ValueError, match="cell_decay"):
            RmbNetConfig(cell_decay=bad)


def test_edge_input_reads_where_the_clip_cuts_the_window_and_leaves_the_rest_of_a_clip_alone():
    """``edge_input``: two planes, the fractions of the past and future window positions outside the clip; a model
    widened to read them computes its old function, and weights on them change only the edge frames."""
    from rmbvideo.net.weights import widen_model

    assert "edge_input" not in RmbNetConfig().to_dict()  # older cards stay as they were written
    with pytest.raises(ValueError, match="edge_input"):
        RmbNetConfig(w=0, edge_input=True)
    cfg = RmbNetConfig(w=2, width=0.25, edge_input=True)
    assert RmbNetConfig.from_dict(cfg.to_dict()) == cfg
    torch.manual_seed(0)
    old = RmbNet(replace(cfg, edge_input=False)).eval()
    model = widen_model(old, cfg)
    assert model.decoder.head[0][0].in_channels == old.decoder.head[0][0].in_channels + 2
    i_s, i_m = torch.rand(1, 7, 16, 16) * 10, torch.rand(1, 7, 16, 16) * 70
    with torch.inference_mode():
        frames = model.encode(i_s[0], i_m[0], range(7))
        for i, expected in ((0, (1.0, 0.0)), (1, (0.5, 0.0)), (3, (0.0, 0.0)), (5, (0.0, 0.5)), (6, (0.0, 1.0))):
            planes = model._head_inputs([frames[j] for j in window_indices(i, 2, 7)], window_valid(i, 2, 7), 0.0)[:, -2:]
            assert torch.equal(planes, torch.tensor(expected).reshape(1, 2, 1, 1).expand_as(planes))
        before, _ = old.forward_sequence(i_s, i_m, prime=2)
        widened, _ = model.forward_sequence(i_s, i_m, prime=2)
        torch.testing.assert_close(widened, before, rtol=1e-5, atol=1e-6)  # other channel counts, other rounding
        model.decoder.head[0][0].weight[:, -2:].normal_(std=0.5)
        edged, _ = model.forward_sequence(i_s, i_m, prime=2)
    torch.testing.assert_close(edged[:, 2:5], widened[:, 2:5], rtol=0, atol=0)  # whole windows: unchanged
    assert all(not torch.allclose(edged[:, i], widened[:, i]) for i in (0, 1, 5, 6))


def test_edge_slide_fills_a_cut_window_with_the_frames_beyond_its_other_end():
    """``edge_slide``: the positions past a clip's edge hold the frames beyond the window's other end, nearest first,
    where the clip has them, and are valid; mid-clip windows and the window's reach are as before otherwise."""
    assert window_indices(0, 3, 10, slide=True) == [6, 5, 4, 0, 1, 2, 3]
    assert window_indices(9, 3, 10, slide=True) == [6, 7, 8, 9, 5, 4, 3]
    assert window_indices(1, 3, 10, slide=True) == [6, 5, 0, 1, 2, 3, 4]
    assert window_valid(0, 3, 10, slide=True) == [True] * 7
    assert window_indices(0, 3, 5, slide=True) == [0, 0, 4, 0, 1, 2, 3]  # a clip too short to fill the window
    assert window_valid(0, 3, 5, slide=True) == [False, False, True, True, True, True, True]
    assert window_indices(0, 3, None, slide=True) == [6, 5, 4, 0, 1, 2, 3]  # the end not known: only the start slides
    for i in range(3, 7):
        assert window_indices(i, 3, 10, slide=True) == window_indices(i, 3, 10)
        assert window_valid(i, 3, 10, slide=True) == window_valid(i, 3, 10) == [True] * 7
    assert window_reach(0, 3, 10, slide=True) == range(0, 7) and window_reach(0, 3, 10) == range(0, 4)
    assert window_reach(9, 3, 10, slide=True) == range(3, 10)


def test_edge_slide_changes_only_the_attention_of_an_edge_frame():
    """A slid edge window's extra frames reach both attentions (the fused features change) but not the pooled means
    nor the edge planes (the head's inputs are the cut window's); whole windows give the model's frames exactly."""
    assert "edge_slide" not in RmbNetConfig().to_dict()  # older cards stay as they were written
    with pytest.raises(ValueError, match="edge_slide"):
        RmbNetConfig(w=0, edge_slide=True)
    cfg = RmbNetConfig(w=2, width=0.25, pooled_windows=(3, 5), edge_input=True, edge_slide=True)
    assert RmbNetConfig.from_dict(cfg.to_dict()) == cfg
    torch.manual_seed(0)
    cut = RmbNet(replace(cfg, edge_slide=False)).eval()
    slid = RmbNet(cfg).eval()
    slid.load_state_dict(cut.state_dict())
    i_s, i_m = torch.rand(1, 8, 16, 16) * 10, torch.rand(1, 8, 16, 16) * 70
    with torch.inference_mode():
        frames = slid.encode(i_s[0], i_m[0], range(8))
        for i in (0, 7):
            a = cut._prepare([frames[j] for j in window_indices(i, 2, 8)], {}, window_valid(i, 2, 8), 0.0, None)
            b = slid._prepare([frames[j] for j in window_indices(i, 2, 8, slide=True)], {},
                              window_valid(i, 2, 8, slide=True), 0.0, None)
            assert torch.equal(a.decoder_inputs[2], b.decoder_inputs[2])  # pooled means and edge planes: the cut's
            assert not torch.equal(a.decoder_inputs[0], b.decoder_inputs[0])  # what the attention fused: not
        for i in range(2, 6):  # whole windows: the same inputs to the decoder, in either direction of time
            window, valid = [frames[j] for j in window_indices(i, 2, 8)], window_valid(i, 2, 8)
            for order in (1, -1):
                for a, b in zip(cut._prepare(window[::order], {}, valid, 0.0, None).decoder_inputs[::2],
                                slid._prepare(window[::order], {}, valid, 0.0, None).decoder_inputs[::2]):
                    assert torch.equal(a, b)
        for i in (0, 7):  # an edge window run backwards (priming) reads its own frames' means and planes too
            a = cut._prepare([frames[j] for j in window_indices(i, 2, 8)][::-1], {}, window_valid(i, 2, 8)[::-1],
                             0.0, None)
            b = slid._prepare([frames[j] for j in window_indices(i, 2, 8, slide=True)][::-1], {},
                              window_valid(i, 2, 8, slide=True)[::-1], 0.0, None)
            assert torch.equal(a.decoder_inputs[2], b.decoder_inputs[2])

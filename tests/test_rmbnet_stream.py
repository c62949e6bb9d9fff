"""The streaming RMB-Net engine: chunk-size independence, equality with the plain forward pass,
edges of the capture, long recurrent runs, and the NaN guard."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from rmbvideo.chunks import RmbChunk
from rmbvideo.errors import InputError
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.model import RmbNet
from rmbvideo.recon.prelim import PreliminaryFrames, PrelimFrame, select_centre
from rmbvideo.recon.precision import cpu_has_native_bf16, uses_bf16
from rmbvideo.recon.rmbnet import RmbNetReconstructor, all_finite, inference_copy
from rmbvideo.sensor.readout import RmbReadout

H, W = 20, 13


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def tiny(**kw) -> RmbNet:
    torch.manual_seed(0)
    return RmbNet(RmbNetConfig(**{"w": 2, "width": 0.25, **kw})).eval()


def rmb_stream(readouts: int, seed: int = 0) -> RmbChunk:
    rng = np.random.default_rng(seed)
    light = rng.random((H, W)) * np.linspace(0.05, 4.0, W)[None, :]
    multi = np.minimum(rng.poisson(light * 2, (readouts, H, W)), 7).astype(np.uint8)
    single = (rng.random((readouts, H, W)) < np.minimum(light, 1)).astype(np.uint8)
    full = RmbChunk(single, multi, np.ones((readouts, H), bool), start=0, rate_hz=10_000.0)
    return RmbReadout(band=4, shift=2).apply(full)


def split(chunk: RmbChunk, size: int) -> list[RmbChunk]:
    return [RmbChunk(chunk.single[a:a + size], chunk.multi[a:a + size], chunk.multi_rows[a:a + size],
                     a, chunk.rate_hz) for a in range(0, len(chunk.single), size)]


def stream(model: RmbNet, chunks: list, **kw):
    engine = RmbNetReconstructor(model, device="cpu", **{"precision": "fp32", **kw})
    frames = [f for c in chunks for f in engine.push(c)] + engine.flush()
    return frames, engine


@pytest.mark.parametrize("frame_batch", [1, 3, 32])
def test_chunk_size_independent_and_equal_to_forward_sequence(frame_batch):
    """Whatever the chunks and however many frames each batched pass makes (``frame_batch``)."""
    model = tiny()
    data = rmb_stream(95)
    results = {size: stream(model, split(data, size), frame_batch=frame_batch)[0] for size in (1, 7, 95)}
    prelim = PreliminaryFrames(n=10)
    pframes = prelim.push(data) + prelim.flush()
    assert len(pframes) == 9
    with torch.inference_mode():
        reference = model.forward_sequence(torch.from_numpy(np.stack([p.i_s for p in pframes]))[None],
                                           torch.from_numpy(np.stack([p.i_m for p in pframes]))[None],
                                           prime=model.config.w)[0][0]
    for size, frames in results.items():
        assert [f.index for f in frames] == [p.index for p in pframes], size
        assert [f.time_s for f in frames] == [p.time_s for p in pframes]
        images = np.stack([f.image for f in frames])
        assert images.dtype == np.float32 and np.isfinite(images).all() and (images >= 0).all()
        np.testing.assert_allclose(images, reference.numpy(), rtol=1e-5, atol=1e-7 * float(reference.max()))
    assert not np.allclose(results[1][0].image, results[1][4].image)


@pytest.mark.parametrize("size", [1, 7, 95])
def test_preliminary_frames_made_a_chunk_ahead_give_the_same_frames(size):
    """``preliminary_beside`` (a GPU's default) makes each chunk's preliminary frames in a thread of its own while the
    network works on the chunk before: the same frames bit for bit, a chunk later, all of them by the flush."""
    model = tiny()
    chunks = split(rmb_stream(95), size)
    inline, _ = stream(model, chunks, preliminary_beside=False)
    engine = RmbNetReconstructor(model, device="cpu", precision="fp32", preliminary_beside=True)
    pushed = [engine.push(c) for c in chunks]
    assert pushed[0] == []  # the first chunk's preliminary frames are still being made
    ahead = [f for frames in pushed for f in frames] + engine.flush()
    assert [f.index for f in ahead] == [f.index for f in inline] and len(inline) == 9
    for a, b in zip(ahead, inline):
        np.testing.assert_array_equal(a.image, b.image)
    assert engine.stage_seconds["preliminary frames"] > 0


def test_a_bad_chunk_made_ahead_fails_the_next_call():
    """An error in the thread ahead reaches the caller (at the next push or the flush), as it would inline."""
    model = tiny()
    first = split(rmb_stream(40), 20)[0]
    engine = RmbNetReconstructor(model, device="cpu", precision="fp32", preliminary_beside=True)
    engine.push(first)
    engine.push(first)  # out of order: the preliminary frames refuse it in the thread ahead
    with pytest.raises(ValueError, match="readout"):
        engine.flush()


def test_first_frames_start_from_a_state_primed_backwards_over_the_frames_after_them():
    """The default engine primes frame 0's state by running the network backwards over frames w .. 1: that
    changes the first frames and nothing that the state has forgotten; ``prime=0`` is the plain forward pass,
    a clip shorter than the priming is primed over what it has, and priming is the same whatever the chunks."""
    model = tiny()
    data = rmb_stream(95)
    prelim = PreliminaryFrames(n=10)
    pframes = prelim.push(data) + prelim.flush()
    head = split(data, 20)[0]
    prelim = PreliminaryFrames(n=10)
    short_frames = prelim.push(head) + prelim.flush()
    assert len(short_frames) == 2
    i_s, i_m = (torch.from_numpy(np.stack([getattr(p, k) for p in pframes]))[None] for k in ("i_s", "i_m"))
    s_s, s_m = (torch.from_numpy(np.stack([getattr(p, k) for p in short_frames]))[None] for k in ("i_s", "i_m"))
    with torch.inference_mode():
        plain = model.forward_sequence(i_s, i_m)[0][0].numpy()
        primed = model.forward_sequence(i_s, i_m, prime=model.config.w)[0][0].numpy()
        short = model.forward_sequence(s_s, s_m, prime=model.config.w)[0][0].numpy()
        short_primed_over_what_it_has = model.forward_sequence(s_s, s_m, prime=1)[0][0].numpy()
    assert not np.allclose(plain[0], primed[0], rtol=1e-3)
    np.testing.assert_allclose(short, short_primed_over_what_it_has, rtol=1e-6)
    unprimed = np.stack([f.image for f in stream(model, split(data, 7), prime=0)[0]])
    np.testing.assert_allclose(unprimed, plain, rtol=1e-5, atol=1e-7 * float(plain.max()))
    for size in (1, 40):
        images = np.stack([f.image for f in stream(model, split(data, size))[0]])
        np.testing.assert_allclose(images, primed, rtol=1e-5, atol=1e-7 * float(primed.max()))
    short_stream = np.stack([f.image for f in stream(model, [head])[0]])
    np.testing.assert_allclose(short_stream, short, rtol=1e-5, atol=1e-7 * float(short.max()))
    with pytest.raises(ValueError, match="prime"):
        RmbNetReconstructor(model, device="cpu", prime=-1)


def test_ring_buffer_and_caches_stay_bounded():
    model = tiny()
    rng = np.random.default_rng(1)
    engine = RmbNetReconstructor(model, device="cpu")
    window = model.config.window
    primed = 2 * model.config.w + 1  # before the first frame: the windows of the w frames its state is primed over
    for k in range(30):
        engine.push(PrelimFrame(k, k * 1e-3, rng.integers(0, 11, (H, W)).astype(np.float32),
                                rng.integers(0, 71, (H, W)).astype(np.float32), np.ones(H, bool)))
        assert len(engine._encoded) <= (window if k > primed else primed)
        assert len(engine._pair_cache) <= 3 * window * window


def test_capture_of_one_preliminary_frame():
    frames, _ = stream(tiny(), [rmb_stream(10)])
    assert len(frames) == 1 and frames[0].image.shape == (H, W) and np.isfinite(frames[0].image).all()


def test_empty_capture_gives_no_frames():
    assert stream(tiny(), [rmb_stream(5)])[0] == []


def test_long_run_state_does_not_grow():
    """3,000 recurrent steps through alternating dark/bright stretches of 100: finite, >= 0, the state no
    larger after 3,000 steps than after 1,600."""
    torch.manual_seed(0)
    model = RmbNet(RmbNetConfig(w=1, width=0.125)).eval()
    engine = RmbNetReconstructor(model, device="cpu")
    rng = np.random.default_rng(2)
    peaks = []
    for block in range(30):
        bright = 10.0 if block % 2 else 0.0
        batch = [PrelimFrame(k, k * 1e-3, np.full((16, 16), bright, np.float32),
                             (rng.random((16, 16)) * 70).astype(np.float32), np.ones(16, bool))
                 for k in range(100 * block, 100 * (block + 1))]
        for frame in engine.push(batch):
            assert np.isfinite(frame.image).all() and frame.image.min() >= 0
        if block in (15, 29):
            peaks.append(max(float(t.abs().max()) for layer in engine._state for t in layer))
    assert engine.nonfinite_frames == 0
    assert peaks[1] <= 1.5 * peaks[0] + 1e-3


@pytest.mark.parametrize("frame_batch", [1, 4])
def test_nonfinite_network_output_is_guarded(frame_batch):
    model = tiny()
    with torch.no_grad():
        model.decoder.head[1].bias.fill_(float("nan"))
    frames, engine = stream(model, [rmb_stream(90)], frame_batch=frame_batch)
    assert len(frames) == 9 and engine.nonfinite_frames == 9
    assert all(np.isfinite(f.image).all() and (f.image >= 0).all() for f in frames)


def test_all_finite_matches_isfinite_including_a_sum_that_overflows():
    big = torch.full((4, 4), 3e38)  # every value finite, the sum not
    for t in (torch.rand(3, 5), big, big.bfloat16(), torch.tensor([1.0, float("inf")]),
              torch.tensor([float("-inf"), float("inf")]), torch.tensor([0.0, float("nan")])):
        assert all_finite(t) == bool(torch.isfinite(t).all())


def test_alignment_with_flow_runs_and_is_chunk_independent():
    model = tiny(w=1)
    data = rmb_stream(60)
    a = np.stack([f.image for f in stream(model, split(data, 13), align="dis")[0]])
    b = np.stack([f.image for f in stream(model, [data], align="dis")[0]])
    batched = np.stack([f.image for f in stream(model, [data], align="dis", frame_batch=8)[0]])
    c = np.stack([f.image for f in stream(model, [data])[0]])
    assert a.shape == (6, H, W) and np.isfinite(a).all()
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(batched, b)  # aligned windows are made one by one whatever the frame batch
    assert not np.allclose(a, c)


def test_blend_model_streams_chunk_independent_on_every_bin_count():
    model = tiny(w=3, pooled_windows=(3, 7), convention_input=True, readout="pure-m", blend=True)
    rng = np.random.default_rng(4)
    light = rng.random((H, W)) * np.linspace(0.05, 4.0, W)[None, :]
    data = RmbChunk((rng.random((95, H, W)) < np.minimum(light, 1)).astype(np.uint8),
                    np.minimum(rng.poisson(light * 2, (95, H, W)), 7).astype(np.uint8),
                    np.ones((95, H), bool), start=0, rate_hz=10_000.0)
    prelim = PreliminaryFrames(n=10)
    pframes = prelim.push(data) + prelim.flush()
    with torch.inference_mode():
        reference = model.forward_sequence(torch.from_numpy(np.stack([p.i_s for p in pframes]))[None],
                                           torch.from_numpy(np.stack([p.i_m for p in pframes]))[None],
                                           prime=model.config.w)[0][0]
    for size in (1, 13, 95):
        images = np.stack([f.image for f in stream(model, split(data, size))[0]])
        assert np.isfinite(images).all() and (images >= 0).all()
        np.testing.assert_allclose(images, reference.numpy(), rtol=1e-5, atol=1e-7 * float(reference.max()))


def test_centre_windows_stream_equals_forward_sequence_and_need_the_sums():
    torch.manual_seed(0)
    model = RmbNet(RmbNetConfig(w=2, width=0.25, readout="pure-m", blend=True, centre_windows=(2, 6))).eval()
    rng = np.random.default_rng(4)
    multi = rng.integers(0, 8, (95, H, W)).astype(np.uint8)
    data = RmbChunk((multi > 3).astype(np.uint8), multi, np.ones((95, H), bool), start=0, rate_hz=10_000.0)
    prelim = PreliminaryFrames(n=10)
    pframes = prelim.push(data) + prelim.flush()
    with torch.inference_mode():
        reference = model.forward_sequence(
            torch.from_numpy(np.stack([p.i_s for p in pframes]))[None],
            torch.from_numpy(np.stack([p.i_m for p in pframes]))[None],
            i_c=torch.from_numpy(np.stack([p.i_c[[0, 2]] for p in pframes]))[None], prime=model.config.w)[0][0]
    for size in (7, 95):
        images = np.stack([f.image for f in stream(model, split(data, size))[0]])
        np.testing.assert_allclose(images, reference.numpy(), rtol=1e-5, atol=1e-7 * float(reference.max()))
    engine = RmbNetReconstructor(model, device="cpu")
    bare = PrelimFrame(0, 0.0, pframes[0].i_s, pframes[0].i_m, pframes[0].m_valid)
    with pytest.raises(InputError, match="preliminary frame 0: central sums"):
        engine.push([bare])


@pytest.mark.parametrize("flags, native", [("fpu sse avx512f avx512_bf16 avx512vl", True),
                                           ("fpu sse amx_tile amx_bf16", True), ("fpu sse avx2 fma", False)])
def test_auto_precision_is_bf16_only_where_the_hardware_has_it(tmp_path, flags, native):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(f"processor\t: 0\nflags\t\t: {flags}\n\nprocessor\t: 1\nflags\t\t: {flags}\n")
    assert cpu_has_native_bf16(cpuinfo) is native
    assert cpu_has_native_bf16(tmp_path / "missing") is False
    assert not uses_bf16("auto", torch.device("cuda")) and uses_bf16("bf16", torch.device("cuda"))
    assert uses_bf16("bf16", torch.device("cpu")) and not uses_bf16("fp32", torch.device("cpu"))
    assert uses_bf16("auto", torch.device("cpu")) is cpu_has_native_bf16()
    with pytest.raises(ValueError, match="precision"):
        uses_bf16("fp16", torch.device("cpu"))


def test_bf16_engine_stays_close_to_fp32_and_finite():
    """The bf16 engine (the CPU default where the hardware has bf16) against the fp32 reference path:
    mu-law outputs within 0.03 (bf16 keeps 8 mantissa bits) and nothing non-finite."""
    model = tiny()
    chunks = split(rmb_stream(95), 19)
    exact = np.stack([f.image for f in stream(model, chunks)[0]])
    fast = np.stack([f.image for f in stream(model, chunks, precision="bf16")[0]])
    assert np.isfinite(fast).all() and (fast >= 0).all()
    mu = model.config.output_mu
    compress = lambda x: np.log1p(mu * x) / np.log1p(mu)  # noqa: E731
    assert np.abs(compress(fast) - compress(exact)).max() < 0.03


def test_bf16_weights_stored_once_give_what_autocast_casting_them_per_call_gives():
    """Under bf16 the engine keeps the convolutions' weights in bf16 (the encoders' first convolution in
    fp32): bit for bit the output of autocast casting fp32 weights at every call."""
    model = tiny()
    chunks = split(rmb_stream(60), 20)
    stored, engine = stream(model, chunks, precision="bf16")
    dtypes = {m.weight.dtype for m in engine._net.modules() if isinstance(m, torch.nn.Conv2d)}
    assert dtypes == {torch.bfloat16, torch.float32}
    assert engine._net.encoder_s.blocks[0][0].weight.dtype == torch.float32
    reference = RmbNetReconstructor(model, device="cpu", precision="bf16")
    reference._net = inference_copy(model)  # fp32 weights, cast by autocast at every call
    cast = [f for c in chunks for f in reference.push(c)] + reference.flush()
    assert np.array_equal(np.stack([f.image for f in stored]), np.stack([f.image for f in cast]))


@pytest.mark.parametrize("radius, shift, sharp, evidence", [(None, False, 0, False), (4, True, 2, False),
                                                             (4, True, 0, True)])
def test_aligned_model_stream_equals_forward_sequence_with_the_aligned_means(radius, shift, sharp, evidence):
    """A model with the aligned window mean: the engine computes it per reference frame (windows cut at,
    or with ``aligned_shift`` slid inwards from, the capture's edges; radius w or wider; with ``aligned_evidence``
    its statistics too) and matches the plain forward pass given ``aligned_means``, whatever the chunking."""
    from rmbvideo.net.blend import BIN_TRIALS
    from rmbvideo.recon.aligned_box import aligned_means, network_input

    torch.manual_seed(0)
    model = RmbNet(RmbNetConfig(w=2, width=0.25, readout="pure-m", blend=True, aligned=True, aligned_radius=radius,
                                aligned_shift=shift, aligned_centre=sharp, aligned_evidence=evidence)).eval()
    with torch.no_grad():  # make the aligned candidate (and its statistics) count, so a wrong one shows
        model.decoder.head[-1].bias[-1] = 3.0
        if evidence:
            model.decoder.head[0][0].weight[:, -4:] = 2.0
    rng = np.random.default_rng(6)
    multi = rng.integers(0, 8, (95, H, W)).astype(np.uint8)
    data = RmbChunk((multi > 3).astype(np.uint8), multi, np.ones((95, H), bool), start=0, rate_hz=10_000.0)
    prelim = PreliminaryFrames(n=10)
    pframes = prelim.push(data) + prelim.flush()
    i_m = np.stack([p.i_m for p in pframes]).astype(np.float32)
    centre = (np.stack([select_centre(p.i_c, 10, (sharp,))[0] for p in pframes]).astype(np.float32) / (BIN_TRIALS * sharp)
              if sharp else None)
    means = aligned_means(i_m / (BIN_TRIALS * 10), model.config.aligned_half_width, shift=shift, sharp=centre,
                          statistics=evidence)
    means, statistics = means if evidence else (means, [None] * len(means))
    i_a = np.stack([network_input(m, e, BIN_TRIALS * 10) for m, e in zip(means, statistics)])
    assert i_a.shape[1:] == ((1 + 4, H, W) if evidence else (2, H, W) if sharp else (H, W))
    with torch.inference_mode():
        reference = model.forward_sequence(torch.from_numpy(np.stack([p.i_s for p in pframes]))[None],
                                           torch.from_numpy(i_m)[None], i_a=torch.from_numpy(i_a)[None],
                                           prime=model.config.w)[0][0]
        plain = model.forward_sequence(torch.from_numpy(np.stack([p.i_s for p in pframes]))[None],
                                       torch.from_numpy(i_m)[None], i_a=torch.from_numpy(
                                           np.ascontiguousarray(i_a[:, ::-1]) if i_a.ndim == 4 else i_m)[None])[0][0]
    assert not np.allclose(reference.numpy(), plain.numpy(), rtol=3e-4, atol=1e-6 * float(reference.max()))
    for size in (7, 95):
        images = np.stack([f.image for f in stream(model, split(data, size))[0]])
        assert np.isfinite(images).all()
        # rtol: float rounding of the engine's folded, channels-last network, grown ~8x by the mu-law's inverse at the
        # brightest pixels (1.1e-4 at one of 2,340 with the flows of padded 20x13 frames); a wrong mean is off by far more
        np.testing.assert_allclose(images, reference.numpy(), rtol=3e-4, atol=1e-6 * float(reference.max()))
    with pytest.raises(ValueError, match="aligned window mean"):
        model.forward_sequence(torch.from_numpy(np.stack([p.i_s for p in pframes]))[None], torch.from_numpy(i_m)[None])


def aligned_model_and_stream(seed: int, evidence: bool = False) -> tuple[RmbNet, RmbChunk]:
    """A tiny model that reads the aligned means (their candidate weighted up, so a wrong one shows; with
    ``evidence`` their statistics too, likewise) and 135 readouts of random multi-bit counts."""
    torch.manual_seed(0)
    model = RmbNet(RmbNetConfig(w=2, width=0.25, readout="pure-m", blend=True, aligned=True, aligned_radius=4,
                                aligned_shift=True, aligned_centre=2, aligned_evidence=evidence)).eval()
    with torch.no_grad():
        model.decoder.head[-1].bias[-1] = 3.0
        if evidence:
            model.decoder.head[0][0].weight[:, -4:] = 2.0
    multi = np.random.default_rng(seed).integers(0, 8, (135, H, W)).astype(np.uint8)
    return model, RmbChunk((multi > 3).astype(np.uint8), multi, np.ones((135, H), bool), start=0, rate_hz=10_000.0)


def test_aligned_means_beside_the_network_give_the_same_frames_bit_for_bit():
    """With two threads the aligned window means run in a worker thread of their own beside the network
    (one thread each); the frames are those of the inline run with the same chunks."""
    model, data = aligned_model_and_stream(7)
    for size in (9, 135):
        inline, inline_engine = stream(model, split(data, size), threads=1)
        assert not inline_engine.aligned_beside
        beside, engine = stream(model, split(data, size), threads=2)
        assert engine.aligned_beside and engine._threads_for() == (1, 1)
        assert [f.index for f in beside] == [f.index for f in inline]
        assert np.array_equal(np.stack([f.image for f in beside]), np.stack([f.image for f in inline]))
        assert engine.stage_seconds["aligned mean"] > 0


@pytest.mark.parametrize("evidence", [False, True])
def test_aligned_means_of_a_worker_pool_in_batched_passes_give_the_frames_of_the_plain_run(monkeypatch, evidence):
    """With the network on a GPU the aligned means come from a pool of threads (every core but one) and the network
    makes batched runs of frames: the frames are those of the inline, frame-by-frame run (the means, and their
    statistics, bit for bit; the network's output to float rounding)."""
    import rmbvideo.recon.rmbnet as engine_module

    model, data = aligned_model_and_stream(8, evidence)
    plain, _ = stream(model, [data], threads=1)
    monkeypatch.setattr(engine_module, "aligned_workers", lambda device, threads: 3)
    for size, batch in ((9, 4), (135, 32)):
        pooled, engine = stream(model, split(data, size), threads=1, frame_batch=batch)
        assert engine._aligned_box.pooled and engine.stage_seconds["aligned mean"] > 0
        assert [f.index for f in pooled] == [f.index for f in plain]
        # batched convolutions sum in another order than frame-by-frame ones: a few values differ by ~2e-5 relative
        np.testing.assert_allclose(np.stack([f.image for f in pooled]), np.stack([f.image for f in plain]),
                                   rtol=1e-4, atol=1e-6)
        assert not engine._aligned_box._box._rates.keys() - set(range(135 // 10 - 8, 135 // 10))


def test_frame_batch_is_checked():
    with pytest.raises(ValueError, match="frame_batch"):
        RmbNetReconstructor(tiny(), device="cpu", frame_batch=0)


def test_default_frame_batch_is_one_on_a_cpu_and_bounded_by_frame_size_on_a_gpu():
    from rmbvideo.recon.rmbnet import GPU_BATCH_PIXELS, GPU_FRAME_BATCH, default_frame_batch

    assert default_frame_batch(torch.device("cpu"), (125, 200)) == 1
    assert default_frame_batch(torch.device("cuda"), (125, 200)) == GPU_FRAME_BATCH
    big = default_frame_batch(torch.device("cuda"), (1000, 1000))
    assert 1 <= big < GPU_FRAME_BATCH and big * 1000 * 1000 <= GPU_BATCH_PIXELS
    assert default_frame_batch(torch.device("cuda"), (8000, 8000)) == 1


def test_aligned_workers_follow_threads_on_a_gpu_and_the_policy_on_a_cpu():
    from rmbvideo.recon.rmbnet import aligned_workers
    from rmbvideo.threads import available_cores

    cuda, cpu = torch.device("cuda"), torch.device("cpu")
    assert aligned_workers(cuda, 4) == 4 and aligned_workers(cuda, 1) == 1
    assert aligned_workers(cuda, None) == max(1, available_cores() - 1)
    assert aligned_workers(cpu, 1) == 0 and aligned_workers(cpu, 3) == 1  # inline, or one thread beside


def test_a_failing_cuda_graph_falls_back_to_the_eager_pass_with_a_warning(monkeypatch, caplog):
    """A batched pass whose CUDA graphs fail (a driver or capture problem on a user's GPU) is made again without them,
    once, with a warning: the same frames as a run that never asked for graphs."""
    model = tiny()
    data = rmb_stream(95)
    plain, _ = stream(model, [data], frame_batch=8)
    original = RmbNet.step_run

    def failing(self, *args, graphed: bool = False, **kw):
        if graphed:
            raise RuntimeError("CUDA error: operation not permitted when stream is capturing")
        return original(self, *args, **kw)

    monkeypatch.setattr(RmbNet, "step_run", failing)
    engine = RmbNetReconstructor(model, device="cpu", precision="fp32", frame_batch=8)
    engine._graphed = True  # as on a GPU
    with caplog.at_level("WARNING"):
        frames = engine.push(data) + engine.flush()
    assert not engine._graphed and sum("CUDA graphs failed" in r.message for r in caplog.records) == 1
    np.testing.assert_array_equal(np.stack([f.image for f in frames]), np.stack([f.image for f in plain]))


def test_a_batched_engine_makes_whole_runs_whatever_the_chunks(monkeypatch):
    """With ``frame_batch`` K the frames wait until K are ready, so every batched pass but the clip's last is K frames
    long however small the pushed chunks (a GPU's passes stay full and its CUDA graph keeps one shape); the frames
    are those of the frame-by-frame run."""
    model = tiny()
    data = rmb_stream(255)
    plain, _ = stream(model, [data])
    lengths = []
    original = RmbNet.step_run

    def counted(self, frames, *args, **kw):
        lengths.append(len(frames) - 2 * self.config.w)
        return original(self, frames, *args, **kw)

    monkeypatch.setattr(RmbNet, "step_run", counted)
    batched, engine = stream(model, split(data, 13), frame_batch=8)
    assert lengths and all(k == 8 for k in lengths[:-1]) and 1 < lengths[-1] <= 8, lengths
    assert not engine._encoded.keys() - set(range(25 - 2, 25))  # bounded: the last window's frames only
    assert [f.index for f in batched] == [f.index for f in plain]
    np.testing.assert_allclose(np.stack([f.image for f in batched]), np.stack([f.image for f in plain]),
                               rtol=1e-5, atol=1e-6)


def test_a_model_whose_edge_windows_slide_streams_its_forward_sequence():
    """``edge_slide``: the engine waits for the frames a slid first window reads, keeps those a slid last window
    reads back, and gives ``forward_sequence``'s frames whatever the chunks; warped windows are refused."""
    from rmbvideo.net.model import window_indices, window_valid

    model = tiny(edge_slide=True)
    data = rmb_stream(95)
    results = {size: stream(model, split(data, size))[0] for size in (1, 7, 95)}
    engine = RmbNetReconstructor(model, device="cpu", precision="fp32", prime=0)
    seen, step = [], engine._net.step

    def recording(window, *args, valid=None, **kw):  # the windows the engine hands the network, in its order
        seen.append(([f.index for f in window], list(valid)))
        return step(window, *args, valid=valid, **kw)

    engine._net.step = recording
    for chunk in split(data, 7):
        engine.push(chunk)
    engine.flush()
    count = len(seen)
    assert count == 9 and seen == [(window_indices(i, 2, count, slide=True), window_valid(i, 2, count, slide=True))
                                   for i in range(count)]
    assert seen[0][0] == [4, 3, 0, 1, 2] and seen[-1][0] == [6, 7, 8, 5, 4] and all(seen[0][1] + seen[-1][1])
    prelim = PreliminaryFrames(n=10)
    pframes = prelim.push(data) + prelim.flush()
    with torch.inference_mode():
        i_s = torch.from_numpy(np.stack([p.i_s for p in pframes]))[None]
        i_m = torch.from_numpy(np.stack([p.i_m for p in pframes]))[None]
        reference = model.forward_sequence(i_s, i_m, prime=model.config.w)[0][0]
    for size, frames in results.items():
        assert [f.index for f in frames] == [p.index for p in pframes], size
        images = np.stack([f.image for f in frames])
        np.testing.assert_allclose(images, reference.numpy(), rtol=1e-5, atol=1e-7 * float(reference.max()))
    with pytest.raises(ValueError, match="edge_slide"):
        RmbNetReconstructor(model, device="cpu", align="dis")

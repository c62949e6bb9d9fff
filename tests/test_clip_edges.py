"""A clip's edge frames with an edge model of their own (``rmbvideo.recon.clip_edges``): the first and last w frames mix
in the edge model's run over the clip's first and last 2w frames as clips of their own, every other frame is the
default model's bit for bit, whatever the chunks; the edge model beside a weight file is found and checked."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from rmbvideo.errors import ModelError
from rmbvideo.net.config import RmbNetConfig
from rmbvideo.net.model import RmbNet
from rmbvideo.net.weights import ModelCard, save_model
from rmbvideo.recon.clip_edges import EDGE_MIX
from rmbvideo.recon.prelim import PreliminaryFrames
from rmbvideo.recon.rmbnet import RmbNetReconstructor
from rmbvideo.shipped import edge_model_path
from tests.test_rmbnet_stream import one_thread, rmb_stream, split  # noqa: F401  (one_thread: autouse)

W = 2


def net(seed: int, w: int = W) -> RmbNet:
    torch.manual_seed(seed)
    return RmbNet(RmbNetConfig(w=w, width=0.25)).eval()


def run(model: RmbNet, items: list, **kw) -> list:
    engine = RmbNetReconstructor(model, device="cpu", precision="fp32", **kw)
    return [f for item in items for f in engine.push(item)] + engine.flush()


def mixed(model_frames: list, edge_frames: list) -> list[np.ndarray]:
    """The edge frames the engine makes: the model's with the edge model's mixed in."""
    return [((1 - EDGE_MIX) * a.image + EDGE_MIX * b.image).astype(np.float32)
            for a, b in zip(model_frames, edge_frames)]


def prelim_frames(readouts: int) -> list:
    prelim = PreliminaryFrames(n=10)
    data = rmb_stream(readouts)
    return prelim.push(data) + prelim.flush()


@pytest.mark.parametrize("prime", [None, 0])
def test_edge_frames_are_the_edge_models_clips_and_the_rest_the_models_whatever_the_chunks(prime):
    model, edge = net(0), net(1)
    frames = prelim_frames(95)
    count = len(frames)
    assert count == 9 > 2 * W
    alone = run(model, [frames], prime=prime)
    first = mixed(alone[:W], run(edge, [frames[: 2 * W]], prime=prime)[:W])
    last = mixed(alone[-W:], run(edge, [frames[-2 * W:]], prime=prime)[-W:])
    expected = first + [f.image for f in alone[W:count - W]] + last
    data = rmb_stream(95)
    for chunks in (split(data, 1), split(data, 7), [data]):  # encodings batched otherwise: float rounding apart
        made = run(model, chunks, prime=prime, edge_model=edge)
        assert [f.index for f in made] == [p.index for p in frames]
        assert [f.time_s for f in made] == [p.time_s for p in frames]
        for got, want in zip(made, expected):
            np.testing.assert_allclose(got.image, want, rtol=1e-5, atol=1e-7)
    made = run(model, [frames], prime=prime, edge_model=edge)
    for got, want in zip(made, expected):  # the frames pushed as the references were made: bit for bit
        np.testing.assert_array_equal(got.image, want)
    for k in (0, count - 1):  # the edge model's frames are not the model's
        assert not np.array_equal(made[k].image, alone[k].image)


@pytest.mark.parametrize("readouts", [10, 35, 40])
def test_every_frame_of_a_clip_of_2w_frames_or_fewer_mixes_in_the_edge_models_run(readouts):
    model, edge = net(0), net(1)
    frames = prelim_frames(readouts)
    assert len(frames) <= 2 * W
    made = run(model, [frames], edge_model=edge)
    alone, reference = run(model, [frames]), run(edge, [frames])
    assert [f.index for f in made] == [f.index for f in reference] == [f.index for f in alone]
    for got, want in zip(made, mixed(alone, reference)):
        np.testing.assert_array_equal(got.image, want)


def test_edge_model_must_share_the_models_window_and_readouts():
    with pytest.raises(ValueError, match="edge model's w = 1"):
        RmbNetReconstructor(net(0), device="cpu", edge_model=net(1, w=1))


def test_the_edge_model_beside_a_weight_file_is_used_unless_turned_off(tmp_path):
    main = save_model(tmp_path / "m", net(0), ModelCard(name="m"))
    assert edge_model_path(main) is None
    frames = prelim_frames(95)
    plain = run(net(0), [frames])
    edges = save_model(tmp_path / "m-edges", net(1), ModelCard(name="m-edges"))
    assert edge_model_path(main) == edges == edge_model_path(tmp_path / "m")

    def made(**kw) -> list:
        engine = RmbNetReconstructor.from_file(main, device="cpu", precision="fp32", **kw)
        return engine.push(frames) + engine.flush()

    with_edges, off = made(), made(edges="off")
    assert not np.array_equal(with_edges[0].image, plain[0].image)
    np.testing.assert_array_equal(with_edges[W].image, plain[W].image)
    for got, want in zip(off, plain):
        np.testing.assert_array_equal(got.image, want.image)
    save_model(tmp_path / "m-edges", net(1, w=1), ModelCard(name="m-edges"))
    with pytest.raises(ModelError, match="m-edges.safetensors: the edge model's w = 1"):
        made()


def test_reconstruct_uses_the_edge_model_beside_the_model_and_refuses_a_foreign_one(tmp_path):
    """As a user runs it: ``--edges`` auto (the default) against off on a 1-bit capture, and an edge model of another
    window refused in one line naming it."""
    from cli_helpers import GEOM, capture, cli, one_line_error

    from rmbvideo.io.exr import read_exr

    dat = capture(tmp_path / "c.dat", planes=200)
    model = save_model(tmp_path / "m", net(0), ModelCard(name="m"))
    save_model(tmp_path / "m-edges", net(1), ModelCard(name="m-edges"))
    frames = {}
    for edges in ("auto", "off"):
        out = tmp_path / edges
        proc = cli("reconstruct", dat, "-o", out, *GEOM, "--model", model, "--edges", edges, "--format", "exr",
                   "--resolution", "binned", "--raw-gate", "off", "--threads", "1", "--precision", "fp32", "--quiet")
        assert proc.returncode == 0, proc.stderr
        frames[edges] = [read_exr(p)[0] for p in sorted(out.glob("*.exr"))]
    assert len(frames["auto"]) == len(frames["off"]) == 10
    for k, (auto, off) in enumerate(zip(frames["auto"], frames["off"])):
        assert np.array_equal(auto, off) == (W <= k < 10 - W), k
    save_model(tmp_path / "m-edges", net(1, w=1), ModelCard(name="m-edges"))
    one_line_error(cli("reconstruct", dat, "-o", tmp_path / "bad", *GEOM, "--model", model, "--format", "exr",
                       "--convention", "physical"),
                   "m-edges.safetensors", "edge model's w = 1")

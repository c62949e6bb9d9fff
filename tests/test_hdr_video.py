"""HDR video (HDR10 PQ and HLG, HEVC Main10 BT.2020): the curves invert, and frames played back decode
to the light they were given (decoded with ffmpeg, the transfer inverted)."""

from __future__ import annotations

import subprocess

import imageio_ffmpeg
import numpy as np
import pytest

from rmbvideo.chunks import Frame
from rmbvideo.io.hdr_video import DECODE, ENCODE, auto_nits_per_unit, hlg_decode, pq_decode, pq_encode
from rmbvideo.errors import OutputError
from rmbvideo.io.sinks import PLAYBACK_FPS_RANGE, write_frames


def test_transfer_functions_invert_and_are_monotone():
    nits = np.logspace(-3, 4, 400)
    np.testing.assert_allclose(pq_decode(pq_encode(nits)), nits, rtol=1e-9)
    assert np.all(np.diff(pq_encode(nits)) > 0)
    assert pq_encode(np.array([100.0]))[0] == pytest.approx(0.5081, abs=1e-3)  # 100 nits: PQ code ~0.508
    hlg = np.logspace(-3, 3, 300)
    np.testing.assert_allclose(hlg_decode(ENCODE["hlg"](hlg)), hlg, rtol=1e-9)
    assert ENCODE["hlg"](np.array([1000.0 / 12]))[0] == pytest.approx(0.5)  # the curves meet at E = 1/12


def test_exposure_is_chosen_once_from_the_first_frames():
    assert auto_nits_per_unit([np.full((4, 4), 0.1)]) == pytest.approx(200.0)  # 0.1 -> 20 nits
    assert auto_nits_per_unit([np.full((4, 4), 1e-3)]) == pytest.approx(10000.0)  # capped: a dark capture stays dark
    assert auto_nits_per_unit([np.zeros((4, 4))]) == pytest.approx(200.0)


def _decode_signal(path, shape):
    """The transfer-function signal of every played-back frame: 10-bit luma as decoded, (Y - 64) / 876."""
    height, width = shape
    h2, w2 = height + height % 2, width + width % 2
    raw = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-i", str(path), "-f", "rawvideo",
                          "-pix_fmt", "yuv420p10le", "-"], capture_output=True, check=True).stdout
    frames = np.frombuffer(raw, "<u2").reshape(-1, h2 * w2 * 3 // 2)[:, : h2 * w2].reshape(-1, h2, w2)
    return (frames[:, :height, :width] - 64.0) / 876.0


@pytest.mark.parametrize("fmt, transfer", [("hdr10", "pq"), ("hlg", "hlg")])
def test_played_back_frames_decode_to_the_light_they_were_given(tmp_path, fmt, transfer):
    levels = np.logspace(-3, 0, 8)  # the capture's range, from near the dark floor to saturation
    image = np.repeat(levels, 16)[None, :] * np.ones((17, 1))  # flat patches; odd height is padded
    frames = [Frame(i, i / 1000, (image * (1 + 0.05 * i)).astype(np.float32)) for i in range(10)]
    nits_per_unit = 800.0
    assert write_frames(frames, tmp_path, fmt=fmt, nits_per_unit=nits_per_unit) == 10
    signal = _decode_signal(tmp_path / "frames.mp4", image.shape)
    assert len(signal) == 10
    for frame, decoded in zip(frames, signal):
        patches = decoded[4:13].reshape(9, 8, 16)[:, :, 4:12]  # patch interiors
        played = np.median(patches, axis=(0, 2))
        given = ENCODE[transfer](frame.image[0, ::16].astype(np.float64) * nits_per_unit)
        assert np.abs(played - given).max() <= 2.0 / 876  # within two 10-bit codes (lossy HEVC, CRF 18)
        light = DECODE[transfer](played) / nits_per_unit  # back to linear units: monotone, close
        assert np.all(np.diff(light) > 0)
        visible = frame.image[0, ::16] * nits_per_unit < (1000.0 if transfer == "hlg" else 10000.0)
        np.testing.assert_allclose(light[visible], frame.image[0, ::16][visible], rtol=0.1)  # 2 codes at ~1 nit
    probe = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(tmp_path / "frames.mp4"), "-vf",
                            "showinfo", "-frames:v", "1", "-f", "null", "-"], capture_output=True, text=True).stderr
    trc = "smpte2084" if transfer == "pq" else "arib-std-b67"
    assert f"color_primaries:bt2020 color_trc:{trc}" in probe and "Main 10" in probe
    if fmt == "hdr10":
        assert "Mastering display metadata" in probe and "MaxCLL=800" in probe


@pytest.mark.parametrize("fmt", ["hdr10", "hlg"])
def test_a_frame_too_small_for_hevc_fails_at_its_first_frame_with_the_size_named(tmp_path, fmt):
    frames = iter([Frame(i, i / 1000, np.full((250, 13), 0.1, np.float32)) for i in range(3)])
    with pytest.raises(OutputError, match=r"frames.mp4: HEVC \(%s\) needs frames at least 15x15 pixels; these "
                       r"are 13x250" % fmt):
        write_frames(frames, tmp_path / "out", fmt=fmt, nits_per_unit=100.0)
    assert next(frames).index == 1  # refused at the first frame, not after the whole capture
    assert not (tmp_path / "out").exists()  # the folder is made whole or not at all
    # 15 pixels is padded to 16, which x265 takes
    assert write_frames([Frame(0, 0.0, np.full((15, 15), 0.1, np.float32))], tmp_path / "ok", fmt=fmt) == 1


@pytest.mark.parametrize("fps", [0.0099, 10001.0])
def test_playback_rates_the_muxer_cannot_write_are_refused(tmp_path, fps):
    with pytest.raises(ValueError, match="fps must be between 0.01 and 10000"):
        write_frames([Frame(0, 0.0, np.ones((16, 16), np.float32))], tmp_path, fmt="hdr10", fps=fps)


@pytest.mark.parametrize("fmt", ["mp4", "hdr10"])
@pytest.mark.parametrize("fps", PLAYBACK_FPS_RANGE)
def test_the_extreme_playback_rates_give_videos_of_the_right_length(tmp_path, fmt, fps):
    frames = [Frame(i, i / 1000, np.full((16, 16), 0.1 * (1 + i), np.float32)) for i in range(50)]
    assert write_frames(frames, tmp_path, fmt=fmt, fps=fps) == 50
    count, seconds = imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "frames.mp4"))
    assert count == 50
    if fps < 1:
        assert seconds == pytest.approx(50 / fps, rel=1e-3)

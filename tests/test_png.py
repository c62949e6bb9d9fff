"""Figure PNGs: lossless at the highest compression, written atomically, faults as one-line errors."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from rmbvideo.errors import OutputError
from rmbvideo.io.png import encode_png, write_figure, write_png


def test_a_figure_reads_back_exactly_and_smaller_than_at_opencvs_default(tmp_path: Path) -> None:
    sheet = np.full((120, 400, 3), 255, np.uint8)  # a picture sheet: flat panels with some content
    sheet[20:100, 20:180] = np.random.default_rng(0).integers(0, 256, (80, 160, 3), dtype=np.uint8)
    sheet[20:100, 220:380] = np.linspace(0, 255, 160, dtype=np.uint8)[None, :, None]
    path = write_png(tmp_path / "sheet.png", sheet)
    assert np.array_equal(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), sheet)
    assert path.stat().st_size < len(cv2.imencode(".png", sheet)[1])
    assert [p.name for p in tmp_path.iterdir()] == ["sheet.png"]  # no temporary left behind
    deep = np.arange(64, dtype=np.uint16).reshape(8, 8) * 1000  # 16-bit images stay 16-bit
    assert np.array_equal(cv2.imdecode(np.frombuffer(encode_png(deep, "deep"), np.uint8), cv2.IMREAD_UNCHANGED), deep)


def test_a_figure_into_a_missing_folder_is_one_line_naming_it(tmp_path: Path) -> None:
    target = tmp_path / "missing" / "sheet.png"
    with pytest.raises(OutputError) as info:
        write_png(target, np.zeros((4, 4), np.uint8))
    assert str(target) in str(info.value) and "\n" not in str(info.value)


def test_a_figure_interrupted_while_it_renders_leaves_the_earlier_file_and_no_temporary(tmp_path: Path) -> None:
    """``write_figure`` renders into a temporary file: Ctrl-C mid-render keeps the earlier PNG, leaves nothing else."""
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.artist import Artist

    class Interrupting(Artist):
        def draw(self, renderer) -> None:
            raise KeyboardInterrupt

    path = tmp_path / "checks.png"
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    write_figure(fig, path)
    first = path.read_bytes()
    assert first[:8] == b"\x89PNG\r\n\x1a\n" and not plt.get_fignums()
    fig, ax = plt.subplots()
    ax.add_artist(Interrupting())
    with pytest.raises(KeyboardInterrupt):
        write_figure(fig, path)
    assert path.read_bytes() == first
    assert [p.name for p in tmp_path.iterdir()] == ["checks.png"]
    assert not plt.get_fignums()  # closed either way

"""Which convention a capture's spikes show (``sensor.conventions.convention_from_spikes``) and ``--convention auto``:
a pixel reset to zero fires every second plane over a range of light, so its 40-plane counts pile up at 20."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rmbvideo.io.dat import DatGeometry, write_dat
from rmbvideo.sensor.conventions import PILE_UP_WINDOW, convention_from_spikes
from rmbvideo.sensor.effects import REALISTIC_EFFECTS
from rmbvideo.sensor.emission import RateIntegrateFire, SpikeEmitter
from rmbvideo.sensor.params import SensorParams

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
RAMP = np.tile(np.linspace(0.0, 1.1, 100), (64, 1))  # light from dark to past one threshold a plane


def _reset_to_zero(planes: int = 200) -> np.ndarray:
    params = SensorParams()
    emitter = SpikeEmitter(*RAMP.shape, params, REALISTIC_EFFECTS, 1)
    emitter.settle(1)
    return np.stack([emitter.emit_one(RAMP * params.q_r, 1) for _ in range(planes)])


def _rate_convention(planes: int = 200) -> np.ndarray:
    pixels = RateIntegrateFire(RAMP.shape, 1)
    return np.stack([pixels.emit_one(np.minimum(RAMP, 0.999)) for _ in range(planes)])


def _windows(planes: np.ndarray) -> list[np.ndarray]:
    return [planes[a : a + PILE_UP_WINDOW] for a in range(0, len(planes) - PILE_UP_WINDOW + 1, PILE_UP_WINDOW)]


def test_the_pile_up_at_half_the_planes_tells_the_conventions_apart():
    assert convention_from_spikes(_windows(_reset_to_zero())) == "physical"
    assert convention_from_spikes(_windows(_rate_convention())) == "spikezoo"
    dark = (np.random.default_rng(0).random((200, 64, 100)) < 0.01).astype(np.uint8)
    assert convention_from_spikes(_windows(dark)) is None  # no pixel near half the planes: cannot tell
    with pytest.raises(ValueError, match="40 planes"):
        convention_from_spikes([dark[:39]])


def test_auto_reads_a_capture_in_the_convention_its_spikes_show(tmp_path: Path):
    from rmbvideo.recon.run import prepare_run

    def convention(path: Path, **options) -> float:
        recon = prepare_run(path, resolution="binned", extra_options={"threads": 1, **options},
                            capture={"width": 100, "height": 64}).method
        return getattr(recon, "binned", recon)._convention  # the code the network is given: 0 physical, 1 spikezoo

    reset, rate = tmp_path / "reset.dat", tmp_path / "rate.dat"
    write_dat(reset, _reset_to_zero(), DatGeometry(100, 64))
    write_dat(rate, _rate_convention(), DatGeometry(100, 64))
    assert convention(reset) == 0.0 and convention(rate) == 1.0 and convention(rate, convention="auto") == 1.0
    assert convention(rate, convention="physical") == 0.0  # an explicit choice wins
    (tmp_path / "rate.capture.json").write_text('{"effects": ["shot_noise"]}')  # rmbvideo simulated it: physical
    assert convention(rate) == 0.0


@pytest.mark.parametrize("method", ["gc20", "mg20"])
def test_the_likelihood_baselines_read_a_capture_in_the_convention_its_spikes_show(tmp_path: Path, method: str):
    """GC20's thresholded-Poisson jots read a rate-convention pixel far too bright (39 % at half a spike per plane):
    ``--convention auto`` gives GC20 and MG20 the firing rate itself there, the Poisson model on a reset-to-zero camera."""
    from rmbvideo.recon.pipeline import FrameCollector, reconstruct_stream
    from rmbvideo.recon.run import prepare_run

    rate = tmp_path / "rate.dat"
    write_dat(rate, _rate_convention(), DatGeometry(100, 64))
    write_dat(tmp_path / "reset.dat", _reset_to_zero(), DatGeometry(100, 64))

    def run(path: Path, **options) -> tuple[str, np.ndarray]:
        prepared = prepare_run(path, method=method, resolution="binned", extra_options=options,
                               capture={"width": 100, "height": 64})
        sink = FrameCollector()
        reconstruct_stream(prepared.reader, prepared.method, sink, readout=prepared.readout)
        return prepared.method.response, sink.frames[5].image.mean(axis=0)  # light along the ramp, binned

    assert run(tmp_path / "reset.dat")[0] == "poisson"
    response, read = run(rate)
    assert response == "rate"
    light = RAMP[0].reshape(-1, 2).mean(axis=1)
    mid = (light > 0.3) & (light < 0.7)
    np.testing.assert_allclose(read[mid], light[mid], rtol=0.08)
    poisson_response, poisson = run(rate, convention="physical")  # an explicit choice wins
    assert poisson_response == "poisson" and np.all(poisson[mid] > 1.12 * light[mid])


@pytest.mark.skipif(not (SHARED / "real" / "car.dat").is_file(), reason="../shared/data is not present (development data only)")
def test_the_real_camera_behind_car_dat_shows_the_rate_convention():
    from rmbvideo.io.capture import open_capture

    reader = open_capture(SHARED / "real" / "car.dat")
    assert convention_from_spikes(_windows(reader.read(0, 200))) == "spikezoo"
    from click.testing import CliRunner

    from rmbvideo.cli import main

    result = CliRunner().invoke(main, ["info", str(SHARED / "real" / "car.dat")])
    assert result.exit_code == 0 and "read in the rate convention" in result.output


@pytest.mark.parametrize("effects", [REALISTIC_EFFECTS, ("shot_noise", "threshold_mismatch")])
def test_a_pixel_reset_by_subtraction_fires_at_its_light_and_shows_no_pile_up(effects):
    """``SensorParams(reset="subtract")`` keeps the charge past the threshold (per readout, and by photon arrival for
    the effects arrivals reproduce): its rate is its light up to one spike a plane, where the paper's pixel reset to
    zero fires at about q / (1 + q/2) and every second plane from 0.6 to 0.8."""
    from rmbvideo.sensor.emission import ArrivalSpikeEmitter, arrivals_apply

    params = SensorParams(reset="subtract")
    kind = ArrivalSpikeEmitter if arrivals_apply(effects, 1) else SpikeEmitter
    emitter = kind(*RAMP.shape, params, effects, 2)
    emitter.settle(2)
    planes = np.stack([emitter.emit_one(RAMP * params.q_r, 1) for _ in range(200)])
    rate = planes.mean(axis=(0, 1))
    for q in (0.3, 0.7, 0.9):
        column = int(np.argmin(np.abs(RAMP[0] - q)))
        assert rate[column] == pytest.approx(RAMP[0, column], rel=0.06), q
    assert rate[RAMP[0] > 1.05].min() > 0.97  # past one threshold a plane: a spike every plane, no runaway
    assert convention_from_spikes(_windows(planes)) == "spikezoo"
    with pytest.raises(ValueError, match="reset"):
        SensorParams(reset="sideways")


def test_a_simulated_camera_that_resets_by_subtraction_is_read_in_the_rate_convention(tmp_path: Path):
    from click.testing import CliRunner

    from rmbvideo.cli import main
    from rmbvideo.io.sidecar import simulated_camera
    from rmbvideo.recon.run import prepare_run

    scene = tmp_path / "s.toml"
    scene.write_text('width = 64\nheight = 48\nduration_s = 0.004\neffects = ["shot_noise", "threshold_mismatch"]\n'
                     '[sensor]\nreset = "subtract"\n[background]\npanorama = "studio"\n')
    result = CliRunner().invoke(main, ["simulate", str(scene), "-o", str(tmp_path / "c.dat"), "-q"])
    assert result.exit_code == 0, result.output
    assert simulated_camera(tmp_path / "c.dat").reset == "subtract"
    recon = prepare_run(tmp_path / "c.dat", resolution="binned", raw_gate="off", extra_options={"threads": 1}).method
    assert recon._convention == 1.0  # spikezoo's code: the charge past the threshold kept
    info = CliRunner().invoke(main, ["info", str(tmp_path / "c.dat"), "--json"])
    assert info.exit_code == 0 and '"pixel": "spikezoo"' in info.output  # info says what auto reads it as
    scene.write_text(scene.read_text().replace('reset = "subtract"', 'reset = "sideways"'))
    result = CliRunner().invoke(main, ["simulate", str(scene), "-o", str(tmp_path / "d.dat"), "-q"])
    assert result.exit_code != 0 and "sensor.reset" in result.output


def test_the_held_out_set_can_be_simulated_with_pixels_reset_by_subtraction(tmp_path: Path):
    """``evaluate --reset subtract``: the held-out cameras keep the charge past the threshold, so their streams are in
    the rate convention (what RMB-Net is told and how the classical rates are scored), cached apart from the paper's."""
    from rmbvideo.evaluate.harness import sequence_convention
    from rmbvideo.evaluate.heldout import HeldoutConfig, load_heldout_config

    config = HeldoutConfig(count=1, width=24, height=16, readouts=40, edge_readouts=5)
    paper, subtract = (load_heldout_config(HeldoutConfig(**{**config.__dict__, "reset": r}), tmp_path)
                       for r in ("zero", "subtract"))
    assert sequence_convention(paper[0]) == "physical" and sequence_convention(subtract[0]) == "spikezoo"
    assert len(list(tmp_path.glob("*.npz"))) == 2 and len(list(tmp_path.glob("*reset-subtract*.npz"))) == 1
    np.testing.assert_array_equal(paper[0].gt, subtract[0].gt)  # the same scene, another pixel
    assert subtract[0].multi.mean() > paper[0].multi.mean()  # no charge lost at a spike: more spikes
    with pytest.raises(ValueError, match="reset"):
        HeldoutConfig(reset="sideways")

"""Emission simulator: quantisation rule, effect isolation, determinism, chunking, Monte-Carlo vs theory."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rmbvideo.sensor.emission import ReadoutSpec, SpikeEmitter
from rmbvideo.sensor.params import SensorParams

NOISE = ["shot_noise", "dark_current", "threshold_mismatch", "reset_noise", "thermal_noise", "readout_rounding"]


def test_deterministic_multibit_rule_and_reset() -> None:
    params = SensorParams(capacitance=1.0, voltage=10.0)  # Q_th = 10 electrons exactly
    emitter = SpikeEmitter(1, 3, params, effects=[], seed=0)
    photo = np.array([[[4.0, 10.0, 25.0]]] * 3)
    out = emitter.emit(photo, level=3)
    # pixel 0: 4 -> floor(4*3/10)=1 fires and resets: 1, 1, 1; pixel 1: saturates at L every readout;
    # pixel 2: 25 >= 10 -> L
    assert out[:, 0, 0].tolist() == [1, 1, 1]
    assert out[:, 0, 1].tolist() == [3, 3, 3]
    assert out[:, 0, 2].tolist() == [3, 3, 3]
    one_bit = SpikeEmitter(1, 1, params, effects=[], seed=0).emit(np.full((5, 1, 1), 4.0))
    assert one_bit[:, 0, 0].tolist() == [0, 0, 1, 0, 0]  # carried charge 4, 8, 12 -> fire, reset


def test_no_noise_is_deterministic_and_draws_no_random_numbers(monkeypatch) -> None:
    def forbidden(*args, **kwargs):
        raise AssertionError("a random generator was created")

    monkeypatch.setattr(np.random, "default_rng", forbidden)
    photo = np.random.RandomState(3).uniform(0, 40, size=(30, 6, 7))
    runs = []
    for _ in range(2):
        emitter = SpikeEmitter(6, 7, SensorParams(), effects=["readout_rounding"], seed=5)
        assert set(emitter.components) == {"readout_rounding"}
        runs.append(emitter.emit(photo, level=7))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert runs[0].max() > 0


def test_noise_effect_does_create_a_generator(monkeypatch) -> None:
    calls = []
    original = np.random.default_rng
    monkeypatch.setattr(np.random, "default_rng", lambda *a, **k: calls.append(a) or original(*a, **k))
    SpikeEmitter(2, 2, SensorParams(), effects=["shot_noise"], seed=0)
    assert len(calls) == 1


def test_disabled_effect_is_not_built_and_does_not_change_the_others() -> None:
    photo = np.random.RandomState(1).uniform(0, 60, size=(80, 8, 9))
    base = ["shot_noise", "dark_current", "threshold_mismatch", "readout_rounding"]
    without = SpikeEmitter(8, 9, SensorParams(), base, seed=11)
    assert "thermal_noise" not in without.components
    out_without = without.emit(photo)
    # thermal noise built but with zero spread: it draws from its own generator only
    silent = dataclasses.replace(SensorParams(), temp_v_std=0.0)
    out_silent = SpikeEmitter(8, 9, silent, base + ["thermal_noise"], seed=11).emit(photo)
    np.testing.assert_array_equal(out_without, out_silent)
    loud = dataclasses.replace(SensorParams(), temp_v_std=3.0)
    out_loud = SpikeEmitter(8, 9, loud, base + ["thermal_noise"], seed=11).emit(photo)
    assert not np.array_equal(out_without, out_loud)


def test_seed_changes_noisy_output() -> None:
    photo = np.full((50, 5, 5), 20.0)
    a = SpikeEmitter(5, 5, SensorParams(), NOISE, seed=1).emit(photo)
    b = SpikeEmitter(5, 5, SensorParams(), NOISE, seed=1).emit(photo)
    c = SpikeEmitter(5, 5, SensorParams(), NOISE, seed=2).emit(photo)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_dark_current_is_spatially_correlated() -> None:
    params = dataclasses.replace(SensorParams(), dark_mean=0.0, dark_std=5.0)
    dark = SpikeEmitter(64, 64, params, ["dark_current"], seed=0, dark_correlation_px=3.0).components["dark_current"]
    fields = np.stack([dark.dark_electrons() for _ in range(20)])
    neighbour = np.corrcoef(fields[:, :, :-1].ravel(), fields[:, :, 1:].ravel())[0, 1]
    assert neighbour > 0.8
    assert 3.5 < fields[:, 8:-8, 8:-8].std() < 6.5  # renormalised to sigma_d away from the border
    white = SpikeEmitter(64, 64, params, ["dark_current"], seed=0, dark_correlation_px=0.0).components["dark_current"]
    w = np.stack([white.dark_electrons() for _ in range(20)])
    assert abs(np.corrcoef(w[:, :, :-1].ravel(), w[:, :, 1:].ravel())[0, 1]) < 0.05


def test_rmb_rows_follow_the_readout_band() -> None:
    rows = ReadoutSpec("rmb", level=7, band=4, shift=2).multi_rows(3, 2, 10)
    assert np.flatnonzero(rows[0]).tolist() == [6, 7, 8, 9]
    assert np.flatnonzero(rows[1]).tolist() == [0, 1, 8, 9]  # wraps around the bottom
    assert ReadoutSpec("Lbit").multi_rows(0, 1, 5).all()
    assert not ReadoutSpec("binned").multi_rows(0, 1, 5).any()
    with pytest.raises(ValueError):
        ReadoutSpec("Lbit", level=6)


# ---- Monte-Carlo against the theory (paper Eqns. 4-8) -------------------------------------------

EXPOSURES = np.array([1.0, 8.0, 40.0, 104.0, 300.0, 3000.0])  # photo-electrons per interval, Q_r = 105
PIXELS = 400           # per exposure; pixels are independent, so per-pixel averages are i.i.d.
BURN_IN = 1200         # > 10 renewal cycles at the darkest exposure: stationary state
MEASURE = 1200
WINDOW = 10            # N of S_N^L


def _mc_params(level: int) -> SensorParams:
    # The theory fixes Q_th (and the dark count) per pixel; reset and thermal deviations are drawn
    # per reset/readout in the simulator, so they are switched off here to match its assumptions.
    return SensorParams(level=level, reset_v_std=0.0, temp_v_std=0.0)


def _estimate(per_pixel_1: np.ndarray, per_pixel_2: np.ndarray) -> tuple[float, float, float, float]:
    """Mean and variance with standard errors from per-pixel time averages of S and S^2."""
    n = len(per_pixel_1)
    mean = per_pixel_1.mean()
    var = per_pixel_2.mean() - mean ** 2
    se_mean = per_pixel_1.std(ddof=1) / np.sqrt(n)
    se_var = (per_pixel_2 - 2 * mean * per_pixel_1).std(ddof=1) / np.sqrt(n)
    return mean, var, se_mean, se_var


def _check(name: str, est: float, theory: float, se: float) -> None:
    assert abs(est - theory) <= 4 * se + 1e-9 * max(1.0, abs(theory)), (
        f"{name}: MC {est:.6g} vs theory {theory:.6g} (se {se:.3g}, z {(est - theory) / max(se, 1e-300):.2f})")


@pytest.mark.parametrize("level", [1, 3, 7])
def test_monte_carlo_matches_theory(level: int) -> None:
    from rmbvideo.sensor import theory
    params = _mc_params(level)
    effects = ["shot_noise", "dark_current", "threshold_mismatch", "readout_rounding"]
    emitter = SpikeEmitter(len(EXPOSURES), PIXELS, params, effects, seed=100 + level)
    photo = np.repeat(EXPOSURES[:, None], PIXELS, axis=1)
    for _ in range(BURN_IN):
        emitter.emit_one(photo, level)
    samples = np.stack([emitter.emit_one(photo, level) for _ in range(MEASURE)]).astype(np.float64)
    law = theory.spike_law(EXPOSURES, params)
    windows = samples.reshape(MEASURE // WINDOW, WINDOW, *samples.shape[1:]).sum(axis=1)
    sums = theory.sum_moments(EXPOSURES, WINDOW, params, exact=True)
    spread = theory.pixel_spread(EXPOSURES, params)
    for i, lam in enumerate(EXPOSURES):
        mean, var, se_mean, se_var = _estimate(samples[:, i].mean(0), (samples[:, i] ** 2).mean(0))
        _check(f"E(S^{level}) at {lam}", mean, law.mean[i], se_mean)
        _check(f"Var(S^{level}) at {lam}", var, law.var[i], se_var)
        w = windows[:, i]
        n_mean, n_var, n_se_mean, n_se_var = _estimate(w.mean(0), (w ** 2).mean(0))
        _check(f"E(S_N^{level}) at {lam}", n_mean, WINDOW * law.mean[i], n_se_mean)
        if sums is not None:
            # The MC pools windows over pixels whose thresholds differ: on top of the theory's exact
            # per-pixel variance (which counts the pixel spread once per interval, N * spread) it sees
            # the fixed pattern of the window sums, N^2 * spread in all.
            pooled = np.asarray(sums[1])[i] + WINDOW * (WINDOW - 1) * spread[i]
            _check(f"E(S_N^{level}) at {lam} (sum_moments)", n_mean, np.asarray(sums[0])[i], n_se_mean)
            _check(f"Var(S_N^{level}) at {lam}", n_var, pooled, n_se_var)


def test_a_new_effect_is_one_class_and_one_registry_line(monkeypatch) -> None:
    """Effects share one interface: a new one overrides only the steps it changes."""
    from rmbvideo.sensor import effects

    class DoubleThreshold(effects.Effect):
        name = "double_threshold"
        description = "a threshold twice as high (test only)"

        def threshold(self, threshold):
            return 2 * threshold

    monkeypatch.setitem(effects.EFFECT_TYPES, DoubleThreshold.name, DoubleThreshold)
    photo = np.full((40, 2, 2), 30.0)
    base = SpikeEmitter(2, 2, SensorParams(), [], seed=0).emit(photo).sum()
    doubled = SpikeEmitter(2, 2, SensorParams(), ["double_threshold"], seed=0).emit(photo).sum()
    assert base == 2 * doubled  # 30 e- per readout: fires every 7 readouts instead of every 4 (Q_r = 105)


@pytest.mark.parametrize("effects", [("shot_noise",),
                                     ("shot_noise", "threshold_mismatch", "readout_rounding", "reset_noise")])
@pytest.mark.parametrize("fraction", [0.02, 0.3, 0.9])
def test_photon_arrivals_have_the_statistics_of_per_readout_counts(effects, fraction: float) -> None:
    """The arrival emitter (one Gamma draw per spike) against the per-readout Poisson emitter: the same
    mean rate and the same spread of spike counts per pixel, from the dark end to a spike almost every
    readout; fixed-pattern thresholds come out the same pixel by pixel."""
    from rmbvideo.sensor.emission import ArrivalSpikeEmitter

    params = SensorParams()
    shape, readouts = (48, 48), 300
    photo = np.full(shape, fraction * params.q_r)
    counts = []
    for kind, seed in ((SpikeEmitter, 3), (ArrivalSpikeEmitter, 4)):
        emitter = kind(*shape, params, effects, seed)
        counts.append(sum(emitter.emit_one(photo, 1).astype(np.int64) for _ in range(readouts)))
    slow, fast = (c.astype(np.float64) for c in counts)
    standard_error = np.sqrt(slow.var() / slow.size + fast.var() / fast.size)
    assert abs(fast.mean() - slow.mean()) < 4 * standard_error + 1e-9, (slow.mean(), fast.mean())
    assert 0.8 < (fast.var() + 1e-9) / (slow.var() + 1e-9) < 1.25, (slow.var(), fast.var())


@pytest.mark.parametrize("reset", ["zero", "subtract"])
def test_photon_arrivals_by_flat_index_are_the_boolean_mask_form_bit_for_bit(reset: str) -> None:
    """The arrival emitter gathers and scatters its fired pixels by flat index; the same readouts written with
    boolean masks (its earlier form) give the same spikes from the same random stream, reset noise included."""
    from rmbvideo.sensor.emission import ArrivalSpikeEmitter

    class MaskForm(ArrivalSpikeEmitter):
        def emit_one(self, photo_expected, row_level=1):
            self._expected += photo_expected
            fired = self._expected >= self._target
            if fired.any():
                past = self._expected[fired] - self._target[fired]
                for effect in self._pixels._hooks["after_readout"]:
                    effect.after_readout(fired)
                electrons = self._electrons if self._electrons is not None else self._threshold_electrons()
                self._target[fired] = self._rng.gamma(electrons[fired])
                self._expected[fired] = np.minimum(past, self._target[fired]) if reset == "subtract" else 0.0
            return fired.astype(np.uint8)

    params = dataclasses.replace(SensorParams(), reset=reset)
    light = np.random.default_rng(1).random((24, 32)) * params.q_r  # from dark to a spike every readout
    effects = ["shot_noise", "threshold_mismatch", "reset_noise"]
    indexed, masked = ArrivalSpikeEmitter(24, 32, params, effects, seed=5), MaskForm(24, 32, params, effects, seed=5)
    for emitter in (indexed, masked):
        emitter.settle(5)
    for _ in range(200):
        assert np.array_equal(indexed.emit_one(light), masked.emit_one(light))
    assert np.array_equal(indexed._expected, masked._expected) and np.array_equal(indexed._target, masked._target)


def test_the_simulator_uses_photon_arrivals_only_where_they_are_exact() -> None:
    from rmbvideo.sensor.emission import ARRIVAL_EFFECTS, arrivals_apply
    from rmbvideo.sensor.effects import REALISTIC_EFFECTS

    assert arrivals_apply(("shot_noise", "threshold_mismatch", "readout_rounding"), 1)
    assert not arrivals_apply(("shot_noise",), 7)  # multi-bit values need the charge
    assert not arrivals_apply(("threshold_mismatch",), 1)  # no shot noise: deterministic, per readout
    assert not arrivals_apply(REALISTIC_EFFECTS, 1)  # dark current and thermal noise act every readout
    assert "dark_current" not in ARRIVAL_EFFECTS and "thermal_noise" not in ARRIVAL_EFFECTS


@pytest.mark.parametrize("arrivals", [False, True])
def test_a_settled_array_fires_at_its_steady_rate_from_the_first_plane(arrivals: bool) -> None:
    """A capture starts mid-stream: with ``settle`` a dark flat field fires at its long-run rate from the
    first planes, where a fresh (empty) array stays silent for ~1/level planes."""
    from rmbvideo.sensor.emission import ArrivalSpikeEmitter
    from rmbvideo.simulate.capture import REALISTIC_EFFECTS

    params, level, planes = SensorParams(), 0.01, 40
    photo = np.full((40, 40), level * params.q_r)
    kind, effects = (ArrivalSpikeEmitter, ["shot_noise", "threshold_mismatch"]) if arrivals else (SpikeEmitter, REALISTIC_EFFECTS)
    fresh = kind(40, 40, params, effects, seed=3)
    settled = kind(40, 40, params, effects, seed=3)
    settled.settle(3)
    if not arrivals:
        assert (settled.charge >= 0).all() and (settled.charge < settled.capacitance * params.voltage).all()
    early_fresh = np.mean([fresh.emit_one(photo, 1).mean() for _ in range(planes)])
    early_settled = np.mean([settled.emit_one(photo, 1).mean() for _ in range(planes)])
    assert early_fresh < 0.2 * level  # the start transient of an empty array
    assert abs(early_settled / level - 1) < 0.15  # 640 expected spikes: the steady rate within 4 sigma

"""Dynamic-range theory (paper Sec. 3, supplement Secs. 7-9): Table 1, stability, exactness."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from rmbvideo.cli import main
from rmbvideo.sensor.params import SensorParams
from rmbvideo.sensor.theory import (
    PAPER_TABLE1,
    PAPER_TABLE1_N,
    dynamic_range,
    level_thresholds,
    snr,
    spike_law,
    sum_moments,
    threshold_law,
)



@pytest.fixture
def single_blas_thread():
    """Run OpenBLAS on one thread for this test (the small batched matmuls thrash on a busy CPU)."""
    import ctypes
    import glob
    import os

    libs = glob.glob(os.path.join(os.path.dirname(np.__file__), os.pardir, "numpy.libs",
                                  "*openblas*"))
    lib = ctypes.CDLL(libs[0]) if libs else None
    setter = getattr(lib, "scipy_openblas_set_num_threads64_", None)
    getter = getattr(lib, "scipy_openblas_get_num_threads64_", None)
    if setter is None or getter is None:
        yield
        return
    before = getter()
    setter(1)
    try:
        yield
    finally:
        setter(before)


NOISE_FREE = SensorParams(capacitance=1.0, voltage=2.0, cap_std=0.0, reset_v_std=0.0,
                          temp_v_std=0.0, dark_mean=0.0, dark_std=0.0)


def test_table1_reproduced_within_0p6_db_in_20_of_21_cells():
    diffs = {}
    for level, row in PAPER_TABLE1.items():
        for res, ref in zip(dynamic_range(SensorParams(level=level), list(PAPER_TABLE1_N)), row):
            diffs[(level, res.n)] = res.dr_db - ref
    bad = {cell: d for cell, d in diffs.items() if abs(d) > 0.6}
    assert len(bad) <= 1, bad
    # the one cell off is the paper's L=7, N=70 (64.09 dB), inconsistent with its neighbours
    assert set(bad) <= {(7, 70)}


def test_extreme_exposures_are_finite_monotone_and_normalised():
    lam = np.logspace(-6, 6, 97)
    for level in (1, 3, 7, 255):
        law = spike_law(lam, SensorParams(level=level))
        for arr in (law.pmf, law.mean, law.var, law.dmean):
            assert np.all(np.isfinite(arr))
        assert np.all(law.pmf >= 0)
        assert np.allclose(law.pmf.sum(axis=1), 1.0, atol=1e-12)
        assert np.all(np.diff(law.mean) >= -1e-12 * level)
        assert law.mean[-1] == pytest.approx(level, abs=1e-12)     # saturation
        assert law.var[-1] < 1e-20
        assert law.mean[0] > 0 and law.var[0] > 0                 # no underflow at 1e-6
        assert np.all(np.isfinite(snr(lam, 20000, SensorParams(level=level))))


@pytest.mark.parametrize("level", [1, 3, 7, 255])
def test_exact_variance_never_exceeds_independent_at_n_20000(level, single_blas_thread):
    lam = np.array([1e-6, 1e-2, 40.0, 120.0, 1e6]) if level == 1 else np.logspace(-6, 6, 13)
    params = SensorParams(level=level)
    mean_e, var_e = sum_moments(lam, 20000, params, exact=True)
    mean_i, var_i = sum_moments(lam, 20000, params, exact=False)
    assert np.all(np.isfinite(var_e)) and np.all(var_e >= 0)
    assert np.array_equal(mean_e, mean_i)
    assert np.all(var_e <= var_i * (1 + 1e-9) + 1e-9)
    if level <= 7:   # information inheritance really reduces the variance at moderate exposure
        assert np.any(var_e < 0.5 * var_i)


def test_noise_free_threshold_two_matches_hand_closed_form():
    # Q_th = 2, no dark: E(n) = sum_m P(Pois(m lam) <= 1) = 1/(1-e) + lam e/(1-e)^2, e = exp(-lam)
    lam = np.array([1e-6, 1e-3, 0.3, 1.0, 4.0, 30.0])
    e = np.exp(-lam)
    cycle = 1.0 / (-np.expm1(-lam)) + lam * e / np.expm1(-lam) ** 2
    law = spike_law(lam, NOISE_FREE)
    assert np.allclose(law.mean, 1.0 / cycle, rtol=1e-10)
    assert np.allclose(law.var, law.mean * (1.0 - law.mean), rtol=1e-8)
    def closed_mean(x):
        return np.expm1(-x) ** 2 / (-np.expm1(-x) + x * np.exp(-x))

    h = 1e-6
    slope = (closed_mean(lam * (1 + h)) - closed_mean(lam * (1 - h))) / (2 * h * lam)
    assert np.allclose(law.dmean, slope, rtol=1e-5, atol=1e-10)


def test_derivative_matches_central_difference():
    lam = np.logspace(-3, 2.2, 15)
    for level in (1, 7):
        params = SensorParams(level=level)
        h = 1e-5
        fd = (spike_law(lam * (1 + h), params).mean - spike_law(lam * (1 - h), params).mean) / (2 * h * lam)
        assert np.allclose(spike_law(lam, params).dmean, fd, rtol=1e-5, atol=1e-12)


def _brute_force_sum_variance(lam: float, q: int, level: int, n: int) -> float:
    """Var(S_N) of the noise-free chain started from its stationary law, by dynamic programming."""
    from scipy.stats import poisson

    th = level_thresholds(q, level)
    t1 = int(th[0])
    jmax = 400
    px = poisson.pmf(np.arange(jmax), lam)

    def step(c):  # list of (prob, next charge, readout)
        out = {}
        for x in range(jmax):
            charge = c + x
            h = int(np.sum(charge >= th))
            key = (0 if h else charge, h)
            out[key] = out.get(key, 0.0) + px[x]
        return out

    trans = {c: step(c) for c in range(t1)}
    pi = np.zeros(t1)
    pi[0] = 1.0
    for _ in range(3000):
        new = np.zeros(t1)
        for c in range(t1):
            for (d, _h), p in trans[c].items():
                new[d] += pi[c] * p
        pi = new
    dist = {(c, 0): pi[c] for c in range(t1)}   # (charge, running sum) -> probability
    for _ in range(n):
        new: dict = {}
        for (c, s), p in dist.items():
            for (d, h), pt in trans[c].items():
                new[(d, s + h)] = new.get((d, s + h), 0.0) + p * pt
        dist = new
    m1 = sum(p * s for (_, s), p in dist.items())
    m2 = sum(p * s * s for (_, s), p in dist.items())
    return m2 - m1 * m1


@pytest.mark.parametrize("level,lam", [(1, 1.7), (3, 2.5)])
def test_exact_variance_matches_brute_force_markov_chain(level, lam):
    params = replace(NOISE_FREE, voltage=6.0, level=level)
    for n in (1, 2, 5, 9):
        _, var = sum_moments(np.array([lam]), n, params, exact=True)
        assert var[0] == pytest.approx(_brute_force_sum_variance(lam, 6, level, n), rel=1e-9)


@pytest.mark.parametrize("lam", [0.005, 0.05, 40.0])
def test_level_probabilities_match_the_chain_down_to_the_smallest(lam):
    """P(S = h) of a noise-free L = 3 pixel against its Markov chain's stationary law summed term by term: every level
    to 1e-9 relative, where they span 1e-10 to 1 (a level's probability is a difference of Poisson tails in the
    law, read from the nearer tail so that the small ones keep their digits)."""
    from scipy.stats import poisson

    q, level = 6, 3
    th = level_thresholds(q, level)
    px = poisson.pmf(np.arange(400), lam)
    charges = np.arange(int(th[0]))[:, None] + np.arange(400)[None, :]   # carried charge c plus arrivals x
    h_of = (charges[..., None] >= th).sum(axis=-1)
    nxt = np.where(h_of > 0, 0, charges)
    pi = np.zeros(int(th[0]))
    pi[0] = 1.0
    for _ in range(5000):
        new = np.zeros_like(pi)
        np.add.at(new, nxt[nxt < th[0]], (pi[:, None] * px[None, :])[nxt < th[0]])
        pi = new / new.sum()
    chain = np.array([(pi[:, None] * px[None, :] * (h_of == h)).sum() for h in range(level + 1)])
    law = spike_law(np.array([lam]), replace(NOISE_FREE, voltage=float(q), level=level))
    assert chain.min() < 1e-6  # the small probabilities are there to check
    np.testing.assert_allclose(law.pmf[0], chain, rtol=1e-9)


def test_threshold_law_matches_supplement_noise_scale():
    law = threshold_law(SensorParams())
    mean = float(law.values @ law.probs)
    std = math.sqrt(float((law.values - mean) ** 2 @ law.probs))
    assert law.probs.sum() == pytest.approx(1.0)
    assert mean == pytest.approx(105.0, abs=0.05)
    # sigma^2 ~ 0.005 * V^2 + C^2 * (0.005 + 0.005) + rounding 1/12, with C = 1.4, V = 75
    assert std == pytest.approx(math.sqrt(0.005 * 75**2 + 1.4**2 * 0.01 + 1 / 12), rel=0.02)


def test_cli_json_table_and_plots(tmp_path):
    result = CliRunner().invoke(main, ["dynamic-range", "--L", "1,7", "--N", "1,10", "--json",
                                       "--plots", str(tmp_path / "figs")])
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert [(r["L"], r["N"]) for r in data["table"]] == [(1, 1), (1, 10), (7, 1), (7, 10)]
    assert data["table"][1]["dr_db"] == pytest.approx(22.70, abs=0.6)
    for name in ("fig2_expectation_std.png", "fig3_snr.png"):
        assert (tmp_path / "figs" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_text_table_shows_paper_difference():
    result = CliRunner().invoke(main, ["dynamic-range", "--L", "3", "--N", "1,30"])
    assert result.exit_code == 0, result.output
    assert "paper (Table 1)" in result.output
    assert "13.91" in result.output and "42.35" in result.output


def test_cli_refuses_a_threshold_beyond_reach_at_once():
    """--q-r 1e9 grew the exact law's tables until the kernel killed the process (73 s, no message); above the bound
    it is a usage error naming the range, before any work."""
    result = CliRunner().invoke(main, ["dynamic-range", "--q-r", "1e9"])
    assert result.exit_code == 2 and "--q-r" in result.output and "10000" in result.output


def test_cli_refuses_an_exact_table_out_of_reach_before_any_work():
    """--variance exact at L = 1, Q_r = 400 and the paper's N ran 152 s and then ran out of memory (7.6 GB); its time
    is estimated first, and a table beyond the bound is refused in one line naming the estimate."""
    result = CliRunner().invoke(main, ["dynamic-range", "--variance", "exact", "--q-r", "400", "--levels", "1"])
    assert result.exit_code != 0 and "--variance exact" in result.output and "minutes" in result.output
    assert len(result.output.strip().splitlines()) == 1


@pytest.mark.parametrize("quiet", [False, True])
def test_cli_shows_a_progress_bar_on_a_terminal(quiet: bool):
    """Minutes of work at a large Q_r: a bar per level on a terminal (stderr a pty), none with --quiet."""
    import fcntl
    import os
    import pty
    import select
    import struct
    import subprocess
    import sys
    import termios

    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))
    proc = subprocess.Popen([sys.executable, "-m", "rmbvideo", "dynamic-range", "--L", "1,3", "--N", "10",
                             *(["--quiet"] if quiet else [])], stdout=subprocess.PIPE, stderr=slave)
    os.close(slave)
    terminal = b""
    while True:
        ready, _, _ = select.select([master], [], [], 1.0)
        if ready:
            try:
                data = os.read(master, 4096)
            except OSError:  # the command closed the terminal
                break
            if not data:
                break
            terminal += data
        elif proc.poll() is not None:
            break
    os.close(master)
    assert proc.wait() == 0 and b"22.98" in proc.stdout.read()
    assert (b"2/2" in terminal and b"level" in terminal) != quiet, terminal


def test_pixel_spread_vanishes_without_threshold_noise():
    from rmbvideo.sensor.theory import pixel_spread

    lam = np.array([1e-3, 1.0, 50.0, 1e5])
    assert np.allclose(pixel_spread(lam, replace(NOISE_FREE, voltage=20.0)), 0.0, atol=1e-20)
    spread = pixel_spread(lam, SensorParams())
    assert np.all(np.isfinite(spread)) and spread[2] > 1e-4   # thresholds differ by ~5 e- per pixel
    assert spread[2] <= spike_law(lam, SensorParams()).var[2]


def _iterated_sum_variance(lam: float, q: int, level: int, n: int) -> float:
    """Var(S_N) of the noise-free chain, its lag sum taken term by term (n - 1 products of the stationary chain), in
    extended precision: a long sum cancels to a few digits of its terms."""
    from scipy.stats import poisson

    th = level_thresholds(q, level)
    t1 = int(th[0])
    px = poisson.pmf(np.arange(q + 200), lam).astype(np.longdouble)
    chain, reward = np.zeros((t1, t1), np.longdouble), np.zeros(t1, np.longdouble)
    for c in range(t1):
        for x, p in enumerate(px):
            h = int(np.sum(c + x >= th))
            chain[c, 0 if h else c + x] += p
            reward[c] += h * p
    total = chain.sum(axis=1)
    chain, reward = chain / total[:, None], reward / total
    power = chain.copy()
    for _ in range(20):
        power = power @ power
    pi = power[0] / power[0].sum()
    mu = pi @ reward
    var1 = pi @ np.array([sum(p * (int(np.sum(c + x >= th)) - mu) ** 2 for x, p in enumerate(px)) for c in range(t1)])
    lagged, row = np.longdouble(0.0), np.eye(t1, dtype=np.longdouble)[0]
    for j in range(1, n):
        lagged += (n - j) * mu * (row @ reward - mu)
        row = row @ chain
    return float(n * var1 + 2.0 * lagged)


@pytest.mark.parametrize("level,lam", [(1, 0.4), (1, 9.0), (3, 2.5)])
def test_exact_variance_matches_the_lag_sum_term_by_term_at_long_sums(level, lam, single_blas_thread):
    """Long sums take the cheaper of two exact ways: a renewal equation over the charge's jumps (n = 2,000 here) or binary
    powers of the chain (n = 20,000). Both against the lag sum written out (at 1e-9 of N Var(S), which it saves a
    fraction of)."""
    params = replace(NOISE_FREE, voltage=30.0, level=level)
    for n in (2000, 20000):
        _, var = sum_moments(np.array([lam]), n, params, exact=True)
        assert var[0] == pytest.approx(_iterated_sum_variance(lam, 30, level, n),
                                       abs=1e-9 * n * spike_law(np.array([lam]), params).var[0])


def test_the_two_exact_ways_agree_on_a_noisy_sensor(single_blas_thread):
    """The renewal and the binary powers, on every threshold and dark value of a noisy L = 1 sensor, dark to
    saturated, at four sums at once: to 1e-9 of N Var(S), or to the rounding of a lag sum of n^2 / 2 terms of size up to
    1 (which both share, and which is all there is of Var(S_N) where the pixel fires in nearly every interval)."""
    from rmbvideo.sensor.lag_sums import _power_sums, _renewal_sums
    from rmbvideo.sensor.poisson_tables import PoissonTables
    from rmbvideo.sensor.theory import _conditional, dark_law

    params = replace(SensorParams(level=1), voltage=40.0 / SensorParams().capacitance)
    lam = np.logspace(-4, 3, 8)
    qlaw = threshold_law(params)
    t1s = np.array([int(level_thresholds(int(q), 1)[0]) for q in qlaw.values])
    law = spike_law(lam, params)
    horizons = (2, 10, 1000, 20000)
    for k in dark_law(params).values:
        tab = PoissonTables(lam, int(qlaw.values.max()) + 2, pad=int(k) + 2)
        means = _conditional(lam, qlaw.values, int(k), 1)[1]        # each threshold's own mean readout
        a = _renewal_sums(tab, slice(0, lam.size), int(k), qlaw.values, t1s, 1, horizons, means)
        b = _power_sums(tab, slice(0, lam.size), int(k), qlaw.values, t1s, 1, horizons, means)
        n = np.array(horizons, dtype=float)[:, None, None]
        assert np.all(np.abs(a - b) <= 1e-9 * n * law.var[None, None, :] + 1e-15 * n ** 2)

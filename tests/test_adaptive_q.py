"""Adaptive-Q EKF (issue 40 item 3): ``aq-ekf``, the accelerometer Q factor by maximum likelihood on the
innovations (Fisher scoring with the sensitivity ∂P/∂θ carried beside P), or covariance matching on the
state corrections (Mohamed & Schwarz 1999) with ``method=corrections`` (docs/filters.md "Adaptive process
noise by covariance matching").

The x4 accelerometer-noise step is made in the test: the dynamic IMU schedule (10 s segments) with
its drawn factors replaced by 1 before ``T_CHANGE`` and 4 after on the accelerometer, 1 on the gyro
(``dynamic_bias run``: the bias keeps the first segment's factor, 1). Embedded track 5 (400 s),
synthetic DVL. The filter's accelerometer bias random walk is set to 1e-5 m/s²/√s, near the truth's
constant bias (the default 1e-3 is absorbed by the factor: docs). Measured (500 runs, defaults
forgetting 0.98, prior_std 1): share of runs with φ_a within 1.5x of the truth 89 % just before the
step (median 1.00), 95 % at +100 s (median 3.75), 98 % at +150 s and +198 s; no run lost.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conftest import assert_one_error_line, nespm
from nespm_cli.data.corruption import CorruptionConfig
from nespm_cli.experiments import mc
from nespm_cli.experiments.spec import Spec, validate
from nespm_cli.filters.adaptive import REFERENCE_ACC
from nespm_cli.filters import FilterConfig
from nespm_cli.filters.adaptive_q import block_traces, factor, faded_ratio, matched_q, score_terms, shrunk_factor
from nespm_cli.filters.model import joseph_update
from nespm_cli.filters.registry import get_filter
from nespm_cli.nav.state import LAYOUT_12
from nespm_cli.tuning.space import default_space

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

T_CHANGE, GAIN, SEG = 200.0, 4.0, 10.0
BLOCKS = (slice(0, 3), slice(3, 6))


def stepped(monkeypatch, t_change=T_CHANGE):
    """``mc.draw`` with the accelerometer factor a x4 step at ``t_change`` [s], the gyro's 1."""
    draw = mc.draw

    def step(seed, track, runs, duration, config):
        real = draw(seed, track, runs, duration, config)
        S = real.acc_factors.shape[1]
        a = np.where(np.arange(S) * SEG >= t_change, GAIN, 1.0)
        return dataclasses.replace(real, acc_factors=np.tile(a, (len(runs), 1)), gyro_factors=np.ones((len(runs), S)))
    monkeypatch.setattr(mc, "draw", step)


def simulate(runs, filters, options=(), window=None, bias_rw=None):
    fc = FilterConfig() if bias_rw is None else FilterConfig(acc_bias_rw=bias_rw)
    spec = validate(Spec(tracks=(5,), runs=runs, filters=filters, dvl="synthetic", window=window, filter_config=fc,
                         corruption=CorruptionConfig(schedule="dynamic", segment_s=SEG), filter_options=options))
    res, truth, _ = mc.simulate(spec, 5, np.arange(runs))
    return res


def test_matched_q_is_mohamed_schwarz_with_phi():
    """``Q_used + Δx Δxᵀ − (P⁻ − P⁺)`` is the paper's ``Δx Δxᵀ + P⁺ − Φ P⁺_prev Φᵀ`` when ``P⁻ = Φ P⁺_prev Φᵀ + Q``."""
    rng = np.random.default_rng(3)
    B, n, m = 4, 12, 3
    A = rng.normal(size=(B, n, n))
    P_prev = A @ np.swapaxes(A, -1, -2) * 1e-3 + 1e-4 * np.eye(n)
    Phi = np.eye(n) + 0.05 * rng.normal(size=(B, n, n))
    Q = np.diag(rng.uniform(1e-6, 1e-5, n))
    P_prior = Phi @ P_prev @ np.swapaxes(Phi, -1, -2) + Q
    H = np.zeros((B, m, n))
    H[:, :, :3] = np.eye(m)
    x, P_post, _ = joseph_update(P_prior, H, rng.normal(size=(B, m)) * 0.01, 4e-4 * np.eye(m))
    paper = x[..., :, None] * x[..., None, :] + P_post - Phi @ P_prev @ np.swapaxes(Phi, -1, -2)
    got = matched_q(np.broadcast_to(block_traces(Q, BLOCKS), (B, 2)), x, P_prior, P_post, BLOCKS)
    np.testing.assert_allclose(got, block_traces(paper, BLOCKS), rtol=1e-9, atol=1e-15)


def test_factor_is_the_clipped_root_of_the_faded_ratio():
    num, den = faded_ratio(np.array([[2.0, 0.0]]), np.array([[1.0, 0.0]]), np.array([[14.0, -1.0]]),
                           np.array([[1.0, 0.0]]), 0.5)
    np.testing.assert_allclose(num, [[15.0, -1.0]])
    np.testing.assert_allclose(den, [[1.5, 0.0]])
    np.testing.assert_allclose(factor(num, den, 0.25, 3.0), [[3.0, 1.0]])  # √10 clipped to 3
    np.testing.assert_allclose(factor(np.array([[-1.0, 4.0]]), np.array([[1.0, 1.0]]), 0.25, 24.0), [[0.25, 2.0]])


def test_pinned_factor_is_the_ekf():
    """With ``q_floor = q_ceiling = 1`` the factor stays 1: the EKF's numbers to round-off."""
    res = simulate(3, ("ekf", "aq-ekf"), (("aq-ekf", "q_floor", "1"), ("aq-ekf", "q_ceiling", "1")), window="0:60")
    a, b = res["ekf"][0], res["aq-ekf"][0]
    np.testing.assert_allclose(b.v_n, a.v_n, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.P, a.P, rtol=1e-10, atol=1e-18)


def test_score_terms_recover_the_factor_of_a_linear_model():
    """Innovations ν ~ N(0, S0 + θ D) with the filter running at θ_j: the faded scoring sums
    ``Σ (g + a θ_j) / Σ a`` give θ within 4 standard errors (1/√Σa); ``shrunk_factor`` with an infinite
    prior std is the data's √θ, with a prior of std 1 on log θ it lies between 1 and √θ."""
    rng = np.random.default_rng(5)
    B, m, n, theta = 20_000, 3, 3, 6.0
    D = np.eye(m) * 2e-5
    S0 = np.eye(m) * 4e-4
    th_j = rng.uniform(1.0, 10.0, B)  # the factor each update ran with
    S = S0 + th_j[:, None, None] * D
    nu = rng.multivariate_normal(np.zeros(m), S0 + theta * D, size=B)
    M = np.broadcast_to(D, (B, 1, n, n))
    g, a = score_terms(M, np.broadcast_to(np.eye(m), (B, m, n)), S, nu)
    est, se = (g[:, 0] + a[:, 0] * th_j).sum() / a[:, 0].sum(), 1 / np.sqrt(a[:, 0].sum())
    assert abs(est - theta) < 4 * se and se < 0.5, (est, se)
    np.testing.assert_allclose(shrunk_factor(np.array([[9.0]]), np.array([[1.0]]), 1e6), [[3.0]])
    f = shrunk_factor(np.array([[9.0]]), np.array([[1 / 81]]), 1.0)[0, 0]
    assert np.isclose(f, 3.0 ** 0.5)  # I = 1 on log θ, prior 1: λ = ½


def test_x4_accelerometer_step_is_recovered(monkeypatch):
    """Must hold (issue 40): φ_a within 1.5x of the truth after the documented settling time, before and
    after the step. Measured (500 runs): within 1.5x 89 % at 199 s (truth 1; 150 s of data at the
    prior's weight), 95 % at +100 s after the step (truth 4), median 1.00 and 3.75. Asserted on 20
    runs with 4 binomial sigmas of 20 under those shares; gyro factor pinned by ``adapt = acc``."""
    stepped(monkeypatch)
    runs = 20
    res = simulate(runs, ("ekf", "aq-ekf"), bias_rw=1e-5)
    out = res["aq-ekf"][0]
    std_a, std_g = out.noise_std
    fa = std_a[..., 0] / REFERENCE_ACC  # (R, K) the factor per GT interval
    before, after = fa[:, int(T_CHANGE) - 1], fa[:, int(T_CHANGE) + 99]
    assert 0.9 < np.median(before) < 1.1 and 3.0 < np.median(after) < 4.6, (np.median(before), np.median(after))
    assert np.mean((before > 1 / 1.5) & (before < 1.5)) >= 0.89 - 4 * np.sqrt(0.89 * 0.11 / runs), before
    assert np.mean((after > GAIN / 1.5) & (after < GAIN * 1.5)) >= 0.95 - 4 * np.sqrt(0.95 * 0.05 / runs), after
    e_ekf, e_aq = res["ekf"][1].vel[:, int(T_CHANGE) + 1:], res["aq-ekf"][1].vel[:, int(T_CHANGE) + 1:]
    assert np.sqrt((e_aq ** 2).mean()) < 0.9 * np.sqrt((e_ekf ** 2).mean())  # measured -25 % (500 runs)
    assert not out.diverged.any() and not res["ekf"][0].diverged.any()
    np.testing.assert_allclose(std_g, np.broadcast_to(std_g[:, :1, :1], std_g.shape))  # gyro not adapted


def test_no_run_lost_in_500(monkeypatch):
    """Must hold: no run lost in 500 (a x4 step at 30 s, window 0-60 s, the default bias random walk)."""
    stepped(monkeypatch, 30.0)
    res = simulate(500, ("aq-ekf",), window="0:60")
    out = res["aq-ekf"][0]
    assert not out.diverged.any() and (out.lost_epoch < 0).all()
    assert np.isfinite(res["aq-ekf"][1].vel).all()


def test_corrections_method_is_kept(monkeypatch):
    """``method=corrections`` (Mohamed & Schwarz) still runs; it is the slow, low estimator (docs)."""
    stepped(monkeypatch)
    res = simulate(6, ("aq-ekf",), (("aq-ekf", "method", "corrections"),))
    fa = res["aq-ekf"][0].noise_std[0][..., 0] / REFERENCE_ACC
    assert np.median(fa[:, int(T_CHANGE) - 1]) < 0.67 and not res["aq-ekf"][0].diverged.any()


def test_forgetting_is_searched_by_tune():
    got = {p.key: p for p in default_space("aq-ekf", get_filter("aq-ekf"), LAYOUT_12, ("dvl",), 1e-3)}
    assert (got["forgetting"].low, got["forgetting"].high, got["forgetting"].log) == (0.9, 0.999, False)
    assert "acc_noise_scale" in got and "r_scale_dvl" in got


@pytest.mark.parametrize("option, words", [
    ("aq-ekf.forgetting=1", "aq-ekf.forgetting=1: a forgetting factor must lie in (0, 1)"),
    ("aq-ekf.q_floor=2", "aq-ekf.q_floor/q_ceiling: need 0 < q_floor <= 1 <= q_ceiling"),
    ("aq-ekf.warmup=100", "aq-ekf.warmup=100: not shorter than the track"),
    ("aq-ekf.adapt=gyro", "aq-ekf.adapt=gyro: choose acc or both"),
    ("aq-ekf.method=vb", "aq-ekf.method=vb: choose ml or corrections"),
    ("aq-ekf.prior_std=0", "aq-ekf.prior_std=0: must be > 0 and finite"),
])
def test_bad_options_are_one_line(tmp_path, option, words):
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "1", "--window", "0:40", "--filters", "aq-ekf",
                         "--filter-option", option, "--no-progress", "--jobs", "1", "--out", tmp_path / "o")
    assert_one_error_line(rc, out, err, words)
    assert not (tmp_path / "o").exists()

"""Adaptive-R EKFs (issue 32 item 1): ``iae-ekf``, ``sh-ekf``, ``vb-ekf`` (docs/filters.md, "Adaptive measurement noise").

Embedded track 5 (400 s, DVL at the 1 Hz GT epochs), synthetic DVL (std 0.02 m/s, told to the
filters). The injected change: the DVL noise x4 from t = 200 s, made in the test by scaling each
run's synthetic DVL error (the channel minus its clean twin) after 200 s. Measured (16 runs):
no change, RMSE ratio to the EKF +1.7 % (iae), +0.9 % (sh), +0.2 % (vb); after the change the
velocity RMSE 0.099 m/s (ekf) against 0.064/0.067/0.064, the R estimate (mean over runs, over
the 3 axes) 15.6 R0 at 30 s (iae window), 12.5 R0 (sh) and 12.8 R0 (vb) at the effective window
(1+b)/(1-b) = 66 epochs, of the true 16 R0.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conftest import assert_one_error_line, nespm
from nespm_cli.experiments import mc
from nespm_cli.experiments.spec import Spec, validate
from nespm_cli.filters import FilterConfig
from nespm_cli.filters.adaptive_ekfs import AdaptiveREKF
from nespm_cli.filters.adaptive_r import bounded, iae_r, sage_husa_r, valid_rows, vb_update
from nespm_cli.filters.model import joseph_update
from nespm_cli.filters.registry import get_filter
from nespm_cli.sensors.channels import build_channel

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

ADAPTIVE = ("iae-ekf", "sh-ekf", "vb-ekf")
T_CHANGE, GAIN, STD = 200.0, 4.0, 0.02
R0 = STD**2
Z99 = 2.576  # two-sided 99 % normal quantile: paired intervals of the run means


def stepped_channel(t_change: float, gain: float):
    """``build_channel`` with the DVL's synthetic error times ``gain`` from ``t_change`` [s]."""
    def build(sensor, track, truth, seed, number, runs, clean=False):
        ch = build_channel(sensor, track, truth, seed, number, runs, clean)
        if sensor.name != "dvl" or clean:
            return ch
        c0 = build_channel(sensor, track, truth, seed, number, runs, True)
        g = np.where(ch.t >= t_change, gain, 1.0)[None, :, None]
        return dataclasses.replace(ch, z=c0.z + g * (ch.z - c0.z))
    return build


def run(monkeypatch, runs: int, change: bool, filters=("ekf",) + ADAPTIVE, window=None, options=(),
        t_change=T_CHANGE):
    """``(results, epoch times [s], {filter: (K, R, m, m) the R estimates after each DVL update})``."""
    trace: dict = {}
    update = AdaptiveREKF.update

    def traced(self, measurement, j_last):
        res = update(self, measurement, j_last)
        trace.setdefault(self.name, []).append(next(iter(self.r_est.values())).copy())
        return res

    monkeypatch.setattr(AdaptiveREKF, "update", traced)
    if change:
        monkeypatch.setattr(mc, "build_channel", stepped_channel(t_change, GAIN))
    spec = validate(Spec(tracks=(5,), runs=runs, filters=filters, dvl="synthetic", window=window,
                         filter_options=options))
    res, truth, _ = mc.simulate(spec, 5, np.arange(runs))
    e = truth.epoch_index
    return res, truth.t[e] - truth.t[e[0]], {k: np.array(v) for k, v in trace.items()}


def vrmse(res, f, keep=slice(None)):
    """(R,) per-run velocity RMSE [m/s] over the epochs ``keep``."""
    v = res[f][1].vel[:, keep]
    return np.sqrt((v**2).mean(axis=1))


def test_estimators_are_the_papers_equations():
    rng = np.random.default_rng(1)
    B, m, n, N = 5, 3, 6, 7
    nu = rng.normal(size=(N, B, m))
    hph = 0.1 * np.eye(m) * rng.uniform(0.5, 1, size=(N, B, 1, 1))
    w = np.ones((N, B, m, m))
    w[2, 0] = 0.0  # one measurement missing in run 0
    R_hat, count = iae_r(nu[..., :, None] * nu[..., None, :], hph, w)
    keep = [i for i in range(N) if i != 2]
    ref0 = np.mean([np.outer(nu[i, 0], nu[i, 0]) - hph[i, 0] for i in keep], axis=0)
    assert np.allclose(R_hat[0], ref0) and count[0, 0, 0] == N - 1 and count[1, 0, 0] == N
    R_prev = np.eye(m) * 0.3
    assert np.allclose(sage_husa_r(R_prev, nu[0], hph[0], 0.1)[1],
                       0.9 * R_prev + 0.1 * (np.outer(nu[0, 1], nu[0, 1]) - hph[0, 1]))
    # VB: at the fixed point β = β⁻ + ½ ε² + ½ (H P⁺ Hᵀ)ᵢᵢ, R = β / α
    P = np.broadcast_to(np.eye(n) * 0.05, (B, n, n)).copy()
    H = rng.normal(size=(B, m, n))
    alpha, beta = np.full((B, m), 10.0), np.full((B, m), 10.0 * 0.2)
    valid = np.ones((B, m), dtype=bool)
    x, Pp, S, Rm, a, b = vb_update(P, H, nu[0], alpha, beta, 0.9, 50, valid, np.broadcast_to(np.eye(m) * .2, (B, m, m)))
    assert np.allclose(a, 0.9 * 10 + 0.5)
    x2, P2, _ = joseph_update(P, H, nu[0], (b / a)[..., :, None] * np.eye(m))
    eps = nu[0] - (H @ x2[..., None])[..., 0]
    assert np.allclose(b, 0.9 * beta + 0.5 * eps**2 + 0.5 * np.einsum("...ii->...i", H @ P2 @ np.swapaxes(H, -1, -2)),
                       rtol=1e-6)
    # a masked row (zero H row, zero innovation) is not a measurement
    H[0, 1] = 0.0
    z = nu[0].copy()
    z[0, 1] = 0.0
    assert valid_rows(H, z).sum() == B * m - 1 and not valid_rows(H, z)[0, 1]


def test_bounded_is_positive_definite_between_its_bounds():
    """Vectorised property check: 20 000 random symmetric (mostly indefinite) estimates against
    random nominal R: every projection is PD with floor R0 <= R <= ceiling R0."""
    rng = np.random.default_rng(2)
    B, m = 20_000, 4
    A = rng.normal(size=(B, m, m)) * rng.lognormal(0, 3, size=(B, 1, 1))
    L = rng.normal(size=(B, m, m)) + 3 * np.eye(m)
    R0 = L @ np.swapaxes(L, -1, -2)
    R = bounded(0.5 * (A + np.swapaxes(A, -1, -2)), R0, 0.01, 1e4)
    Li = np.linalg.inv(np.linalg.cholesky(R0))
    lam = np.linalg.eigvalsh(Li @ R @ np.swapaxes(Li, -1, -2))
    # the round-off of whitening by these random R0 (condition numbers up to ~1e3): measured 5e-7 relative
    assert lam.min() >= 0.01 * (1 - 1e-5) and lam.max() <= 1e4 * (1 + 1e-5)
    np.linalg.cholesky(R)  # raises if any is not PD
    # a diagonal R0 (every built-in sensor) takes the short path: the same projection
    d = np.einsum("...ii->...i", R0)[:100]
    Rd = bounded(R[:100] * 3 - R0[:100], d[..., :, None] * np.eye(m), 0.01, 1e4)
    s = np.sqrt(d)
    lam_d = np.linalg.eigvalsh((R[:100] * 3 - R0[:100]) / (s[:, :, None] * s[:, None, :]))
    lam_p = np.linalg.eigvalsh(Rd / (s[:, :, None] * s[:, None, :]))
    assert np.allclose(lam_p, np.clip(lam_d, 0.01, 1e4), rtol=1e-9, atol=1e-12)


@pytest.fixture(scope="module")
def nominal():
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("NESPM_DATA_DIR", raising=False)
        return run(mp, 16, change=False)


@pytest.fixture(scope="module")
def changed():
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("NESPM_DATA_DIR", raising=False)
        return run(mp, 16, change=True)


@pytest.mark.parametrize("f", ADAPTIVE)
def test_true_noise_stays_within_5_percent_of_the_ekf(nominal, f):
    res, _, trace = nominal
    ratio = vrmse(res, f) / vrmse(res, "ekf") - 1
    half = Z99 * ratio.std(ddof=1) / np.sqrt(len(ratio))
    assert -0.05 < ratio.mean() - half and ratio.mean() + half < 0.05, (ratio.mean(), half)
    assert not res[f][0].diverged.any()
    diag = np.einsum("...ii->...i", trace[f]) / R0  # the estimate stays near the truth (1)
    assert 0.7 < diag[100:].mean() < 1.3, diag[100:].mean()


@pytest.mark.parametrize("f", ADAPTIVE)
def test_dvl_noise_x4_is_followed_and_beats_the_fixed_r_ekf(changed, f):
    res, t, trace = changed
    opts = get_filter(f).option_defaults
    if f == "iae-ekf":
        window = opts["window"]  # [s] = DVL epochs at 1 Hz
    else:
        b = opts["forgetting" if f == "sh-ekf" else "rho"]
        window = (1 + b) / (1 - b)  # the equivalent window of the fading memory [epochs]
    k = int(np.searchsorted(t[1:], T_CHANGE + window))  # the DVL update at the window's end
    est = np.einsum("...ii->...i", trace[f][k]).mean(axis=-1) / (GAIN**2 * R0)  # (R,) over the 3 axes
    assert abs(est.mean() - 1) < 0.3, (f, est.mean(), est.min())
    after = t >= T_CHANGE
    d = vrmse(res, f, after) - vrmse(res, "ekf", after)
    half = Z99 * d.std(ddof=1) / np.sqrt(len(d))
    assert d.mean() + half < 0, (f, d.mean(), half)


def test_r_stays_positive_definite_in_500_runs(monkeypatch):
    """500 runs of a 30 s span, the DVL noise x4 from 15 s, short memories, and the Sage-Husa
    innovation form (the one that can lose definiteness unbounded): every R estimate of every
    run is PD (Q is the EKF's, fixed and PD)."""
    opts = (("iae-ekf", "window", "5"), ("sh-ekf", "forgetting", "0.8"), ("sh-ekf", "form", "innovation"),
            ("vb-ekf", "rho", "0.8"))
    res, _, trace = run(monkeypatch, 500, change=True, filters=ADAPTIVE, window="0:30", options=opts, t_change=15.0)
    for f in ADAPTIVE:
        R = trace[f]
        assert R.shape[:2] == (29, 500)  # a DVL update at every epoch but the first
        assert np.linalg.eigvalsh(R).min() > 0, f
        assert not res[f][0].diverged.any()


@pytest.mark.parametrize("state, sensors, opts", [
    ("15", ("dvl", "depth", "fix"), (("fix", "interval", "5"), ("fix", "dropout", "0.3"))),
    ("12", ("dvl-beams",), (("dvl-beams", "beam_outage", "2@5:15"),)),
], ids=["15-dvl-depth-fix-dropout", "12-beams-outage"])
def test_every_layout_and_sensor_suite(monkeypatch, state, sensors, opts):
    """Each sensor gets its own estimate; a lost beam's row keeps the nominal R, uncoupled; runs
    without a measurement (fix dropouts) keep theirs."""
    spec = validate(Spec(tracks=(5,), runs=4, filters=ADAPTIVE, dvl="synthetic", window="0:40", sensors=sensors,
                         sensor_options=opts, filter_config=FilterConfig(state=state),
                         filter_options=(("iae-ekf", "window", "10"),)))
    seen: dict = {}
    update = AdaptiveREKF.update

    def traced(self, measurement, j_last):
        res = update(self, measurement, j_last)
        key = type(measurement).__name__
        seen.setdefault(self.name, {}).setdefault(key, []).append(
            (float(self.t_end[j_last]), self.r_est[next(k for k in self.r_est if k[1] == key)].copy(),
             np.broadcast_to(measurement.R, self.r_est[next(k for k in self.r_est if k[1] == key)].shape).copy()))
        return res

    monkeypatch.setattr(AdaptiveREKF, "update", traced)
    res, _, _ = mc.simulate(spec, 5, np.arange(4))
    for f in ADAPTIVE:
        assert not res[f][0].diverged.any(), f
        assert len(seen[f]) == len(sensors), (f, list(seen[f]))
        for rows in seen[f].values():
            assert min(np.linalg.eigvalsh(R).min() for _, R, _ in rows) > 0
        if "dvl-beams" in sensors:  # beam 2 lost 5-15 s: its row keeps the nominal R, uncoupled; not after
            lost = [(R, R0) for t, R, R0 in seen[f]["BeamMeasurement"] if 6 <= t < 14]
            assert lost and all(np.array_equal(R[:, 1], R0[:, 1]) and np.array_equal(R[:, :, 1], R0[:, :, 1])
                                for R, R0 in lost), f
            t, R, R0 = seen[f]["BeamMeasurement"][-1]
            assert not np.array_equal(R[:, 1, 1], R0[:, 1, 1]), f


@pytest.mark.parametrize("option, words", [
    ("iae-ekf.window=60", "iae-ekf.window=60: longer than the track ("),
    ("sh-ekf.forgetting=1", "sh-ekf.forgetting=1: a forgetting factor must lie in (0, 1)"),
    ("sh-ekf.forgetting=0", "sh-ekf.forgetting=0: a forgetting factor must lie in (0, 1)"),
    ("vb-ekf.rho=1.5", "vb-ekf.rho=1.5: a forgetting factor must lie in (0, 1)"),
    ("sh-ekf.form=other", "choose residual or innovation"),
])
def test_bad_options_are_one_line(tmp_path, option, words):
    f = option.split(".")[0]
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "1", "--window", "0:40", "--filters", f,
                         "--filter-option", option, "--no-progress", "--jobs", "1", "--out", tmp_path / "o")
    assert_one_error_line(rc, out, err, words)
    assert not (tmp_path / "o").exists()  # refused before anything is written

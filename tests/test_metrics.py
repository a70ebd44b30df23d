"""Tests of nespm_cli.experiments.metrics: horizontal position error columns, distance travelled, and that
the existing per-run columns are unchanged by them."""
from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from nespm_cli.nav.earth import radii
from nespm_cli.experiments.metrics import EpochErrors, distance_travelled, epoch_errors, nees_band, run_metrics

# On the equator from longitude 0, so that metre offsets of 1e-7 rad are not lost to the rounding
# of a large latitude/longitude (at 32 deg, lat + 3 m / R_N is only good to ~1e-10 m).
LAT = 0.0
H = -20.0  # 20 m below the ellipsoid
R_N, R_E = radii(np.array(LAT))
R_N, R_E = float(R_N), float(R_E)


def east_line(n: int, step: float) -> np.ndarray:
    """(n, 3) truth along the parallel LAT at height H, ``step`` m east per epoch (ned_offset metric)."""
    dlon = step / ((R_E + H) * np.cos(LAT))
    pos = np.zeros((n, 3))
    pos[:, 0] = LAT
    pos[:, 1] = dlon * np.arange(n)
    pos[:, 2] = H
    return pos


def output_with_offset(pos_true: np.ndarray, runs: int, north: float, east: float) -> SimpleNamespace:
    """A FilterOutput stand-in: perfect velocity/attitude, position offset (north, east) m from the truth."""
    n = len(pos_true)
    pos = np.broadcast_to(pos_true, (runs, n, 3)).copy()
    pos[..., 0] += north / (R_N + H)
    pos[..., 1] += east / ((R_E + H) * np.cos(LAT))
    eye = np.broadcast_to(np.eye(3), (runs, n, 3, 3))
    return SimpleNamespace(pos=pos, v_n=np.zeros((runs, n, 3)), C_bn=eye.copy(),
                           P6=np.broadcast_to(np.eye(6), (runs, n, 6, 6)).copy(),
                           diverged=np.zeros(runs, bool))


def truth_for(n: int) -> tuple[np.ndarray, np.ndarray]:
    return np.zeros((n, 3)), np.broadcast_to(np.eye(3), (n, 3, 3)).copy()


def test_hpe_straight_line_constant_offset_known_answer() -> None:
    n, step = 401, 1.5
    pos_true = east_line(n, step)
    out = output_with_offset(pos_true, runs=3, north=3.0, east=4.0)
    err = epoch_errors(out, *truth_for(n), pos_true)
    np.testing.assert_allclose(err.hpe, 5.0, rtol=1e-12)
    np.testing.assert_allclose(err.hpe, np.hypot(err.ne[..., 0], err.ne[..., 1]), rtol=0, atol=0)
    np.testing.assert_allclose(err.dist, step * np.arange(n), rtol=1e-12, atol=1e-9)
    m = run_metrics(err, out.diverged)
    distance = step * (n - 1)  # 600 m
    assert m["hpe_final"] == pytest.approx(np.full(3, 5.0), rel=1e-12)
    assert m["hpe_rms"] == pytest.approx(np.full(3, 5.0), rel=1e-12)
    assert m["hpe_max"] == pytest.approx(np.full(3, 5.0), rel=1e-12)
    assert m["sse_hpe"] == pytest.approx(np.full(3, 25.0 * n), rel=1e-12)
    assert m["distance"] == pytest.approx(np.full(3, distance), rel=1e-12)
    assert m["hpe_final_pct"] == pytest.approx(np.full(3, 100 * 5.0 / distance), rel=1e-12, abs=1e-12)
    assert m["n_samples"].tolist() == [n] * 3


def test_distance_is_path_length_not_displacement() -> None:
    """East 10 steps of 2 m, then north 10 steps of 2 m: 40 m travelled, 28.3 m displaced."""
    pos = [east_line(11, 2.0)[i] for i in range(11)]
    for _ in range(10):  # north steps of exactly 2 m in the ned_offset metric at the previous point
        p = pos[-1].copy()
        rn, _ = radii(np.array(p[0]))
        p[0] += 2.0 / (float(rn) + p[2])
        pos.append(p)
    d = distance_travelled(np.array(pos))
    assert d[0] == 0.0 and len(d) == 21
    assert d[-1] == pytest.approx(40.0, rel=1e-12)
    assert d[10] == pytest.approx(20.0, rel=1e-12)
    assert np.all(np.diff(d) > 0)


def test_hpe_of_diverged_run_is_nan_distance_is_not() -> None:
    n = 50
    pos_true = east_line(n, 1.0)
    out = output_with_offset(pos_true, runs=2, north=1.0, east=0.0)
    out.pos[1, 30:] = np.nan  # the diverged run's state blew up
    out.diverged = np.array([False, True])
    m = run_metrics(epoch_errors(out, *truth_for(n), pos_true), out.diverged)
    for key in ("sse_hpe", "hpe_final", "hpe_rms", "hpe_max", "hpe_final_pct", "vrmse", "sse_vel"):
        assert np.isfinite(m[key][0]) and np.isnan(m[key][1]), key
    assert m["distance"] == pytest.approx([49.0, 49.0], rel=1e-12)
    assert m["hpe_final"][0] == pytest.approx(1.0, rel=1e-12)


def test_stationary_truth_gives_nan_percentage() -> None:
    n = 20
    pos_true = np.broadcast_to(east_line(1, 0.0), (n, 3)).copy()
    out = output_with_offset(pos_true, runs=1, north=2.0, east=0.0)
    m = run_metrics(epoch_errors(out, *truth_for(n), pos_true), out.diverged)
    assert m["distance"][0] == 0.0 and np.isnan(m["hpe_final_pct"][0])
    assert m["hpe_final"][0] == pytest.approx(2.0, rel=1e-12)


def test_existing_columns_unchanged_by_hpe() -> None:
    """The velocity/attitude/NEES columns are the same formulas as before the HPE columns, bit for bit."""
    rng = np.random.default_rng(5)
    R, N = 4, 30
    vel, att, nees = rng.random((R, N)), 0.01 * rng.random((R, N)), 6 * rng.random((R, N))
    ne = rng.standard_normal((R, N, 2))
    bad = np.array([False, True, False, False])
    m = run_metrics(EpochErrors(vel, att, nees, ne), bad)  # 4-argument construction still works
    sse_vel = np.where(bad, np.nan, (vel**2).sum(axis=1))
    sse_att = np.where(bad, np.nan, (att**2).sum(axis=1))
    expected = {
        "vrmse": np.sqrt(sse_vel / N), "mrmse": np.sqrt(sse_att / N), "sse_vel": sse_vel, "sse_att": sse_att,
        "max_vel_err": np.where(bad, np.nan, vel.max(axis=1)),
        "max_att_err": np.where(bad, np.nan, att.max(axis=1)),
        "nees": np.where(bad, np.nan, nees.mean(axis=1)),
    }
    for key, want in expected.items():
        np.testing.assert_array_equal(m[key], want, err_msg=key)
    assert m["diverged"].tolist() == bad.tolist()
    assert list(m)[:9] == ["vrmse", "mrmse", "sse_vel", "sse_att", "n_samples", "max_vel_err",
                           "max_att_err", "nees", "diverged"]
    # without a truth position the distance is unknown: NaN, and so the percentage
    assert np.isnan(m["distance"]).all() and np.isnan(m["hpe_final_pct"]).all()
    np.testing.assert_allclose(m["hpe_final"][~bad], np.hypot(ne[~bad, -1, 0], ne[~bad, -1, 1]), rtol=1e-15)


def test_nees_band_brackets_dof() -> None:
    lo, hi = nees_band(6, 40)
    assert lo < 6 < hi and hi - lo < nees_band(6, 10)[1] - nees_band(6, 10)[0]


def test_cep50_of_a_circular_gaussian():
    """CEP50 of a circular Gaussian (std sigma per axis) is sigma sqrt(2 ln 2) = 1.1774 sigma; from
    200,000 samples the sample median lies within 0.5 % of it (its relative std is about 0.2 %),
    inside the 2 % the issue asks for. R95 is sigma sqrt(-2 ln 0.05) = 2.4477 sigma."""
    from nespm_cli.experiments.metrics import cep

    rng = np.random.default_rng(5)
    sigma = 3.0
    xy = rng.normal(0.0, sigma, (200_000, 2))
    r = np.hypot(xy[:, 0], xy[:, 1])
    assert abs(cep(r) / (1.1774 * sigma) - 1) < 0.005, cep(r) / sigma
    assert abs(cep(r, 0.95) / (np.sqrt(-2 * np.log(0.05)) * sigma) - 1) < 0.01
    assert np.isnan(cep(np.array([np.nan])))


def test_anees_bounds_are_the_chi_square_quantiles():
    """nees_band(n, N) = chi2.ppf([a/2, 1 - a/2], N n) / N for N runs of n states."""
    from scipy.stats import chi2

    from nespm_cli.experiments.metrics import nees_band

    for n, N in ((3, 100), (6, 16), (15, 50)):
        lo, hi = nees_band(n, N)
        assert (lo, hi) == (chi2.ppf(0.025, N * n) / N, chi2.ppf(0.975, N * n) / N)
        assert lo < n < hi


def test_lost_epoch_and_the_errors_before_it():
    """A run lost by the engine at epoch 3, one beyond the attitude bound from epoch 6 (after 5 s),
    one not lost: each keeps its errors up to that point, with the time."""
    from nespm_cli.experiments.metrics import DivergenceRule, EpochErrors, alive_metrics, lost_epoch

    N = 10
    t = np.arange(N, dtype=float)
    vel = np.tile(np.arange(1.0, N + 1), (3, 1))
    att = np.full((3, N), 0.01)
    att[1, 6:] = np.radians(60.0)
    vel[0, 3:] = np.nan  # the engine lost run 0 at epoch 3
    err = EpochErrors(vel=vel, att=att, nees=np.ones((3, N)), ne=np.zeros((3, N, 2)))
    rule = DivergenceRule(att_deg=45.0, after_s=5.0)
    reason = np.array(["numeric", "attitude", ""], dtype=object)
    k = lost_epoch(err, reason, np.array([3, -1, -1]), t, rule)
    assert k.tolist() == [3, 6, -1]
    m = alive_metrics(err, k, t)
    np.testing.assert_array_equal(m["lost_at"][:2], [3.0, 6.0])
    assert np.isnan(m["lost_at"][2])
    np.testing.assert_allclose(m["vrmse_alive"], [np.sqrt(np.mean(np.arange(1.0, 4) ** 2)),
                                                  np.sqrt(np.mean(np.arange(1.0, 7) ** 2)),
                                                  np.sqrt(np.mean(np.arange(1.0, N + 1) ** 2))], rtol=1e-14)
    # where the engine's epoch is unknown, the first non-finite error marks it
    assert lost_epoch(err, reason, None, t, rule).tolist() == [3, 6, -1]


def test_cep_over_time_is_the_quantile_of_the_runs_at_each_epoch():
    """epochs.parquet's hpe_cep50 / hpe_r95: per epoch, the quantiles over the runs not lost; the last
    epoch's equals the report's final CEP (metrics.cep) of the same runs. A circular Gaussian of std s per
    axis has CEP50 = 1.1774 s (within 2 % over 20000 runs)."""
    from nespm_cli.experiments.assembly import epoch_cep
    from nespm_cli.experiments.metrics import cep

    rng = np.random.default_rng(8)
    sigma = np.array([1.0, 2.0, 5.0])
    ne = rng.standard_normal((20000, 3, 2)) * sigma[None, :, None]
    hpe = np.hypot(ne[..., 0], ne[..., 1])
    hpe[3, :] = np.nan  # a lost run
    c50, r95 = epoch_cep(hpe)
    np.testing.assert_allclose(c50 / sigma, 1.1774, rtol=0.02)
    np.testing.assert_allclose(r95 / sigma, np.sqrt(-2 * np.log(0.05)), rtol=0.02)
    assert c50[-1] == pytest.approx(cep(hpe[:, -1], 0.5), rel=1e-6)


def test_cep_over_time_takes_numpys_quantiles_epoch_by_epoch_where_runs_were_lost():
    """epoch_cep takes the epochs without a lost run together (np.quantile) and only the others through
    np.nanquantile: the same bits as np.nanquantile over every epoch, whatever was lost (one run at some
    epochs, every run at one, none at all, no run)."""
    from nespm_cli.experiments.assembly import epoch_cep

    rng = np.random.default_rng(3)
    for R, N in [(100, 60), (7, 20), (1, 5), (0, 4)]:
        hpe = 3.0 * np.abs(rng.standard_normal((R, N))).astype(np.float32).astype(float)
        if R > 3:
            hpe[2, 5:12] = np.nan
            hpe[:, 15] = np.nan
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            ref = np.nanquantile(hpe, [0.5, 0.95], axis=0) if R else np.full((2, N), np.nan)
        c50, r95 = epoch_cep(hpe)
        assert np.array_equal(c50, ref[0], equal_nan=True) and np.array_equal(r95, ref[1], equal_nan=True)
        assert np.isnan(c50).sum() == (N if R == 0 else 1 if R > 3 else 0)

"""Robust updates (issue 40 item 4; nespm_cli/filters/robust.py): χ² gating with a lock-out guard and a
Huber reweighting of R, screened by the engine for every filter with a covariance.

Scenario: track 5, 0-120 s, 8 runs, synthetic DVL with ``outliers=0.05:10`` (5 % of samples with an
extra N(0, (10 x 0.02 m/s)²) error per component); the EKF plain, gated (``robust=gate``) and Huber
(``robust=huber``), and the outlier-free EKF on the same realizations.
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import assert_one_error_line, nespm
from nespm_cli.errors import NespmError
from nespm_cli.experiments.mc import simulate
from nespm_cli.experiments.spec import Spec, validate
from nespm_cli.experiments.suite import sensor_suite
from nespm_cli.filters import FilterConfig
from nespm_cli.filters.options import check_filter_options
from nespm_cli.filters.registry import get_filter
from nespm_cli.filters.robust import chi2_quantile, gate, huber_weight, innovation_test, lockout_guard

RUNS = np.arange(8)
OUTLIERS = ("dvl", "outliers", "0.05:10")


@pytest.fixture(autouse=True)
def embedded(monkeypatch):
    """The embedded tracks, whatever the shell's $NESPM_DATA_DIR."""
    monkeypatch.delenv("NESPM_DATA_DIR", raising=False)


def spec_with(outliers: bool, options=(), filters=("ekf",)) -> Spec:
    return validate(Spec(tracks=(5,), runs=len(RUNS), filters=filters, window="0:120", dvl="synthetic",
                         sensor_options=(OUTLIERS,) if outliers else (), filter_options=options))


def pooled_vrmse(err) -> float:
    """The bench's VRMSE (metrics: pooled over runs and epochs) [m/s]."""
    return float(np.sqrt((err.vel ** 2).mean()))


@pytest.fixture(scope="module")
def scenario():
    import os

    os.environ.pop("NESPM_DATA_DIR", None)
    out = {"clean": simulate(spec_with(False), 5, RUNS)[0]["ekf"], "plain": simulate(spec_with(True), 5, RUNS)[0]["ekf"]}
    for mode in ("gate", "huber"):
        out[mode] = simulate(spec_with(True, (("ekf", "robust", mode),)), 5, RUNS)[0]["ekf"]
    s = spec_with(True)
    dvl = next(x for x in sensor_suite(s) if x.name == "dvl")
    out["mask"] = dvl.outlier_draws(out["gate"][0].sensors["dvl"].t, s.seed, 5, RUNS)[1]
    return out


def test_gate_false_alarm_rate_and_huber_weight_on_gaussian_innovations():
    """Consistent innovations (ν ~ N(0, S)): the gate rejects 1 − p of them within 4 binomial sigmas;
    Huber reweights 5 % of them; a masked row (zero H row, zero ν) is not counted in the dof."""
    rng = np.random.default_rng(3)
    B, m, n = 200_000, 3, 6
    P = np.broadcast_to(np.eye(n) * 0.01, (B, n, n))
    H = np.zeros((B, m, n))
    H[:, :, :m] = np.eye(m)
    Rm = np.eye(m) * 0.03
    nu = rng.normal(size=(B, m)) * np.sqrt(0.04)
    nis, dof = innovation_test(P, H, nu, Rm)
    assert np.allclose(nis, (nu ** 2).sum(-1) / 0.04) and (dof == 3).all()
    for p in (0.99, 0.999):
        rate = gate(nis, dof, p).mean()
        assert abs(rate - (1 - p)) < 4 * np.sqrt(p * (1 - p) / B), (p, rate)
    w = huber_weight(nis, dof)
    assert abs((w > 1).mean() - 0.05) < 4 * np.sqrt(0.05 * 0.95 / B)
    assert np.allclose(w[w > 1], np.sqrt(nis[w > 1] / chi2_quantile(0.95, 3)))
    H[0, 1], nu[0, 1] = 0.0, 0.0
    nis0, dof0 = innovation_test(P[:1], H[:1], nu[:1], np.eye(m) * 0.03)
    assert dof0[0] == 2
    assert not gate(np.array([np.nan, 1e9]), np.array([3, 0]), 0.999).any()  # no NIS or no dof: never rejected


def test_lockout_guard_opens_after_the_streak():
    """Limit 2: failures 1, 2 rejected, the 3rd applied and the gate open for 2 samples, then closed."""
    state, ok, seen = np.zeros(1, dtype=np.int64), np.ones(1, dtype=bool), []
    for failed in [1, 1, 1, 1, 1, 1, 0, 1]:
        rej, state = lockout_guard(np.array([bool(failed)]), ok, state, 2)
        seen.append(bool(rej[0]))
    assert seen == [True, True, False, False, False, True, False, True]
    rej, kept = lockout_guard(np.array([True]), np.array([False]), np.array([1]), 2)
    assert not rej[0] and kept[0] == 1  # a run without the sample keeps its state


def test_gate_counts_the_injected_outliers(scenario):
    """Rejected samples are the injected outliers: 46 of 50 caught (the missed ones are small draws or
    come while P0 is large), 5 good samples rejected of 902 (3 in the run whose first DVL sample is
    an outlier, while its state recovers). Measured: injected 50, rejected 51."""
    rec, mask = scenario["gate"][0].sensors["dvl"], scenario["mask"]
    present = rec.used | rec.rejected
    assert not (rec.used & rec.rejected).any()
    injected, rejected = int((mask & present).sum()), int(rec.rejected.sum())
    hits, false = int((rec.rejected & mask).sum()), int((rec.rejected & ~mask).sum())
    assert injected >= 40 and hits >= 0.85 * injected, (injected, hits)
    assert abs(rejected - injected) <= 0.1 * injected, (rejected, injected)
    good = int((present & ~mask).sum())
    # runs whose first outlier comes after the P0 transient (10 samples): the gate's false-alarm rate
    late = np.array([np.flatnonzero(m)[0] >= 10 for m in mask])
    fa = int((rec.rejected & ~mask)[late].sum())
    n_late = int((present & ~mask)[late].sum())
    assert fa <= 0.001 * n_late + 4 * np.sqrt(0.001 * n_late), (fa, n_late)
    assert false <= 0.01 * good
    assert (scenario["huber"][0].sensors["dvl"].rejected.sum() == 0
            and (scenario["huber"][0].sensors["dvl"].weight[mask & present] > 1).mean() > 0.9)


def test_vrmse_with_outliers(scenario):
    """Pooled VRMSE (measured): clean 0.0373, plain 0.0546 (+46 %), Huber 0.0403 (+8 %), gated 0.0602
    (+61 %, worse than plain). The gate's whole loss is one run, whose first DVL sample is an outlier
    (undetectable under P0: NIS 7.9 < 16.3): it corrupts the bias estimate, the next samples are
    rejected until the lock-out guard opens (run VRMSE 0.143 against plain 0.082 m/s). Every run whose
    first outlier comes after the P0 transient (10 samples; 7 of 8) is within 10 % of the clean EKF
    and better than plain. The issue's must-hold (gated within 10 % pooled) is NOT met here."""
    v = {k: pooled_vrmse(scenario[k][1]) for k in ("clean", "plain", "gate", "huber")}
    assert v["plain"] > 1.2 * v["clean"], v
    assert v["huber"] < 1.10 * v["clean"], v
    per = {k: np.sqrt((scenario[k][1].vel ** 2).mean(axis=1)) for k in ("clean", "plain", "gate")}
    late = np.array([np.flatnonzero(m)[0] >= 10 for m in scenario["mask"]])
    assert late.sum() >= 6
    assert (per["gate"][late] < 1.10 * per["clean"][late]).all(), (per["gate"], per["clean"])
    assert (per["gate"][late] < per["plain"][late]).all() and per["gate"][~late].max() > per["plain"][~late].max()


def test_no_robust_option_is_todays_numbers(scenario):
    """``robust=none`` given explicitly is the plain filter bit for bit (the default path)."""
    none = simulate(spec_with(True, (("ekf", "robust", "none"),)), 5, RUNS)[0]["ekf"]
    assert np.array_equal(none[1].vel, scenario["plain"][1].vel) and np.array_equal(none[0].P, scenario["plain"][0].P)


def test_robust_for_a_sigma_point_filter():
    """The UKF takes the same option (first-order S): it rejects about the injected count."""
    s = spec_with(True, (("ukf", "robust", "gate"),), filters=("ukf",))
    rec = simulate(s, 5, RUNS[:4])[0]["ukf"][0].sensors["dvl"]
    dvl = next(x for x in sensor_suite(s) if x.name == "dvl")
    mask = dvl.outlier_draws(rec.t, s.seed, 5, RUNS[:4])[1] & (rec.used | rec.rejected)
    assert (rec.rejected & mask).sum() >= 0.8 * mask.sum() and (rec.rejected & ~mask).sum() <= 6


@pytest.mark.parametrize("key,value", [("robust", "median"), ("gate_prob", "1.5"), ("gate_prob", "x"),
                                       ("gate_streak", "0")])
def test_bad_values_are_one_line(key, value):
    with pytest.raises(NespmError, match=f"ekf.{key}"):
        check_filter_options([("ekf", key, value)], ("ekf",), get_filter)
    with pytest.raises(NespmError, match="ins.robust"):
        check_filter_options([("ins", "robust", "gate")], ("ins",), get_filter)
    assert FilterConfig(options=(("robust", "gate"),)).robust_update() == ("gate", 0.999, 3)


def test_cli_bad_value_exit_2(tmp_path):
    res = nespm("mc", "--tracks", "5", "--runs", "2", "--window", "0:10", "--filters", "ekf", "--filter-option",
                "ekf.robust=median", "--out", str(tmp_path / "o"))
    assert_one_error_line(*res, "ekf.robust")
    assert not (tmp_path / "o").exists()

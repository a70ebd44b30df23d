"""Robust updates (issue 40 item 4; nespm_cli/filters/robust.py): χ² gating with a lock-out guard and a
Huber reweighting of R, screened by the engine for every filter with a covariance (the gate tests only an
informative prior, ``tr(H P Hᵀ) <= GATE_RATIO tr(R)``).

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
from nespm_cli.filters.robust import GATE_RATIO, chi2_quantile, gate, huber_weight, informative, innovation_test, \
    lockout_guard

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
    """Limit 2: failures 1, 2 rejected, the 3rd applied and the gate open (failures applied) until a sample
    passes, then closed: the next failure is rejected again."""
    state, ok, seen = np.zeros(1, dtype=np.int64), np.ones(1, dtype=bool), []
    for failed in [1, 1, 1, 1, 1, 0, 1, 1]:
        rej, state = lockout_guard(np.array([bool(failed)]), ok, state, 2)
        seen.append(bool(rej[0]))
    assert seen == [True, True, False, False, False, False, True, True]
    rej, kept = lockout_guard(np.array([True]), np.array([False]), np.array([1]), 2)
    assert not rej[0] and kept[0] == 1  # a run without the sample keeps its state


def test_gate_counts_the_injected_outliers(scenario):
    """Rejected samples are the injected outliers within the gate's false-alarm rate. Measured (8 runs):
    injected 50, rejected 49, caught 46 (the missed ones are small draws or come in the P0 transient,
    where the gate does not test), 3 good samples rejected of 902; 48 runs: injected 276, rejected
    280, caught 260, 20 good rejected of 5436 (0.37 %: the false alarms come after a missed early
    outlier, while the state recovers)."""
    rec, mask = scenario["gate"][0].sensors["dvl"], scenario["mask"]
    present = rec.used | rec.rejected
    assert not (rec.used & rec.rejected).any()
    injected, rejected = int((mask & present).sum()), int(rec.rejected.sum())
    hits, false = int((rec.rejected & mask).sum()), int((rec.rejected & ~mask).sum())
    good = int((present & ~mask).sum())
    assert injected >= 40 and hits >= 0.85 * injected, (injected, hits)
    # |rejected - injected| = |false alarms - misses|: each within the 0.1 % rate plus 4 binomial sigmas
    # of the good samples, or the measured 0.5 % after an early miss, whichever is larger
    allowance = max(0.005 * good, 0.001 * good + 4 * np.sqrt(0.001 * good))
    assert false <= allowance, (false, good)
    assert abs(rejected - injected) <= allowance + (injected - hits), (rejected, injected)
    assert injected - hits <= 0.15 * injected
    assert (scenario["huber"][0].sensors["dvl"].rejected.sum() == 0
            and (scenario["huber"][0].sensors["dvl"].weight[mask & present] > 1).mean() > 0.9)


def test_gate_tests_only_an_informative_prior():
    """A prior with ``tr(H P Hᵀ) > GATE_RATIO tr(R)`` (the P0 transient) is not tested: its sample is applied."""
    H = np.zeros((2, 3, 6))
    H[:, :, :3] = np.eye(3)
    P = np.stack([np.eye(6) * 0.0004 * GATE_RATIO * 0.99, np.eye(6) * 0.0004 * GATE_RATIO * 1.01])
    assert informative(P, H, np.eye(3) * 0.0004).tolist() == [True, False]


def test_vrmse_with_outliers(scenario):
    """Must hold (issue 40): with 5 % outliers of 10x the DVL std the gated EKF's VRMSE is within 10 % of the
    outlier-free EKF's; the plain EKF's is reported. Pooled VRMSE measured (8 runs): clean 0.0373, plain
    0.0546 (+46 %), gated 0.0401 (+7.3 %), Huber 0.0403 (+8.0 %); 48 runs: clean 0.0415, plain +38 %,
    gated +8.2 %, Huber +9.1 %. The worst gated run (first outlier on the first DVL sample) is 1.24x
    its clean VRMSE (plain 1.53x)."""
    v = {k: pooled_vrmse(scenario[k][1]) for k in ("clean", "plain", "gate", "huber")}
    assert v["plain"] > 1.2 * v["clean"], v
    assert v["gate"] < 1.10 * v["clean"], v
    assert v["huber"] < 1.10 * v["clean"], v
    per = {k: np.sqrt((scenario[k][1].vel ** 2).mean(axis=1)) for k in ("clean", "plain", "gate")}
    assert (per["gate"] < 1.4 * per["clean"]).all(), (per["gate"], per["clean"])
    assert (per["gate"] <= per["plain"] * 1.02).all(), (per["gate"], per["plain"])


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

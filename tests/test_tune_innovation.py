"""Tuning without ground truth: ``nespm tune --objective innovation`` scores a trial by the filter's own
innovations (their likelihood; docs/tuning.md, "Tuning without ground truth"), no truth read.

The recovery world of tests/test_tune_recovery.py (embedded track 5, its first 90 s, the synthetic
DVL of 0.02 m/s; the EKF told the accelerometer and gyro white noise x10 and the DVL std x0.2), with
20 runs per trial and 50 trials (and the refinement). Measured (training seeds 0-3 of the study):
acc 0.82-1.08 of the truth, DVL 0.96-1.07, the gyro anywhere (its profile moves the score by < 1e-4:
flat); with 6 runs the acc lands at 0.46-1.08 (one seed of four outside 2x), with 12 at 0.86-1.42.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from nespm_cli.experiments.spec import validate
from nespm_cli.filters.engine import SensorRecord
from nespm_cli.tuning.innovation import innovation_score, likelihood, per_sensor, sensor_sums
from nespm_cli.tuning.objective import OBJECTIVES, leveled, score, trial_statistics
from nespm_cli.tuning.run import run_tune
from nespm_cli.tuning.spec import TuneSpec, level_bases

from test_tune_recovery import RANGES, TOLD_DVL_STD, TRUE_DVL_STD, mis_set_world

def test_innovation_objective_recovers_mis_set_noise(tmp_path):
    spec = mis_set_world(tracks=(5,), runs=20)
    rec = run_tune(TuneSpec(spec, trials=50, objective="innovation", ranges=RANGES), tmp_path / "t")
    best = rec["best"]["ekf"]
    v = best["values"]
    acc = v["acc_noise_scale"] * 10  # tuned / true (seed 0: 1.003)
    dvl = v["r_scale_dvl"] * TOLD_DVL_STD / TRUE_DVL_STD  # (seed 0: 0.957)
    assert 1 / 1.5 <= dvl <= 1.5, dvl
    assert 1 / 2 <= acc <= 2, acc
    prof = best["profile"]
    # what the innovations see: the DVL std strongly (/3 multiplies the score by ~12), the acc weakly (x3: ~3 %), the
    # gyro white noise not at all over 90 s (< 1e-4)
    assert not prof["r_scale_dvl"]["flat"] and prof["r_scale_dvl"]["change"] > 1.0, prof
    assert not prof["acc_noise_scale"]["flat"], prof
    assert prof["gyro_noise_scale"]["flat"] and prof["gyro_noise_scale"]["change"] < 1e-3, prof
    # the default (x10, x0.2) is far less likely than the tuned setting: 0.22 nats per DVL row
    assert np.log(best["default_score"] / best["score"]) > 0.1, (best["default_score"], best["score"])


def perturbed_truth(simulate):
    """``simulate`` whose truth (velocity, attitude, position) and errors are changed after the filters
    ran: a statistic that reads the truth changes, one that does not is bit-identical."""

    def wrapped(*args, **kwargs):
        results, truth, real = simulate(*args, **kwargs)
        rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        truth = dataclasses.replace(truth, v_n=truth.v_n * 2.0 + 0.3, C_bn=rot @ truth.C_bn, pos=truth.pos + 1e-5)
        moved = {}
        for k, (out, err, secs) in results.items():
            err = dataclasses.replace(err, vel=err.vel * 3.0 + 0.05, att=err.att * 2.0, nees=err.nees * 7.0,
                                      ne=err.ne + 2.0, hpe=None)
            moved[k] = (out, err, secs)
        return moved, truth, real

    return wrapped


def test_innovation_score_reads_no_truth(monkeypatch):
    """The truth and the errors moved after the filter ran: the RMSE and the NEES change, the innovation
    statistics and score are bit-identical; and the score needs only ``innovation`` and ``lost_numeric``."""
    import nespm_cli.experiments.mc as mc

    spec = validate(mis_set_world(tracks=(5,), runs=4, window="0:60"))
    values = {"acc_noise_scale": 0.3, "r_scale_dvl": 2.0}
    a = trial_statistics(spec, "ekf", values)
    monkeypatch.setattr(mc, "simulate", perturbed_truth(mc.simulate))
    b = trial_statistics(spec, "ekf", values)
    assert b["rmse"] > 2 * a["rmse"] and b["anees6"] > 5 * a["anees6"]  # the truth's statistics moved
    assert score(b, "consistency") != score(a, "consistency")
    assert score(b, "innovation") == score(a, "innovation")  # bit for bit
    for k in a["innovation"]:
        np.testing.assert_array_equal(a["innovation"][k], b["innovation"][k])
    only = {"innovation": a["innovation"], "lost_numeric": a["lost_numeric"]}  # nothing else to read
    assert score(only, "innovation") == score(a, "innovation")
    assert score({**only, "lost_numeric": 0.25}, "innovation") == 1e6 + 0.25  # the LOST rule
    assert "innovation" in OBJECTIVES


def test_sensor_sums_by_hand():
    """Two runs, three measurements of a 2-row sensor: one not applied (NaN), one with a masked row (ν 0, a
    unit uncoupled S row: no row, no NIS, no log det), the second run flagged (not kept)."""
    S = np.array([[4.0, 0.0], [0.0, 9.0]])
    Sm = np.array([[4.0, 0.0], [0.0, 1.0]])  # the second row masked
    nan = np.full((2, 2), np.nan)
    rec = SensorRecord(t=np.array([1.0, 2.0, 3.0]), used=np.array([[True, False, True]] * 2),
                       nu=np.array([[[2.0, 3.0], [np.nan, np.nan], [1.0, 0.0]]] * 2),
                       S=np.array([[S, nan, Sm]] * 2))
    out = type("Out", (), {"sensors": {"dvl": rec}})()
    sums = sensor_sums(out, np.array([True, False]))
    nis = 4 / 4 + 9 / 9 + 1 / 4
    logdet = np.log(36.0) + np.log(4.0)
    np.testing.assert_allclose(sums["dvl"], [nis, logdet, 3.0, 2.0], rtol=1e-12)
    assert likelihood(sums) == pytest.approx(0.5 * (nis + logdet) / 3.0, rel=1e-12)
    assert per_sensor(sums)["dvl"]["nis"] == pytest.approx(nis / 3.0, rel=1e-12)
    assert innovation_score({}) == float("inf")  # no innovation (a filter with no covariance)


def test_likelihood_sets_the_nis_at_its_expectation_along_the_level():
    """Every Q, R and P0 variance x c: the EKF's NIS per row is divided by c and its log det S per row
    grows by log c (1e-9), so along the level the likelihood ``½ (NIS/c + logdet + log c)`` is least
    where the NIS per row is 1: the likelihood's optimum is NIS-consistent in that direction."""
    spec = validate(mis_set_world(tracks=(5,), runs=4, window="0:60"))
    shape = {"acc_noise_scale": 0.2, "r_scale_dvl": 3.0, "p0_att_scale": 1.5}
    c = 2.5
    a = per_sensor(trial_statistics(spec, "ekf", shape)["innovation"])["dvl"]
    b = per_sensor(trial_statistics(spec, "ekf", leveled(shape, level_bases(spec, "ekf"), c))["innovation"])["dvl"]
    assert b["nis"] == pytest.approx(a["nis"] / c, rel=1e-9)
    assert b["logdet"] == pytest.approx(a["logdet"] + np.log(c), rel=1e-9, abs=1e-9)
    # the closed-form best level from the one run: c* = NIS per row; its likelihood beats both
    best = leveled(shape, level_bases(spec, "ekf"), a["nis"])
    at = {k: likelihood(trial_statistics(spec, "ekf", x)["innovation"]) for k, x in
          (("shape", shape), ("c", leveled(shape, level_bases(spec, "ekf"), c)), ("best", best))}
    assert at["best"] < min(at["shape"], at["c"]), at
    assert per_sensor(trial_statistics(spec, "ekf", best)["innovation"])["dvl"]["nis"] == pytest.approx(1.0, rel=1e-9)

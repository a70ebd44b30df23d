"""Recovery: in the synthetic world, whose noise is known, a filter told the accelerometer and gyro
white noise x10 and the DVL std x0.2 gets them back from ``nespm tune`` with the consistency
objective (docs/tuning.md).

The world: embedded track 5, its first 90 s, 6 runs per trial, the synthetic DVL (0.02 m/s); the
filter told the truth about everything else (P0 from the corruption; the constant biases as
bias random walks of 1e-5 m/s²/√s and 1e-8 rad/s/√s). The space: the three mis-set factors, each
over three decades (the answer, 0.1 / 0.1 / 5, inside). 50 trials (seeded TPE), then the local
refinement (its default budget). Measured: acc 0.1056 (truth 0.1), DVL 4.83 (truth 5), gyro 0.685
(truth 0.1; in 90 s the gyro white noise is seen from above only: its profile moves the score 0.3 %
at /3 and 11 % at x3, so only an upper bound is identified, and the report says so); the search
converged, its training score 0.0873 1.3 % below the score at the true values (0.0885); every
block's ANEES in its per-epoch band at 91-100 % of the epochs.
"""
from __future__ import annotations

from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE
from nespm_cli.experiments.spec import Spec
from nespm_cli.tuning.run import run_tune
from nespm_cli.tuning.spec import TuneSpec
from nespm_cli.filters import FilterConfig

import pandas as pd

TRUE_DVL_STD = 0.02  # the synthetic DVL's noise [m/s]
TOLD_DVL_STD = 0.2 * TRUE_DVL_STD


OFF = ("acc_bias_rw_scale", "gyro_bias_rw_scale", "p0_vel_scale", "p0_att_scale", "p0_acc_bias_scale",
       "p0_gyro_bias_scale")
RANGES = (("*", "acc_noise_scale", 0.01, 10.0), ("*", "gyro_noise_scale", 0.01, 10.0),
          ("*", "r_scale_dvl", 0.1, 30.0)) + tuple(("*", k, None, None) for k in OFF)  # the three mis-set factors


def mis_set_world(**kw) -> Spec:
    """The recovery world: the EKF told the white noise x10 and the DVL std x0.2 (also tests/test_tune_innovation.py)."""
    kw = {"window": "0:90", **kw}
    return Spec(filters=("ekf",), dvl="synthetic",
                filter_acc_noise=10 * NOMINAL_ACC_NOISE, filter_gyro_noise=10 * NOMINAL_GYRO_NOISE,
                sensor_options=(("dvl", "r_std", str(TOLD_DVL_STD)),),
                filter_config=FilterConfig(acc_bias_rw=1e-5, gyro_bias_rw=1e-8), **kw)


def test_consistency_objective_recovers_mis_set_noise(tmp_path):
    spec = mis_set_world(tracks=(5,), runs=6)
    ranges = RANGES
    rec = run_tune(TuneSpec(spec, trials=50, objective="consistency", ranges=ranges), tmp_path / "t")
    best = rec["best"]["ekf"]
    v = best["values"]
    acc = v["acc_noise_scale"] * 10 * NOMINAL_ACC_NOISE / NOMINAL_ACC_NOISE  # tuned / true
    dvl = v["r_scale_dvl"] * TOLD_DVL_STD / TRUE_DVL_STD
    gyro = v["gyro_noise_scale"] * 10
    assert 1 / 1.5 <= acc <= 1.5, acc
    assert 1 / 1.5 <= dvl <= 1.5, dvl
    assert 1 / 1.5 <= gyro <= 1.5 or best["profile"]["gyro_noise_scale"]["flat_side"], (gyro, best["profile"])
    assert best["convergence"]["status"] == "converged", best["convergence"]
    # the tuned training score is no worse than the score at the true values (by more than 1 %)
    import dataclasses

    from nespm_cli.experiments.spec import validate
    from nespm_cli.tuning.objective import score, trial_statistics

    train = validate(dataclasses.replace(spec, seed=rec["tuned_on"]["seed"]))
    truth = score(trial_statistics(train, "ekf", {"acc_noise_scale": 0.1, "gyro_noise_scale": 0.1,
                                                   "r_scale_dvl": TRUE_DVL_STD / TOLD_DVL_STD}), "consistency")
    assert best["score"] <= 1.01 * truth, (best["score"], truth)
    trials = pd.read_parquet(tmp_path / "t" / "trials.parquet")
    row = trials[trials["trial"] == best["trial"]].iloc[0]
    for block in ("vel", "att", "ba", "bg"):
        assert row[f"in_band_{block}"] >= 0.8, (block, row[f"in_band_{block}"])
    # the default (trial 0) is far from consistent; the tuned filter is not
    assert trials.iloc[0]["consistency"] > 10 * best["score"]

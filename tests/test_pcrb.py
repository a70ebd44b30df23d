"""The posterior Cramér–Rao bound (filters/pcrb.py, experiments/pcrb_table.py; docs/pcrb.md)."""
from __future__ import annotations

import numpy as np
import pytest

from nespm_cli.data.corruption import CorruptionConfig
from nespm_cli.experiments.mc import simulate
from nespm_cli.experiments.pcrb_table import track_bound, unknown_reason
from nespm_cli.experiments.spec import Spec, validate
from nespm_cli.filters.model import FilterConfig
from nespm_cli.filters.pcrb import noise_within_span, riccati_predict, riccati_update

TRUE_TUNING = FilterConfig(acc_bias_rw=0.0, gyro_bias_rw=0.0)  # the realizations' biases are constant


def test_linear_gaussian_covariance_form_is_the_information_recursion():
    """Tichavský et al.'s J_{k+1} = D22 − D21 (J_k + D11)⁻¹ D12 with D11 = Fᵀ Q⁻¹ F, D12 = −Fᵀ Q⁻¹,
    D22 = Q⁻¹ + Hᵀ R⁻¹ H (linear-Gaussian) against the covariance form, 30 steps, 3 patterns with
    different missing measurements: the same matrices to 1e-10 relative."""
    rng = np.random.default_rng(1)
    n, m, B, K = 4, 2, 3, 30
    P0 = np.diag([1.0, 0.5, 2.0, 0.1])
    J = np.broadcast_to(np.linalg.inv(P0), (B, n, n)).copy()
    P = np.broadcast_to(P0, (B, n, n)).copy()
    for _ in range(K):
        F = np.eye(n) + 0.1 * rng.standard_normal((n, n))
        A = rng.standard_normal((n, n))
        Q = 0.01 * (A @ A.T + np.eye(n))
        H = rng.standard_normal((m, n))
        Rm = np.diag([0.2, 0.3])
        ok = rng.random(B) < 0.6
        Qi = np.linalg.inv(Q)
        D11, D12, D22 = F.T @ Qi @ F, -F.T @ Qi, Qi + np.where(ok[:, None, None], H.T @ np.linalg.inv(Rm) @ H, 0.0)
        J = D22 - D12.T @ np.linalg.solve(J + D11, np.broadcast_to(D12, (B, n, n)))
        P = riccati_update(riccati_predict(P, F, Q), H[None], Rm, ok)
    q = rng.random(n)  # the noise within a span, diagonal and dense forms
    A = F - np.eye(n)
    Qd = np.diag(q)
    np.testing.assert_allclose(noise_within_span(F, q[None])[0], Qd + (A @ Qd + Qd @ A.T) / 2 + A @ Qd @ A.T / 3,
                               rtol=1e-13, atol=1e-15)
    Pj = np.linalg.inv(J)
    assert np.abs(P - Pj).max() / np.abs(Pj).max() < 1e-10


@pytest.mark.parametrize("state,sensors,tol", [("12", ("dvl",), 1e-10), ("15", ("dvl", "depth", "fix"), 1e-8)])
def test_ekf_told_the_truth_on_clean_data_is_the_bound(state, sensors, tol):
    """On the error-free IMU and measurements the EKF's solution stays on the truth (to ~1e-11), so
    its covariance, told the true statistics, is the bound's Riccati recursion: measured 4e-13
    (12 states) and 4e-10 (15 states: the position fixes' innovations of 1e-11 move it a little)."""
    spec = validate(Spec(tracks=(5,), runs=1, dvl="synthetic", filters=("ekf",), sensors=sensors,
                         corruption=CorruptionConfig(pos_h_std=1.0, pos_v_std=0.5),
                         filter_config=FilterConfig(acc_bias_rw=0.0, gyro_bias_rw=0.0, state=state)))
    res, _, _ = simulate(spec, 5, np.arange(1), clean=True)
    P = np.einsum("nii->ni", res["ekf"][0].P[0])
    bound, labels = track_bound(spec, 5, np.arange(1), within_span=False)  # the filters' Q at the span's end
    assert len(labels) == int(state)
    rel = np.abs(P - bound[0]) / bound[0]
    assert np.nanmax(rel) < tol


def rmse_against_bound(err2: np.ndarray, bound: np.ndarray) -> tuple[float, float, float]:
    """``(rmse, half, root)``: the RMS over runs and epochs of the squared errors ``err2`` (R, N), its
    3-sigma sampling half-interval (the runs' spread of their mean square, delta method) and the
    root of the bound ``bound`` (N,) averaged over the epochs."""
    s = err2.mean(axis=1)
    rmse = float(np.sqrt(s.mean()))
    return rmse, 3.0 * s.std(ddof=1) / np.sqrt(len(s)) / (2.0 * rmse), float(np.sqrt(bound.mean()))


@pytest.mark.parametrize("case", ["papers", "dynamic-dropout", "position"])
def test_no_filter_beats_the_bound_at_200_runs(case):
    """200 runs, the first 60 s of track 5: every filter's velocity and attitude RMSE (over runs and
    epochs, and per epoch) is at least √PCRB less its sampling interval (3σ of the runs' spread;
    per epoch 4.5σ for the ~60 epochs tested). ``dynamic-dropout``: the dynamic schedule with bias
    steps at every segment and 30 % DVL dropouts (a bound per run, averaged); the filters keep
    their default tuning there (mismatched), which the bound does not care about. ``position``: 15
    states, DVL, depth and 1 m fixes every 10 s, a 2 m initial position error: the EKF and the
    invariant EKF, the horizontal position too."""
    R = 200
    if case == "papers":
        spec = validate(Spec(tracks=(5,), runs=R, dvl="synthetic", filters=("ekf", "ukf"), window="0:60",
                             filter_config=TRUE_TUNING))
    elif case == "position":
        spec = validate(Spec(tracks=(5,), runs=R, dvl="synthetic", filters=("ekf", "iekf"), window="0:60",
                             sensors=("dvl", "depth", "fix"), sensor_options=(("fix", "interval", 10.0),),
                             corruption=CorruptionConfig(pos_h_std=2.0, pos_v_std=0.5),
                             filter_config=FilterConfig(state="15", p0_pos=(2.0, 2.0, 0.5))))
    else:
        spec = validate(Spec(tracks=(5,), runs=R, dvl="synthetic", filters=("ekf",), window="0:60",
                             corruption=CorruptionConfig(schedule="dynamic", dynamic_bias="segment", segment_s=10.0),
                             sensor_options=(("dvl", "dropout", 0.3),)))
    res, _, _ = simulate(spec, 5, np.arange(R))
    bound, labels = track_bound(spec, 5, np.arange(R))
    if case == "dynamic-dropout":
        assert len({tuple(b) for b in bound[:, -1].round(12)}) > 100  # a bound per run
    mean = bound.mean(axis=0)
    for name, (_, err, _) in res.items():
        blocks = [(err.vel ** 2, ("dvN", "dvE", "dvD")), (err.att ** 2, ("dpsiN", "dpsiE", "dpsiD"))]
        if "dpN" in labels:
            blocks.append((err.hpe ** 2, ("dpN", "dpE")))
        for e2, comps in blocks:
            b = mean[:, [labels.index(c) for c in comps]].sum(axis=1)
            rmse, half, root = rmse_against_bound(e2, b)
            assert rmse >= root - half, (name, rmse, half, root)
            sd = e2.std(axis=0, ddof=1) / np.sqrt(R)
            assert np.all(e2.mean(axis=0)[1:] >= b[1:] - 4.5 * sd[1:]), name


def test_ekf_told_the_truth_is_efficient_on_the_papers_protocol():
    """The papers' protocol (12 states, synthetic DVL, constant biases), 100 runs of track 5: the EKF
    told the true statistics has RMSE / √PCRB within 10 % of 1 for the velocity and the attitude
    (measured at 200 runs: 1.018 and 0.988), its error dynamics being near-linear."""
    R = 100
    spec = validate(Spec(tracks=(5,), runs=R, dvl="synthetic", filters=("ekf",), filter_config=TRUE_TUNING))
    res, _, _ = simulate(spec, 5, np.arange(R))
    mean = track_bound(spec, 5, np.arange(R))[0].mean(axis=0)
    err = res["ekf"][1]
    for e2, sl in ((err.vel ** 2, slice(0, 3)), (err.att ** 2, slice(3, 6))):
        rmse, half, root = rmse_against_bound(e2, mean[:, sl].sum(axis=1))
        assert abs(rmse / root - 1.0) < 0.10, (rmse, root)


def test_patterns_are_computed_per_run():
    """A run's bound does not depend on the other runs of its batch (patterns deduplicated)."""
    spec = validate(Spec(tracks=(5,), runs=6, dvl="synthetic", filters=("ekf",), window="0:30",
                         sensor_options=(("dvl", "dropout", 0.5),)))
    all_runs, _ = track_bound(spec, 5, np.arange(6))
    one, _ = track_bound(spec, 5, np.array([4]))
    assert np.array_equal(all_runs[4], one[0])
    assert not np.array_equal(all_runs[4], all_runs[3])


def test_unknown_where_the_statistics_are_unknown():
    assert unknown_reason(validate(Spec(tracks=(5,), dvl="synthetic"))) is None
    # the embedded tracks' DVL is generated in code with one draw every run shares: no bound, said so
    assert "dvl is the embedded track's" in unknown_reason(validate(Spec(tracks=(5,), dvl="recorded")))


def test_noise_within_a_span_is_the_per_step_bound():
    """15 states with depth and fixes, 60 s of track 5: the white noise propagated inside each 1 s
    span (noise_within_span) gives the bound of one time update per IMU step to 2.4e-7 (measured;
    bound 1e-5), where adding it at the span's end, as the filters do, is 2.8 % off in the vertical
    velocity (the velocity noise's integral into the depth)."""
    def spec(time_update):
        return validate(Spec(tracks=(5,), runs=1, dvl="synthetic", window="0:60", sensors=("dvl", "depth", "fix"),
                             filter_config=FilterConfig(state="15", time_update=time_update)))

    span, _ = track_bound(spec("dvl"), 5, [0])
    step, _ = track_bound(spec("imu"), 5, [0])
    end, _ = track_bound(spec("dvl"), 5, [0], within_span=False)
    assert np.abs(np.sqrt(span[0, 1:] / step[0, 1:]) - 1).max() < 1e-5
    assert np.abs(np.sqrt(end[0, 1:] / step[0, 1:]) - 1).max() > 1e-2


@pytest.mark.parametrize("dvl", ["synthetic", "recorded"])
def test_mc_writes_the_bound_and_the_report_its_efficiency(tmp_path, dvl):
    """``mc`` puts ``pcrb_<label>`` into epochs.parquet and the status into the manifest; the report
    has the efficiency table, or, with the recorded DVL (statistics unknown), says so instead."""
    import json

    import nespm_cli.api as nespm
    from nespm_cli.reports.mc import write_mc_report

    out = tmp_path / dvl
    nespm.run_mc(Spec(tracks=(5,), runs=4, dvl=dvl, filters=("ekf",), window="0:30"), out, progress=False)
    man = json.loads((out / "manifest.json").read_text())
    e = nespm.load(out).epochs
    cols = [c for c in e.columns if c.startswith("pcrb_")]
    assert len(cols) == 12
    text = write_mc_report(out, n_boot=50).read_text()
    eff = nespm.report_tables(out, n_boot=50)["efficiency"]
    if dvl == "synthetic":
        assert man["pcrb"]["status"] == "computed"
        assert np.isfinite(e[cols].to_numpy()).all()
        np.testing.assert_allclose(e.loc[e["epoch"] == 0, "pcrb_dvN"], 0.25 ** 2)  # the true P0
        vel = eff[eff["block"] == "vel"].iloc[0]
        assert vel["efficiency"] == pytest.approx(vel["rmse"] / vel["root_pcrb"]) and vel["efficiency"] > 0.5
        assert "| 5 | ekf | velocity [m/s] |" in text
    else:
        assert man["pcrb"]["status"] == "unknown" and "dvl is the embedded track's" in man["pcrb"]["reason"]
        assert man["sensors"]["all"]["dvl"]["source"] == "embedded"  # generated in code, not recorded
        assert "sensors dvl (embedded)" in text
        assert e[cols].isna().all().all() and eff["efficiency"].isna().all()
        assert "**Unknown**: dvl is the embedded track's" in text and "run the same study with `--dvl synthetic`" in text


def test_a_failing_sensor_model_leaves_the_study_and_says_why(monkeypatch):
    """An exception in the bound (here: a sensor's measurement model) does not lose a finished
    study: its columns are NaN and the manifest's status says why."""
    from nespm_cli.experiments import pcrb_table
    from nespm_cli.experiments.mc import Cell
    from nespm_cli.sensors.dvl import Dvl

    def broken(self, *a, **k):
        raise ValueError("no model here")

    monkeypatch.setattr(Dvl, "measurement", broken)
    spec = validate(Spec(tracks=(5,), runs=2, dvl="synthetic", filters=("ekf",), window="0:10"))
    import pandas as pd
    epochs = pd.DataFrame({"track": 5, "filter": "ekf", "epoch": np.arange(11)})
    out, status = pcrb_table.add_pcrb(epochs, [Cell(spec)])
    assert status["status"] == "unknown" and "ValueError: no model here" in status["reason"]
    assert out["pcrb_dvN"].isna().all() and len(out) == 11

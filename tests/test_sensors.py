"""Sensors and error-state layouts end to end (docs/sensors.md): physics, pairing, options.

Physics pinned here (embedded track 5; each bound states what it is derived from):

* zero noise, zero initial error: every layout and sensor combination keeps the solution on the
  truth; velocity and attitude to 1e-9 (measured 6.7e-10 m/s and 1e-12 rad with position
  sensors, 2.4e-12 / 2e-14 without), position to 1e-7 m. The position floor is round-off, not a
  model error: the truth's position comes from the synthesis' vectorized integration and the
  filter's from na_cycle step by step; a latitude ulp is 1.1e-16 rad = 7e-10 m and 6000 steps of
  differently ordered sums leave 2.4e-8 m (measured), which position fixes feed back into the
  velocity (the 6.7e-10). The NESPM points run at alpha = 0.5 here: at the papers' 1e-3 the
  weights (about 4e4 each) amplify the same round-off to 1e-8 m/s (test_regression pins that
  family with the measured spread).
* fixes of std 1 m every 10 s: the 15-state EKF's horizontal RMS is below 1 m (measured 0.47 m)
  and the fixes' mean NIS lies in the two-sided 99 % χ² band of 2 x (number of fixes) dof.
* depth of std 0.05 m: vertical RMS below 0.1 m (measured 0.026 m).
* the 15-state EKF with the DVL alone is no worse in velocity than the 12-state one.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

from conftest import assert_one_error_line, nespm
from nespm_cli.data.corruption import CorruptionConfig, draw
from nespm_cli.errors import NespmError
from nespm_cli.experiments.mc import simulate
from nespm_cli.experiments.metrics import block_nees
from nespm_cli.experiments.spec import Spec, track_inputs, validate
from nespm_cli.experiments.suite import sensor_suite
from nespm_cli.filters import FilterConfig
from nespm_cli.sensors.channels import build_channel

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

TINY = FilterConfig(p0_vel=(1e-6,) * 3, p0_att_deg=(1e-8,) * 3, p0_acc_bias=1e-6, p0_gyro_bias=1e-10,
                    acc_bias_rw=1e-12, gyro_bias_rw=1e-14, acc_noise=1e-9, gyro_noise=1e-12, p0_pos=(1e-6,) * 3,
                    alpha=0.5)
OFF_GRID = (("fix", "interval", "7.3"), ("fix", "jitter", "0.3"), ("fix", "vertical", "true"),
            ("depth", "interval", "0.77"))
CASES = [("12", ("dvl",)), ("15", ("dvl",)), ("15", ("dvl", "depth", "fix")), ("15", ("fix", "depth"))]


@pytest.mark.parametrize("state,sensors", CASES, ids=["12-dvl", "15-dvl", "15-dvl-depth-fix", "15-fix-depth"])
def test_clean_case_stays_on_truth(state, sensors):
    """Exact IMU, initial solution and measurements (fixes off the IMU grid and jittered, depth
    every 0.77 s: both split IMU steps), every built-in filter the layout serves."""
    filters = ("ekf", "ukf", "ukf-nespm", "ckf", "ckf-nespm", "anukf", "iekf")
    opts = tuple(o for o in OFF_GRID if o[0] in sensors)
    spec = validate(Spec(tracks=(5,), runs=2, filters=filters, window="0:60", dvl="synthetic", sensors=sensors,
                         sensor_options=opts, tell_filter=False, filter_config=dataclasses.replace(TINY, state=state)))
    res, _, _ = simulate(spec, 5, np.arange(2), clean=True)
    for f, (out, err, _) in res.items():
        assert not out.diverged.any(), f
        assert out.P.shape[-1] == (15 if state == "15" else 12)
        assert err.vel.max() < 1e-9, (f, err.vel.max())
        assert err.att.max() < 1e-9, (f, err.att.max())
        assert err.hpe.max() < 1e-7 and np.abs(err.down).max() < 1e-7, (f, err.hpe.max(), np.abs(err.down).max())
        for name in sensors:
            assert out.sensors[name].used.any(), (f, name)


@pytest.fixture(scope="module")
def aided():
    """16 runs of the whole embedded track 5, synthetic DVL, 15 states: DVL + depth + fixes every 10 s."""
    with pytest.MonkeyPatch.context() as mp:  # the embedded tracks, whatever the shell's $NESPM_DATA_DIR
        mp.delenv("NESPM_DATA_DIR", raising=False)
        spec = validate(Spec(tracks=(5,), runs=16, filters=("ekf",), dvl="synthetic", sensors=("dvl", "depth", "fix"),
                             sensor_options=(("fix", "interval", "10"), ("fix", "std", "1")),
                             filter_config=FilterConfig(state="15")))
    res, truth, _ = simulate(spec, 5, np.arange(16))
    return (*res["ekf"][:2], truth)


def test_fixes_bound_the_horizontal_error_and_are_consistent(aided):
    out, err, truth = aided
    rms = float(np.sqrt((err.hpe**2).mean()))
    assert rms < 1.0, rms
    rec = out.sensors["fix"]
    nis = rec.nis()[rec.used]
    k = nis.size
    lo, hi = chi2.ppf(0.005, 2 * k) / k, chi2.ppf(0.995, 2 * k) / k
    assert k >= 16 * 38 and lo < nis.mean() < hi, (k, nis.mean(), lo, hi)
    # per-block NEES of the position block: 3 for a consistent filter (measured 3.08; epochs are
    # correlated, so the band is wider than a chi-square band of 16 x 400 independent draws)
    e = truth.epoch_index
    pos_nees = block_nees(out, "pos", truth.v_n[e], truth.C_bn[e], truth.pos[e])[:, 1:]
    assert 2.0 < pos_nees.mean() < 4.5, pos_nees.mean()


def test_depth_bounds_the_vertical_error(aided):
    out, err, _ = aided
    vert = float(np.sqrt((err.down**2).mean()))
    assert vert < 0.1, vert
    nis = out.sensors["depth"].nis()[out.sensors["depth"].used]
    k = nis.size
    assert chi2.ppf(0.005, k) / k < nis.mean() < chi2.ppf(0.995, k) / k, nis.mean()


def test_position_in_the_state_does_not_cost_velocity():
    """DVL only: the 15-state EKF's velocity RMSE is the 12-state one's (position is unobservable
    and, but for the vertical gravity gradient, decoupled); measured equal to 1e-6 relative."""
    v = {}
    for state in ("12", "15"):
        spec = validate(Spec(tracks=(5,), runs=8, filters=("ekf",), dvl="synthetic",
                             filter_config=FilterConfig(state=state)))
        res, _, _ = simulate(spec, 5, np.arange(8))
        v[state] = float(np.sqrt((res["ekf"][1].vel ** 2).mean()))
    assert v["15"] <= v["12"] * (1 + 1e-4), v


def test_adding_a_sensor_leaves_every_other_draw_alone():
    """The IMU and initial errors do not depend on the sensors; each sensor's channel is the same
    whichever other sensors run beside it, in whatever order (bit for bit)."""
    base = validate(Spec(tracks=(5,), runs=3, dvl="synthetic", filters=("ekf",), filter_config=FilterConfig(state="15"),
                         corruption=CorruptionConfig(pos_h_std=1.0)))
    more = validate(dataclasses.replace(base, sensors=("fix", "depth", "dvl"),
                                        sensor_options=(("fix", "dropout", "0.3"), ("depth", "jitter", "0.1"))))
    track, truth = track_inputs(base, 5)
    runs = np.arange(3)

    def channels(spec):
        return {s.name: build_channel(s, track, truth, spec.seed, 5, runs) for s in sensor_suite(spec)}

    a, b = channels(base), channels(more)
    assert np.array_equal(a["dvl"].z, b["dvl"].z) and np.array_equal(a["dvl"].ok, b["dvl"].ok)
    alone = validate(dataclasses.replace(more, sensors=("fix",), sensor_options=(("fix", "dropout", "0.3"),)))
    c = channels(alone)
    assert np.array_equal(b["fix"].z, c["fix"].z) and np.array_equal(b["fix"].ok, c["fix"].ok)
    assert 0.5 < b["fix"].ok[:, 1:].mean() < 0.9  # the dropouts happen, per run
    assert not np.array_equal(b["fix"].ok[0], b["fix"].ok[1])
    d1 = draw(base.seed, 5, runs, 60.0, base.corruption)
    d2 = draw(more.seed, 5, runs, 60.0, more.corruption)
    for k in ("dv0", "dpsi0", "b_a", "b_g", "dp0"):
        assert np.array_equal(getattr(d1, k), getattr(d2, k)), k
    assert np.abs(d1.dp0).max() > 0.1


def test_dropout_applies_each_run_its_own_fixes():
    """A fix missing in some runs (dropout) updates only the others; a run without any fix keeps the
    error growth of the DVL-only filter."""
    spec = validate(Spec(tracks=(5,), runs=4, filters=("ekf", "ukf"), dvl="synthetic", window="0:120",
                         sensors=("dvl", "fix"), filter_config=FilterConfig(state="15"),
                         sensor_options=(("fix", "interval", "5"), ("fix", "dropout", "0.5"))))
    res, _, _ = simulate(spec, 5, np.arange(4))
    for f, (out, err, _) in res.items():
        used = out.sensors["fix"].used
        assert 0.3 < used[:, 1:].mean() < 0.7, used.mean()
        nis = out.sensors["fix"].nis()
        assert np.isnan(nis[~used]).all() and np.isfinite(nis[used]).all()
        assert np.isfinite(err.hpe).all() and not out.diverged.any()


def test_api_and_cli_give_the_same_numbers(tmp_path):
    """The P0 coupling lives in the library: an API Spec with a 5 deg heading error gives the CLI's
    numbers (before the fix the API run's EKF had a NEES of 113 where the CLI's had 3.2)."""
    from nespm_cli.experiments.mc import run_mc
    import pandas as pd

    rc, _, err = nespm("mc", "--tracks", "5", "--runs", "2", "--filters", "ekf", "--heading-deg", "5", "--window",
                       "0:60", "--out", str(tmp_path / "cli"), "--no-progress", "--jobs", "1")
    assert rc == 0, err
    spec = validate(Spec(tracks=(5,), runs=2, filters=("ekf",), window="0:60",
                         corruption=CorruptionConfig(heading_deg=5.0)))
    run_mc(spec, tmp_path / "api", jobs=1, progress=False)
    a = pd.read_parquet(tmp_path / "cli" / "metrics.parquet")
    b = pd.read_parquet(tmp_path / "api" / "metrics.parquet")
    for col in ("vrmse", "mrmse", "nees", "hpe_rms"):
        assert np.array_equal(a[col].to_numpy(), b[col].to_numpy()), col
    assert b["nees"].mean() < 10.0, b["nees"].mean()


def test_imu_rate_sets_the_synthesized_steps():
    """round(rate x GT step) steps per GT interval (the embedded GT step is 400/399 s, so 100 Hz
    gives the papers' 100 steps and 200 Hz 201), the step within one part in ``steps`` of 1/rate."""
    for rate, steps in ((100.0, 100), (50.0, 50), (200.0, 201), (10.0, 10)):
        _, truth = track_inputs(validate(Spec(tracks=(5,), imu_rate=rate)), 5)
        assert set(np.diff(truth.epoch_index).tolist()) == {steps}
        assert abs(1.0 / np.median(truth.dt) - rate) / rate < 1.0 / steps


def test_config_sensor_tables_are_the_command_line_options(tmp_path):
    from nespm_cli import cli as cli_mod

    cfg = tmp_path / "s.toml"
    cfg.write_text('state = "15"\n[sensors.dvl]\n[sensors.fix]\ninterval = 10\nstd = 2.0\nlever_arm = [0, 0, -1]\n'
                   '[sensors.depth]\n')
    words = cli_mod._expand_config(["mc", "--config", str(cfg)])
    assert words == ["mc", "--state", "15", "--sensors", "dvl,fix,depth", "--sensor-option", "fix.interval=10",
                     "--sensor-option", "fix.std=2.0", "--sensor-option", "fix.lever_arm=0,0,-1"]


@pytest.mark.parametrize("args,needle", [
    (["--sensors", "dvl,sonar"], "unknown sensor 'sonar'"),
    (["--sensors", "dvl,fix"], "does not hold"),  # a fix with the 12-state layout
    (["--state", "15", "--sensors", "dvl", "--sensor-option", "fix.std=1"], "fix is not in --sensors"),
    (["--state", "15", "--sensors", "dvl,fix", "--sensor-option", "fix.colour=red"], "unknown option"),
    (["--state", "15", "--sensors", "dvl,fix", "--sensor-option", "fix.std=-1"], "positive std"),
    (["--state", "15", "--sensors", "dvl,fix", "--sensor-option", "fix.interval=abc"], "expected a"),
    (["--state", "15", "--sensors", "dvl,fix", "--sensor-option", "fixstd=1"], "NAME.KEY=VALUE"),
    (["--state", "15", "--sensors", "dvl,depth", "--sensor-option", "depth.dropout=1.5"], "probability"),
    (["--state", "15", "--sensors", "dvl,depth", "--sensor-option", "depth.outage=50:20"], "START < END"),
    (["--state", "16"], "unknown block"),
    (["--state", "pos,vel,att", "--filters", "iekf"], "serves --state 12 or 15"),
    (["--imu", "recorded", "--imu-rate", "200"], "--imu-rate"),
    (["--imu-rate", "0"], "--imu-rate"),
    (["--state", "15", "--sensors", "dvl,depth", "--sensor-option", "depth.source=recorded"], "no depth file"),
    (["--sensors", "depth", "--scenario", "outage", "--state", "15"], "not in --sensors"),
])
def test_bad_sensor_input_is_one_line(tmp_path, args, needle):
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "1", "--out", str(tmp_path / "x"), "--no-progress", *args)
    assert_one_error_line(rc, out, err, needle)
    assert not (tmp_path / "x").exists()


def test_spec_refuses_a_layout_its_filters_do_not_serve():
    with pytest.raises(NespmError, match="serves --state 12 or 15"):
        validate(Spec(tracks=(5,), filters=("ekf", "iekf"), filter_config=FilterConfig(state="pos,vel,att")))


def test_recorded_depth_and_fix_files_at_their_own_stamps(tmp_path):
    """A track folder with DEPTH_ and FIX_ files at their own (off-grid) stamps, NaN rows and a DVL
    epoch marked missing: the filter applies exactly the finite measurements inside the track (each
    at its own time, the IMU step split there), the same in every run, and no DVL at the NaN epoch."""
    from conftest import short_track
    from nespm_cli.data.tracks import write_akit
    from nespm_cli.sensors.channels import locate, truth_at

    tr = short_track(5, 61)
    t_d = tr.t[0] + np.arange(0.37, 60.0, 0.9)
    depth = np.full((len(t_d), 1), np.nan)
    t_f = tr.t[0] + np.array([7.31, 19.9, 33.333, 52.5])
    fix = np.full((4, 2), np.nan)
    dvl = np.array(tr.dvl, copy=True)
    dvl[30] = np.nan
    track = dataclasses.replace(tr, dvl=dvl, channels={"depth": (t_d, depth), "fix": (t_f, fix)})
    folder = tmp_path / "data"
    write_akit(track, folder)
    spec = validate(Spec(tracks=(5,), runs=2, filters=("ekf", "ukf"), data_dir=str(folder), sensors=("dvl", "depth", "fix"),
                         filter_config=FilterConfig(state="15")))
    # fill the files with the exact truth at their stamps (NaN kept in two depth rows)
    _, truth = track_inputs(spec, 5)
    d_truth = truth_at(truth, *locate(truth, t_d - tr.t[0]))
    depth = -d_truth.pos[:, 2:3]
    depth[[3, 17]] = np.nan
    f_truth = truth_at(truth, *locate(truth, t_f - tr.t[0]))
    track = dataclasses.replace(track, channels={"depth": (t_d, depth), "fix": (t_f, f_truth.pos[:, :2])})
    write_akit(track, folder)
    spec = validate(dataclasses.replace(spec, sensor_options=(("depth", "source", "recorded"), ("fix", "source", "recorded"))))
    res, _, _ = simulate(spec, 5, np.arange(2))
    for f, (out, err, _) in res.items():
        used = out.sensors["depth"].used
        assert used.sum(axis=1).tolist() == [len(t_d) - 2] * 2, f
        assert out.sensors["fix"].used.sum() == 2 * 4
        assert np.allclose(out.sensors["depth"].t, t_d - tr.t[0]) and not out.dvl_used[:, 30].any() and out.dvl_used[:, 29].all()
        assert np.abs(err.down).max() < 0.2 and np.isfinite(err.hpe).all()


def test_recorded_dvl_at_its_own_stamps_is_applied_at_them(tmp_path):
    """A DVL file at 2 Hz, half a second off the GT epochs, holding the exact body velocity there:
    the clean filters stay on the truth (each sample applied at its own time, the IMU step split
    there) and every sample inside the track is used."""
    from conftest import short_track
    from nespm_cli.data.tracks import load_track, write_akit
    from nespm_cli.sensors.channels import locate, truth_at

    tr = short_track(5, 41)
    t_dvl = tr.t[0] + np.arange(0.25, 40.0, 0.5)
    spec0 = validate(Spec(tracks=(5,), runs=1, window="0:40"))
    _, truth = track_inputs(spec0, 5)
    at = truth_at(truth, *locate(truth, t_dvl - tr.t[0]))
    v_b = np.einsum("kji,kj->ki", at.C_bn, at.v_n)  # C_bnᵀ v_n, no lever arm
    folder = tmp_path / "data"
    write_akit(dataclasses.replace(tr, channels={"dvl": (t_dvl, v_b)}), folder)
    assert "dvl" in load_track(5, folder).channels
    spec = validate(Spec(tracks=(5,), runs=1, filters=("ekf", "ukf"), data_dir=str(folder), tell_filter=False,
                         filter_config=TINY))
    res, _, _ = simulate(spec, 5, np.arange(1), clean=True)
    for f, (out, err, _) in res.items():
        assert out.sensors["dvl"].used.sum() == len(t_dvl), f
        assert err.vel.max() < 1e-9 and err.att.max() < 1e-9, (f, err.vel.max(), err.att.max())

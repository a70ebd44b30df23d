"""``nespm check``: exact IMUs are found consistent; planted defects are found within stated tolerances."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from conftest import exact_imu_table, assert_one_error_line, nespm
from nespm_cli.checks.verdict import check_track
from nespm_cli.data.corrections import Corrections, apply_corrections, axes_matrix, axes_text, read_corrections
from nespm_cli.data.embedded import embedded_track
from nespm_cli.data.tracks import load_track, write_akit
from nespm_cli.nav.rotations import signed_permutations

# tolerances of the planted-defect test (embedded track 5: 400 s, turns of up to ~5 deg/s)
OFFSET_TOL = 0.02  # [s] the time offset is found to within this (grid 0.01 s, 1-sigma ~0.005 s here)
BIAS_STEP = 0.005  # [rad/s] (~1000 deg/h) planted gyro-z bias step over 200-220 s
PLANTED_OFFSET = 0.3  # [s] IMU stamp minus GT time


exact_imu = exact_imu_table  # the synthesized IMU as a recorded file holds it


@pytest.fixture(scope="module")
def exact_track():
    tr = embedded_track(5)
    return dataclasses.replace(tr, imu=exact_imu(tr))


@pytest.fixture(scope="module")
def exact_result(exact_track):
    return check_track(exact_track)


@pytest.fixture(scope="module")
def planted(exact_track):
    """Flipped y axis, 0.3 s offset and a gyro-z bias step of BIAS_STEP over 200-220 s."""
    imu = np.array(exact_track.imu)
    t_true = imu[:, 0].copy()
    step = (t_true > 200.0) & (t_true <= 220.0)
    imu[step, 6] += BIAS_STEP
    imu[:, [2, 5]] *= -1.0  # recorded y = -body y
    imu[:, 0] = t_true + PLANTED_OFFSET  # stamps late by 0.3 s
    return check_track(dataclasses.replace(exact_track, imu=imu))


def test_exact_imu_is_consistent(exact_result):
    """The exact (synthesized) IMU of a track is found consistent: identity axes, no offset, no bad window."""
    imu = exact_result["imu"]
    assert imu["axis_mapping"]["axes"] == "x,y,z"
    assert imu["axis_mapping"]["cost"] < 1e-3  # residual energy below 0.1 % of the signal's
    assert abs(imu["time_offset"]["offset_s"]) <= 0.01
    assert not any(w["inconsistent"] for w in imu["windows"])
    assert max(abs(x) for x in imu["attitude_drift"]["final_deg"]) < 0.05  # the exact IMU integrates to the GT
    assert min(imu["stats"]["gyro"]["corr"]) > 0.999
    assert exact_result["corrections"]["imu_axes"] == "x,y,z"
    assert exact_result["corrections"]["imu_time_offset"] == 0.0
    assert exact_result["corrections"]["window"] is None


def test_planted_defects_are_found(planted):
    """nespm check finds a planted axis flip, time offset and gyro bias step in an otherwise exact IMU."""
    imu = planted["imu"]
    assert imu["axis_mapping"]["axes"] == "x,-y,z"
    assert imu["axis_mapping"]["identity_cost"] > 5 * imu["axis_mapping"]["cost"]
    assert abs(imu["time_offset"]["offset_s"] - PLANTED_OFFSET) <= OFFSET_TOL
    assert imu["time_offset"]["std_s"] < 0.05
    bad = [w for w in imu["windows"] if w["inconsistent"]]
    assert bad, "the gyro bias step was not flagged"
    # every flagged window overlaps the step, and the step's own window is flagged on gyro z
    assert all(w["start"] < 220.0 and w["end"] > 200.0 for w in bad)
    assert any("gyro z bias" in r for w in bad for r in w["reasons"])
    step_window = min(imu["windows"], key=lambda w: abs(w["start"] - 200.0))
    assert step_window["inconsistent"]
    assert step_window["gyro_bias"][2] == pytest.approx(BIAS_STEP, rel=0.2)
    c = planted["corrections"]
    assert c["imu_axes"] == "x,-y,z" and c["imu_time_offset"] == pytest.approx(PLANTED_OFFSET, abs=OFFSET_TOL)
    assert planted["verdict"] == "inconsistent"
    assert any("200-220 s" in f for f in planted["findings"])


PLANTED_DRIFT = -2500e-6  # [s/s] as the real IMU files against the GT


def test_planted_clock_drift_is_found(exact_track):
    """Stamps = (1 + d) t + o: the local offsets' line finds d and o; the correction undoes them."""
    imu = np.array(exact_track.imu)
    imu[:, 0] = imu[:, 0] * (1.0 + PLANTED_DRIFT) + 0.4
    r = check_track(dataclasses.replace(exact_track, imu=imu))
    o = r["imu"]["time_offset"]
    assert o["drift"]["significant"]
    assert o["drift"]["drift"] == pytest.approx(PLANTED_DRIFT, abs=1e-4)  # 4 % of the drift: 0.04 s over 400 s
    assert abs(o["drift"]["drift"] - PLANTED_DRIFT) < 4 * o["drift"]["drift_std"] + 1e-6
    assert o["offset_s"] == pytest.approx(0.4, abs=OFFSET_TOL)
    assert not any(w["inconsistent"] for w in r["imu"]["windows"])
    c = r["corrections"]
    fixed = apply_corrections(dataclasses.replace(exact_track, imu=imu), Corrections(
        imu_time_offset=c["imu_time_offset"], imu_time_drift=c["imu_time_drift"]))
    assert np.abs(fixed.imu[:, 0] - exact_track.imu[:, 0]).max() < 0.03  # [s] back on the GT clock


def test_corrections_undo_the_planted_flip_and_offset(exact_track):
    imu = np.array(exact_track.imu)
    bad = imu.copy()
    bad[:, [2, 5]] *= -1.0
    bad[:, 0] += PLANTED_OFFSET
    fixed = apply_corrections(dataclasses.replace(exact_track, imu=bad),
                              Corrections(imu_axes="x,-y,z", imu_time_offset=PLANTED_OFFSET))
    np.testing.assert_allclose(fixed.imu, imu, rtol=0, atol=1e-12)
    assert len(fixed.t) == len(exact_track.t)  # the shifted IMU still covers every epoch


def test_every_signed_permutation_round_trips():
    perms = signed_permutations()
    assert len(perms) == 48 and len({axes_text(A) for A in perms}) == 48
    for A in perms:
        np.testing.assert_array_equal(axes_matrix(axes_text(A)), A)
    assert np.array_equal(perms[0], np.eye(3))


@pytest.mark.parametrize("text", ["x,x,z", "x,y", "a,b,c", "x,--y,z", "x,y,z,x"])
def test_bad_axis_mapping_is_one_line(text):
    rc, out, err = nespm("mc", "--imu", "recorded", "--imu-axes", text, "--runs", "1", "--out", "/nonexistent/x")
    assert_one_error_line(rc, out, err, "--imu-axes", "signed permutation")


def test_imu_options_need_a_recorded_imu(tmp_path):
    rc, out, err = nespm("mc", "--imu-axes", "x,-y,z", "--runs", "1", "--out", str(tmp_path / "r"))
    assert_one_error_line(rc, out, err, "--imu recorded")


def test_no_imu_files_reports_the_dvl_part(tmp_path, no_env_data_dir):
    """The embedded tracks have no IMU file: the DVL part runs, the IMU part says what it needs."""
    rc, out, err = nespm("check", "--tracks", "5", "--out", str(tmp_path / "c"), "--no-figures", "--no-progress")
    assert rc == 0, err
    assert "no IMU file" in out
    res = json.loads((tmp_path / "c" / "check.json").read_text())
    r = res["tracks"][0]
    assert r["imu"] is None
    assert r["dvl"]["lever_arm"][0] == pytest.approx(-1.6, abs=0.1)  # embedded L_DVL
    assert read_corrections(tmp_path / "c" / "corrections.json")[5] == Corrections(**{
        **r["corrections"], "window": None})


def test_check_writes_corrections_that_mc_applies(tmp_path, exact_track):
    """A folder with a planted flip: check finds it, and mc --corrections runs with it."""
    tr = dataclasses.replace(exact_track, t=exact_track.t[:80], pos=exact_track.pos[:80], v_n=exact_track.v_n[:80],
                             euler=exact_track.euler[:80], dvl=exact_track.dvl[:80])
    imu = exact_imu(tr)
    imu[:, [2, 5]] *= -1.0
    write_akit(dataclasses.replace(tr, imu=imu), tmp_path / "data")
    rc, out, err = nespm("check", "--data-dir", str(tmp_path / "data"), "--out", str(tmp_path / "c"), "--no-progress")
    assert rc == 0, err
    assert "--imu-axes x,-y,z" in out
    assert (tmp_path / "c" / "check-track5-rates.png").stat().st_size > 10_000
    corr = read_corrections(tmp_path / "c" / "corrections.json")
    assert corr[5].imu_axes == "x,-y,z"
    runs = []
    for extra in ([], ["--corrections", str(tmp_path / "c" / "corrections.json")]):
        out_dir = tmp_path / f"mc{len(extra)}"
        rc, _, err = nespm("mc", "--data-dir", str(tmp_path / "data"), "--tracks", "5", "--runs", "2",
                           "--filters", "ekf", "--imu", "recorded", "--out", str(out_dir), "--no-progress",
                           "--jobs", "1", *extra)
        assert rc == 0, err
        import pandas as pd

        runs.append(pd.read_parquet(out_dir / "metrics.parquet")["vrmse"].mean())
        man = json.loads((out_dir / "manifest.json").read_text())
    assert man["options"]["track_corrections"][0][1]["imu_axes"] == "x,-y,z"
    assert runs[1] < 0.5 * runs[0]  # the flipped axis, uncorrected, costs accuracy


def test_remus_imu_is_consistent():
    """A simulated REMUS 100 run: its IMU is the exact inverse strapdown of its 100 Hz truth (200 s: the
    statements hold as on 400 s, measured: offset 0.075 +- 0.156 s vs 0.056 +- 0.098 s, window from 41 vs 51 s)."""
    from nespm_cli.vehicles import simulate_runs, to_track

    tr = to_track(simulate_runs(1, 200.0, seed=3), 0, 1)
    r = check_track(tr)
    imu = r["imu"]
    assert imu["axis_mapping"]["axes"] == "x,y,z"
    # the helix turns at a near-constant rate, so timing is weakly observable: 0 within 2 sigma
    assert abs(imu["time_offset"]["offset_s"]) <= 2 * imu["time_offset"]["std_s"]
    assert r["corrections"]["imu_axes"] == "x,y,z" and r["corrections"]["imu_time_offset"] == 0.0
    assert not any(w["inconsistent"] for w in imu["windows"])
    # the controller's first seconds roll the vehicle faster than the 1 Hz GT resolves: "unresolved", not
    # inconsistent, and cut by the suggested window at most in the first 60 s
    assert r["verdict"] in ("consistent", "consistent after corrections")
    assert r["corrections"]["window"] is None or r["corrections"]["window"][0] <= 60.0


def test_real_shared_folder_without_imu(real_data_dir, tmp_path):
    rc, out, err = nespm("check", "--data-dir", str(real_data_dir), "--tracks", "5", "--out", str(tmp_path / "c"),
                         "--no-figures", "--no-progress")
    assert rc == 0, err
    assert "track 5: no IMU file" in out
    r = json.loads((tmp_path / "c" / "check.json").read_text())["tracks"][0]
    assert -0.7 < r["dvl"]["time_offset_s"] < -0.3  # measured -0.51 +- 0.02 s on the 2024-06 release


def test_real_recorded_imu_is_found_flipped(real_data_dir):
    """On the real recorded IMU of track 5, check finds the y/z flip and the IMU clock's 1/399 drift."""
    imu_dir = real_data_dir.parent / "snapir-akit-imu"
    if not imu_dir.is_dir():
        pytest.skip(f"{imu_dir} does not exist")
    r = check_track(load_track(5, imu_dir))
    assert r["imu"]["axis_mapping"]["axes"] == "x,-y,z"
    # the IMU clock runs 1/399 slow against the GT's 400/399 s epoch step (measured -2389 +- 69 ppm)
    d = r["imu"]["time_offset"]["drift"]
    assert d["significant"] and abs(d["drift"] + 1 / 399) < 4e-4
    assert 0.3 < r["imu"]["time_offset"]["offset_s"] < 0.6
    assert r["corrections"]["imu_time_drift"] == pytest.approx(d["drift"], abs=1e-6)


@pytest.mark.parametrize("text,msg", [
    ("{", "not valid JSON"),
    ('{"x": 1}', "'tracks' object"),
    ('{"tracks": {"5": {"imu_axes": "x,y,y"}}}', "signed permutation"),
    ('{"tracks": {"5": {"lever": 1}}}', "unknown key 'lever'"),
    ('{"tracks": {"5": {"imu_time_offset": "soon"}}}', "track 5"),
    ('{"tracks": {"5": {"imu_time_drift": 0.5}}}', "clock drift"),
    ('{"tracks": {"5": {"window": [30, 10]}}}', "START < END"),
])
def test_bad_corrections_file_is_one_line(tmp_path, text, msg):
    p = tmp_path / "corrections.json"
    p.write_text(text)
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "1", "--imu", "recorded", "--corrections", str(p),
                         "--out", str(tmp_path / "r"))
    assert_one_error_line(rc, out, err, str(p), msg)
    assert not (tmp_path / "r" / "metrics.parquet").exists()


@pytest.mark.parametrize("opt,val,msg", [("--imu-time-offset", "11", "within +-10"),
                                         ("--imu-time-drift", "0.2", "within +-0.01"),
                                         ("--dvl-time-offset", "nan", "finite"),
                                         ("--window", "400:20", "START < END"),
                                         ("--window", "a:b", "START:END")])
def test_bad_correction_option_is_one_line(tmp_path, opt, val, msg):
    extra = ["--imu", "recorded"] if opt.startswith("--imu") else []
    rc, out, err = nespm("mc", "--tracks", "5", "--runs", "1", opt, val, *extra, "--out", str(tmp_path / "r"))
    assert_one_error_line(rc, out, err, opt, msg)


def test_window_cuts_the_epochs(short_data_dir, tmp_path):
    """--window keeps the epochs inside it: a 20-60 s window of an 80-epoch track runs 40 epochs."""
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), "--tracks", "5", "--runs", "1", "--filters", "ekf",
                       "--window", "20:60", "--out", str(tmp_path / "w"), "--no-progress", "--jobs", "1")
    assert rc == 0, err
    import pandas as pd

    ep = pd.read_parquet(tmp_path / "w" / "epochs.parquet")
    t = load_track(5, short_data_dir).t
    assert len(ep) == int(((t >= 20 - 1e-9) & (t <= 60 + 1e-9)).sum())
    assert ep["t"].min() == 0.0


def test_report_sets_folders_beside(short_data_dir, tmp_path):
    for name, extra in (("a", []), ("b", ["--dvl", "synthetic"])):
        rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), "--tracks", "5", "--runs", "2", "--filters", "ekf",
                           "--out", str(tmp_path / name), "--no-progress", "--jobs", "1", *extra)
        assert rc == 0, err
    rc, out, err = nespm("report", str(tmp_path / "a"), "--beside", str(tmp_path / "b"))
    assert rc == 0, err
    text = (tmp_path / "a" / "report.md").read_text()
    assert "## Beside other results folders" in text
    assert "b (imu synthetic, dvl synthetic)" in text and "a (imu synthetic, dvl recorded)" in text
    import pandas as pd

    mb = pd.read_parquet(tmp_path / "b" / "metrics.parquet")
    vb = (mb["sse_vel_post"] / mb["n_post"]) ** 0.5  # each run's VRMSE after t = 0 (docs/report.md)
    beside = text.split("## Beside other results folders", 1)[1]  # the section's own table
    row = next(line for line in beside.splitlines() if line.startswith("| ekf |") and "dvl" not in line)
    assert f"{float(((vb ** 2).mean()) ** 0.5):.4g}" in row  # eq 51 over one track and two runs, t = 0 out


def test_check_runs_on_a_dvl_at_its_own_stamps(tmp_path, capsys):
    """A DVL at its own stamps (not the GT epochs): the check reports what it can, no traceback (the
    report once formatted a missing DVL residual as a number)."""
    import dataclasses

    import numpy as np

    from conftest import cli
    from nespm_cli.data.tracks import load_track, write_akit

    tr = load_track(1, None)
    t = tr.t[0] + np.arange(0.3, tr.t[-1] - tr.t[0] - 1.0, 0.5)
    v = np.column_stack([np.interp(t, tr.t, tr.dvl[:, i]) for i in range(3)])
    write_akit(dataclasses.replace(tr, channels={"dvl": (t, v)}), tmp_path / "data")
    rc, out, err = cli(capsys, "check", "--data-dir", tmp_path / "data", "--tracks", "1", "--no-figures",
                       "--no-progress", "--out", tmp_path / "check")
    assert rc == 0, err
    assert "DVL against GT" in (tmp_path / "check" / "check.md").read_text()

"""``nespm simulate``: simulated REMUS 100 tracks are ordinary tracks for every other command."""
from __future__ import annotations

import json

import pytest

from conftest import assert_one_error_line, cli
from nespm_cli.data.tracks import load_track


def test_simulated_tracks_load_and_their_imu_round_trips(capsys, tmp_path):
    out = tmp_path / "sim"
    rc, so, err = cli(capsys, "simulate", "--out", out, "--runs", "2", "--duration", "30", "--first-number", "3")
    assert rc == 0, err
    assert "2 tracks (3-4)" in so
    for n in (3, 4):
        tr = load_track(n, out)
        assert tr.imu is not None and len(tr.t) == 31
    # the recorded (simulated) IMU, clean, through the free-inertial navigation cycle
    rc, so, err = cli(capsys, "run", "--data-dir", out, "--track", "3", "--filter", "ins", "--clean",
                      "--imu", "recorded", "--dvl", "synthetic", "--json")
    assert rc == 0, err
    s = json.loads(so)
    assert s["vrmse"] < 1e-6 and s["max_vel_err"] < 1e-6


@pytest.mark.parametrize("args,flag", [(["--runs", "0"], "--runs"), (["--duration", "1"], "--duration"),
                                       (["--dvl", "fake"], "--dvl")])
def test_simulate_bad_input_is_one_line(capsys, tmp_path, args, flag):
    assert_one_error_line(*cli(capsys, "simulate", "--out", tmp_path / "s", *args), flag)


def test_gp_ukf_command_and_report_dispatch(capsys, tmp_path):
    """`nespm gp-ukf` end to end on 2 short runs; `nespm report` recognises its folder."""
    out = tmp_path / "gp"
    rc, so, err = cli(capsys, "gp-ukf", "--runs", "2", "--duration", "20", "--max-points", "60", "--out", out,
                      "--no-progress")
    assert rc == 0, err
    assert "0 diverged" in so
    rc, so, err = cli(capsys, "report", out, "--n-boot", "50")
    assert rc == 0, err
    text = (out / "report.md").read_text()
    assert "Table 3" in text and "Table 4" in text and "0.0158" in text  # published GP-UKF u RMSE
    assert_one_error_line(*cli(capsys, "gp-ukf", "--runs", "0", "--out", tmp_path / "bad"), "--runs")

"""``nespm tracks``: units print as written, the lever arm comes with its uncertainty, and a
track whose turns cannot determine it is flagged."""
from __future__ import annotations

import dataclasses

import numpy as np

from conftest import nespm
from nespm_cli.data.embedded import L_DVL, embedded_track
from nespm_cli.data.tracks import LEVER_MIN_TURN_DPS, Track, track_summary, write_akit


def test_tracks_prints_units_and_lever_arm_std():
    rc, stdout, stderr = nespm("tracks", "--no-progress")
    assert rc == 0, stderr
    for unit in ("duration [s]", "distance [m]", "[m/s]", "lever arm ± 1σ [m]"):
        assert unit in stdout
    assert "±" in stdout.split("lever arm")[1]


def test_lever_arm_std_covers_the_true_arm():
    """The embedded tracks carry a known 1.6 m aft arm: the fit is within 3 of its sigmas."""
    for n in (5, 6):
        s = track_summary(embedded_track(n))
        err = np.abs(np.array(s["lever_arm"][:2]) - L_DVL[:2])
        std = np.array(s["lever_arm_std"][:2])
        assert np.all(std > 0) and np.all(err < 3 * std + 1e-3), (n, s["lever_arm"], s["lever_arm_std"])
        assert s["lever_arm_warning"] is None


def _straight(track: Track) -> Track:
    """The track with its heading frozen: no turns, so the lever arm is not observable."""
    euler = np.array(track.euler)
    euler[:, 2] = euler[0, 2]
    euler[:, :2] = 0.0
    C = Track(track.number, track.t, track.pos, track.v_n, euler, track.dvl, None, "test").C_bn
    dvl = np.einsum("nji,nj->ni", C, track.v_n)  # C^T v: a DVL with no rotation term
    return dataclasses.replace(track, euler=euler, dvl=dvl, imu=None, source="test")


def test_straight_track_warns(tmp_path):
    s = track_summary(_straight(embedded_track(5)))
    assert s["yaw_rate_rms_dps"] < LEVER_MIN_TURN_DPS
    assert s["lever_arm_warning"] and "too few turns" in s["lever_arm_warning"]
    write_akit(_straight(embedded_track(5)), tmp_path)
    rc, stdout, stderr = nespm("tracks", "--data-dir", tmp_path, "--no-progress")
    assert rc == 0, stderr
    assert "warning: track 5" in stdout and "(?)" in stdout

"""The recorded-IMU path: the split step grid, training windows, the IMU's own noise, filter-noise options."""
from __future__ import annotations

import dataclasses
import json

import numpy as np

from conftest import exact_imu_table, assert_one_error_line, nespm
from nespm_cli.checks.imu_gt import own_noise
from nespm_cli.data.embedded import embedded_track
from nespm_cli.data.tracks import write_akit
from nespm_cli.learn.training import make_windows
from nespm_cli.nav.synthesis import from_recorded, recorded_grid, synthesize


def cut(track, n):
    return dataclasses.replace(track, t=track.t[:n], pos=track.pos[:n], v_n=track.v_n[:n], euler=track.euler[:n],
                               dvl=track.dvl[:n])


exact_imu = exact_imu_table  # the synthesized IMU as a recorded file holds it


def test_recorded_grid_splits_the_step_at_every_epoch():
    """An IMU on its own 10.0002500 ms grid, 3 ms off the 400/399 s GT grid."""
    t_gt = np.arange(12) * 400 / 399
    t_imu = -0.003 + np.arange(1200) * 0.0100002500
    t, sample, e = recorded_grid(t_imu, t_gt)
    np.testing.assert_array_equal(t[e], t_gt)  # every epoch is a grid sample, exactly
    assert t[0] == t_gt[0] and t[-1] == t_gt[-1] and np.all(np.diff(t) > 0)
    assert np.all(np.diff(sample) >= 0)
    # the reading of step k is the first sample stamped at or after the step's end...
    assert np.all(t_imu[sample] >= t[1:] - 1e-6)
    # ...and that sample's interval (t_imu[i-1], t_imu[i]] holds the step
    assert np.all(t_imu[sample - 1] <= t[:-1] + 1e-6)
    steps = np.diff(e)
    assert steps.min() >= 100 and steps.max() <= 102  # 100.25 samples per interval, plus the split


def test_exact_imu_file_reads_back_as_the_synthesized_imu():
    tr = cut(embedded_track(5), 30)
    tr = dataclasses.replace(tr, imu=exact_imu(tr))
    ref, rec = synthesize(tr), from_recorded(tr)
    np.testing.assert_array_equal(rec.epoch_index, ref.epoch_index)
    np.testing.assert_allclose(rec.t, ref.t, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rec.f_b, ref.f_b)
    np.testing.assert_array_equal(rec.w_ib_b, ref.w_ib_b)
    np.testing.assert_allclose(rec.v_n, ref.v_n, rtol=0, atol=1e-9)  # the same splines through the GT


def test_training_windows_from_a_recorded_file_equal_the_synthesized(tmp_path):
    """An IMU file holding the exact synthesized IMU gives the training windows of --imu synthetic."""
    for n in (5, 6):
        tr = cut(embedded_track(n), 30)
        write_akit(dataclasses.replace(tr, imu=exact_imu(tr)), tmp_path)
    syn = make_windows((5, 6), tmp_path, runs=2, seed=1)
    rec = make_windows((5, 6), tmp_path, runs=2, seed=1, imu="recorded")
    for k in ("X_acc", "X_gyro", "y_acc", "y_gyro", "track", "run"):
        np.testing.assert_allclose(rec[k], syn[k], rtol=0, atol=1e-12)


def test_own_noise_recovers_planted_white_noise():
    tr = embedded_track(5)
    imu = exact_imu(tr)
    rng = np.random.default_rng(4)
    imu[:, 1:4] += rng.normal(0.0, 0.02, (len(imu), 3))
    imu[:, 4:7] += rng.normal(0.0, 3e-4, (len(imu), 3))
    nz = own_noise(dataclasses.replace(tr, imu=imu))
    np.testing.assert_allclose(nz["acc"], 0.02, rtol=0.03)  # MAD of 40,000 samples: ~1 % std error
    np.testing.assert_allclose(nz["gyro"], 3e-4, rtol=0.03)
    clean = own_noise(dataclasses.replace(tr, imu=exact_imu(tr)))
    assert max(clean["gyro"]) < 1e-6 and max(clean["acc"]) < 1e-3  # the smooth exact IMU has next to none


def test_filter_noise_options_reach_the_filters(short_data_dir, tmp_path):
    rc, _, err = nespm("mc", "--data-dir", str(short_data_dir), "--tracks", "5", "--runs", "1", "--filters", "ekf",
                       "--filter-gyro-noise", "5e-4", "--filter-acc-noise", "0.035", "--out", str(tmp_path / "a"),
                       "--no-progress", "--jobs", "1")
    assert rc == 0, err
    fc = json.loads((tmp_path / "a" / "manifest.json").read_text())["filter_config"]["all"]
    assert fc["gyro_noise"] == 5e-4 and fc["acc_noise"] == 0.035
    rc, out, err = nespm("mc", "--filter-gyro-noise", "-1", "--out", str(tmp_path / "b"))
    assert_one_error_line(rc, out, err, "--filter-gyro-noise", "positive")


def test_train_takes_the_correction_options(tmp_path):
    rc, out, err = nespm("train", "--imu", "bogus", "--out", str(tmp_path / "w.npz"))
    assert_one_error_line(rc, out, err, "--imu", "bogus")
    rc, out, err = nespm("train", "--imu", "recorded", "--imu-axes", "x,y,y", "--out", str(tmp_path / "w.npz"))
    assert_one_error_line(rc, out, err, "--imu-axes", "signed permutation")

"""The DVL-vs-GT consistency fit (nespm_cli.checks.dvl_gt): lever arm, scale factor,
misalignment and time offset recovered from DVL records planted on the embedded tracks' GT.

The planted DVL is ``(1 + s) exp(-[d x]) (C^T v_n + w x l)`` at GT time ``t_k - tau`` (the
module's model and signs), with ``C`` and ``w`` from scipy's RotationSpline (value and
derivative) and ``v_n`` from a cubic spline, plus white noise of 0.005 m/s per axis. On these
smooth tracks the splines are within 1e-5 m/s and 2e-5 rad/s of the analytic truth, so the
tolerances below are set by the noise through the fit's own std:

* well-determined parameters get an absolute tolerance of ~4-5 std (std over both tracks:
  lever x, y 0.004 m; scale 1.4e-4; misalignment pitch, yaw 0.008 deg; offset 0.023 s);
* the weak ones, lever z (std ~0.045 m: only the small roll and pitch rates see it) and roll
  misalignment (std ~0.2 deg: it only acts on the ~0.02 m/s lateral and vertical body
  velocity), are checked against 4 std only.

Every estimate must also be within 4 of its stated std (over 40 seeds the z-scores had
std 0.87-1.07, max |z| 3.2), and each fit takes well under a second.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline

from conftest import needs_real_data, REAL_DATA
from nespm_cli.checks.dvl_gt import fit_dvl_to_gt, dvl_residual
from nespm_cli.data.embedded import L_DVL, embedded_track
from nespm_cli.data.track import Track
from nespm_cli.data.tracks import LEVER_MAX_STD, load_track
from nespm_cli.nav.dvl import dvl_velocity
from nespm_cli.nav.rotations import euler_to_dcm, exp_so3

LEVER = np.array([-1.6, 0.1, 0.2])  # [m]
SCALE = 0.01
MIS_DEG = np.array([0.3, -0.5, 1.0])
TAU = 0.3  # [s] DVL stamp minus GT time
NOISE = 0.005  # [m/s]


def planted(track: Track, lever=LEVER, scale=SCALE, mis_deg=MIS_DEG, tau=TAU, noise=NOISE, seed=0) -> Track:
    """``track`` with its DVL replaced by the model at GT time ``t - tau`` plus white noise."""
    T = track.t - tau
    v = CubicSpline(track.t, track.v_n, axis=0)(T)
    spline = RotationSpline(track.t, Rotation.from_matrix(track.C_bn))
    dvl = dvl_velocity(spline(T).as_matrix(), v, spline(T, 1), np.asarray(lever))
    dvl = (1 + scale) * dvl @ exp_so3(-np.radians(mis_deg)).T
    return dataclasses.replace(track, dvl=dvl + np.random.default_rng(seed).normal(0.0, noise, dvl.shape))


def estimates(fit: dict) -> tuple[np.ndarray, np.ndarray]:
    """(value, std) (8,): lever x, y, z [m], scale, misalignment x, y, z [deg], offset [s]."""
    val = np.r_[fit["lever_arm"], fit["scale_factor"], fit["misalignment_deg"], fit["time_offset_s"]]
    std = np.r_[fit["lever_arm_std"], fit["scale_factor_std"], fit["misalignment_std_deg"], fit["time_offset_std_s"]]
    return val.astype(float), std.astype(float)


@pytest.fixture(scope="module", params=[5, 6])
def planted_fit(request):
    track = planted(embedded_track(request.param), seed=request.param)
    return track, fit_dvl_to_gt(track)


def test_recovers_planted_values(planted_fit):
    _, fit = planted_fit
    val, std = estimates(fit)
    truth = np.r_[LEVER, SCALE, MIS_DEG, TAU]
    err = val - truth
    # absolute tolerances for the well-determined parameters (see the module docstring)
    assert np.all(np.abs(err[:2]) < 0.02), err[:2]  # lever x, y [m]
    assert abs(err[3]) < 1e-3, err[3]  # scale
    assert np.all(np.abs(err[5:7]) < 0.05), err[5:7]  # misalignment pitch, yaw [deg]
    assert abs(err[7]) < 0.1, err[7]  # offset [s]
    # weak parameters and the stated sigmas: every error within 4 sigma, sigmas of the expected size
    assert np.all(np.isfinite(std)), std
    assert np.all(np.abs(err) < 4 * std), (err, std)
    assert std[2] < 0.1 and std[4] < 0.4 and std[7] < 0.04, std
    assert fit["undetermined"] == []


def test_fit_output_is_plain_json_and_residual_matches(planted_fit):
    track, fit = planted_fit
    assert json.loads(json.dumps(fit, allow_nan=False)) == fit  # plain Python types only
    curve = fit["offset_curve"]
    assert len(curve["tau_s"]) == len(curve["rms"]) == 401
    assert curve["tau_s"][0] == -2.0 and curve["tau_s"][-1] == 2.0
    assert abs(curve["tau_s"][int(np.argmin(curve["rms"]))] - fit["time_offset_s"]) <= 0.01
    r = dvl_residual(track, fit)
    assert r.shape == (len(track.t), 3)
    ok = ~np.isnan(r).any(axis=1)
    assert ok[1:-1].all() and not ok[0]  # only t_0 - tau (before the GT start) is NaN
    # full-fit residual at the noise level; before (lever arm alone) it is visibly larger
    assert fit["resid_rms_after"] == pytest.approx(NOISE, rel=0.1)
    assert np.allclose(np.nanstd(r, axis=0), fit["resid_std_after"], rtol=0.05)
    assert np.all(np.array(fit["resid_std_before"]) > np.array(fit["resid_std_after"]))


def test_noise_free_recovery_is_tight():
    fit = fit_dvl_to_gt(planted(embedded_track(6), noise=0.0))
    val, _ = estimates(fit)
    err = val - np.r_[LEVER, SCALE, MIS_DEG, TAU]
    # the remaining errors are the first-order grid search in tau (~1-2 ms) and its effect
    assert np.all(np.abs(err) < [2e-3, 2e-3, 0.01, 1e-5, 0.01, 1e-3, 1e-3, 5e-3]), err
    assert fit["resid_rms_after"] < 1e-4


@pytest.mark.parametrize("number", [5, 6])
def test_unmodified_embedded_track(number):
    """The embedded DVL has no offset, scale or misalignment, lever arm L_DVL and 0.02 m/s noise."""
    fit = fit_dvl_to_gt(embedded_track(number))
    val, std = estimates(fit)
    err = val - np.r_[L_DVL, 0.0, 0.0, 0.0, 0.0, 0.0]
    assert np.all(np.abs(err) < 4 * std), (err, std)
    assert abs(fit["scale_factor"]) < 1e-3
    assert abs(fit["lever_arm"][0] - L_DVL[0]) < 0.05
    # 0.02 m/s noise: the offset is only known to ~0.1 s on these tracks (the 4-sigma bound above)
    assert std[7] < 0.15
    assert fit["resid_rms_after"] == pytest.approx(0.02, rel=0.1)


def test_straight_track_does_not_crash():
    """Constant velocity and attitude: no rotation (lever arm), no velocity change (offset)."""
    n = 200
    t = np.arange(n) * 1.0
    v_n = np.tile([2.0, 0.5, 0.0], (n, 1))
    euler = np.tile([0.0, 0.01, np.arctan2(0.5, 2.0)], (n, 1))
    dvl = np.einsum("nji,nj->ni", euler_to_dcm(euler), v_n) + np.random.default_rng(0).normal(0, 0.01, (n, 3))
    track = Track(number=99, t=t, pos=np.tile([0.57, 0.61, -10.0], (n, 1)), v_n=v_n, euler=euler,
                  dvl=dvl, imu=None, source="test")
    fit = fit_dvl_to_gt(track)
    json.dumps(fit, allow_nan=False)
    assert fit["lever_arm_std"] == [None, None, None]
    assert fit["time_offset_std_s"] is None
    assert {"lever_arm_x", "lever_arm_y", "lever_arm_z", "misalignment_x", "time_offset"} <= set(fit["undetermined"])
    assert fit["scale_factor_std"] is not None and abs(fit["scale_factor"]) < 4 * fit["scale_factor_std"]
    assert np.all(np.isfinite(fit["lever_arm"]))


def test_turn_free_cut_flags_the_lever_arm():
    """61 epochs of embedded track 5 between its turns: the lever arm x, y are not determined."""
    tr = embedded_track(5)
    k = (tr.t > 110) & (tr.t < 175)
    cut = Track(number=5, t=tr.t[k], pos=tr.pos[k], v_n=tr.v_n[k], euler=tr.euler[k], dvl=tr.dvl[k],
                imu=None, source="cut")
    fit = fit_dvl_to_gt(cut)
    for s in fit["lever_arm_std"][:2]:
        assert s is None or s > LEVER_MAX_STD


@needs_real_data
@pytest.mark.parametrize("number", [5, 6])
def test_real_track_sanity(number):
    fit = fit_dvl_to_gt(load_track(number, REAL_DATA))
    print(f"\ntrack {number}:", {k: v for k, v in fit.items() if k != "offset_curve"})
    assert abs(fit["scale_factor"]) < 0.05
    assert abs(fit["time_offset_s"]) < 2.0 and fit["time_offset_std_s"] is not None
    assert -2.5 < fit["lever_arm"][0] < -1.0
    assert fit["resid_rms_after"] < np.sqrt(np.mean(np.square(fit["resid_std_before"])))

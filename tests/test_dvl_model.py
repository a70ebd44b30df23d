"""The one DVL model (nav/dvl.py) and the merged physics of issue "One house".

* ``dvl_velocity`` against a hand computation (exact rotation, rate and lever arm);
* body rate from attitude against a known constant-rate rotation;
* every merged function against the formula it replaced (copied here verbatim from the
  pre-merge code), on the embedded tracks, to 1e-12 or bitwise.
"""
from __future__ import annotations

import numpy as np
import pytest

from nespm_cli.data import embedded
from nespm_cli.data.embedded import EMBEDDED_TRACKS, L_DVL, embedded_track
from nespm_cli.nav import earth, strapdown
from nespm_cli.nav.dvl import body_rate_at_epochs, body_rate_from_attitude, body_rate_step, dvl_velocity
from nespm_cli.nav.rotations import exp_so3, log_so3, wrap_angle
from nespm_cli.nav.synthesis import integrate_position, synthesize
from nespm_cli.nav.trig import sin_cos

ALL = pytest.mark.parametrize("number", EMBEDDED_TRACKS)

# yaw = +90 deg written out exactly: body x -> north... C_bn = Rz(90 deg)
C_YAW90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


# ----------------------------------------------------------------------------- the DVL model


def test_dvl_velocity_hand_computation() -> None:
    v_n = np.array([1.0, 2.0, 3.0])
    w = np.array([0.1, 0.2, 0.3])
    lever = np.array([-1.6, 0.5, 0.2])
    # C^T v = [2, -1, 3]; w x l = [0.2*0.2 - 0.3*0.5, 0.3*(-1.6) - 0.1*0.2, 0.1*0.5 - 0.2*(-1.6)]
    expected = np.array([2.0 - 0.11, -1.0 - 0.5, 3.0 + 0.37])
    np.testing.assert_allclose(dvl_velocity(C_YAW90, v_n, w, lever), expected, rtol=0, atol=1e-12)


def test_dvl_velocity_no_rotation_no_lever_is_body_velocity() -> None:
    v_n = np.array([1.5, -0.3, 0.2])
    assert np.array_equal(dvl_velocity(np.eye(3), v_n, np.zeros(3), L_DVL), v_n)
    assert np.array_equal(dvl_velocity(np.eye(3), v_n, np.array([0.0, 0.0, 0.5]), np.zeros(3)), v_n)


def test_dvl_velocity_batched_equals_single_calls() -> None:
    r = np.random.default_rng(3)
    C = exp_so3(r.normal(size=(4, 5, 3)))
    v = r.normal(size=(4, 5, 3))
    w = r.normal(scale=0.1, size=(4, 5, 3))
    got = dvl_velocity(C, v, w, L_DVL)
    assert got.shape == (4, 5, 3)
    for i in range(4):
        for j in range(5):
            one = C[i, j].T @ v[i, j] + np.cross(w[i, j], L_DVL)
            np.testing.assert_allclose(got[i, j], one, rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------- body rate


def _constant_rate(t: np.ndarray, w: np.ndarray) -> np.ndarray:
    C0 = exp_so3(np.array([0.3, -0.2, 1.1]))
    return C0 @ exp_so3(t[:, None] * w)  # C(t) = C0 exp(t [w x]): constant body rate w


def test_body_rate_from_attitude_constant_rate() -> None:
    t = np.cumsum(np.r_[0.0, np.full(59, 1.0025)])
    w = np.array([0.01, -0.02, 0.15])
    np.testing.assert_allclose(body_rate_from_attitude(t, _constant_rate(t, w)), np.broadcast_to(w, (60, 3)), rtol=0, atol=1e-9)


def test_body_rate_at_epochs_constant_rate() -> None:
    t = np.arange(301) * 0.01
    w = np.array([-0.04, 0.03, -0.2])
    got = body_rate_at_epochs(_constant_rate(t, w), np.diff(t), np.arange(0, 301, 100))
    np.testing.assert_allclose(got, np.broadcast_to(w, (4, 3)), rtol=0, atol=1e-9)


def test_body_rate_step_is_eq31_inverted() -> None:
    C0 = exp_so3(np.array([0.1, 0.2, -0.3]))
    w = np.array([0.05, -0.01, 0.2])
    np.testing.assert_allclose(body_rate_step(C0, C0 @ exp_so3(w * 0.5), 0.5), w, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- merged == old


def _old_body_rate_fd(t, C_bn):  # data/tracks.body_rate_fd before the merge
    CT = np.swapaxes(C_bn, -1, -2)
    w = np.empty((len(t), 3))
    w[1:-1] = log_so3(CT[:-2] @ C_bn[2:]) / (t[2:] - t[:-2])[:, None]
    w[0] = log_so3(CT[0] @ C_bn[1]) / (t[1] - t[0])
    w[-1] = log_so3(CT[-2] @ C_bn[-1]) / (t[-1] - t[-2])
    return w


def _old_body_rate_truth(truth):  # experiments/mc.body_rate_truth
    e = truth.epoch_index
    j = np.maximum(e - 1, 0)
    w = log_so3(np.swapaxes(truth.C_bn[j], -1, -2) @ truth.C_bn[j + 1]) / truth.dt[j][:, None]
    w[e == 0] = w[1]
    return w


def _old_rates(lat, h, v_n, R_N, R_E):  # nav/strapdown._rates before the merge, with today's latitude sines
    sl, cl = sin_cos(lat)  # np.sin / np.cos before issue 41 (docs/conventions.md "Sines of latitude")
    zero = np.zeros_like(lat * v_n[..., 0])
    w_ie = np.stack([earth.OMEGA_IE * cl + zero, zero, -earth.OMEGA_IE * sl + zero], axis=-1)
    vN, vE = v_n[..., 0], v_n[..., 1]
    w_en = np.stack([vE / (R_E + h), -vN / (R_N + h), -vE * sl / cl / (R_E + h)], axis=-1)
    return w_ie, w_en


def _old_wrap(a):  # data/embedded._wrap before the merge
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


@ALL
def test_merged_dvl_and_body_rate_equal_old_on_embedded(number: int) -> None:
    tr = embedded_track(number)
    t = np.asarray(tr.t)
    k = embedded._kinematics(embedded._SPECS[number], t)
    C = tr.C_bn
    # embedded DVL: the noise-free part of the track's DVL, old formula
    noise = np.random.default_rng(1000 + number).normal(0.0, embedded.DVL_NOISE, size=(len(t), 3))
    C_k = embedded.euler_to_dcm(k["euler"])
    old = np.einsum("nji,nj->ni", C_k, k["v_n"]) + np.cross(k["w_b"], L_DVL)
    np.testing.assert_allclose(dvl_velocity(C_k, k["v_n"], k["w_b"], L_DVL), old, rtol=0, atol=1e-12)
    np.testing.assert_allclose(tr.dvl - noise, old, rtol=0, atol=1e-12)
    # tracks.body_rate_fd
    np.testing.assert_allclose(body_rate_from_attitude(t, C), _old_body_rate_fd(t, C), rtol=0, atol=1e-12)
    # experiments.mc synthetic DVL (body_rate_truth + its inline model)
    truth = synthesize(tr)
    e = truth.epoch_index
    lever = np.array([-1.6, 0.2, 0.3])
    w_old = _old_body_rate_truth(truth)
    w_new = body_rate_at_epochs(truth.C_bn, truth.dt, e)
    np.testing.assert_allclose(w_new, w_old, rtol=0, atol=1e-12)
    old_mc = (np.swapaxes(truth.C_bn[e], -1, -2) @ truth.v_n[e][..., None])[..., 0] + np.cross(w_old, lever)
    np.testing.assert_allclose(dvl_velocity(truth.C_bn[e], truth.v_n[e], w_new, lever), old_mc, rtol=0, atol=1e-12)
    # filters/model.dvl_innovation's prediction (batched, lever broadcast)
    pred = (np.swapaxes(C, -1, -2) @ np.asarray(tr.v_n)[..., None])[..., 0] + strapdown.cross(
        w_old, np.broadcast_to(lever, w_old.shape)
    )
    np.testing.assert_allclose(dvl_velocity(C, tr.v_n, w_old, lever), pred, rtol=0, atol=1e-12)


@ALL
def test_merged_rates_and_wrap_equal_old_on_embedded(number: int) -> None:
    truth = synthesize(embedded_track(number))
    pos, v = truth.pos, truth.v_n
    R_N, R_E = earth.radii(pos[:, 0])
    new = earth.transport_rates(pos[:, 0], pos[:, 2], v, R_N, R_E)
    old = _old_rates(pos[:, 0], pos[:, 2], v, R_N, R_E)
    for a, b in zip(new, old):
        assert np.array_equal(a, b)  # the filters' implementation, moved: bitwise
    assert not hasattr(strapdown, "_rates")  # one implementation: earth.transport_rates
    np.testing.assert_allclose(earth.w_en_n(pos, v), new[1], rtol=1e-14, atol=1e-24)
    np.testing.assert_allclose(earth.w_ie_n(pos), new[0], rtol=0, atol=0)
    yaw = embedded._kinematics(embedded._SPECS[number], np.asarray(embedded_track(number).t))["euler"][:, 2]
    np.testing.assert_allclose(wrap_angle(yaw), _old_wrap(yaw), rtol=0, atol=1e-12)
    assert np.all((wrap_angle(yaw) > -np.pi) & (wrap_angle(yaw) <= np.pi))


def test_grid_position_integration_equals_stepwise_update() -> None:
    """synthesis.integrate_position is strapdown.update_position solved over a grid (1e-12)."""
    truth = synthesize(embedded_track(1))
    n = 3000
    pos = integrate_position(truth.pos[0], truth.v_n[: n + 1], truth.dt[:n])
    p = truth.pos[0]
    step = [p]
    for j in range(n):
        p = strapdown.update_position(p, truth.v_n[j], truth.v_n[j + 1], truth.dt[j])
        step.append(p)
    step = np.array(step)
    np.testing.assert_allclose(pos[:, :2], step[:, :2], rtol=0, atol=1e-12)  # rad
    np.testing.assert_allclose(pos[:, 2], step[:, 2], rtol=0, atol=1e-9)  # m


@ALL
def test_embedded_position_close_to_filter_scheme(number: int) -> None:
    """The truth generator's per-sample-radius trapezoid and the filter's eq 29 reading
    (synthesis.integrate_position) agree far below the GT's resolution."""
    tr = embedded_track(number)
    truth = synthesize(tr)
    np.testing.assert_allclose(truth.pos[truth.epoch_index, :2], tr.pos[:, :2], rtol=0, atol=1e-9)

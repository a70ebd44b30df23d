"""The measurement protocol (nespm_cli.filters.measurements): the DVL measurement.

``H`` must be the Jacobian of ``h`` at x = 0 (central finite differences, relative 1e-6),
``h(0)`` zero (h is the change from x = 0), and ``z − predict(nav)`` / ``innovation`` the
old ``dvl_innovation`` (bit for bit).
"""
from __future__ import annotations

import numpy as np

from nespm_cli.filters.measurements import DvlMeasurement, Measurement
from nespm_cli.filters.model import N_STATES, NavState, dvl_H, dvl_h, dvl_innovation
from nespm_cli.nav.rotations import exp_so3


def batch(B: int = 5, seed: int = 3):
    rng = np.random.default_rng(seed)
    nav = NavState(pos=np.column_stack([rng.uniform(0.3, 0.8, B), rng.uniform(0.3, 0.6, B), rng.uniform(-50, 0, B)]),
                   v_n=rng.normal(0, 1.5, (B, 3)), C_bn=exp_so3(rng.normal(0, 1.0, (B, 3))),
                   b_a=rng.normal(0, 0.1, (B, 3)), b_g=rng.normal(0, 1e-4, (B, 3)))
    dvl_b = rng.normal(0, 1.5, (B, 3))
    w_nb = rng.normal(0, 0.05, (B, 3))
    lever = np.array([0.4, -0.2, 0.7])
    return nav, DvlMeasurement(dvl_b, w_nb, lever, 0.02), rng


def test_dvl_measurement_is_a_measurement():
    nav, m, _ = batch()
    assert isinstance(m, Measurement) and m.dim == 3
    assert m.z.shape == (5, 3) and m.R.shape == (3, 3)
    assert np.array_equal(m.R, np.eye(3) * 0.02**2)


def test_H_is_finite_difference_jacobian_of_h():
    nav, m, _ = batch()
    B = nav.v_n.shape[0]
    eps = 1e-6
    X = np.zeros((B, 2 * N_STATES, N_STATES))
    for i in range(N_STATES):
        X[:, i, i] = eps
        X[:, N_STATES + i, i] = -eps
    hz = m.h(X, nav)  # (B, 24, 3)
    fd = np.swapaxes((hz[:, :N_STATES] - hz[:, N_STATES:]) / (2 * eps), -1, -2)  # (B, 3, 12)
    H = m.H(nav)
    assert H.shape == (B, 3, N_STATES)
    scale = np.abs(H).max()
    assert np.abs(fd - H).max() < 1e-6 * scale, np.abs(fd - H).max() / scale


def test_h_of_zero_is_zero_and_matches_model():
    nav, m, rng = batch()
    assert np.abs(m.h(np.zeros((5, 1, N_STATES)), nav)).max() == 0.0
    X = rng.normal(0, 1e-2, (5, 7, N_STATES))
    assert np.array_equal(m.h(X, nav), dvl_h(X, nav, m.lever))
    assert np.array_equal(m.H(nav), dvl_H(nav, m.lever))


def test_innovation_is_the_old_one():
    nav, m, _ = batch()
    old = dvl_innovation(nav, m.z, m.w_nb, m.lever)
    assert np.array_equal(m.innovation(nav), old)
    assert np.array_equal(m.z - m.predict(nav), old)  # z − h(0), h(0) the predicted measurement


def test_predict_is_body_velocity_plus_lever_arm_term():
    nav, m, _ = batch()
    pred = np.einsum("bji,bj->bi", nav.C_bn, nav.v_n) + np.cross(m.w_nb, m.lever)
    assert np.allclose(m.predict(nav), pred, rtol=0, atol=1e-14)

"""Tests of nespm_cli.nav.strapdown: the navigation cycle ``na_cycle`` (ukf-nespm.md eqs 24-32),
its inverse ``na_cycle_inverse`` and the position update of eqs 28-30.

State: pos = [lat, lon, h] (h positive up), v_n NED [m/s], C_bn body -> NED.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nespm_cli.nav import earth

from nespm_cli.nav.rotations import attitude_minus, euler_to_dcm, exp_so3, log_so3, skew
from nespm_cli.nav.strapdown import cross, na_cycle, na_cycle_inverse, update_position

# first GT epoch of Snapir track 1 (/work/shared/data/snapir-akit/Trajectory1)
POS_REAL = np.array([0.573337071406794, 0.6089844335224215, -19.859909])
DT = 400.0 / 399.0 / 100.0  # the IMU step of the synthesized Snapir IMU [s]


def random_states(r: np.random.Generator, shape: tuple[int, ...], speed: float = 2.0):
    """Random navigation states within a few km / tens of m of a real Snapir position."""
    pos = np.empty(shape + (3,))
    pos[..., 0] = POS_REAL[0] + r.uniform(-1e-3, 1e-3, shape)
    pos[..., 1] = POS_REAL[1] + r.uniform(-1e-3, 1e-3, shape)
    pos[..., 2] = r.uniform(-40.0, 0.0, shape)
    v = r.normal(size=shape + (3,)) * speed / np.sqrt(3.0)
    v[..., 2] *= 0.2
    euler = np.stack(
        [r.uniform(-0.3, 0.3, shape), r.uniform(-0.3, 0.3, shape), r.uniform(-np.pi, np.pi, shape)], axis=-1
    )
    return pos, v, euler_to_dcm(euler)


def random_imu(r: np.random.Generator, shape: tuple[int, ...]):
    f = np.array([0.0, 0.0, -9.8]) + r.normal(scale=0.5, size=shape + (3,))
    w = r.normal(scale=0.2, size=shape + (3,))
    return f, w


def at_rest_imu(pos: np.ndarray, C: np.ndarray):
    """Specific force and angular rate sensed by a vehicle at rest on the rotating earth."""
    CT = np.swapaxes(C, -1, -2)
    f = (CT @ (-earth.gravity_n(pos))[..., None])[..., 0]
    w = (CT @ earth.w_ie_n(pos)[..., None])[..., 0]
    return f, w


# ----------------------------------------------------------------------------- helpers


def test_cross_matches_numpy_and_broadcasts():
    r = np.random.default_rng(1)
    a = r.normal(size=(7, 25, 3))
    b = r.normal(size=(25, 3))
    np.testing.assert_allclose(cross(a, b), np.cross(a, b), rtol=0, atol=1e-15)
    np.testing.assert_allclose(cross(a, b), (skew(a) @ b[..., None])[..., 0], rtol=0, atol=1e-15)


def test_transport_rates_match_earth_module():
    r = np.random.default_rng(2)
    pos, v, _ = random_states(r, (7, 25))
    R_N, R_E = earth.radii(pos[..., 0])
    w_ie, w_en = earth.transport_rates(pos[..., 0], pos[..., 2], v, R_N, R_E)
    np.testing.assert_allclose(w_ie, earth.w_ie_n(pos), rtol=0, atol=1e-20)
    np.testing.assert_allclose(w_en, earth.w_en_n(pos, v), rtol=1e-14, atol=1e-24)


# ----------------------------------------------------------------------------- batching


def test_batch_equals_single_calls():
    """A (7, 25) batch (MC runs x sigma points) equals the 175 single-state calls."""
    r = np.random.default_rng(3)
    shape = (7, 25)
    pos, v, C = random_states(r, shape)
    f, w = random_imu(r, shape)
    dt = DT * (1.0 + 0.1 * r.uniform(size=shape))
    P, V, CC = na_cycle(pos, v, C, f, w, dt)
    assert P.shape == (7, 25, 3) and V.shape == (7, 25, 3) and CC.shape == (7, 25, 3, 3)
    worst = 0.0
    for i in range(shape[0]):
        for j in range(shape[1]):
            p1, v1, c1 = na_cycle(pos[i, j], v[i, j], C[i, j], f[i, j], w[i, j], dt[i, j])
            assert p1.shape == (3,) and v1.shape == (3,) and c1.shape == (3, 3)
            worst = max(
                worst,
                np.abs(P[i, j] - p1).max(),
                np.abs(V[i, j] - v1).max(),
                np.abs(CC[i, j] - c1).max(),
            )
    assert worst < 1e-12, worst


def test_batch_with_broadcast_imu_and_dt():
    """One IMU sample broadcast over every sigma point; dt per MC run (shape (7, 1))."""
    r = np.random.default_rng(4)
    pos, v, C = random_states(r, (7, 25))
    f, w = random_imu(r, (7, 1))  # one IMU sample per MC run
    dt = DT * (1.0 + 0.1 * r.uniform(size=(7, 1)))
    P, V, CC = na_cycle(pos, v, C, f, w, dt)
    assert P.shape == (7, 25, 3) and CC.shape == (7, 25, 3, 3)
    for i in range(7):
        for j in (0, 11, 24):
            p1, v1, c1 = na_cycle(pos[i, j], v[i, j], C[i, j], f[i, 0], w[i, 0], float(dt[i, 0]))
            np.testing.assert_allclose(P[i, j], p1, rtol=0, atol=1e-12)
            np.testing.assert_allclose(V[i, j], v1, rtol=0, atol=1e-12)
            np.testing.assert_allclose(CC[i, j], c1, rtol=0, atol=1e-12)
    # scalar IMU for the whole batch
    P2, V2, C2 = na_cycle(pos, v, C, f[0, 0], w[0, 0], DT)
    p1, v1, c1 = na_cycle(pos[5, 7], v[5, 7], C[5, 7], f[0, 0], w[0, 0], DT)
    np.testing.assert_allclose(V2[5, 7], v1, rtol=0, atol=1e-12)
    np.testing.assert_allclose(C2[5, 7], c1, rtol=0, atol=1e-12)
    np.testing.assert_allclose(P2[5, 7], p1, rtol=0, atol=1e-12)


def test_batch_inverse_equals_single_calls():
    r = np.random.default_rng(5)
    pos, v, C = random_states(r, (7, 25))
    v1 = v + r.normal(scale=0.02, size=v.shape)
    C1 = C @ exp_so3(r.normal(scale=0.005, size=v.shape))
    p1 = update_position(pos, v, v1, DT)
    F, W = na_cycle_inverse(pos, v, C, p1, v1, C1, DT)
    assert F.shape == W.shape == (7, 25, 3)
    for i in range(7):
        for j in range(25):
            f, w = na_cycle_inverse(pos[i, j], v[i, j], C[i, j], p1[i, j], v1[i, j], C1[i, j], DT)
            np.testing.assert_allclose(F[i, j], f, rtol=0, atol=1e-10)
            np.testing.assert_allclose(W[i, j], w, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- physics


def test_stationary_vehicle_stays_at_rest():
    """f = C^T(-g^n), w = C^T w_ie^n: 1000 steps of 0.01 s leave the vehicle where it was."""
    r = np.random.default_rng(6)
    n = 12
    pos = np.stack([np.radians(np.linspace(-70.0, 70.0, n)), r.uniform(-3, 3, n), r.uniform(-40, 0, n)], -1)
    pos[0] = POS_REAL
    C0 = euler_to_dcm(np.stack([r.uniform(-0.5, 0.5, n), r.uniform(-0.5, 0.5, n), r.uniform(-3, 3, n)], -1))
    f, w = at_rest_imu(pos, C0)
    p, v, C = pos.copy(), np.zeros((n, 3)), C0.copy()
    for _ in range(1000):
        p, v, C = na_cycle(p, v, C, f, w, 0.01)
    assert np.abs(v).max() < 1e-9
    assert np.abs(attitude_minus(C, C0)).max() < 1e-12
    assert np.abs(p[:, :2] - pos[:, :2]).max() < 1e-15  # rad: ~6e-9 m
    assert np.abs(p[:, 2] - pos[:, 2]).max() < 1e-9


def test_stationary_vehicle_without_earth_rate_drifts():
    """Negative control: omitting the earth rate from the gyros makes the attitude drift by
    w_ie * t (the stationary test is sensitive to the earth-rate terms)."""
    pos = POS_REAL
    C0 = euler_to_dcm([0.1, -0.05, 1.0])
    f, _ = at_rest_imu(pos, C0)
    p, v, C = pos, np.zeros(3), C0
    for _ in range(1000):
        p, v, C = na_cycle(p, v, C, f, np.zeros(3), 0.01)
    drift = attitude_minus(C, C0)
    np.testing.assert_allclose(drift, -earth.w_ie_n(pos) * 10.0, rtol=1e-3, atol=1e-10)
    assert np.abs(v).max() > 1e-5


@pytest.mark.parametrize("axis", [[0, 0, 1], [1, 0, 0], [0.3, -0.4, 0.866]])
def test_pure_rotation_at_rest(axis):
    """A vehicle at rest spinning at 0.5 rad/s about a fixed body axis: the gyros sense
    C^T w_ie + w_body, the accelerometers the mid-step C*^T(-g). After 1000 steps of 0.01 s
    the attitude is C0 exp(w_body * 10 s) and the velocity is still zero."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    w_body = 0.5 * axis
    dt = 0.01
    C0 = euler_to_dcm([0.05, -0.1, 0.7])
    pos = POS_REAL.copy()
    g = earth.gravity_n(pos)
    w_ie = earth.w_ie_n(pos)
    half = exp_so3(w_body * dt / 2)
    p, v, C = pos, np.zeros(3), C0
    for _ in range(1000):
        w_ib = C.T @ w_ie + w_body
        f = (C @ half).T @ (-g)
        p, v, C = na_cycle(p, v, C, f, w_ib, dt)
    expected = C0 @ Rotation.from_rotvec(w_body * 1000 * dt).as_matrix()
    assert np.abs(C - expected).max() < 1e-12
    assert np.abs(v).max() < 1e-9
    if axis[2] == 1.0:  # level-ish yaw spin: yaw advanced by 5 rad (mod 2 pi) in body-z terms
        np.testing.assert_allclose(log_so3(C0.T @ C), [0.0, 0.0, 5.0 - 2 * np.pi], atol=1e-12)


def test_free_fall_one_step():
    """f = 0 at rest: v_next = g^n dt, h_next = h - g_D dt^2 / 2 (trapezoid of eq 28)."""
    pos = POS_REAL
    C = euler_to_dcm([0.2, 0.1, -2.0])
    _, w = at_rest_imu(pos, C)
    dt = 0.01
    p1, v1, C1 = na_cycle(pos, np.zeros(3), C, np.zeros(3), w, dt)
    g = earth.gravity_n(pos)
    np.testing.assert_allclose(v1, g * dt, rtol=0, atol=1e-16)
    assert abs(p1[2] - (pos[2] - g[2] * dt * dt / 2)) < 1e-14


def test_coriolis_and_transport_terms_one_step():
    """Moving vehicle whose gyros follow the nav frame (no body rotation relative to NED):
    v_next = v + (-cross(w_en + 2 w_ie, v)) dt, with the earth-module rates (eq 26-27).
    Going east in the northern hemisphere the Coriolis force pushes south and up."""
    pos = POS_REAL
    C = euler_to_dcm([0.0, 0.0, np.pi / 2])
    v = np.array([0.0, 2.0, 0.0])
    dt = 0.01
    f = C.T @ (-earth.gravity_n(pos))
    w = C.T @ (earth.w_ie_n(pos) + earth.w_en_n(pos, v))
    p1, v1, C1 = na_cycle(pos, v, C, f, w, dt)
    acc = (v1 - v) / dt
    expected = -np.cross(earth.w_en_n(pos, v) + 2 * earth.w_ie_n(pos), v)
    np.testing.assert_allclose(acc, expected, rtol=0, atol=1e-12)
    assert acc[0] < -1.5e-4 and acc[2] < -2e-4  # south and up (NED)
    # north: -2 Omega sin L v_E (Coriolis) - v_E^2 tan L / (R_E + h) (transport)
    R_E = earth.radii(pos[0])[1]
    assert abs(acc[0] + 2 * 2.0 * earth.OMEGA_IE * np.sin(pos[0]) + 4.0 * np.tan(pos[0]) / (R_E + pos[2])) < 1e-14


def test_update_position_constant_velocity():
    """Trapezoid of eqs 28-30 with v constant: dh = -v_D dt, dlat = v_N/(R_N + h) dt,
    dlon = v_E / ((R_E + h) cos L) dt to first order (eq 30 with the 1/cos L factor)."""
    pos = POS_REAL
    v = np.array([1.2, -0.7, 0.3])
    dt = 1.0
    p1 = update_position(pos, v, v, dt)
    R_N, R_E = earth.radii(pos[0])
    h1 = pos[2] - 0.3
    assert abs(p1[2] - h1) < 1e-14
    # (rtol limited by the round-off of lat1 - lat, 1e-16 / 2e-7)
    np.testing.assert_allclose(p1[0] - pos[0], 0.5 * (1.2 / (R_N + pos[2]) + 1.2 / (R_N + h1)), rtol=1e-8)
    dlon = -0.7 / ((R_E + pos[2]) * np.cos(pos[0]))
    np.testing.assert_allclose(p1[1] - pos[1], dlon, rtol=1e-6)
    # northing / easting in metres
    off = earth.ned_offset(p1, pos)
    np.testing.assert_allclose(off, [1.2, -0.7, 0.3], rtol=1e-6)


# ----------------------------------------------------------------------------- inverse


@pytest.mark.parametrize("dt", [DT, 0.01, 1.0025])
def test_inverse_then_forward_reproduces_next_state(dt):
    r = np.random.default_rng(7)
    shape = (400,)
    pos, v, C = random_states(r, shape)
    # consecutive states: accelerations up to ~2 m/s^2, body rates up to ~0.5 rad/s
    v1 = v + r.normal(scale=1.0, size=v.shape) * dt
    C1 = C @ exp_so3(r.normal(scale=0.3, size=v.shape) * dt)
    p1 = update_position(pos, v, v1, dt)
    f, w = na_cycle_inverse(pos, v, C, p1, v1, C1, dt)
    P, V, CC = na_cycle(pos, v, C, f, w, dt)
    assert np.abs(P[:, :2] - p1[:, :2]).max() < 1e-15  # rad
    assert np.abs(P[:, 2] - p1[:, 2]).max() < 1e-12
    assert np.abs(V - v1).max() < 1e-12
    assert np.abs(CC - C1).max() < 1e-12
    # plausible sensor values
    assert np.all(np.abs(np.linalg.norm(f, axis=-1) - 9.8) < 6.0)


def test_forward_then_inverse_recovers_imu():
    r = np.random.default_rng(8)
    pos, v, C = random_states(r, (7, 25))
    f, w = random_imu(r, (7, 25))
    P, V, CC = na_cycle(pos, v, C, f, w, DT)
    f2, w2 = na_cycle_inverse(pos, v, C, P, V, CC, DT)
    np.testing.assert_allclose(f2, f, rtol=0, atol=1e-11)
    np.testing.assert_allclose(w2, w, rtol=0, atol=1e-12)


def test_inverse_with_inconsistent_position_differs():
    """Negative control: pos_next not made by update_position changes the result slightly
    (the inverse really uses pos_next through the eq 32 rates)."""
    r = np.random.default_rng(9)
    pos, v, C = random_states(r, (50,))
    v1 = v + 0.01
    C1 = C @ exp_so3(np.full((50, 3), 1e-3))
    p1 = update_position(pos, v, v1, DT)
    p_bad = p1 + np.array([1e-3, 0.0, 0.0])  # ~6 km off in latitude
    _, w_good = na_cycle_inverse(pos, v, C, p1, v1, C1, DT)
    _, w_bad = na_cycle_inverse(pos, v, C, p_bad, v1, C1, DT)
    assert np.abs(w_good - w_bad).max() > 1e-9

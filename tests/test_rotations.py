"""Tests of nespm_cli.nav.rotations: skew/vee, SO(3) exp/log, Euler <-> DCM, attitude ⊕/⊖.

Conventions under test: C_bn = body -> NED DCM, Euler [roll, pitch, yaw] ZYX
(C_bn = Rz(yaw) Ry(pitch) Rx(roll)), ⊕ = exp([d x]) C (nav-frame misalignment on the left),
⊖(C1, C2) = log(C1 C2^T) (ukf-nespm.md eqs 37 and 40). Everything is batched.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from nespm_cli.nav import rotations as rot

PI = np.pi
RNG_SEED = 20240611


# ----------------------------------------------------------------------------- helpers


def rng(offset: int = 0) -> np.random.Generator:
    return np.random.default_rng(RNG_SEED + offset)


def unit_vectors(r: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    u = r.normal(size=shape + (3,))
    return u / np.linalg.norm(u, axis=-1, keepdims=True)


def rotvecs(r: np.random.Generator, angles: np.ndarray) -> np.ndarray:
    """Rotation vectors with the given angles [rad] about random axes."""
    angles = np.asarray(angles, dtype=float)
    return unit_vectors(r, angles.shape) * angles[..., None]


def random_dcms(r: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    return Rotation.random(int(np.prod(shape)), random_state=r).as_matrix().reshape(shape + (3, 3))


def wrap(a: np.ndarray) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(a) + PI) % (2.0 * PI) - PI


def angle_err(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(wrap(np.asarray(a) - np.asarray(b)))


def ortho_err(C: np.ndarray) -> float:
    I = np.eye(3)
    e1 = np.abs(np.swapaxes(C, -1, -2) @ C - I).max()
    e2 = np.abs(C @ np.swapaxes(C, -1, -2) - I).max()
    return float(max(e1, e2))


# Angle families of the brief: tiny (1e-9 rad), the Taylor/closed-form switch (1e-4),
# moderate, and close to pi (up to pi - 1e-6).
ANGLE_FAMILIES = {
    "zero": np.zeros(5),
    "tiny": np.array([1e-12, 1e-10, 1e-9, 3e-9, 1e-8]),
    "switch": np.array([1e-6, 9.99e-5, 1e-4, 1.0001e-4, 1e-3]),
    "moderate": np.linspace(0.01, 2.5, 50),
    "large": np.linspace(2.5, 3.1, 50),
    "near_pi": PI - np.array([1e-2, 1e-3, 1e-4, 1e-5, 3e-6, 1e-6]),
}


# ----------------------------------------------------------------------------- skew / vee


def test_skew_times_b_is_cross_product():
    r = rng(1)
    a = r.normal(size=(7, 25, 3))
    b = r.normal(size=(7, 25, 3))
    S = rot.skew(a)
    assert S.shape == (7, 25, 3, 3)
    got = (S @ b[..., None])[..., 0]
    np.testing.assert_allclose(got, np.cross(a, b), rtol=0, atol=1e-14)


def test_skew_is_antisymmetric_and_vee_inverts_it():
    r = rng(2)
    a = r.normal(size=(100, 3)) * 10.0
    S = rot.skew(a)
    np.testing.assert_array_equal(S, -np.swapaxes(S, -1, -2))
    np.testing.assert_array_equal(rot.vee(S), a)
    # explicit layout of [a x]
    np.testing.assert_array_equal(
        rot.skew(np.array([1.0, 2.0, 3.0])),
        np.array([[0.0, -3.0, 2.0], [3.0, 0.0, -1.0], [-2.0, 1.0, 0.0]]),
    )


def test_vee_takes_antisymmetric_part():
    r = rng(3)
    a = r.normal(size=(20, 3))
    sym = r.normal(size=(20, 3, 3))
    sym = sym + np.swapaxes(sym, -1, -2)
    np.testing.assert_allclose(rot.vee(rot.skew(a) + sym), a, rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------- exp / log


@pytest.mark.parametrize("family", list(ANGLE_FAMILIES))
def test_log_exp_round_trip(family):
    r = rng(10 + len(family))
    angles = np.repeat(ANGLE_FAMILIES[family], 20)
    phi = rotvecs(r, angles)
    C = rot.exp_so3(phi)
    assert ortho_err(C) < 1e-14
    np.testing.assert_allclose(np.linalg.det(C), 1.0, rtol=0, atol=1e-14)
    back = rot.log_so3(C)
    assert np.abs(back - phi).max() < 1e-12, f"{family}: max err {np.abs(back - phi).max():.3e}"


def test_log_exp_round_trip_uniform_ball():
    """Rotation vectors uniform in the ball of radius pi - 1e-6 (mostly large angles)."""
    r = rng(20)
    n = 20000
    angles = (PI - 1e-6) * r.uniform(size=n) ** (1.0 / 3.0)
    phi = rotvecs(r, angles)
    back = rot.log_so3(rot.exp_so3(phi))
    assert np.abs(back - phi).max() < 1e-12


def test_exp_log_round_trip_random_matrices():
    r = rng(21)
    C = random_dcms(r, (5000,))
    phi = rot.log_so3(C)
    assert np.all(np.linalg.norm(phi, axis=-1) <= PI + 1e-15)
    np.testing.assert_allclose(rot.exp_so3(phi), C, rtol=0, atol=1e-13)


def test_tiny_angle_log_has_full_relative_accuracy():
    """No arccos: a 1e-9 rad rotation is recovered to ~1e-16 relative, not 1e-8 absolute."""
    r = rng(22)
    phi = rotvecs(r, np.full(50, 1e-9))
    back = rot.log_so3(rot.exp_so3(phi))
    assert np.abs(back - phi).max() < 1e-22  # relative 1e-13 of a 1e-9 rad angle


def test_log_beyond_pi_wraps_to_shortest_rotation():
    r = rng(23)
    axis = unit_vectors(r, (40,))
    ang = np.linspace(PI + 1e-3, 2 * PI - 0.1, 40)
    back = rot.log_so3(rot.exp_so3(axis * ang[:, None]))
    np.testing.assert_allclose(back, axis * (ang - 2 * PI)[:, None], rtol=0, atol=1e-12)


def test_log_of_exact_pi_rotation():
    for axis in np.eye(3):
        C = rot.exp_so3(axis * PI)
        phi = rot.log_so3(C)
        assert abs(np.linalg.norm(phi) - PI) < 1e-12
        # either +axis*pi or -axis*pi: both represent the same rotation
        assert min(np.abs(phi - axis * PI).max(), np.abs(phi + axis * PI).max()) < 1e-12
        np.testing.assert_allclose(rot.exp_so3(phi), C, rtol=0, atol=1e-14)


def test_log_of_identity_is_zero():
    np.testing.assert_array_equal(rot.log_so3(np.eye(3)), np.zeros(3))
    np.testing.assert_array_equal(rot.exp_so3(np.zeros(3)), np.eye(3))


def test_exp_matches_scipy_rotvec():
    r = rng(24)
    angles = np.concatenate([v for v in ANGLE_FAMILIES.values()] + [r.uniform(0, PI, 500)])
    phi = rotvecs(r, angles)
    np.testing.assert_allclose(rot.exp_so3(phi), Rotation.from_rotvec(phi).as_matrix(), rtol=0, atol=1e-14)


def test_log_matches_scipy_rotvec():
    r = rng(25)
    angles = r.uniform(0, PI - 1e-3, 2000)
    phi = rotvecs(r, angles)
    C = Rotation.from_rotvec(phi).as_matrix()
    np.testing.assert_allclose(rot.log_so3(C), Rotation.from_matrix(C).as_rotvec(), rtol=0, atol=1e-12)


def test_exp_taylor_branch_is_continuous_at_switch():
    """Closed form and Taylor series agree at the 1e-4 rad switch to double precision."""
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    lo = rot.exp_so3(axis * np.nextafter(1e-4, 0.0))
    hi = rot.exp_so3(axis * 1e-4)
    np.testing.assert_allclose(lo, hi, rtol=0, atol=1e-15)
    np.testing.assert_allclose(lo, Rotation.from_rotvec(axis * 1e-4).as_matrix(), rtol=0, atol=3e-16)


def test_exp_of_opposite_vectors_is_transpose():
    r = rng(26)
    phi = rotvecs(r, r.uniform(0, PI, 300))
    np.testing.assert_allclose(rot.exp_so3(-phi), np.swapaxes(rot.exp_so3(phi), -1, -2), rtol=0, atol=1e-15)


@settings(max_examples=300, deadline=None)
@given(
    axis=st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 3).filter(lambda a: np.linalg.norm(a) > 1e-3),
    log_angle=st.floats(-12.0, np.log10(PI - 1e-6), allow_nan=False),
)
def test_property_log_exp_round_trip(axis, log_angle):
    a = np.asarray(axis) / np.linalg.norm(axis)
    phi = a * 10.0**log_angle
    np.testing.assert_allclose(rot.log_so3(rot.exp_so3(phi)), phi, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- Euler <-> DCM


def random_eulers(r: np.random.Generator, n: int, pitch_margin: float = 0.01) -> np.ndarray:
    return np.stack(
        [
            r.uniform(-PI, PI, n),
            r.uniform(-PI / 2 + pitch_margin, PI / 2 - pitch_margin, n),
            r.uniform(-PI, PI, n),
        ],
        axis=-1,
    )


def test_euler_dcm_euler_round_trip():
    r = rng(30)
    e = random_eulers(r, 20000)
    back = rot.dcm_to_euler(rot.euler_to_dcm(e))
    assert angle_err(back, e).max() < 1e-12
    # yaw and roll come back in [-pi, pi], pitch in [-pi/2, pi/2]
    assert np.all(np.abs(back) <= PI)
    assert np.all(np.abs(back[:, 1]) <= PI / 2)


def test_euler_round_trip_close_to_gimbal_lock():
    """1e-3 rad from pitch +-90 deg the round trip still holds to 1e-12 (error ~ eps / cos pitch)."""
    r = rng(31)
    e = random_eulers(r, 2000)
    e[:, 1] = np.where(r.uniform(size=2000) < 0.5, -1.0, 1.0) * (PI / 2 - 1e-3)
    back = rot.dcm_to_euler(rot.euler_to_dcm(e))
    assert angle_err(back, e).max() < 1e-12


def test_euler_to_dcm_is_orthonormal():
    r = rng(32)
    e = np.stack([r.uniform(-PI, PI, 20000), r.uniform(-PI, PI, 20000), r.uniform(-PI, PI, 20000)], -1)
    C = rot.euler_to_dcm(e)
    assert ortho_err(C) < 1e-14
    np.testing.assert_allclose(np.linalg.det(C), 1.0, rtol=0, atol=1e-14)


def test_euler_to_dcm_matches_scipy_ZYX():
    r = rng(33)
    e = random_eulers(r, 5000, pitch_margin=0.0)
    ref = Rotation.from_euler("ZYX", e[:, ::-1]).as_matrix()  # [yaw, pitch, roll]
    np.testing.assert_allclose(rot.euler_to_dcm(e), ref, rtol=0, atol=1e-15)
    # and the inverse agrees with scipy's as_euler away from gimbal lock
    ref = ref[np.abs(e[:, 1]) < PI / 2 - 0.01]
    np.testing.assert_allclose(
        angle_err(rot.dcm_to_euler(ref), Rotation.from_matrix(ref).as_euler("ZYX")[:, ::-1]), 0.0, atol=1e-12
    )


def test_euler_to_dcm_elementary_rotations():
    """Body x forward, z down: yaw 90 deg points the nose east; pitch up raises the nose."""
    a = 0.3
    c, s = np.cos(a), np.sin(a)
    np.testing.assert_allclose(rot.euler_to_dcm([0, 0, a]), [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-16)
    np.testing.assert_allclose(rot.euler_to_dcm([0, a, 0]), [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=1e-16)
    np.testing.assert_allclose(rot.euler_to_dcm([a, 0, 0]), [[1, 0, 0], [0, c, -s], [0, s, c]], atol=1e-16)
    nose = rot.euler_to_dcm([0.0, 0.0, PI / 2]) @ [1.0, 0.0, 0.0]
    np.testing.assert_allclose(nose, [0.0, 1.0, 0.0], atol=1e-16)  # NED east
    nose = rot.euler_to_dcm([0.0, 0.2, 0.0]) @ [1.0, 0.0, 0.0]
    assert nose[2] < 0  # pitch up -> nose has a negative down (upward) component
    # C_bn = Rz Ry Rx composition order
    e = np.array([0.4, -0.7, 2.1])
    Rz = rot.euler_to_dcm([0, 0, e[2]])
    Ry = rot.euler_to_dcm([0, e[1], 0])
    Rx = rot.euler_to_dcm([e[0], 0, 0])
    np.testing.assert_allclose(rot.euler_to_dcm(e), Rz @ Ry @ Rx, rtol=0, atol=1e-15)


def test_dcm_to_euler_yaw_range():
    yaw = np.array([PI, -PI, PI - 1e-9, -PI + 1e-9, 0.0])
    e = np.stack([np.zeros(5), np.zeros(5), yaw], axis=-1)
    back = rot.dcm_to_euler(rot.euler_to_dcm(e))
    # NOTE: the docstring promises yaw in (-pi, pi], but yaw = -pi comes back as exactly -pi
    # (C[1, 0] = sin(-pi) = -1.2e-16 < 0); same rotation, so only [-pi, pi] is asserted here.
    assert np.all(back[:, 2] >= -PI) and np.all(back[:, 2] <= PI)
    assert angle_err(back[:, 2], yaw).max() < 1e-12


@settings(max_examples=300, deadline=None)
@given(
    roll=st.floats(-PI, PI),
    pitch=st.floats(-PI / 2 + 0.01, PI / 2 - 0.01),
    yaw=st.floats(-PI, PI),
)
def test_property_euler_round_trip(roll, pitch, yaw):
    e = np.array([roll, pitch, yaw])
    C = rot.euler_to_dcm(e)
    assert ortho_err(C) < 1e-14
    assert angle_err(rot.dcm_to_euler(C), e).max() < 1e-12


# ----------------------------------------------------------------------------- ⊕ / ⊖


def test_minus_inverts_plus():
    r = rng(40)
    C = random_dcms(r, (3000,))
    angles = np.concatenate(
        [np.full(500, 1e-9), r.uniform(0, 1e-3, 500), r.uniform(0, 1, 1000), r.uniform(1, PI - 1e-6, 1000)]
    )
    d = rotvecs(r, angles)
    np.testing.assert_allclose(rot.attitude_minus(rot.attitude_plus(C, d), C), d, rtol=0, atol=1e-12)


def test_plus_inverts_minus():
    r = rng(41)
    C1 = random_dcms(r, (3000,))
    C2 = random_dcms(r, (3000,))
    d = rot.attitude_minus(C1, C2)
    np.testing.assert_allclose(rot.attitude_plus(C2, d), C1, rtol=0, atol=1e-12)
    # and for nearby attitudes (the filter's use case)
    C3 = rot.attitude_plus(C1, rotvecs(r, r.uniform(0, 0.05, 3000)))
    np.testing.assert_allclose(rot.attitude_plus(C1, rot.attitude_minus(C3, C1)), C3, rtol=0, atol=1e-14)


def test_plus_is_nav_frame_left_multiplication():
    """⊕ applies exp([d x]) on the NED side: C ⊕ d = exp([d x]) C, not C exp([d x])."""
    C = rot.euler_to_dcm([0.1, 0.2, 1.3])
    d = np.array([0.0, 0.0, 0.25])  # rotation about NED down = pure yaw increment
    out = rot.attitude_plus(C, d)
    np.testing.assert_allclose(out, Rotation.from_rotvec(d).as_matrix() @ C, rtol=0, atol=1e-15)
    e = rot.dcm_to_euler(out)
    np.testing.assert_allclose(e, [0.1, 0.2, 1.55], rtol=0, atol=1e-14)
    assert np.abs(out - C @ Rotation.from_rotvec(d).as_matrix()).max() > 1e-3


def test_minus_is_antisymmetric_and_zero_on_equal():
    r = rng(42)
    C1 = random_dcms(r, (500,))
    C2 = rot.attitude_plus(C1, rotvecs(r, r.uniform(0, 2.0, 500)))
    np.testing.assert_allclose(rot.attitude_minus(C1, C2), -rot.attitude_minus(C2, C1), rtol=0, atol=1e-13)
    np.testing.assert_allclose(rot.attitude_minus(C1, C1), 0.0, rtol=0, atol=1e-15)


def test_small_misalignment_matches_euler_difference_for_level_vehicle():
    """For a level vehicle a small yaw error is the D component of ⊖ (sign check)."""
    ya = 0.5 + 1e-5
    Ca = rot.euler_to_dcm([0.0, 0.0, ya])
    Cb = rot.euler_to_dcm([0.0, 0.0, 0.5])
    # (ya - 0.5 is the exactly representable yaw difference, not 1e-5)
    np.testing.assert_allclose(rot.attitude_minus(Ca, Cb), [0.0, 0.0, ya - 0.5], rtol=0, atol=1e-16)
    Cc = rot.euler_to_dcm([0.0, 1e-6, 0.0])  # small pitch-up of a north-pointing vehicle
    np.testing.assert_allclose(rot.attitude_minus(Cc, np.eye(3)), [0.0, 1e-6, 0.0], rtol=0, atol=1e-18)


@settings(max_examples=200, deadline=None)
@given(
    e1=st.tuples(st.floats(-PI, PI), st.floats(-1.5, 1.5), st.floats(-PI, PI)),
    e2=st.tuples(st.floats(-PI, PI), st.floats(-1.5, 1.5), st.floats(-PI, PI)),
)
def test_property_plus_minus(e1, e2):
    C1 = rot.euler_to_dcm(np.array(e1))
    C2 = rot.euler_to_dcm(np.array(e2))
    d = rot.attitude_minus(C1, C2)
    assert np.linalg.norm(d) <= PI + 1e-12
    np.testing.assert_allclose(rot.attitude_plus(C2, d), C1, rtol=0, atol=1e-12)
    if np.linalg.norm(d) < PI - 1e-6:
        np.testing.assert_allclose(rot.attitude_minus(rot.attitude_plus(C2, d), C2), d, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- batching


def test_batched_shapes_and_elementwise_equality():
    r = rng(50)
    shape = (7, 25)
    phi = rotvecs(r, r.uniform(0, PI - 1e-3, shape))
    phi[0, 0] = 0.0
    phi[1, 1] *= 1e-9 / np.linalg.norm(phi[1, 1])
    phi[2, 2] *= (PI - 1e-6) / np.linalg.norm(phi[2, 2])
    e = random_eulers(r, 175).reshape(shape + (3,))
    C = rot.exp_so3(phi)
    assert C.shape == shape + (3, 3)
    assert rot.log_so3(C).shape == shape + (3,)
    assert rot.skew(phi).shape == shape + (3, 3)
    assert rot.vee(C).shape == shape + (3,)
    E = rot.euler_to_dcm(e)
    assert E.shape == shape + (3, 3)
    assert rot.dcm_to_euler(E).shape == shape + (3,)
    assert rot.attitude_plus(E, phi).shape == shape + (3, 3)
    assert rot.attitude_minus(E, C).shape == shape + (3,)
    assert rot.orthonormalize(C).shape == shape + (3, 3)
    # every batched element equals the single-element call
    L = rot.log_so3(C)
    M = rot.attitude_minus(E, C)
    for i in range(shape[0]):
        for j in range(shape[1]):
            np.testing.assert_array_equal(C[i, j], rot.exp_so3(phi[i, j]))
            np.testing.assert_allclose(L[i, j], rot.log_so3(C[i, j]), rtol=0, atol=1e-15)
            np.testing.assert_array_equal(E[i, j], rot.euler_to_dcm(e[i, j]))
            np.testing.assert_allclose(M[i, j], rot.attitude_minus(E[i, j], C[i, j]), rtol=0, atol=1e-15)


def test_batched_log_mixed_near_pi_and_small():
    """The near-pi branch works on a boolean subset of a multi-dimensional batch."""
    r = rng(51)
    ang = r.uniform(0, PI - 1e-6, (7, 25, 3))
    ang[..., 0] = PI - r.uniform(1e-6, 1e-2, (7, 25))
    ang[..., 1] = r.uniform(0, 1e-8, (7, 25))
    phi = rotvecs(r, ang)
    np.testing.assert_allclose(rot.log_so3(rot.exp_so3(phi)), phi, rtol=0, atol=1e-12)


def test_orthonormalize_restores_rotation():
    r = rng(52)
    C = random_dcms(r, (200,))
    noisy = C + r.normal(scale=1e-6, size=C.shape)
    R = rot.orthonormalize(noisy)
    assert ortho_err(R) < 1e-14
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)
    assert np.abs(R - C).max() < 1e-5
    np.testing.assert_allclose(rot.orthonormalize(C), C, rtol=0, atol=1e-15)


def test_wrap_angle_range_and_single_home() -> None:
    from nespm_cli.nav.rotations import wrap_angle
    from nespm_cli.vehicles import sensors

    assert sensors.wrap_angle is wrap_angle  # re-exported, not re-implemented
    a = np.array([-np.pi, np.pi, 3 * np.pi, -3 * np.pi, 0.0, 7.0, -7.0, 2 * np.pi])
    w = wrap_angle(a)
    assert np.all((w > -np.pi) & (w <= np.pi))
    np.testing.assert_allclose(w[:4], np.pi, rtol=0, atol=1e-15)
    np.testing.assert_allclose(w[4:], [0.0, 7.0 - 2 * np.pi, -7.0 + 2 * np.pi, 0.0], rtol=0, atol=1e-15)

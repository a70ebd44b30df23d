"""Tests of nespm_cli.nav.synthesis: the 100 Hz truth and clean IMU synthesized from 1 Hz GT by
inverse strapdown, on the 13 recorded Snapir tracks, the 6 embedded tracks and synthetic
straight-and-level / stationary vehicles. The real tracks' cases are skipped, with the
reason, when the real data is not found (conftest.REAL_DATA); the rest need nothing but the repo.
"""
from __future__ import annotations

import types

import numpy as np
import pytest

from conftest import REAL_DATA, needs_real_data
from nespm_cli.nav import earth
from nespm_cli.data.embedded import embedded_track
from nespm_cli.errors import NespmError
from nespm_cli.nav.rotations import attitude_minus, euler_to_dcm
from nespm_cli.nav.strapdown import na_cycle
from nespm_cli.nav.synthesis import ImuTruth, integrate_position, synthesize
from nespm_cli.data.tracks import load_track

REAL = [("real", n) for n in range(1, 14)]
EMBEDDED = [("embedded", n) for n in range(1, 7)]
ALL = REAL + EMBEDDED
IDS = [f"{kind}-{n}" for kind, n in ALL]
# the real tracks' cases are skipped (with the reason) when the real data is not found (conftest)
KEYS = [pytest.param(key, id=i, marks=needs_real_data if key[0] == "real" else ()) for key, i in zip(ALL, IDS)]
KINDS = [pytest.param("real", marks=needs_real_data), "embedded"]
SUBSTEPS = 100


@pytest.fixture(scope="module")
def embedded_tracks():
    """The 6 embedded tracks and their synthesized truth/IMU, keyed by (kind, number)."""
    return {key: (tr, synthesize(tr)) for key in EMBEDDED for tr in [embedded_track(key[1])]}


@pytest.fixture(scope="module")
def real_tracks(real_data_dir):
    """The 13 real tracks and their synthesized truth/IMU (skipped without the real data)."""
    return {key: (tr, synthesize(tr)) for key in REAL for tr in [load_track(key[1], real_data_dir)]}


@pytest.fixture
def tracks(request):
    """The (kind, number) -> (track, synthesis) lookup: the embedded tracks, plus the real ones
    when the real data is there (the real cases are skipped otherwise)."""
    out = dict(request.getfixturevalue("embedded_tracks"))
    if REAL_DATA is not None:
        out.update(request.getfixturevalue("real_tracks"))
    return out


@pytest.fixture(scope="module")
def free_inertial(request, embedded_tracks):
    """Free-inertial run of every available track (the 6 embedded, and the 13 real ones when
    the real data is there) in ONE batched na_cycle loop (state stacked on a leading axis of
    19, dt of shape (19,)) from the initial truth with the clean IMU.

    Returns ``{(kind, number): (worst velocity [m/s], worst attitude [rad] error vs GT at every
    GT epoch, (N,) each)}``.
    """
    tracks = dict(embedded_tracks)
    if REAL_DATA is not None:
        tracks.update(request.getfixturevalue("real_tracks"))
    keys = [key for key in ALL if key in tracks]
    items = [tracks[key] for key in keys]
    steps = {s.steps for _, s in items}
    assert len(steps) == 1, f"tracks have different IMU step counts: {steps}"
    M = steps.pop()
    pos = np.stack([s.pos[0] for _, s in items])
    v = np.stack([s.v_n[0] for _, s in items])
    C = np.stack([s.C_bn[0] for _, s in items])
    F = np.stack([s.f_b for _, s in items], axis=1)  # (M, K, 3)
    W = np.stack([s.w_ib_b for _, s in items], axis=1)
    DT = np.stack([s.dt for _, s in items], axis=1)  # (M, K)
    gt_v = np.stack([tr.v_n for tr, _ in items], axis=1)  # (N, K, 3)
    gt_C = euler_to_dcm(np.stack([tr.euler for tr, _ in items], axis=1))
    N = gt_v.shape[0]
    assert M == SUBSTEPS * (N - 1)
    err_v = np.zeros((len(items), N))
    err_a = np.zeros((len(items), N))
    err_v[:, 0] = np.abs(v - gt_v[0]).max(axis=-1)
    err_a[:, 0] = np.abs(attitude_minus(C, gt_C[0])).max(axis=-1)
    for j in range(M):
        pos, v, C = na_cycle(pos, v, C, F[j], W[j], DT[j])
        if (j + 1) % SUBSTEPS == 0:
            k = (j + 1) // SUBSTEPS
            err_v[:, k] = np.abs(v - gt_v[k]).max(axis=-1)
            err_a[:, k] = np.abs(attitude_minus(C, gt_C[k])).max(axis=-1)
    return {key: (err_v[i], err_a[i]) for i, key in enumerate(keys)}


# ----------------------------------------------------------------------------- grid


@pytest.mark.parametrize("key", KEYS)
def test_imu_grid(tracks, key):
    tr, s = tracks[key]
    N = len(tr.t)
    assert isinstance(s, ImuTruth) and s.exact
    assert N == 400
    M = SUBSTEPS * (N - 1)
    assert s.steps == M
    assert s.t.shape == (M + 1,) and s.dt.shape == (M,)
    assert s.pos.shape == (M + 1, 3) and s.v_n.shape == (M + 1, 3) and s.C_bn.shape == (M + 1, 3, 3)
    assert s.f_b.shape == (M, 3) and s.w_ib_b.shape == (M, 3)
    np.testing.assert_array_equal(s.epoch_index, np.arange(N) * SUBSTEPS)
    np.testing.assert_array_equal(s.t[s.epoch_index], tr.t)  # exactly, not approximately
    np.testing.assert_array_equal(s.dt, np.diff(s.t))
    assert np.all(s.dt > 0)
    np.testing.assert_allclose(s.dt, 400.0 / 399.0 / SUBSTEPS, rtol=1e-9)


# ----------------------------------------------------------------------------- truth at GT epochs


@pytest.mark.parametrize("key", KEYS)
def test_truth_passes_through_gt(tracks, key):
    tr, s = tracks[key]
    e = s.epoch_index
    assert np.abs(s.v_n[e] - tr.v_n).max() < 1e-6
    assert np.abs(attitude_minus(s.C_bn[e], euler_to_dcm(tr.euler))).max() < 1e-8
    np.testing.assert_array_equal(s.pos[0], tr.pos[0])
    # every 100 Hz attitude is a rotation matrix
    CtC = np.swapaxes(s.C_bn, -1, -2) @ s.C_bn
    assert np.abs(CtC - np.eye(3)).max() < 1e-13


@pytest.mark.parametrize("key", KEYS)
def test_synthesized_imu_is_plausible(tracks, key):
    """Specific force near 1 g and body rates below 1 rad/s (no spline overshoot blow-ups);
    the measured ranges on these tracks are |f| 8.9-11.8 m/s^2, |w| <= 0.66 rad/s."""
    _, s = tracks[key]
    fn = np.linalg.norm(s.f_b, axis=-1)
    assert np.all(np.isfinite(s.f_b)) and np.all(np.isfinite(s.w_ib_b))
    assert 8.5 < fn.min() and fn.max() < 12.5
    assert np.linalg.norm(s.w_ib_b, axis=-1).max() < 1.0
    # resolved in NED, the specific force averages to -g_D (the mean vertical acceleration
    # over 400 s is |dv_D| / 400 s < 2e-3 m/s^2); track 9 pitches up to 20 deg, so the body
    # z reading alone averages only -9.48 m/s^2
    f_n = (s.C_bn[:-1] @ s.f_b[..., None])[..., 0]
    g_D = earth.gravity_n(s.pos[:-1])[:, 2]
    assert abs(np.mean(f_n[:, 2] + g_D)) < 0.01


@pytest.mark.parametrize("key", KEYS)
def test_integrated_position_vs_gt(tracks, key):
    """Position is integrated from velocity (only pos[0] is used). The embedded tracks are
    built the same way, so they agree to < 1 mm; the recorded GT position and velocity are
    not exactly consistent (measured up to ~18 m after 400 s, track 9), so the bound for
    them only catches gross errors (a missing 1/cos L in longitude would be ~100 m)."""
    kind, _ = key
    tr, s = tracks[key]
    off = earth.ned_offset(s.pos[s.epoch_index], tr.pos)
    if kind == "embedded":
        assert np.abs(off).max() < 1e-3
    else:
        assert np.abs(off[:, :2]).max() < 30.0
        assert np.abs(off[:, 2]).max() < 1.0


def test_embedded_synthesis_close_to_analytic_truth(embedded_tracks):
    """Between GT epochs the splines stay close to the embedded tracks' analytic C-infinity
    kinematics (uses the private embedded._kinematics; measured max errors: v 9e-5 m/s,
    attitude 3.3e-5 rad, body rate 9.4e-5 rad/s)."""
    from nespm_cli.data import embedded

    for n in range(1, 7):
        tr, s = embedded_tracks[("embedded", n)]
        k = embedded._kinematics(embedded._SPECS[n], s.t)
        assert np.abs(s.v_n - k["v_n"]).max() < 5e-4
        assert np.abs(attitude_minus(s.C_bn, euler_to_dcm(k["euler"]))).max() < 2e-4
        # body rate relative to NED, as used by eq 32
        CT = np.swapaxes(s.C_bn[:-1], -1, -2)
        rates = earth.w_ie_n(s.pos[1:]) + earth.w_en_n(s.pos[1:], s.v_n[1:])
        w_nb = s.w_ib_b - (CT @ rates[..., None])[..., 0]
        km = embedded._kinematics(embedded._SPECS[n], 0.5 * (s.t[1:] + s.t[:-1]))
        assert np.abs(w_nb - km["w_b"]).max() < 5e-4


# ----------------------------------------------------------------------------- free inertial


@pytest.mark.parametrize("kind", KINDS)
def test_free_inertial_velocity_tracks_gt(free_inertial, kind):
    """The synthesized IMU drives a free INS onto the GT velocity to 1e-6 m/s on every track (embedded and real)."""
    worst = {f"{k}-{n}": float(ev.max()) for (k, n), (ev, _) in free_inertial.items() if k == kind}
    assert len(worst) == (13 if kind == "real" else 6)
    bad = {name: w for name, w in worst.items() if w >= 1e-6}
    assert not bad, f"velocity error >= 1e-6 m/s: {bad}"


@pytest.mark.parametrize("kind", KINDS)
def test_free_inertial_attitude_tracks_gt(free_inertial, kind):
    worst = {f"{k}-{n}": float(ea.max()) for (k, n), (_, ea) in free_inertial.items() if k == kind}
    assert len(worst) == (13 if kind == "real" else 6)
    bad = {name: w for name, w in worst.items() if w >= 1e-8}
    assert not bad, f"attitude error >= 1e-8 rad: {bad}"


def test_free_inertial_is_sensitive_to_imu(embedded_tracks):
    """Negative control: a 1e-3 m/s^2 accelerometer bias on the same loop gives ~0.1 m/s
    after 100 s, so the 1e-6 m/s tolerance above is meaningful."""
    tr, s = embedded_tracks[("embedded", 1)]
    pos, v, C = s.pos[0], s.v_n[0], s.C_bn[0]
    M = 100 * SUBSTEPS
    for j in range(M):
        pos, v, C = na_cycle(pos, v, C, s.f_b[j] + 1e-3, s.w_ib_b[j], s.dt[j])
    assert np.abs(v - tr.v_n[100]).max() > 0.05


# ----------------------------------------------------------------------------- synthetic vehicles


LAT0 = np.radians(32.8)
DT_GT = 400.0 / 399.0


def synthetic_track(v_n: np.ndarray, euler: np.ndarray, n: int = 400, depth: float = 10.0):
    """Track-like namespace for a vehicle at constant NED velocity and constant attitude."""
    t = np.arange(n) * DT_GT
    v = np.broadcast_to(np.asarray(v_n, float), (n, 3)).copy()
    pos0 = np.array([LAT0, np.radians(34.93), -depth])
    # fine 100 Hz integration for a consistent GT position (only pos[0] is used by synthesize)
    t_fine = np.arange((n - 1) * SUBSTEPS + 1) * (DT_GT / SUBSTEPS)
    v_fine = np.broadcast_to(np.asarray(v_n, float), (len(t_fine), 3))
    pos = integrate_position(pos0, v_fine, np.diff(t_fine))[::SUBSTEPS]
    return types.SimpleNamespace(
        number=99, t=t, pos=pos, v_n=v, euler=np.broadcast_to(np.asarray(euler, float), (n, 3)).copy()
    )


def expected_imu(s: ImuTruth, C: np.ndarray, v: np.ndarray):
    """f_b = C^T(-g^n + (2 w_ie + w_en) x v) at step start, w_ib_b = C^T(w_ie + w_en) with
    the eq 32 (step-end) rates, for constant C and v."""
    p0, p1 = s.pos[:-1], s.pos[1:]
    vv = np.broadcast_to(v, p0.shape)
    f_n = -earth.gravity_n(p0) + np.cross(2.0 * earth.w_ie_n(p0) + earth.w_en_n(p0, vv), vv)
    w_n = earth.w_ie_n(p1) + earth.w_en_n(p1, vv)
    return f_n @ C, w_n @ C  # rows: (C^T x)^T = x^T C


def test_straight_level_constant_velocity():
    v = np.array([1.8, 0.5, 0.0])
    euler = np.array([0.0, 0.0, np.arctan2(0.5, 1.8)])
    C = euler_to_dcm(euler)
    tr = synthetic_track(v, euler)
    s = synthesize(tr)
    f_exp, w_exp = expected_imu(s, C, v)
    # The brief's target is 1e-6; both hold far tighter (spline/rotation-spline round-off only).
    assert np.abs(s.f_b - f_exp).max() < 1e-9
    assert np.abs(s.w_ib_b - w_exp).max() < 1e-12
    # NOTE: f_b is NOT C^T(0, 0, -g): the Coriolis + transport term (2 w_ie + w_en) x v is
    # 1.6e-4 m/s^2 here (2 * 7.29e-5 rad/s * 1.87 m/s * sin(angle(w_ie, v)): NED components
    # (4.0e-5, -1.42e-4, 6.1e-5), i.e. to the right and upward (Eotvos), plus ~1e-6 transport),
    # and the gyros sense the earth rate plus the transport rate, not zero.
    g = earth.gravity_n(s.pos[:-1])
    f_naive = -(g @ C)
    corr = np.linalg.norm(s.f_b - f_naive, axis=-1)
    assert np.all((1.5e-4 < corr) & (corr < 1.7e-4)), (corr.min(), corr.max())
    assert np.abs(s.w_ib_b - earth.w_ie_n(s.pos[1:]) @ C).max() > 1e-7  # transport rate ~3e-7
    # the truth moves at the constant velocity: ~718 m north, ~200 m east in 400 s
    np.testing.assert_allclose(s.v_n, np.broadcast_to(v, s.v_n.shape), rtol=0, atol=1e-12)
    off = earth.ned_offset(s.pos[-1], s.pos[0])
    # (1 cm: ned_offset scales longitude with cos L at the start point, which over 720 m of
    # northing overstates easting by tan L * dL / 2 ~ 3.6e-5 relative, 7 mm)
    np.testing.assert_allclose(off, v * (s.t[-1] - s.t[0]), rtol=0, atol=1e-2)
    assert np.abs(attitude_minus(s.C_bn, C)).max() < 1e-13


def test_straight_level_imu_reproduces_motion():
    """Feeding the synthesized IMU through na_cycle keeps the vehicle at constant velocity."""
    v = np.array([1.8, 0.5, 0.0])
    euler = np.array([0.0, 0.0, np.arctan2(0.5, 1.8)])
    s = synthesize(synthetic_track(v, euler, n=21))
    pos, vv, C = s.pos[0], s.v_n[0], s.C_bn[0]
    for j in range(s.steps):
        pos, vv, C = na_cycle(pos, vv, C, s.f_b[j], s.w_ib_b[j], s.dt[j])
    np.testing.assert_allclose(vv, v, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pos, s.pos[-1], rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "euler", [[0.0, 0.0, np.radians(30.0)], [0.1, -0.05, np.radians(-120.0)]], ids=["level", "tilted"]
)
def test_stationary_vehicle(euler):
    """v = 0: f_b = C^T(-g^n) (g^n has a ~7e-8 m/s^2 north component at 10 m depth) and
    w_ib_b = C^T w_ie^n."""
    euler = np.asarray(euler)
    C = euler_to_dcm(euler)
    tr = synthetic_track(np.zeros(3), euler)
    s = synthesize(tr)
    np.testing.assert_allclose(s.pos, np.broadcast_to(tr.pos[0], s.pos.shape), rtol=0, atol=1e-15)
    g = earth.gravity_n(tr.pos[0])
    f_exp = C.T @ (-g)
    w_exp = C.T @ earth.w_ie_n(tr.pos[0])
    assert np.abs(s.f_b - f_exp).max() < 1e-6
    assert np.abs(s.w_ib_b - w_exp).max() < 1e-12
    if euler[0] == 0.0 and euler[1] == 0.0:
        # level: vertical specific force is exactly -g_D, horizontal only the tiny g_N part
        assert np.abs(s.f_b[:, 2] + g[2]).max() < 1e-9
        assert np.abs(s.f_b[:, :2]).max() < 1e-7
        assert abs(g[2] - 9.7962) < 1e-3  # normal gravity at 32.8 deg, 10 m below the surface


def test_substeps_parameter_and_short_track_rejected():
    tr = synthetic_track(np.array([1.0, 0.0, 0.0]), np.zeros(3), n=10)
    s = synthesize(tr, substeps=10)
    assert s.steps == 90
    np.testing.assert_array_equal(s.epoch_index, np.arange(10) * 10)
    np.testing.assert_array_equal(s.t[s.epoch_index], tr.t)
    short = synthetic_track(np.array([1.0, 0.0, 0.0]), np.zeros(3), n=3)
    with pytest.raises(NespmError, match="at least 4"):
        synthesize(short)

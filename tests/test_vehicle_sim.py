"""Tests of the closed-loop REMUS 100 helix simulator (nespm_cli.vehicles: sensors, guidance,
simulate) and its A-KIT track export (gp-ukf.md section 6).

Durations are short (<= 200 s of simulated time) to keep the file well under a minute.
"""
from __future__ import annotations

import numpy as np
import pytest

from nespm_cli.nav.earth import ned_offset
from nespm_cli.nav.rotations import attitude_minus
from nespm_cli.nav.strapdown import na_cycle
from nespm_cli.nav.synthesis import from_recorded
from nespm_cli.data.tracks import load_track
from nespm_cli.vehicles import MEASUREMENT_NAMES, SensorSuite, simulate_runs, to_track, write_tracks
from nespm_cli.vehicles.guidance import Helix
from nespm_cli.nav.rotations import wrap_angle
from nespm_cli.vehicles.sensors import measure, quantize, true_measurement
from nespm_cli.vehicles.simulate import LAT0, LON0

SETTLE = 100.0  # [s] settling time before the path-following bounds apply
CROSS_BOUND = 0.5  # [m] horizontal cross-track bound after SETTLE (measured max 0.22 m over 800 s)
VERTICAL_BOUND = 0.3  # [m] depth error bound after SETTLE (measured max 0.02 m over 800 s)


@pytest.fixture(scope="module")
def helix_runs():
    """Two runs of 200 s (seed 11)."""
    return simulate_runs(2, 200.0, seed=11)


@pytest.fixture(scope="module")
def short_runs():
    """Three runs of 20 s (seed 5) for the batch / seed tests."""
    return simulate_runs(3, 20.0, seed=5)


# ----------------------------------------------------------------------------- shapes and rates


def test_result_layout(helix_runs):
    """The simulator's outputs have their documented shapes, rates and wrapping (two 200 s helix runs)."""
    r = helix_runs
    N = 200 * 5 + 1  # 5 Hz output
    assert r.t.shape == (N,) and r.t[1] == pytest.approx(0.2) and r.t[-1] == pytest.approx(200.0)
    assert r.x.shape == (2, N, 12) and r.u.shape == (2, N, 3) and r.z.shape == (2, N, 10)
    assert r.path_error.shape == (2, N, 3) and r.nav.shape == (2, N, 3)
    assert r.t_fine.shape == (20001,) and r.x_fine.shape == (2, 20001, 12)
    np.testing.assert_array_equal(r.x_fine[:, ::20], r.x)  # output samples are integration samples
    assert np.all(np.abs(r.x[..., 10]) <= np.pi)  # psi wrapped
    assert len(MEASUREMENT_NAMES) == 10
    with pytest.raises(ValueError):
        simulate_runs(1, 10.0, integration_hz=100.0, control_hz=30.0)
    with pytest.raises(ValueError):
        simulate_runs(1, 10.05)


# ----------------------------------------------------------------------------- path following


def test_helix_is_followed(helix_runs):
    """After SETTLE s the true position stays within CROSS_BOUND m across and VERTICAL_BOUND m
    in depth of the guidance point, at the commanded 1.4 m/s, descending along the helix."""
    r = helix_runs
    late = r.t >= SETTLE
    e = r.path_error[:, late]
    assert np.abs(e[..., 1]).max() < CROSS_BOUND
    assert np.abs(e[..., 2]).max() < VERTICAL_BOUND
    assert np.abs(e[..., 0]).max() < 1.0  # the point P keeps pace (along-track)
    u = r.x[:, late, 0]
    assert np.abs(u - 1.4).max() < 0.05
    # horizontal distance from the helix axis ~ radius, depth follows the descent
    rho = np.hypot(r.x[:, late, 6], r.x[:, late, 7])
    assert np.abs(rho - r.helix.radius).max() < CROSS_BOUND
    assert np.all(r.x[:, -1, 8] > r.x[:, np.argmax(late), 8] + 0.5)
    # it started off the path and accelerated from 0.5 m/s
    assert r.x[0, 0, 0] == pytest.approx(0.5)
    assert np.abs(r.path_error[0, 0]).max() > 0.9


def test_controller_uses_the_corrupted_signals(helix_runs):
    """Commands respect the limits, and the dead-reckoned position (from the noisy DVL /
    attitude) stays close to, but is not, the truth."""
    r, p = helix_runs, helix_runs.params
    assert np.all((r.u[..., 0] >= p.rpm_min) & (r.u[..., 0] <= p.rpm_max))
    assert np.all(np.abs(r.u[..., 1:]) <= p.fin_max)
    d = np.abs(r.nav - r.x[..., 6:9])
    assert d.max() < 2.0 and d[:, 1:, :2].min() >= 0.0 and d[:, -1, :2].max() > 1e-4


# ----------------------------------------------------------------------------- sensors


def test_quantizer():
    lo, hi = np.array([-1.0]), np.array([1.0])
    lsb = 2.0 / 4095
    q = quantize(np.linspace(-2, 2, 100001)[:, None], lo, hi, 12)
    levels = np.unique(q)
    assert len(levels) == 4096 and levels[0] == -1.0 and levels[-1] == pytest.approx(1.0)
    assert np.abs(np.diff(levels) - lsb).max() < 1e-12
    x = np.linspace(-0.999, 0.999, 1001)[:, None]
    assert np.abs(quantize(x, lo, hi, 12) - x).max() <= lsb / 2 + 1e-15


def test_measurements_are_noisy_quantised_states(helix_runs):
    """z = Q(h(x) + sigma xi): on the 12-bit grid, and z - h(x) has about the channel's std."""
    r = helix_runs
    suite = SensorSuite()
    z, h = r.z.reshape(-1, 10), true_measurement(r.x.reshape(-1, 12))
    k = (z - suite.lo) / suite.lsb
    assert np.abs(k - np.rint(k)).max() < 1e-6  # on the ADC grid
    d = z - h
    d[:, 8] = wrap_angle(d[:, 8])
    ratio = d.std(axis=0) / np.sqrt(suite.sigma**2 + suite.lsb**2 / 12)
    assert np.all((ratio > 0.9) & (ratio < 1.1)), ratio
    assert np.abs(d.mean(axis=0)).max() < 4 * (suite.sigma / np.sqrt(len(d)) + suite.lsb).max()


def test_noiseless_suite_only_quantises():
    x = np.zeros((5, 12))
    x[:, 0] = np.linspace(0.3, 1.6, 5)
    x[:, 10] = np.linspace(-3.5, 3.5, 5)  # unwrapped yaw is wrapped by the compass
    s = SensorSuite().noiseless()
    z = measure(x, np.ones((5, 10)), s)
    assert np.abs(z - true_measurement(x)).max() <= s.lsb.max() / 2 + 1e-12


# ----------------------------------------------------------------------------- randomness


def test_batch_invariance(short_runs):
    """Run r of a batch equals run r simulated alone (to 1e-12; in fact bitwise)."""
    alone = simulate_runs(0, 20.0, seed=5, runs=[2])
    for f in ("x", "u", "z", "path_error", "x_fine"):
        assert np.abs(getattr(short_runs, f)[2] - getattr(alone, f)[0]).max() <= 1e-12, f


def test_reproducible_with_seed(short_runs):
    again = simulate_runs(3, 20.0, seed=5)
    for f in ("x", "u", "z", "x_fine"):
        np.testing.assert_array_equal(getattr(short_runs, f), getattr(again, f))
    other = simulate_runs(1, 20.0, seed=6)
    assert np.abs(other.z[0] - short_runs.z[0]).max() > 1e-3  # another seed, other noise
    assert np.abs(short_runs.z[0] - short_runs.z[1]).max() > 1e-3  # runs are independent


# ----------------------------------------------------------------------------- A-KIT export


def free_ins(track):
    """Free-inertial na_cycle with the track's recorded IMU from the first GT epoch; returns the
    worst velocity [m/s], attitude [rad] and horizontal position [m] error at the GT epochs."""
    it = from_recorded(track)
    e = it.epoch_index
    pos, v, C = it.pos[e[0]], it.v_n[e[0]], it.C_bn[e[0]]
    ev = ea = ep = 0.0
    k = 1
    for j in range(it.steps):
        pos, v, C = na_cycle(pos, v, C, it.f_b[j], it.w_ib_b[j], it.dt[j])
        if k < len(e) and j + 1 == e[k]:
            ev = max(ev, np.abs(v - track.v_n[k]).max())
            ea = max(ea, np.abs(attitude_minus(C, track.C_bn[k])).max())
            ep = max(ep, np.abs(ned_offset(pos, track.pos[k])).max())
            k += 1
    assert k == len(e)
    return ev, ea, ep


def test_written_tracks_load_and_round_trip(tmp_path):
    """write_tracks -> load_track validates; the 100 Hz IMU drives na_cycle back onto the GT:
    free-INS velocity error < 1e-6 m/s (measured ~1e-12) over the whole track."""
    res = simulate_runs(2, 40.0, seed=2)
    folders = write_tracks(res, tmp_path, first_number=4)
    assert [f.name for f in folders] == ["Trajectory4", "Trajectory5"]
    for i, n in enumerate((4, 5)):
        tr = load_track(n, tmp_path)
        assert tr.imu is not None and tr.imu.shape == (40 * 100 + 1, 7)
        np.testing.assert_allclose(np.diff(tr.t), 1.0)  # 1 Hz GT and DVL
        np.testing.assert_allclose(np.diff(tr.imu[:, 0]), 0.01, atol=1e-12)  # 100 Hz IMU
        np.testing.assert_array_equal(tr.imu[::100, 0], tr.t)  # GT epochs are IMU samples
        ev, ea, ep = free_ins(tr)
        assert ev < 1e-6 and ea < 1e-8 and ep < 1e-3
        # the track is the simulated run: NED offsets from the origin match the simulator
        # position to mm, depth = -altitude, the DVL is the run's measured DVL
        off = ned_offset(tr.pos, np.array([LAT0, LON0, 0.0]))
        np.testing.assert_allclose(off, res.x[i, ::5, 6:9], atol=5e-3)
        np.testing.assert_array_equal(tr.dvl, res.z[i, ::5, 0:3])
        np.testing.assert_allclose(tr.euler[:, 1], res.x[i, ::5, 9])
        # specific force ~ gravity, small body rates
        f = np.linalg.norm(tr.imu[:, 1:4], axis=1)
        assert np.all((f > 9.0) & (f < 10.6)) and np.abs(tr.imu[:, 4:7]).max() < 1.0


def test_to_track_options_and_errors():
    res = simulate_runs(1, 5.0, seed=1)
    tr = to_track(res, 0, 9, dvl="true")
    np.testing.assert_array_equal(tr.dvl, res.x[0, ::5, 0:3])
    assert tr.number == 9 and tr.t[-1] == 5.0
    with pytest.raises(ValueError):
        to_track(res, 0, 9, dvl="bogus")
    with pytest.raises(ValueError):
        to_track(simulate_runs(1, 5.0, keep_fine=False), 0, 1)
    with pytest.raises(ValueError):
        to_track(simulate_runs(1, 2.0), 0, 1)  # fewer than 4 GT epochs


def test_helix_geometry():
    h = Helix(radius=50.0, center=(10.0, -5.0), z_start=3.0, descent_per_rad=1.0, direction=-1)
    p = h.point(np.array([0.0, -np.pi / 2]))
    np.testing.assert_allclose(p, [[60.0, -5.0, 3.0], [10.0, -55.0, 3.0 + np.pi / 2]], atol=1e-12)
    assert h.course(0.0) == pytest.approx(-np.pi / 2)  # counter-clockwise at the north point: west
    e = h.errors(np.array([[61.0, -6.0, 4.0]]), 0.0)[0]  # 1 m ahead (west), 1 m right (outside), 1 m below
    np.testing.assert_allclose(e, [1.0, 1.0, 1.0], atol=1e-12)

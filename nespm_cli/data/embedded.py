"""Deterministic Snapir-like tracks used when no data folder is given (tracks 1-6).

Each track is 400 s long, on the real A-KIT epochs ``t = k * 400/399 s`` (k = 0..399, so
400 epochs from 0 to 400 s, like the recorded files), with 1 Hz GT and DVL and no IMU.

The tracks are built from C-infinity analytic profiles (sums of ``tanh`` smooth steps):

* horizontal speed ``U(t)`` [m/s] and depth ``d(t)`` [m] as smooth steps,
* course rate ``r(t)`` [rad/s] as smooth rectangular pulses (the turns), course
  ``chi = chi0 + int r`` in closed form,
* ``v_n = [U cos chi, U sin chi, d']`` (so the depth is exactly the integral of V Down),
* yaw ``= chi - beta`` with a small sideslip ``beta = beta0 + K_BETA r``, pitch ``= gamma + ALPHA``
  with the flight-path angle ``gamma = atan2(-d', U)``, roll ``= K_ROLL r`` (bank in turns),
* body rate ``w_nb^b`` from the analytic Euler-angle rates,
* latitude / longitude integrated from ``v_n`` with the WGS-84 radii on a 100-samples-per-epoch
  grid (trapezoid), altitude ``= -d``,
* DVL ``= C_bn^T v_n + w_nb^b x L_DVL + N(0, DVL_NOISE^2)`` from ``default_rng(1000 + number)``.

Tracks 1 and 2 have many turns, 3 and 4 long straight legs, 5 and 6 a mix. Everything is
computed in memory (or read back from the per-user cache, :mod:`.embedded_cache`, the same bits), cached,
and returned as read-only arrays (same arrays on every call).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from nespm_cli.data import embedded_cache
from nespm_cli.nav.dvl import dvl_velocity
from nespm_cli.nav.earth import lat_rate, lon_rate, radii
from nespm_cli.errors import NespmError
from nespm_cli.nav.rotations import euler_to_dcm, wrap_angle
from nespm_cli.data.track import Track

EMBEDDED_TRACKS = (1, 2, 3, 4, 5, 6)
N_EPOCHS = 400  # as in the recorded files: 0 .. 400 s
DT = 400.0 / 399.0  # [s] epoch step of the recorded files
SUBSTEPS = 100  # position integration sub-steps per epoch (~100 Hz)
L_DVL = np.array([-1.6, 0.0, 0.0])  # [m] DVL lever arm in body axes (aft of the INS)
DVL_NOISE = 0.02  # [m/s] white DVL noise std per axis
K_BETA = 0.2  # [s] sideslip per course rate
K_ROLL = 0.3  # [s] bank angle per course rate (15 deg/s -> 4.5 deg)
ALPHA = np.radians(0.5)  # [rad] constant angle of attack
LAT0 = np.radians(32.84)  # [rad] off Haifa
LON0 = np.radians(34.93)  # [rad]
TURN_TAU = 3.0  # [s] edge time constant of the turn pulses


@dataclass(frozen=True)
class _Steps:
    """``f(t) = base + sum_j a_j s((t - c_j) / tau_j)`` with ``s(x) = (1 + tanh x) / 2``."""

    base: float
    steps: tuple[tuple[float, float, float], ...]  # (a_j, c_j [s], tau_j [s])

    def value(self, t: np.ndarray) -> np.ndarray:
        out = np.full_like(t, self.base)
        for a, c, tau in self.steps:
            out += 0.5 * a * (1.0 + np.tanh((t - c) / tau))
        return out

    def d1(self, t: np.ndarray) -> np.ndarray:
        out = np.zeros_like(t)
        for a, c, tau in self.steps:
            out += 0.5 * a / tau / np.cosh((t - c) / tau) ** 2
        return out

    def d2(self, t: np.ndarray) -> np.ndarray:
        out = np.zeros_like(t)
        for a, c, tau in self.steps:
            x = (t - c) / tau
            out -= a / tau**2 * np.tanh(x) / np.cosh(x) ** 2
        return out

    def integral(self, t: np.ndarray) -> np.ndarray:
        """``int_0^t f(u) du``."""

        def prim(x: np.ndarray | float) -> np.ndarray:  # int s dx = (x + log cosh x) / 2
            return 0.5 * (x + np.logaddexp(x, -x) - np.log(2.0))

        out = self.base * t
        for a, c, tau in self.steps:
            out = out + a * tau * (prim((t - c) / tau) - prim(-c / tau))
        return out


def _turns(turns: tuple[tuple[float, float, float], ...]) -> _Steps:
    """Course-rate profile [rad/s] from turns ``(start s, end s, rate deg/s)``."""
    steps: list[tuple[float, float, float]] = []
    for t0, t1, rate in turns:
        r = np.radians(rate)
        steps += [(r, t0, TURN_TAU), (-r, t1, TURN_TAU)]
    return _Steps(0.0, tuple(steps))


@dataclass(frozen=True)
class _Spec:
    heading0: float  # [deg] initial course
    beta0: float  # [deg] constant sideslip (crab)
    speed: _Steps  # horizontal speed [m/s]
    depth: _Steps  # depth [m], positive down
    turns: tuple[tuple[float, float, float], ...]  # (start s, end s, course rate deg/s)


_SPECS: dict[int, _Spec] = {
    # 1, 2: many manoeuvres
    1: _Spec(40.0, 1.0, _Steps(1.9, ((-0.25, 60, 6), (0.35, 200, 10), (-0.2, 330, 8))),
             _Steps(10.0, ((12.0, 90, 22), (-6.0, 250, 15))),
             ((30, 42, 14), (75, 88, -13), (120, 132, 14.5), (170, 178, -12), (215, 229, 13),
              (265, 272, -14), (310, 322, 12), (355, 368, -13))),
    2: _Spec(-120.0, -0.8, _Steps(2.1, ((-0.4, 140, 10), (0.3, 300, 8))),
             _Steps(30.0, ((-10.0, 120, 18), (4.0, 300, 10))),
             ((20, 34, -12), (60, 70, 14), (100, 118, 13), (150, 160, -14.5), (190, 204, 12),
              (240, 250, -14), (280, 300, 10), (340, 352, -13))),
    # 3, 4: long straight legs
    3: _Spec(10.0, 0.5, _Steps(2.0, ((-0.3, 180, 15),)),
             _Steps(15.0, ((10.0, 60, 20),)),
             ((140, 152, 14), (320, 333, -13))),
    4: _Spec(170.0, -1.2, _Steps(1.7, ((0.45, 80, 12),)),
             _Steps(28.0, ((5.0, 150, 15), (-8.0, 320, 20))),
             ((120, 131, -14), (260, 274, 12))),
    # 5, 6: mixed
    5: _Spec(-30.0, 0.7, _Steps(1.8, ((0.3, 50, 8), (-0.4, 220, 10))),
             _Steps(6.0, ((4.0, 100, 10), (3.0, 280, 10))),
             ((70, 80, 12), (95, 105, -12), (180, 193, 14), (290, 300, -11), (330, 336, 9))),
    6: _Spec(95.0, -0.5, _Steps(2.05, ((-0.35, 120, 8), (0.2, 260, 10))),
             _Steps(18.0, ((-10.0, 60, 17), (12.0, 230, 20))),
             ((40, 55, -10), (150, 162, 14), (200, 214, -13), (350, 358, 8))),
}


def _speed_course(spec: _Spec, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal speed ``U`` [m/s] and course ``chi`` [rad] at times ``t`` (K,) [s]: all that the
    position needs on the fine grid (:func:`_integrate_position`), without the attitude and rates."""
    return spec.speed.value(t), np.radians(spec.heading0) + _turns(spec.turns).integral(t)


def _kinematics(spec: _Spec, t: np.ndarray) -> dict[str, np.ndarray]:
    """Velocity, attitude and body rate at times ``t`` (K,) [s] from the analytic profiles."""
    rate = _turns(spec.turns)
    U, chi = _speed_course(spec, t)
    dU = spec.speed.d1(t)
    dd, ddd = spec.depth.d1(t), spec.depth.d2(t)
    r, dr = rate.value(t), rate.d1(t)
    v_n = np.stack([U * np.cos(chi), U * np.sin(chi), dd], axis=-1)

    gamma = np.arctan2(-dd, U)
    dgamma = (-U * ddd + dd * dU) / (U * U + dd * dd)
    roll, droll = K_ROLL * r, K_ROLL * dr
    pitch, dpitch = gamma + ALPHA, dgamma
    yaw, dyaw = chi - np.radians(spec.beta0) - K_BETA * r, r - K_BETA * dr
    sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    w_b = np.stack(
        [droll - dyaw * sp, dpitch * cr + dyaw * sr * cp, -dpitch * sr + dyaw * cr * cp], axis=-1
    )
    euler = np.stack([roll, pitch, yaw], axis=-1)
    return {"v_n": v_n, "euler": euler, "w_b": w_b, "depth": spec.depth.value(t)}


def _integrate_position(number: int, t: np.ndarray, spec: _Spec) -> np.ndarray:
    """``[lat, lon, alt]`` (K, 3) on the fine grid ``t`` by trapezoid integration of v_n.

    Same rates as the navigation cycle (:func:`earth.lat_rate`, :func:`earth.lon_rate`, eqs
    29-30) but a different scheme from :func:`synthesis.integrate_position`, on purpose: this
    is the *truth generator*, so it integrates the exact ODE (radii at each sample, the plain
    trapezoid ``cumtrapz`` of the rate) rather than the filter's eq 29 reading (R_N at L_k
    for both terms), and the altitude is the analytic ``-depth`` rather than integrated.
    Changing it would change every embedded track.
    """
    U, chi = _speed_course(spec, t)
    vN, vE = U * np.cos(chi), U * np.sin(chi)
    h = -spec.depth.value(t)
    dt = np.diff(t)
    lat0 = LAT0 + np.radians(0.004) * (number - 1)
    lon0 = LON0 - np.radians(0.005) * (number - 1)

    def cumtrapz(y: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * dt)])

    lat = np.full_like(t, lat0)
    for _ in range(3):  # fixed point on R_N(lat): converges to ~1e-15 rad in 2-3 passes
        R_N, R_E = radii(lat)
        lat = lat0 + cumtrapz(lat_rate(vN, h, R_N))
    R_N, R_E = radii(lat)
    lon = lon0 + cumtrapz(lon_rate(vE, lat, h, R_E))
    return np.stack([lat, lon, h], axis=-1)


@lru_cache(maxsize=None)
def embedded_track(number: int) -> Track:
    """Embedded track ``number`` (1-6): 400 epochs, step 400/399 s, ``source="embedded"``.

    Deterministic and cached: every call returns the same :class:`Track` (read-only arrays).
    Raises :class:`NespmError` for any other number.
    """
    if number not in _SPECS:
        raise NespmError(
            f"embedded tracks: no track {number} (available: {', '.join(map(str, EMBEDDED_TRACKS))}; "
            "use --data-dir or NESPM_DATA_DIR for recorded tracks)"
        )
    a = embedded_cache.load(number)
    if a is None:
        a = build_arrays(number)
        embedded_cache.save(number, a)
    return Track(number=number, t=a["t"], pos=a["pos"], v_n=a["v_n"], euler=a["euler"], dvl=a["dvl"], imu=None,
                 source="embedded")


def build_arrays(number: int) -> dict[str, np.ndarray]:
    """Track ``number``'s arrays computed from its profiles: ``t`` (400,) [s], ``pos`` (400, 3) [rad,
    rad, m], ``v_n`` (400, 3) [m/s], ``euler`` (400, 3) [rad], ``dvl`` (400, 3) [m/s, body]
    (:func:`embedded_track` reads them from the per-user cache when a process before built them)."""
    spec = _SPECS[number]
    t_fine = np.arange((N_EPOCHS - 1) * SUBSTEPS + 1) * (DT / SUBSTEPS)
    pos = _integrate_position(number, t_fine, spec)[::SUBSTEPS]
    t = np.arange(N_EPOCHS) * DT
    k = _kinematics(spec, t)
    C_bn = euler_to_dcm(k["euler"])
    rng = np.random.default_rng(1000 + number)
    dvl = dvl_velocity(C_bn, k["v_n"], k["w_b"], L_DVL) + rng.normal(0.0, DVL_NOISE, size=(N_EPOCHS, 3))
    euler = k["euler"].copy()
    euler[:, 2] = wrap_angle(euler[:, 2])
    return {"t": t, "pos": pos, "v_n": k["v_n"], "euler": euler, "dvl": dvl}

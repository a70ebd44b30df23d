"""Helix path following: line-of-sight guidance and PID autopilots (gp-ukf.md section 6).

The paper: "A path-following controller (Xiang et al., 2017) composed of a line-of-sight (LOS)
law that pursues a point P(t) and three robust PID controllers, produces the signals for RPM,
elevator [...] and rudder [...]. The controllers employ the corrupted measurement".

Here (all batched over runs, arrays (R,)):

* **Path** -- :class:`Helix`: a circle of radius R about ``center`` in the horizontal plane whose
  depth grows linearly with the travelled angle. ``varpi`` is the polar angle of the path point
  P seen from the centre (0 = north, pi/2 = east).
* **Point P(t)** -- the path parameter is propagated (the Lyapunov-based along-track law of
  Breivik & Fossen's path following; Fossen 2011 ch. 10) so that P runs ahead of / behind the
  vehicle as the along-track error demands:
  ``ds/dt = U_h cos(chi_r) + k_along x_e``, ``dvarpi/dt = direction * (ds/dt) / R``.
* **LOS** -- errors of the vehicle position in the path-tangential frame at P
  (``x_e`` along, ``y_e`` cross, positive to the right, ``z_e`` vertical, positive below);
  desired course ``chi_d = chi_p + atan(-y_e / Delta_h)`` and desired pitch
  ``theta_d = -gamma_p + atan((z_e + k_iz int z_e) / Delta_v)`` (vertical LOS with integral
  action, which removes the depth offset of the buoyancy trim).
* **Speed PID (RPM)** -- ``n = n_ff(U_d) + kp_u e_u + ki_u int e_u``, ``e_u = U_d - u_meas``,
  with the feed-forward ``n_ff`` of the steady thrust/drag balance.
* **Heading PID (rudder)** -- ``delta_r = -(kp e_psi + ki int e_psi + kd (r_ff - r_meas))``,
  ``e_psi = wrap(chi_d - beta_meas - psi_meas)`` with the side-slip ``beta = atan2(v, u)`` from
  the DVL and the path yaw-rate feed-forward ``r_ff = direction * U_h / R``. (N_uudr < 0: a
  positive rudder yaws to port.)
* **Depth PID (stern plane)** -- cascade: the vertical LOS above is the depth P and I part, the
  inner pitch loop ``delta_s = kp_theta (theta_meas - theta_d) + kd_theta q_meas`` the damping
  (D) part. (M_uuds < 0: a positive stern plane pitches nose down.)

Position is not in the measured vector, so the controller dead-reckons its own horizontal
position from the measured DVL velocity rotated by the measured attitude (trapezoid at the
control rate) and takes the depth from the depth sensor.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nespm_cli.vehicles.remus100 import IDR, IDS, IRPM, Remus100Params
from nespm_cli.nav.rotations import wrap_angle

# measured-vector indices (sensors.MEASUREMENT_NAMES)
_MU, _MV, _MW, _MP, _MQ, _MR, _MZ, _MTH, _MPSI, _MPHI = range(10)


@dataclass(frozen=True)
class Helix:
    """A helix about a vertical axis, descending as it is followed.

    Attributes:
        radius: horizontal radius [m] (60 m: the GP-UKF authors' public simulator,
            github ArizaWilmerUTAS/Path-Following, SimulatorFileRemusPID.m).
        center: (north, east) of the axis [m].
        z_start: depth of the start point [m].
        descent_per_rad: depth gained per radian travelled [m/rad]; 1.2/pi (2.4 m per turn) is
            the authors' helix (depth rate 0.006 m/s at pi/200 rad/s).
        phase_start: polar angle of the start point from the centre [rad] (0 = north).
        direction: +1 clockwise seen from above (starboard turns), -1 counter-clockwise.
        speed: desired speed U_d [m/s] (1.4 m/s: "accelerated from 0.5 m/s to 1.4 m/s").
    """

    radius: float = 60.0
    center: tuple[float, float] = (0.0, 0.0)
    z_start: float = 5.0
    descent_per_rad: float = 1.2 / np.pi
    phase_start: float = 0.0
    direction: int = 1
    speed: float = 1.4

    def __post_init__(self) -> None:
        if self.direction not in (1, -1):
            raise ValueError("Helix.direction must be +1 or -1")
        if self.radius <= 0:
            raise ValueError("Helix.radius must be positive")

    @property
    def dive_angle(self) -> float:
        """Path flight-path angle gamma_p [rad], positive descending: atan(descent_per_rad / R)."""
        return float(np.arctan2(self.descent_per_rad, self.radius))

    def point(self, varpi: np.ndarray) -> np.ndarray:
        """P(varpi) (..., 3) [north, east, depth] in m."""
        varpi = np.asarray(varpi, dtype=float)
        travelled = self.direction * (varpi - self.phase_start)
        return np.stack(
            [
                self.center[0] + self.radius * np.cos(varpi),
                self.center[1] + self.radius * np.sin(varpi),
                self.z_start + self.descent_per_rad * travelled,
            ],
            axis=-1,
        )

    def course(self, varpi: np.ndarray) -> np.ndarray:
        """Path course chi_p (...,) [rad] at P(varpi): ``varpi + direction * pi/2``, wrapped."""
        return wrap_angle(np.asarray(varpi, dtype=float) + self.direction * np.pi / 2)

    def errors(self, pos: np.ndarray, varpi: np.ndarray) -> np.ndarray:
        """Path-frame errors (..., 3) ``[x_e along, y_e cross (right +), z_e vertical (below +)]``
        of NED positions ``pos`` (..., 3) relative to P(varpi) [m]."""
        d = np.asarray(pos, dtype=float) - self.point(varpi)
        chi = np.asarray(varpi, dtype=float) + self.direction * np.pi / 2
        c, s = np.cos(chi), np.sin(chi)
        return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], axis=-1)

    def angle_of(self, pos: np.ndarray) -> np.ndarray:
        """Polar angle (...,) [rad] of NED positions about the axis (the nearest path angle mod 2 pi)."""
        pos = np.asarray(pos, dtype=float)
        return np.arctan2(pos[..., 1] - self.center[1], pos[..., 0] - self.center[0])


@dataclass(frozen=True)
class GuidanceGains:
    """LOS and PID gains (documented choices, tuned on the default helix; docs/remus100.md).

    Units: lookaheads [m]; k_along [1/s]; kp_u [rpm/(m/s)], ki_u [rpm/m]; kp_psi [rad/rad],
    ki_psi [1/s], kd_psi [s]; k_iz [1/s]; kp_theta [rad/rad], kd_theta [s].
    """

    lookahead_h: float = 10.0
    lookahead_v: float = 10.0
    k_along: float = 0.5
    kp_u: float = 500.0
    ki_u: float = 50.0
    int_u_max: float = 400.0  # [rpm] bound on ki_u * int e_u (anti-windup)
    kp_psi: float = 1.0
    ki_psi: float = 0.02
    kd_psi: float = 2.0
    int_psi_max: float = 0.1  # [rad] bound on ki_psi * int e_psi
    k_iz: float = 0.05
    int_z_max: float = 3.0  # [m] bound on k_iz * int z_e
    kp_theta: float = 2.0
    kd_theta: float = 2.0


@dataclass
class GuidanceState:
    """Per-run controller memory (arrays (R,) or (R, 3)); mutated by :func:`control_step`.

    Attributes:
        varpi: path parameter of P [rad].
        nav: dead-reckoned position [north, east, depth] (R, 3) [m].
        v_prev: last measured NED velocity (R, 3) [m/s] (for the trapezoid).
        int_u, int_psi, int_z: integrator states [m, rad s, m s].
    """

    varpi: np.ndarray
    nav: np.ndarray
    v_prev: np.ndarray | None
    int_u: np.ndarray
    int_psi: np.ndarray
    int_z: np.ndarray

    @classmethod
    def start(cls, helix: Helix, pos0: np.ndarray) -> "GuidanceState":
        """Initial memory for vehicles at NED positions ``pos0`` (R, 3) (known at launch)."""
        pos0 = np.array(pos0, dtype=float)
        R = pos0.shape[0]
        return cls(
            varpi=np.asarray(helix.angle_of(pos0), dtype=float),
            nav=pos0.copy(),
            v_prev=None,
            int_u=np.zeros(R),
            int_psi=np.zeros(R),
            int_z=np.zeros(R),
        )


def measured_ned_velocity(z: np.ndarray) -> np.ndarray:
    """NED velocity (R, 3) from the measured DVL velocity and attitude in ``z`` (R, 10)."""
    u, v, w = z[:, _MU], z[:, _MV], z[:, _MW]
    th, ps, ph = z[:, _MTH], z[:, _MPSI], z[:, _MPHI]
    st, ct, ss, cs, sp, cp = np.sin(th), np.cos(th), np.sin(ps), np.cos(ps), np.sin(ph), np.cos(ph)
    vn = cs * ct * u + (cs * st * sp - ss * cp) * v + (ss * sp + cs * cp * st) * w
    ve = ss * ct * u + (cp * cs + sp * st * ss) * v + (st * ss * cp - cs * sp) * w
    vd = -st * u + ct * sp * v + ct * cp * w
    return np.stack([vn, ve, vd], axis=-1)


def _integrate(integral, error, dt, ki, bound, output, lo, hi):
    """Integrator update with conditional integration (anti-windup) and a hard bound.

    The step ``integral + dt * error`` is taken unless the output it gives is saturated
    (outside ``[lo, hi]``) and the error drives it further out; ``|ki * integral| <= bound``.
    ``output(i)`` is the controller output as an increasing function of the integral.
    """
    if ki <= 0:
        return integral
    cand = np.clip(integral + dt * error, -bound / ki, bound / ki)
    y = output(cand)
    ok = ((y < hi) | (error < 0)) & ((y > lo) | (error > 0))
    return np.where(ok, cand, integral)


def control_step(
    state: GuidanceState,
    z: np.ndarray,
    dt: float,
    helix: Helix,
    gains: GuidanceGains,
    params: Remus100Params,
) -> np.ndarray:
    """One control cycle from the measurements ``z`` (R, 10); returns commands (R, 3).

    Commands ``[rpm, delta_s, delta_r]`` are saturated to the actuator limits; ``state`` is
    advanced in place (dead reckoning, path parameter, integrators). ``dt`` is the control
    period [s]; the first call (``state.v_prev is None``) does not move the dead reckoning.
    """
    g = gains
    v_now = measured_ned_velocity(z)
    if state.v_prev is not None:
        state.nav[:, :2] += (0.5 * dt) * (state.v_prev[:, :2] + v_now[:, :2])
    state.v_prev = v_now
    state.nav[:, 2] = z[:, _MZ]

    u_m, v_m = z[:, _MU], z[:, _MV]
    U_h = np.hypot(u_m, v_m)
    # LOS errors at P(varpi) from the dead-reckoned position
    e = helix.errors(state.nav, state.varpi)
    x_e, y_e, z_e = e[:, 0], e[:, 1], e[:, 2]
    chi_r = np.arctan(-y_e / g.lookahead_h)
    chi_d = helix.course(state.varpi) + chi_r
    # vertical LOS with integral action (the depth loop's P and I)
    if g.k_iz > 0:
        bound = g.int_z_max / g.k_iz
        state.int_z = np.clip(state.int_z + dt * z_e, -bound, bound)
    theta_d = -helix.dive_angle + np.arctan((z_e + g.k_iz * state.int_z) / g.lookahead_v)
    # propagate P (along-track law)
    state.varpi = state.varpi + dt * helix.direction * (U_h * np.cos(chi_r) + g.k_along * x_e) / helix.radius

    # speed PID -> rpm
    U_d = helix.speed
    e_u = U_d - u_m
    n_ff = np.sqrt(-params.Xuu / params.k_thrust) * U_d
    state.int_u = _integrate(state.int_u, e_u, dt, g.ki_u, g.int_u_max,
                             lambda i: n_ff + g.kp_u * e_u + g.ki_u * i, params.rpm_min, params.rpm_max)
    rpm = n_ff + g.kp_u * e_u + g.ki_u * state.int_u

    # heading PID -> rudder
    beta = np.arctan2(v_m, u_m)
    e_psi = wrap_angle(chi_d - beta - z[:, _MPSI])
    r_ff = helix.direction * U_h / helix.radius
    rudder = lambda i: -(g.kp_psi * e_psi + g.ki_psi * i + g.kd_psi * (r_ff - z[:, _MR]))  # noqa: E731
    # the rudder output decreases with the integral: integrate the negated error against -limits
    state.int_psi = _integrate(state.int_psi, e_psi, dt, g.ki_psi, g.int_psi_max,
                               lambda i: -rudder(i), -params.fin_max, params.fin_max)
    delta_r = rudder(state.int_psi)

    # depth cascade inner loop -> stern plane
    delta_s = g.kp_theta * (z[:, _MTH] - theta_d) + g.kd_theta * z[:, _MQ]

    cmd = np.empty((z.shape[0], 3))
    cmd[:, IRPM] = np.clip(rpm, params.rpm_min, params.rpm_max)
    cmd[:, IDS] = np.clip(delta_s, -params.fin_max, params.fin_max)
    cmd[:, IDR] = np.clip(delta_r, -params.fin_max, params.fin_max)
    return cmd

"""WGS-84 earth model: radii of curvature, normal gravity, earth and transport rates, position rates.

Positions are ``pos = [lat, lon, h]`` (..., 3) with latitude and longitude in rad and
``h`` the ellipsoidal height in m, positive up (below the sea surface it is negative).
Every function is batched over leading axes. Sines and cosines of latitude are :func:`.trig.sin_cos`'s
(the compiled kernels' own, bit for bit). Formulas follow Groves, *Principles of
GNSS, Inertial, and Multisensor Integrated Navigation Systems*, 2nd ed., ch. 2 and 5.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.nav.trig import sin_cos

A = 6378137.0  # semi-major axis [m]
F = 1.0 / 298.257223563  # flattening
E2 = F * (2.0 - F)  # first eccentricity squared
B = A * (1.0 - F)  # semi-minor axis [m]
OMEGA_IE = 7.292115e-5  # earth rotation rate [rad/s]
MU = 3.986004418e14  # gravitational constant [m^3/s^2]
GAMMA_E = 9.7803253359  # normal gravity at the equator [m/s^2]
K_SOMIGLIANA = 1.93185265241e-3  # Somigliana constant (WGS-84)


def radii(lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Meridian ``R_N`` and transverse ``R_E`` radii of curvature [m] at latitude ``lat`` [rad].

    Groves eqs 2.105-2.106. (The papers call them R_n and R_e.)
    """
    return radii_of_sin(sin_cos(lat)[0])


def radii_of_sin(sl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`radii` from ``sl`` = sin L (of :func:`.trig.sin_cos`, for a caller that has it)."""
    s2 = sl ** 2
    den = 1.0 - E2 * s2
    R_N = A * (1.0 - E2) / (den * np.sqrt(den))  # den^1.5; sqrt is correctly rounded everywhere, pow is not
    R_E = A / np.sqrt(den)
    return R_N, R_E


def gravity_n(pos: np.ndarray) -> np.ndarray:
    """Gravity vector g^n [m/s^2] in NED (..., 3) at ``pos`` (..., 3).

    Somigliana normal gravity with the second-order height correction and the small
    north component (Groves eqs 2.134 and 2.140).
    """
    lat, h = pos[..., 0], pos[..., 2]
    sl, cl = sin_cos(lat)
    s2 = sl ** 2
    g0 = GAMMA_E * (1.0 + K_SOMIGLIANA * s2) / np.sqrt(1.0 - E2 * s2)
    m = OMEGA_IE**2 * A**2 * B / MU
    g_down = g0 * (1.0 - 2.0 / A * (1.0 + F + m - 2.0 * F * s2) * h + 3.0 * h * h / A**2)
    g_north = -8.08e-9 * h * (2.0 * sl * cl)  # sin 2L
    return np.stack([g_north, np.zeros_like(g_down), g_down], axis=-1)


def gravity_down_gradient(pos: np.ndarray) -> np.ndarray:
    """``∂g_D/∂D`` [1/s²] (...,) of :func:`gravity_n` at ``pos`` (..., 3): the vertical gravity
    gradient, about +2g/R = 3.1e-6 s⁻² (gravity grows downwards; D = −h). Exact for the model above."""
    lat, h = pos[..., 0], pos[..., 2]
    s2 = sin_cos(lat)[0] ** 2
    g0 = GAMMA_E * (1.0 + K_SOMIGLIANA * s2) / np.sqrt(1.0 - E2 * s2)
    m = OMEGA_IE**2 * A**2 * B / MU
    return g0 * (2.0 / A * (1.0 + F + m - 2.0 * F * s2) - 6.0 * h / A**2)


def transport_rates(
    lat: np.ndarray, h: np.ndarray, v_n: np.ndarray, R_N: np.ndarray, R_E: np.ndarray,
    sc: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Earth rate ``w_ie^n`` and transport rate ``w_en^n`` [rad/s] (..., 3) in NED.

    The one implementation used by the navigation cycle (ukf-nespm.md eqs 25, 26 and 32)
    and the filters. ``lat``, ``h`` (...,) [rad, m], ``v_n`` (..., 3) [m/s] and the radii
    ``R_N``, ``R_E`` (...,) [m] precomputed by :func:`radii` (callers reuse them).

    * ``w_ie^n = Omega [cos L, 0, -sin L]`` (Groves eq 5.41);
    * ``w_en^n = [v_E/(R_E+h), -v_N/(R_N+h), -v_E tan L/(R_E+h)]`` (Groves eq 5.44), with
      ``tan L`` evaluated as ``sin L / cos L``.

    Both outputs have the broadcast batch shape of ``lat`` and ``v_n``. ``sc``: ``sin_cos(lat)`` if the
    caller has it.
    """
    sl, cl = sin_cos(lat) if sc is None else sc
    zero = np.zeros_like(lat * v_n[..., 0])
    w_ie = np.stack([OMEGA_IE * cl + zero, zero, -OMEGA_IE * sl + zero], axis=-1)
    vN, vE = v_n[..., 0], v_n[..., 1]
    w_en = np.stack([vE / (R_E + h), -vN / (R_N + h), -vE * sl / cl / (R_E + h)], axis=-1)
    return w_ie, w_en


def w_ie_n(pos: np.ndarray) -> np.ndarray:
    """Earth rate w_ie^n [rad/s] in NED (..., 3): ``Omega [cos L, 0, -sin L]`` (see :func:`transport_rates`)."""
    lat = pos[..., 0]
    return transport_rates(lat, pos[..., 2], np.zeros(lat.shape + (3,)), *radii(lat))[0]


def w_en_n(pos: np.ndarray, v_n: np.ndarray) -> np.ndarray:
    """Transport rate w_en^n [rad/s] in NED (..., 3) for velocity ``v_n`` (..., 3) [m/s].

    Groves eq 5.44 (see :func:`transport_rates`).
    """
    lat = pos[..., 0]
    return transport_rates(lat, pos[..., 2], v_n, *radii(lat))[1]


# ---------------------------------------------------------------- position rates, eqs 28-30
# The right-hand sides of ukf-nespm.md eqs 28-30, shared by every position integrator
# (strapdown.update_position, synthesis.integrate_position, data.embedded). The integrators
# differ only in which radii they pass (see their docstrings) and in the trapezoid layout.


def height_rate(v_D: np.ndarray) -> np.ndarray:
    """``dh/dt = -v_D`` [m/s] (eq 28; ``h`` positive up)."""
    return -v_D


def lat_rate(v_N: np.ndarray, h: np.ndarray, R_N: np.ndarray) -> np.ndarray:
    """``dL/dt = v_N / (R_N + h)`` [rad/s] (eq 29)."""
    return v_N / (R_N + h)


def lon_rate(v_E: np.ndarray, lat: np.ndarray, h: np.ndarray, R_E: np.ndarray) -> np.ndarray:
    """``dlambda/dt = v_E / ((R_E + h) cos L)`` [rad/s] (eq 30 with the 1/cos L it omits; Groves eq 5.56)."""
    return v_E / ((R_E + h) * sin_cos(lat)[1])


def d_w_en_d_v(pos: np.ndarray) -> np.ndarray:
    """Jacobian ∂w_en^n/∂v^n (..., 3, 3) [1/m] at ``pos`` (w_en is linear in v)."""
    lat, h = pos[..., 0], pos[..., 2]
    R_N, R_E = radii(lat)
    J = np.zeros(lat.shape + (3, 3))
    J[..., 0, 1] = 1.0 / (R_E + h)
    J[..., 1, 0] = -1.0 / (R_N + h)
    J[..., 2, 1] = -np.tan(lat) / (R_E + h)
    return J


def ned_offset(pos: np.ndarray, pos0: np.ndarray) -> np.ndarray:
    """Local NED offset [m] (..., 3) of ``pos`` from ``pos0`` (small-distance approximation)."""
    R_N, R_E = radii(pos0[..., 0])
    dN = (pos[..., 0] - pos0[..., 0]) * (R_N + pos0[..., 2])
    dE = (pos[..., 1] - pos0[..., 1]) * (R_E + pos0[..., 2]) * sin_cos(pos0[..., 0])[1]
    dD = -(pos[..., 2] - pos0[..., 2])
    return np.stack([dN, dE, dD], axis=-1)

"""The strapdown navigation cycle of ukf-nespm.md eqs 24-32 (``na_cycle``) and its inverse.

A navigation state is the triple ``(pos, v_n, C_bn)``:

* ``pos``  (..., 3)    ``[lat, lon, h]`` [rad, rad, m], ``h`` positive up;
* ``v_n``  (..., 3)    velocity relative to earth in NED [m/s];
* ``C_bn`` (..., 3, 3) body-to-NED DCM.

Every function is batched over any leading shape (MC runs x sigma points, ...); the IMU
inputs broadcast against it. ``na_cycle_inverse`` solves the same equations for the
specific force and angular rate that take one state to the next, which is how the clean
100 Hz IMU is synthesized from ground truth (see ``synthesis.py``).
"""
from __future__ import annotations

import numpy as np

from nespm_cli.nav.earth import gravity_n, height_rate, lat_rate, lon_rate, radii, transport_rates
from nespm_cli.nav.products import mat_mul, mat_vec, matT_vec
from nespm_cli.nav.rotations import exp_so3, log_so3


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched cross product ``a x b`` of (..., 3) arrays (faster than np.cross for small batches)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def update_position(
    pos: np.ndarray, v_n: np.ndarray, v_n_next: np.ndarray, dt: float | np.ndarray
) -> np.ndarray:
    """One step of eqs 28-30 (trapezoid in the position rates) -> ``pos`` at k+1 (..., 3).

    The rates are :func:`earth.height_rate`, :func:`earth.lat_rate`, :func:`earth.lon_rate`
    (shared with :func:`synthesis.integrate_position`, which is this same recursion solved
    over a whole grid at once). Eq 29 uses the meridian radius at L_k for both terms
    (L_{k+1} is not known yet); eq 30 is printed without the 1/cos L factor: we use the
    correct form ``dlon/dt = v_E / ((R_E + h) cos L)`` (Groves eq 5.56). Longitude does not
    feed back into velocity or attitude, so this choice has no effect on VRMSE/MRMSE.
    """
    lat, lon, h = pos[..., 0], pos[..., 1], pos[..., 2]
    R_N, R_E = radii(lat)
    half = 0.5 * np.asarray(dt)
    h1 = h + (height_rate(v_n_next[..., 2]) + height_rate(v_n[..., 2])) * half  # eq 28
    lat1 = lat + (lat_rate(v_n[..., 0], h, R_N) + lat_rate(v_n_next[..., 0], h1, R_N)) * half  # eq 29
    _, R_E1 = radii(lat1)
    lon1 = lon + (
        lon_rate(v_n[..., 1], lat, h, R_E) + lon_rate(v_n_next[..., 1], lat1, h1, R_E1)
    ) * half  # eq 30 (with cos L)
    return np.stack([lat1, lon1, h1], axis=-1)


def na_cycle(
    pos: np.ndarray,
    v_n: np.ndarray,
    C_bn: np.ndarray,
    f_b: np.ndarray,
    w_ib_b: np.ndarray,
    dt: float | np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One navigation algorithm cycle, ukf-nespm.md eqs 24-32, batched.

    Args:
        pos: (..., 3) ``[lat, lon, h]`` at step k [rad, rad, m].
        v_n: (..., 3) NED velocity at step k [m/s].
        C_bn: (..., 3, 3) body-to-NED DCM at step k.
        f_b: (..., 3) specific force f_ib^b sensed during step k+1 [m/s^2] (broadcasts).
        w_ib_b: (..., 3) angular rate w_ib^b sensed during step k+1 [rad/s] (broadcasts).
        dt: cycle duration [s] (scalar or broadcasting array).

    Returns:
        ``(pos, v_n, C_bn)`` at step k+1, same shapes.
    """
    dt = np.asarray(dt, dtype=float)
    lat, h = pos[..., 0], pos[..., 2]
    R_N, R_E = radii(lat)
    w_ie, w_en = transport_rates(lat, h, v_n, R_N, R_E)
    # eq 25: intermediate body rate relative to NED, with the step-k transport/earth rates
    w_nb_star = w_ib_b - matT_vec(C_bn, w_ie + w_en)
    # eq 24: mid-step attitude used to resolve the specific force
    C_star = mat_mul(C_bn, exp_so3(w_nb_star * (0.5 * dt)[..., None]))
    # eq 26-27: velocity
    v_dot = mat_vec(C_star, f_b) + gravity_n(pos) - cross(w_en + 2.0 * w_ie, v_n)
    v_next = v_n + v_dot * dt[..., None]
    # eqs 28-30: position
    pos_next = update_position(pos, v_n, v_next, dt)
    # eq 32: body rate relative to NED with the updated position and velocity
    R_N1, R_E1 = radii(pos_next[..., 0])
    w_ie1, w_en1 = transport_rates(pos_next[..., 0], pos_next[..., 2], v_next, R_N1, R_E1)
    w_nb = w_ib_b - matT_vec(C_bn, w_ie1 + w_en1)
    # eq 31: attitude
    C_next = mat_mul(C_bn, exp_so3(w_nb * dt[..., None]))
    return pos_next, v_next, C_next


def na_cycle_inverse(
    pos: np.ndarray,
    v_n: np.ndarray,
    C_bn: np.ndarray,
    pos_next: np.ndarray,
    v_n_next: np.ndarray,
    C_bn_next: np.ndarray,
    dt: float | np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Specific force and angular rate that take step k to step k+1 through ``na_cycle``.

    Inverts eqs 31-32 for ``w_ib_b`` and eqs 24-27 for ``f_b``. ``pos_next`` must be the
    eq 28-30 update of ``pos`` with ``v_n, v_n_next`` (see :func:`update_position`),
    otherwise the round trip is only as exact as that position.

    Returns:
        ``(f_b, w_ib_b)``, each (..., 3) [m/s^2], [rad/s].
    """
    dt = np.asarray(dt, dtype=float)
    # eq 31 inverted: w_nb = log(C_k^T C_{k+1}) / dt
    w_nb = log_so3(np.swapaxes(C_bn, -1, -2) @ C_bn_next) / dt[..., None]
    R_N1, R_E1 = radii(pos_next[..., 0])
    w_ie1, w_en1 = transport_rates(pos_next[..., 0], pos_next[..., 2], v_n_next, R_N1, R_E1)
    w_ib_b = w_nb + matT_vec(C_bn, w_ie1 + w_en1)  # eq 32 inverted
    R_N, R_E = radii(pos[..., 0])
    w_ie, w_en = transport_rates(pos[..., 0], pos[..., 2], v_n, R_N, R_E)
    w_nb_star = w_ib_b - matT_vec(C_bn, w_ie + w_en)  # eq 25
    C_star = mat_mul(C_bn, exp_so3(w_nb_star * (0.5 * dt)[..., None]))  # eq 24
    v_dot = (v_n_next - v_n) / dt[..., None]  # eq 27 inverted
    f_n = v_dot - gravity_n(pos) + cross(w_en + 2.0 * w_ie, v_n)  # eq 26 inverted
    f_b = matT_vec(C_star, f_n)
    return f_b, w_ib_b

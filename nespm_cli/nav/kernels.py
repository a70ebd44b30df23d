"""Compiled (numba, ``nopython``) twins of the navigation cycle, one state at a time.

The NumPy functions of :mod:`.earth`, :mod:`.rotations` and :mod:`.strapdown` are the
reference; the functions here compute the same formulas, in the same order and with the
same branches, on the scalars of one state, so a compiled loop over runs, sigma points and
IMU steps agrees with the reference to round-off (tests/test_kernels.py: 1e-9 on whole
filter runs, in practice ~1e-13). Each compiled function is cached on disk
(``cache=True``: next to this file in ``__pycache__``, or in ``NUMBA_CACHE_DIR``), so a
machine compiles once.

Why numba: it compiles this plain-Python arithmetic to machine code without a second
language or a build step, it is maintained on PyPI with wheels for every platform NumPy has,
and its on-disk cache makes the compile a one-time cost. Without numba the filters run
the NumPy reference (:func:`available` is False).

Shapes: ``pos`` (3,) ``[lat, lon, h]`` [rad, rad, m]; ``v`` (3,) NED [m/s]; ``C`` (3, 3)
body-to-NED; IMU ``f`` (3,) [m/s²], ``w`` (3,) [rad/s]; ``dt`` [s]. Output arrays are
written in place (``*_out``) so the loops allocate nothing.
"""
from __future__ import annotations

import math

import numpy as np

from nespm_cli.nav.earth import A, B, E2, F, GAMMA_E, K_SOMIGLIANA, MU, OMEGA_IE

try:  # numba is a dependency; without it the NumPy reference runs (available() is False)
    import numba
    from numba import njit
except ImportError:  # pragma: no cover - exercised only where numba is not installed
    numba = None

    def njit(*args, **kwargs):
        if args and callable(args[0]):
            return args[0]
        return lambda f: f

SERIES2 = 1e-4  # rotations._SERIES2: squared angle below which the exp series is used
GRAV_M = OMEGA_IE**2 * A**2 * B / MU  # gravity_n's m


def available() -> bool:
    """Whether numba is installed (the compiled loop can run)."""
    return numba is not None


@njit(cache=True, error_model="numpy", inline="always")
def exp_so3_s(p0, p1, p2, E):
    """``exp([p x])`` into ``E`` (3, 3) (rotations.exp_so3: series below 0.01 rad, Rodrigues above)."""
    th2 = p0 * p0 + p1 * p1 + p2 * p2
    if th2 >= SERIES2:
        th = math.sqrt(th2)
        a = math.sin(th) / th
        b = (1.0 - math.cos(th)) / (th * th)
    else:  # also for NaN, as the reference
        a = 1.0 - th2 / 6.0 * (1.0 - th2 / 20.0 * (1.0 - th2 / 42.0))
        b = 0.5 - th2 / 24.0 * (1.0 - th2 / 30.0 * (1.0 - th2 / 56.0))
    d = 1.0 - b * th2
    E[0, 0] = b * (p0 * p0) + d
    E[0, 1] = -(p2 * a) + b * (p0 * p1)
    E[0, 2] = p1 * a + b * (p0 * p2)
    E[1, 0] = p2 * a + b * (p1 * p0)
    E[1, 1] = b * (p1 * p1) + d
    E[1, 2] = -(p0 * a) + b * (p1 * p2)
    E[2, 0] = -(p1 * a) + b * (p2 * p0)
    E[2, 1] = p0 * a + b * (p2 * p1)
    E[2, 2] = b * (p2 * p2) + d


@njit(cache=True, error_model="numpy", inline="always")
def matmul3(X, Y, out):
    """``out = X @ Y`` for (3, 3) matrices (``out`` distinct from both)."""
    for i in range(3):
        for k in range(3):
            out[i, k] = X[i, 0] * Y[0, k] + X[i, 1] * Y[1, k] + X[i, 2] * Y[2, k]


#: layout of the earth cache of one state (:func:`earth_s`): sin L, cos L, R_N, R_E, w_ie^n, w_en^n
N_EARTH = 10


@njit(cache=True, error_model="numpy", inline="always")
def earth_s(lat, h, v, e):
    """Fill the earth cache ``e`` (10,) of a state: ``[sin L, cos L, R_N, R_E, w_ie (3), w_en (3)]``.

    The navigation cycle ends by evaluating these at the new state (eq 32), which is where the
    next cycle starts (eq 25): :func:`na_cycle_s` hands them on instead of computing them twice
    (the reference evaluates them twice, with the same inputs, so to the same bits).
    """
    sl, cl = math.sin(lat), math.cos(lat)
    den = 1.0 - E2 * (sl * sl)
    R_N = A * (1.0 - E2) / (den * math.sqrt(den))
    R_E = A / math.sqrt(den)
    e[0], e[1], e[2], e[3] = sl, cl, R_N, R_E
    e[4] = OMEGA_IE * cl
    e[5] = 0.0
    e[6] = -OMEGA_IE * sl
    e[7] = v[1] / (R_E + h)
    e[8] = -v[0] / (R_N + h)
    e[9] = -v[1] * sl / cl / (R_E + h)


@njit(cache=True, error_model="numpy", inline="always")
def exp_mul_s(C, p0, p1, p2, out):
    """``out = C @ exp([p x])`` (3, 3) (eqs 24 and 31); ``out`` may alias nothing."""
    th2 = p0 * p0 + p1 * p1 + p2 * p2
    if th2 >= SERIES2:
        th = math.sqrt(th2)
        a = math.sin(th) / th
        b = (1.0 - math.cos(th)) / (th * th)
    else:  # also for NaN, as the reference
        a = 1.0 - th2 / 6.0 * (1.0 - th2 / 20.0 * (1.0 - th2 / 42.0))
        b = 0.5 - th2 / 24.0 * (1.0 - th2 / 30.0 * (1.0 - th2 / 56.0))
    d = 1.0 - b * th2
    e00 = b * (p0 * p0) + d
    e01 = -(p2 * a) + b * (p0 * p1)
    e02 = p1 * a + b * (p0 * p2)
    e10 = p2 * a + b * (p1 * p0)
    e11 = b * (p1 * p1) + d
    e12 = -(p0 * a) + b * (p1 * p2)
    e20 = -(p1 * a) + b * (p2 * p0)
    e21 = p0 * a + b * (p2 * p1)
    e22 = b * (p2 * p2) + d
    for i in range(3):
        x0, x1, x2 = C[i, 0], C[i, 1], C[i, 2]
        out[i, 0] = (x0 * e00 + x1 * e10) + x2 * e20
        out[i, 1] = (x0 * e01 + x1 * e11) + x2 * e21
        out[i, 2] = (x0 * e02 + x1 * e12) + x2 * e22


@njit(cache=True, error_model="numpy", inline="always")
def na_cycle_s(pos, v, C, f, w, dt, e, pos_out, v_out, C_out):
    """One navigation cycle, ukf-nespm.md eqs 24-32 (strapdown.na_cycle), for one state.

    ``e`` is the state's earth cache (:func:`earth_s`) on entry and the new state's on exit.
    ``C_out`` is used as scratch for C* before eq 31; the outputs may not alias the inputs.
    """
    lat, lon, h = pos[0], pos[1], pos[2]
    sl, cl, R_N, R_E = e[0], e[1], e[2], e[3]
    u0, u1, u2 = e[4] + e[7], e[5] + e[8], e[6] + e[9]
    half = 0.5 * dt
    # eq 25: w_nb* = w_ib - C^T (w_ie + w_en); eq 24: C* = C exp(w_nb* dt/2)
    p0 = (w[0] - ((C[0, 0] * u0 + C[1, 0] * u1) + C[2, 0] * u2)) * half
    p1 = (w[1] - ((C[0, 1] * u0 + C[1, 1] * u1) + C[2, 1] * u2)) * half
    p2 = (w[2] - ((C[0, 2] * u0 + C[1, 2] * u1) + C[2, 2] * u2)) * half
    Cs = C_out
    exp_mul_s(C, p0, p1, p2, Cs)
    # gravity (earth.gravity_n)
    s2 = sl * sl
    g0 = GAMMA_E * (1.0 + K_SOMIGLIANA * s2) / math.sqrt(1.0 - E2 * s2)
    gN = -8.08e-9 * h * math.sin(2.0 * lat)
    gD = g0 * (1.0 - 2.0 / A * (1.0 + F + GRAV_M - 2.0 * F * s2) * h + 3.0 * h * h / A**2)
    # eqs 26-27: v_dot = C* f + g - (w_en + 2 w_ie) x v
    a0, a1, a2 = e[7] + 2.0 * e[4], e[8] + 2.0 * e[5], e[9] + 2.0 * e[6]
    v0, v1, v2 = v[0], v[1], v[2]
    f0, f1, f2 = f[0], f[1], f[2]
    vd0 = (((Cs[0, 0] * f0 + Cs[0, 1] * f1) + Cs[0, 2] * f2) + gN) - (a1 * v2 - a2 * v1)
    vd1 = (((Cs[1, 0] * f0 + Cs[1, 1] * f1) + Cs[1, 2] * f2) + 0.0) - (a2 * v0 - a0 * v2)
    vd2 = (((Cs[2, 0] * f0 + Cs[2, 1] * f1) + Cs[2, 2] * f2) + gD) - (a0 * v1 - a1 * v0)
    n0, n1, n2 = v0 + vd0 * dt, v1 + vd1 * dt, v2 + vd2 * dt
    v_out[0], v_out[1], v_out[2] = n0, n1, n2
    # eqs 28-30: position (strapdown.update_position)
    h1 = h + (-n2 + -v2) * half
    lat1 = lat + (v0 / (R_N + h) + n0 / (R_N + h1)) * half
    earth_s(lat1, h1, v_out, e)
    lon1 = lon + (v1 / ((R_E + h) * cl) + n1 / ((e[3] + h1) * e[1])) * half
    pos_out[0], pos_out[1], pos_out[2] = lat1, lon1, h1
    # eq 32: w_nb with the updated position and velocity; eq 31: C_{k+1} = C exp(w_nb dt)
    u0, u1, u2 = e[4] + e[7], e[5] + e[8], e[6] + e[9]
    p0 = (w[0] - ((C[0, 0] * u0 + C[1, 0] * u1) + C[2, 0] * u2)) * dt
    p1 = (w[1] - ((C[0, 1] * u0 + C[1, 1] * u1) + C[2, 1] * u2)) * dt
    p2 = (w[2] - ((C[0, 2] * u0 + C[1, 2] * u1) + C[2, 2] * u2)) * dt
    exp_mul_s(C, p0, p1, p2, C_out)


@njit(cache=True, error_model="numpy")
def na_cycle_batch(pos, v, C, f, w, dt, pos_out, v_out, C_out):
    """:func:`na_cycle_s` over a flat batch: ``pos``, ``v``, ``f``, ``w`` (B, 3), ``C`` (B, 3, 3), ``dt`` (B,)."""
    e = np.empty(N_EARTH)
    for b in range(pos.shape[0]):
        earth_s(pos[b, 0], pos[b, 2], v[b], e)
        na_cycle_s(pos[b], v[b], C[b], f[b], w[b], dt[b], e, pos_out[b], v_out[b], C_out[b])


@njit(cache=True, error_model="numpy")
def strapdown_span(pos, v, C, b_a, b_g, f, w, dt, j0, j1):
    """Free-inertial steps ``[j0, j1)`` of R runs in place: ``pos``, ``v``, ``b_a``, ``b_g`` (R, 3),
    ``C`` (R, 3, 3); IMU ``f``, ``w`` (R, M, 3) compensated by the run's biases; ``dt`` (M,)."""
    e = np.empty(N_EARTH)
    fc, wc = np.empty(3), np.empty(3)
    p1, v1, C1 = np.empty(3), np.empty(3), np.empty((3, 3))
    for r in range(pos.shape[0]):
        earth_s(pos[r, 0], pos[r, 2], v[r], e)
        for j in range(j0, j1):
            for i in range(3):
                fc[i] = f[r, j, i] - b_a[r, i]
                wc[i] = w[r, j, i] - b_g[r, i]
            na_cycle_s(pos[r], v[r], C[r], fc, wc, dt[j], e, p1, v1, C1)
            pos[r, :] = p1
            v[r, :] = v1
            C[r, :, :] = C1


def na_cycle_compiled(pos: np.ndarray, v_n: np.ndarray, C_bn: np.ndarray, f_b: np.ndarray,
                      w_ib_b: np.ndarray, dt) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`nespm_cli.nav.strapdown.na_cycle` through the compiled kernel (same shapes, broadcast)."""
    batch = np.broadcast_shapes(pos.shape[:-1], v_n.shape[:-1], C_bn.shape[:-2], f_b.shape[:-1],
                                w_ib_b.shape[:-1], np.shape(dt))
    flat = lambda a, tail: np.ascontiguousarray(np.broadcast_to(a, batch + tail), dtype=float).reshape((-1,) + tail)  # noqa: E731
    p, v, C = flat(pos, (3,)), flat(v_n, (3,)), flat(C_bn, (3, 3))
    outs = np.empty_like(p), np.empty_like(v), np.empty_like(C)
    na_cycle_batch(p, v, C, flat(f_b, (3,)), flat(w_ib_b, (3,)), flat(np.asarray(dt, float), ()), *outs)
    return outs[0].reshape(batch + (3,)), outs[1].reshape(batch + (3,)), outs[2].reshape(batch + (3, 3))

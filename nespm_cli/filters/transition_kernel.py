"""Compiled loops over one time-update span (numba; called through :mod:`.kernels`).

``transition_span`` is ``ErrorStateFilter.transition`` (model.system_matrix + na_cycle per
IMU step) and ``points_span`` the sigma/cubature-point propagation of ukf-nespm.md eqs 35-38,
one run (and point) at a time, the loops over runs and points innermost in machine code.
Shapes as in :mod:`.kernels`; the error state is ``[dv, dpsi, b_a, b_g]`` (model.py).

Φ = Π (I + F dt): F has non-zero rows only for dv and dpsi, so Φ keeps its bias rows
[0 I]; only its top six rows are carried, ``Φ_top ← (I + F dt)_top Φ`` with the bias columns
of F entering through the identity rows (the same sums as the dense product, without the
zeros).
"""
from __future__ import annotations

import math

import numpy as np

from nespm_cli.nav.kernels import cycle_t, exp_t, gravity_t, load_t, matrix_t, mul_t, njit, state_t, store_t


@njit(cache=True, error_model="numpy", inline="always")
def identity_plus_dt(M, dt):
    """``M ← I + M dt`` in place for the top six rows (6, 12) of F."""
    for i in range(6):
        for k in range(12):
            M[i, k] *= dt
        M[i, i] += 1.0


@njit(cache=True, error_model="numpy", inline="always")
def system_top_s(x, f0, f1, f2, M, dt):
    """Rows 0-5 of ``I + F dt`` into ``M`` (6, 12): F of model.system_matrix (Groves 14.2.4).

    dv'   = (-[(2 w_ie + w_en) x] + [v x] J) dv - [f_n x] dpsi - C b_a
    dpsi' = -J dv - [w_in x] dpsi - C b_g        (J = d w_en / d v)
    """
    lat, h = x[0], x[2]
    R_N, R_E = x[17], x[18]
    J01 = 1.0 / (R_E + h)
    J10 = -1.0 / (R_N + h)
    J21 = -math.tan(lat) / (R_E + h)
    for i in range(6):
        for k in range(12):
            M[i, k] = 0.0
    # -skew(2 w_ie + w_en)
    u0, u1, u2 = 2.0 * x[19] + x[22], 2.0 * x[20] + x[23], 2.0 * x[21] + x[24]
    a01, a02, a12 = u2, -u1, u0  # -skew(u): [0, u2, -u1; -u2, 0, u0; u1, -u0, 0]
    # [v x] J with J = [[0, J01, 0], [J10, 0, 0], [0, J21, 0]]
    v0, v1, v2 = x[3], x[4], x[5]
    # skew(v) = [[0, -v2, v1], [v2, 0, -v0], [-v1, v0, 0]]
    s00 = -v2 * J10
    s01 = v1 * J21
    s10 = 0.0
    s11 = v2 * J01 + -v0 * J21
    s20 = v0 * J10
    s21 = -v1 * J01
    M[0, 0] = s00
    M[0, 1] = a01 + s01
    M[0, 2] = a02
    M[1, 0] = -a01 + s10
    M[1, 1] = s11
    M[1, 2] = a12
    M[2, 0] = -a02 + s20
    M[2, 1] = -a12 + s21
    M[2, 2] = 0.0
    # -[f_n x], f_n = C f
    fn0 = x[6] * f0 + x[7] * f1 + x[8] * f2
    fn1 = x[9] * f0 + x[10] * f1 + x[11] * f2
    fn2 = x[12] * f0 + x[13] * f1 + x[14] * f2
    M[0, 4], M[0, 5] = fn2, -fn1
    M[1, 3], M[1, 5] = -fn2, fn0
    M[2, 3], M[2, 4] = fn1, -fn0
    # -J
    M[3, 1] = -J01
    M[4, 0] = -J10
    M[5, 1] = -J21
    # -skew(w_ie + w_en)
    u0, u1, u2 = x[19] + x[22], x[20] + x[23], x[21] + x[24]
    M[3, 4], M[3, 5] = u2, -u1
    M[4, 3], M[4, 5] = -u2, u0
    M[5, 3], M[5, 4] = u1, -u0
    # -C into the bias columns
    for i in range(3):
        for k in range(3):
            M[i, 6 + k] = -x[6 + 3 * i + k]
            M[3 + i, 9 + k] = -x[6 + 3 * i + k]
    identity_plus_dt(M, dt)


@njit(cache=True, error_model="numpy", inline="always")
def invariant_top_s(x, M, dt, S):
    """Rows 0-5 of ``I + F_inv dt`` into ``M`` (6, 12): F_inv of model.invariant_system_matrix.

    ρ̇ = −[(2ω_ie + ω_en)×] ρ + ([g×] + [v×][ω_ie×]) φ − C b_a − [v×] C b_g
    φ̇ = −J ρ + (J [v×] − [ω_in×]) φ − C b_g.      ``S`` (5, 3, 3) scratch.
    """
    lat, h = x[0], x[2]
    R_N, R_E = x[17], x[18]
    gN, gD = gravity_t(lat, h, x[15])
    V, W, J, T = S[0], S[1], S[2], S[3]
    skew_s(x[3], x[4], x[5], V)
    skew_s(x[19], x[20], x[21], W)
    C = S[4]
    for i in range(3):
        for k in range(3):
            C[i, k] = x[6 + 3 * i + k]
    for i in range(3):
        for k in range(3):
            J[i, k] = 0.0
    J[0, 1] = 1.0 / (R_E + h)
    J[1, 0] = -1.0 / (R_N + h)
    J[2, 1] = -math.tan(lat) / (R_E + h)
    for i in range(6):
        for k in range(12):
            M[i, k] = 0.0
    skew_s(2.0 * x[19] + x[22], 2.0 * x[20] + x[23], 2.0 * x[21] + x[24], T)
    for i in range(3):
        for k in range(3):
            M[i, k] = -T[i, k]
    skew_s(gN, 0.0, gD, T)
    for i in range(3):
        for k in range(3):
            M[i, 3 + k] = T[i, k] + (V[i, 0] * W[0, k] + V[i, 1] * W[1, k] + V[i, 2] * W[2, k])
            M[i, 6 + k] = -C[i, k]
            M[i, 9 + k] = -(V[i, 0] * C[0, k] + V[i, 1] * C[1, k] + V[i, 2] * C[2, k])
            M[3 + i, k] = -J[i, k]
            M[3 + i, 9 + k] = -C[i, k]
    skew_s(x[19] + x[22], x[20] + x[23], x[21] + x[24], T)
    for i in range(3):
        for k in range(3):
            M[3 + i, 3 + k] = (J[i, 0] * V[0, k] + J[i, 1] * V[1, k] + J[i, 2] * V[2, k]) - T[i, k]
    identity_plus_dt(M, dt)


@njit(cache=True, error_model="numpy", inline="always")
def skew_s(a0, a1, a2, out):
    """``[a x]`` into ``out`` (3, 3)."""
    out[0, 0], out[0, 1], out[0, 2] = 0.0, -a2, a1
    out[1, 0], out[1, 1], out[1, 2] = a2, 0.0, -a0
    out[2, 0], out[2, 1], out[2, 2] = -a1, a0, 0.0


@njit(cache=True, error_model="numpy")
def transition_span(pos, v, C, b_a, b_g, f, w, dt, j0, j1, Phi, invariant):
    """Steps ``[j0, j1)`` in place on the solution; Φ (R, 12, 12) = Π (I + F dt) into ``Phi``
    (``invariant``: F_inv of the right-invariant error, iekf.py, instead of model.system_matrix)."""
    S = np.empty((5, 3, 3))
    M = np.empty((6, 12))
    top = np.empty((6, 12))
    for r in range(pos.shape[0]):
        P = Phi[r]
        for i in range(12):
            for k in range(12):
                P[i, k] = 1.0 if i == k else 0.0
        x = load_t(pos[r], v[r], C[r])
        ba0, ba1, ba2, bg0, bg1, bg2 = b_a[r, 0], b_a[r, 1], b_a[r, 2], b_g[r, 0], b_g[r, 1], b_g[r, 2]
        for j in range(j0, j1):
            f0, f1, f2 = f[r, j, 0] - ba0, f[r, j, 1] - ba1, f[r, j, 2] - ba2
            if invariant:
                invariant_top_s(x, M, dt[j], S)
            else:
                system_top_s(x, f0, f1, f2, M, dt[j])
            for i in range(6):
                for k in range(12):
                    s = 0.0
                    for c in range(6):
                        s += M[i, c] * P[c, k]
                    if k >= 6:
                        s += M[i, k]  # rows 6-11 of Φ are the identity rows
                    top[i, k] = s
            for i in range(6):
                for k in range(12):
                    P[i, k] = top[i, k]
            x = cycle_t(x, f0, f1, f2, w[r, j, 0] - bg0, w[r, j, 1] - bg1, w[r, j, 2] - bg2, dt[j])
        store_t(x, pos[r], v[r], C[r])


@njit(cache=True, error_model="numpy")
def points_span(pos, v, C, b_a, b_g, X, f, w, dt, j0, j1, pos_o, v_o, C_o):
    """The mean and the 2n offsets ``X`` (R, 2n, 12) of each run through steps ``[j0, j1)``
    (ukf-nespm.md eqs 35-38) into ``pos_o``, ``v_o`` (R, 2n+1, 3), ``C_o`` (R, 2n+1, 3, 3)."""
    S = X.shape[1] + 1
    for r in range(pos.shape[0]):
        for s in range(S):
            # eqs 35-37: position unperturbed, v + dv, exp([dpsi x]) C (point 0: the mean)
            if s == 0:
                x = load_t(pos[r], v[r], C[r])
                ba0, ba1, ba2, bg0, bg1, bg2 = b_a[r, 0], b_a[r, 1], b_a[r, 2], b_g[r, 0], b_g[r, 1], b_g[r, 2]
            else:
                d = X[r, s - 1]
                x = state_t(pos[r, 0], pos[r, 1], pos[r, 2], v[r, 0] + d[0], v[r, 1] + d[1], v[r, 2] + d[2],
                            mul_t(exp_t(d[3], d[4], d[5]), matrix_t(C[r])))
                ba0, ba1, ba2 = b_a[r, 0] + d[6], b_a[r, 1] + d[7], b_a[r, 2] + d[8]
                bg0, bg1, bg2 = b_g[r, 0] + d[9], b_g[r, 1] + d[10], b_g[r, 2] + d[11]
            for j in range(j0, j1):  # eq 38, the point compensating its own biases
                x = cycle_t(x, f[r, j, 0] - ba0, f[r, j, 1] - ba1, f[r, j, 2] - ba2,
                            w[r, j, 0] - bg0, w[r, j, 1] - bg1, w[r, j, 2] - bg2, dt[j])
            store_t(x, pos_o[r, s], v_o[r, s], C_o[r, s])

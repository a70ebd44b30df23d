"""Compiled loops over one time-update span (numba; called through :mod:`nespm_cli.filters.kernels`).

``transition_span_common`` is ``ErrorStateFilter.transition`` (model.system_matrix + na_cycle per IMU step)
and ``points_span`` the sigma/cubature-point propagation of ukf-nespm.md eqs 35-38, one run (and
point) at a time. Shapes as in :mod:`nespm_cli.filters.kernels`; the error state is any layout of model.py, passed as
``off``: the first index of the ``[pos, vel, att, ba, bg]`` blocks (-1 for an absent one,
``nav.state.StateLayout.offsets``).

Φ = Π (I + F dt): F has non-zero rows only for the position, velocity and attitude blocks, so Φ
keeps its bias rows [0 I]; only the rows that change are formed (``transition_span_common``; the
same sums, in the same order, as the dense product's top six rows); for the 15 states ``[dp, dv,
dpsi, b_a, b_g]`` ``transition_span_position`` forms the same Φ bit for bit with F's structural zeros
skipped (the papers' 12 states: :mod:`.unrolled_12`, the same sums unrolled, what ``kernels``
runs for them). The iekf's right-invariant error has ``transition_span_invariant`` (12 states) and
``transition_span_invariant_position`` (15: F_inv's ρ_p row is dense, and it needs each run's origin).
"""
from __future__ import annotations

import math

import numpy as np

from nespm_cli.filters.compiled.entries import va_entries_t
from nespm_cli.nav.earth import A, E2, F, GAMMA_E, K_SOMIGLIANA
from nespm_cli.nav.kernels import (GRAV_M, cycle_t, earth_t, exp_t, gravity_t, helper, load_t, matrix_t, mul_t, njit, state_t,
                                   store_t)


@helper
def identity_plus_dt(M, dt, v):
    """``M ← I + M dt`` in place for the velocity and attitude rows ``v .. v+5`` of F (M (n, n))."""
    n = M.shape[1]
    for i in range(v, v + 6):
        for k in range(n):
            M[i, k] *= dt
        M[i, i] += 1.0


@helper
def system_rows_s(x, f0, f1, f2, M, dt, off):
    """The velocity and attitude rows of ``I + F dt`` into ``M`` (n, n): F of model.system_matrix
    (Groves 14.2.4); the position rows (dp' = dv) are applied by the span loops directly.

    dv'   = (-[(2 w_ie + w_en) x] + [v x] J) dv - [f_n x] dpsi - C b_a  (+ dg_D/dD dp_D)
    dpsi' = -J dv - [w_in x] dpsi - C b_g        (J = d w_en / d v)
    """
    p, v, a, ba, bg = off[0], off[1], off[2], off[3], off[4]
    lat, h = x[0], x[2]
    R_N, R_E = x[17], x[18]
    J01 = 1.0 / (R_E + h)
    J10 = -1.0 / (R_N + h)
    J21 = -math.tan(lat) / (R_E + h)
    n = M.shape[1]
    for i in range(v, v + 6):
        for k in range(n):
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
    M[v, v] = s00
    M[v, v + 1] = a01 + s01
    M[v, v + 2] = a02
    M[v + 1, v] = -a01 + s10
    M[v + 1, v + 1] = s11
    M[v + 1, v + 2] = a12
    M[v + 2, v] = -a02 + s20
    M[v + 2, v + 1] = -a12 + s21
    M[v + 2, v + 2] = 0.0
    # -[f_n x], f_n = C f
    fn0 = x[6] * f0 + x[7] * f1 + x[8] * f2
    fn1 = x[9] * f0 + x[10] * f1 + x[11] * f2
    fn2 = x[12] * f0 + x[13] * f1 + x[14] * f2
    M[v, a + 1], M[v, a + 2] = fn2, -fn1
    M[v + 1, a], M[v + 1, a + 2] = -fn2, fn0
    M[v + 2, a], M[v + 2, a + 1] = fn1, -fn0
    # -J
    M[a, v + 1] = -J01
    M[a + 1, v] = -J10
    M[a + 2, v + 1] = -J21
    # -skew(w_ie + w_en)
    u0, u1, u2 = x[19] + x[22], x[20] + x[23], x[21] + x[24]
    M[a, a + 1], M[a, a + 2] = u2, -u1
    M[a + 1, a], M[a + 1, a + 2] = -u2, u0
    M[a + 2, a], M[a + 2, a + 1] = u1, -u0
    # -C into the bias columns
    for i in range(3):
        for k in range(3):
            if ba >= 0:
                M[v + i, ba + k] = -x[6 + 3 * i + k]
            if bg >= 0:
                M[a + i, bg + k] = -x[6 + 3 * i + k]
    if p >= 0:  # the vertical gravity gradient couples dp_D into dv_D
        M[v + 2, p + 2] = gravity_gradient_t(lat, h, x[15])
    identity_plus_dt(M, dt, v)


@helper
def gravity_gradient_t(lat, h, sl):
    """earth.gravity_down_gradient: ∂g_D/∂D [1/s²] at latitude ``lat`` (``sl = sin lat``), height ``h``."""
    s2 = sl * sl
    g0 = GAMMA_E * (1.0 + K_SOMIGLIANA * s2) / math.sqrt(1.0 - E2 * s2)
    return g0 * (2.0 / A * (1.0 + F + GRAV_M - 2.0 * F * s2) - 6.0 * h / A**2)


@helper
def invariant_top_s(x, M, dt, S):
    """Rows 0-5 of ``I + F_inv dt`` into ``M`` (12, 12): F_inv of model.invariant_system_matrix
    for the 12-state layout (with position: :func:`invariant_position_blocks_s`).

    ρ̇ = −[(2ω_ie + ω_en)×] ρ + ([g×] + [v×][ω_ie×]) φ − C b_a − [v×] C b_g
    φ̇ = −J ρ + (J [v×] − [ω_in×]) φ − C b_g.      ``S`` (5, 3, 3) scratch.
    """
    lat, h = x[0], x[2]
    R_N, R_E = x[17], x[18]
    gN, gD = gravity_t(h, x[15], x[16])
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
    identity_plus_dt(M, dt, 0)


@helper
def mat3_s(A, B, out):
    """``out ← A @ B`` for (3, 3) arrays."""
    for i in range(3):
        for k in range(3):
            out[i, k] = A[i, 0] * B[0, k] + A[i, 1] * B[1, k] + A[i, 2] * B[2, k]


@helper
def invariant_position_blocks_s(x, S, q0, q1, q2):
    """The non-zero 3x3 blocks of F_inv (model.invariant_system_matrix with the position block) at
    the group position ``q`` [m] (the solution's NED offset from the run's origin), into ``S``
    (16, 3, 3); returns γ = ∂g_D/∂D, the only entry of the ρ_v–ρ_p block (at D, D)::

        ρ̇_p = (I − [q×]J) ρ_v + [q×](J[v×] − [ω_in×]) φ − [q×] C b_g
        ρ̇_v = Γ ρ_p − [(2ω_ie + ω_en)×] ρ_v + ([g×] + [v×][ω_ie×] − Γ[q×]) φ − C b_a − [v×] C b_g
        φ̇  = −J ρ_v + (J[v×] − [ω_in×]) φ − C b_g

    Blocks: ``S[0]`` ρ_p–ρ_v, ``S[1]`` ρ_p–φ, ``S[2]`` ρ_p–b_g, ``S[3]`` ρ_v–ρ_v, ``S[4]`` ρ_v–φ,
    ``S[5]`` ρ_v–b_a, ``S[6]`` ρ_v–b_g, ``S[7]`` φ–ρ_v, ``S[8]`` φ–φ, ``S[9]`` φ–b_g; ``S[10:16]`` scratch.
    """
    lat, h = x[0], x[2]
    R_N, R_E = x[17], x[18]
    gN, gD = gravity_t(h, x[15], x[16])
    gamma = gravity_gradient_t(lat, h, x[15])
    V, W, J, T, C, Q = S[10], S[11], S[12], S[13], S[14], S[15]
    skew_s(x[3], x[4], x[5], V)
    skew_s(x[19], x[20], x[21], W)
    skew_s(q0, q1, q2, Q)
    for i in range(3):
        for k in range(3):
            C[i, k] = x[6 + 3 * i + k]
            J[i, k] = 0.0
    J[0, 1] = 1.0 / (R_E + h)
    J[1, 0] = -1.0 / (R_N + h)
    J[2, 1] = -math.tan(lat) / (R_E + h)
    # φ–φ: J[v×] − [ω_in×]; φ–ρ_v: −J; φ–b_g: −C
    Wphi = S[8]
    skew_s(x[19] + x[22], x[20] + x[23], x[21] + x[24], T)
    mat3_s(J, V, Wphi)
    for i in range(3):
        for k in range(3):
            Wphi[i, k] -= T[i, k]
            S[7][i, k] = -J[i, k]
            S[9][i, k] = -C[i, k]
            S[5][i, k] = -C[i, k]
    # ρ_p row
    mat3_s(Q, J, S[0])
    mat3_s(Q, Wphi, S[1])
    mat3_s(Q, C, S[2])
    for i in range(3):
        for k in range(3):
            S[0][i, k] = (1.0 if i == k else 0.0) - S[0][i, k]
            S[2][i, k] = -S[2][i, k]
    # ρ_v row
    skew_s(2.0 * x[19] + x[22], 2.0 * x[20] + x[23], 2.0 * x[21] + x[24], T)
    mat3_s(V, W, S[4])
    mat3_s(V, C, S[6])
    for i in range(3):
        for k in range(3):
            S[3][i, k] = -T[i, k]
            S[6][i, k] = -S[6][i, k]
    skew_s(gN, 0.0, gD, T)
    for i in range(3):
        for k in range(3):
            S[4][i, k] += T[i, k]
    for k in range(3):
        S[4][2, k] -= gamma * Q[2, k]
    return gamma


@helper
def skew_s(a0, a1, a2, out):
    """``[a x]`` into ``out`` (3, 3)."""
    out[0, 0], out[0, 1], out[0, 2] = 0.0, -a2, a1
    out[1, 0], out[1, 1], out[1, 2] = a2, 0.0, -a0
    out[2, 0], out[2, 1], out[2, 2] = -a1, a0, 0.0


@helper
def set_identity(P):
    """``P ← I`` in place (one run's Φ at the start of a span)."""
    n = P.shape[0]
    for i in range(n):
        for k in range(n):
            P[i, k] = 1.0 if i == k else 0.0


@njit(cache=True, error_model="numpy")
def transition_span_common(pos, v, C, b_a, b_g, f, w, dt, j0, j1, Phi, off):
    """Steps ``[j0, j1)`` in place on the solution; Φ (R, n, n) = Π (I + F dt) into ``Phi`` for the
    common error (model.system_matrix) of the layout ``off``.

    Only the rows of Φ that change are formed: the velocity and attitude rows ``va = v .. v+5``
    ``Φ_va ← M_va,va Φ_va + M_va,bias`` (the bias rows of Φ are identity rows) ``+ M[vD, pD] Φ_pD``
    (the vertical gravity gradient, with a position block); the position rows ``Φ_p ← Φ_p + dt Φ_v``.
    For the papers' 12 states the sums, in the order, of the dense product's top six rows.

    The row loop is written out here and in :func:`transition_span_invariant`, not shared: as a helper
    called per IMU step (inlined by LLVM or by numba) it cost 1.5-1.6x the time per run-step (320 against
    200 ns, the 12 states at 50 runs), and as one helper for the whole span, called by both with a constant,
    it compiled in 1.1 CPU-s more (benchmarks/README.md)."""
    n = Phi.shape[1]
    p, vo = off[0], off[1]
    e = vo + 6  # the first bias column
    M = np.zeros((n, n))
    top = np.empty((n, n))
    for r in range(pos.shape[0]):
        P = Phi[r]
        set_identity(P)
        x = load_t(pos[r], v[r], C[r])
        ba0, ba1, ba2, bg0, bg1, bg2 = b_a[r, 0], b_a[r, 1], b_a[r, 2], b_g[r, 0], b_g[r, 1], b_g[r, 2]
        for j in range(j0, j1):
            f0, f1, f2 = f[r, j, 0] - ba0, f[r, j, 1] - ba1, f[r, j, 2] - ba2
            system_rows_s(x, f0, f1, f2, M, dt[j], off)
            for i in range(vo, e):  # Φ_va ← M_va,va Φ_va + M_va,bias
                for k in range(n):
                    s = 0.0
                    for c in range(vo, e):
                        s += M[i, c] * P[c, k]
                    if k >= e:
                        s += M[i, k]  # the bias rows of Φ are identity rows
                    top[i, k] = s
            if p >= 0:  # + M[vD, pD] Φ_pD; Φ_p ← Φ_p + dt Φ_v
                g = M[vo + 2, p + 2]
                for k in range(n):
                    top[vo + 2, k] += g * P[p + 2, k]
                for i in range(3):
                    for k in range(n):
                        P[p + i, k] += dt[j] * P[vo + i, k]  # Φ_v before this step's update
            for i in range(vo, e):
                for k in range(n):
                    P[i, k] = top[i, k]
            x = cycle_t(x, f0, f1, f2, w[r, j, 0] - bg0, w[r, j, 1] - bg1, w[r, j, 2] - bg2, dt[j])
        store_t(x, pos[r], v[r], C[r])


@njit(cache=True, error_model="numpy")
def transition_span_invariant(pos, v, C, b_a, b_g, f, w, dt, j0, j1, Phi, off):
    """:func:`transition_span_common` for F_inv of the right-invariant error (iekf.py, 12 states; with
    the position block: :func:`transition_span_invariant_position`): the same row loop, each step's
    rows from :func:`invariant_top_s`."""
    S = np.empty((5, 3, 3))
    n = Phi.shape[1]
    p, vo = off[0], off[1]
    e = vo + 6  # the first bias column
    M = np.zeros((n, n))
    top = np.empty((n, n))
    for r in range(pos.shape[0]):
        P = Phi[r]
        set_identity(P)
        x = load_t(pos[r], v[r], C[r])
        ba0, ba1, ba2, bg0, bg1, bg2 = b_a[r, 0], b_a[r, 1], b_a[r, 2], b_g[r, 0], b_g[r, 1], b_g[r, 2]
        for j in range(j0, j1):
            f0, f1, f2 = f[r, j, 0] - ba0, f[r, j, 1] - ba1, f[r, j, 2] - ba2
            invariant_top_s(x, M, dt[j], S)
            for i in range(vo, e):  # Φ_va ← M_va,va Φ_va + M_va,bias
                for k in range(n):
                    s = 0.0
                    for c in range(vo, e):
                        s += M[i, c] * P[c, k]
                    if k >= e:
                        s += M[i, k]  # the bias rows of Φ are identity rows
                    top[i, k] = s
            if p >= 0:  # + M[vD, pD] Φ_pD; Φ_p ← Φ_p + dt Φ_v
                g = M[vo + 2, p + 2]
                for k in range(n):
                    top[vo + 2, k] += g * P[p + 2, k]
                for i in range(3):
                    for k in range(n):
                        P[p + i, k] += dt[j] * P[vo + i, k]  # Φ_v before this step's update
            for i in range(vo, e):
                for k in range(n):
                    P[i, k] = top[i, k]
            x = cycle_t(x, f0, f1, f2, w[r, j, 0] - bg0, w[r, j, 1] - bg1, w[r, j, 2] - bg2, dt[j])
        store_t(x, pos[r], v[r], C[r])


@njit(cache=True, error_model="numpy")
def transition_span_position(pos, v, C, b_a, b_g, f, w, dt, j0, j1, Phi):
    """:func:`transition_span_common` for the 15-state layout ``[dp, dv, dpsi, b_a, b_g]`` (offsets 0, 3, 6,
    9, 12) of the common error, column by column with F's structural zeros skipped: the ``M`` of
    :func:`system_rows_s` as scalars (the same entries, ``value · dt``, diagonal ``+ 1``), each
    non-zero term added in the order of :func:`transition_span_common`'s sums (skipping an exact zero
    term changes no sum but the sign of a zero), so the same Φ (tests/test_kernels.py)."""
    S = np.empty((3, 3))
    for r in range(pos.shape[0]):
        P = Phi[r]
        set_identity(P)
        x = load_t(pos[r], v[r], C[r])
        ba0, ba1, ba2, bg0, bg1, bg2 = b_a[r, 0], b_a[r, 1], b_a[r, 2], b_g[r, 0], b_g[r, 1], b_g[r, 2]
        for j in range(j0, j1):
            f0, f1, f2 = f[r, j, 0] - ba0, f[r, j, 1] - ba1, f[r, j, 2] - ba2
            h = dt[j]
            (m00, m01, m02, m10, m11, m12, m20, m21, n04, n05, n13, n15, n23, n24, q31, q40, q51,
             t34, t35, t43, t45, t53, t54) = va_entries_t(x, math.tan(x[0]), f0, f1, f2, h)
            g = gravity_gradient_t(x[0], x[2], x[15]) * h
            for i in range(3):
                for k in range(3):
                    S[i, k] = -x[6 + 3 * i + k] * h
            for k in range(15):
                p2 = P[2, k]
                V0, V1, V2, A0, A1, A2 = P[3, k], P[4, k], P[5, k], P[6, k], P[7, k], P[8, k]
                d0 = m00 * V0 + m01 * V1 + m02 * V2 + n04 * A1 + n05 * A2
                d1 = m10 * V0 + m11 * V1 + m12 * V2 + n13 * A0 + n15 * A2
                d2 = m20 * V0 + m21 * V1 + V2 + n23 * A0 + n24 * A1
                e0 = q31 * V1 + A0 + t34 * A1 + t35 * A2
                e1 = q40 * V0 + t43 * A0 + A1 + t45 * A2
                e2 = q51 * V1 + t53 * A0 + t54 * A1 + A2
                if k >= 9:
                    if k < 12:
                        d0 += S[0, k - 9]
                        d1 += S[1, k - 9]
                        d2 += S[2, k - 9]
                    else:
                        e0 += S[0, k - 12]
                        e1 += S[1, k - 12]
                        e2 += S[2, k - 12]
                d2 += g * p2
                P[0, k] += h * V0
                P[1, k] += h * V1
                P[2, k] += h * V2
                P[3, k], P[4, k], P[5, k], P[6, k], P[7, k], P[8, k] = d0, d1, d2, e0, e1, e2
            x = cycle_t(x, f0, f1, f2, w[r, j, 0] - bg0, w[r, j, 1] - bg1, w[r, j, 2] - bg2, h)
        store_t(x, pos[r], v[r], C[r])


@njit(cache=True, error_model="numpy")
def transition_span_invariant_position(pos, v, C, b_a, b_g, f, w, dt, j0, j1, Phi, off, origin):
    """:func:`transition_span_invariant` with the position block (iekf.py, 15 states): Φ_inv
    (R, n, n) = Π (I + F_inv dt) into ``Phi``, F_inv (:func:`invariant_position_blocks_s`) at the group
    position, the NED offset from the run's ``origin`` (R, 3) ``[lat, lon, h]``. Only the rows of ρ_p,
    ρ_v, φ change, column by column: ``Φ_top[:, k] += dt (F_top,top Φ_top[:, k] + F_top,k)`` (the last
    term for the bias columns only), F_inv's zero blocks skipped (tests/test_kernels.py)."""
    n = Phi.shape[1]
    p, vo, a, ba, bg = off[0], off[1], off[2], off[3], off[4]
    S = np.empty((16, 3, 3))
    for r in range(pos.shape[0]):
        P = Phi[r]
        set_identity(P)
        x = load_t(pos[r], v[r], C[r])
        lat0, lon0, h0 = origin[r, 0], origin[r, 1], origin[r, 2]
        e0 = earth_t(lat0, h0, 0.0, 0.0)
        kN = e0[2] + h0
        kE = (e0[3] + h0) * e0[1]
        ba0, ba1, ba2, bg0, bg1, bg2 = b_a[r, 0], b_a[r, 1], b_a[r, 2], b_g[r, 0], b_g[r, 1], b_g[r, 2]
        for j in range(j0, j1):
            f0, f1, f2 = f[r, j, 0] - ba0, f[r, j, 1] - ba1, f[r, j, 2] - ba2
            h = dt[j]
            gamma = invariant_position_blocks_s(x, S, (x[0] - lat0) * kN, (x[1] - lon0) * kE, -(x[2] - h0))
            Fpv, Fpa, Fpg, Fvv, Fva = S[0], S[1], S[2], S[3], S[4]
            Fvb, Fvg, Fav, Faa, Fag = S[5], S[6], S[7], S[8], S[9]
            for k in range(n):
                p2 = P[p + 2, k]  # the gravity gradient reads δp_D only
                v0, v1, v2 = P[vo, k], P[vo + 1, k], P[vo + 2, k]
                a0, a1, a2 = P[a, k], P[a + 1, k], P[a + 2, k]
                for i in range(3):
                    dp = ((Fpv[i, 0] * v0 + Fpv[i, 1] * v1 + Fpv[i, 2] * v2)
                          + (Fpa[i, 0] * a0 + Fpa[i, 1] * a1 + Fpa[i, 2] * a2))
                    dv = ((Fvv[i, 0] * v0 + Fvv[i, 1] * v1 + Fvv[i, 2] * v2)
                          + (Fva[i, 0] * a0 + Fva[i, 1] * a1 + Fva[i, 2] * a2))
                    da = ((Fav[i, 0] * v0 + Fav[i, 1] * v1 + Fav[i, 2] * v2)
                          + (Faa[i, 0] * a0 + Faa[i, 1] * a1 + Faa[i, 2] * a2))
                    if i == 2:
                        dv += gamma * p2
                    if ba >= 0 and ba <= k < ba + 3:
                        dv += Fvb[i, k - ba]
                    if bg >= 0 and bg <= k < bg + 3:
                        dp += Fpg[i, k - bg]
                        dv += Fvg[i, k - bg]
                        da += Fag[i, k - bg]
                    P[p + i, k] += h * dp
                    P[vo + i, k] += h * dv
                    P[a + i, k] += h * da
            x = cycle_t(x, f0, f1, f2, w[r, j, 0] - bg0, w[r, j, 1] - bg1, w[r, j, 2] - bg2, dt[j])
        store_t(x, pos[r], v[r], C[r])


@helper
def point_start(pos, v, C, b_a, b_g, X, r, s, off):
    """Point ``s`` of run ``r`` at the start of a span (eqs 35-37): ``(x, b_a (3), b_g (3), dp (3))``,
    point 0 the mean, point s > 0 the mean ⊕ ``X[r, s-1]`` (position ⊕ dp with a position block,
    else unperturbed as the papers), with its own biases."""
    p, vo, a, ba, bg = off[0], off[1], off[2], off[3], off[4]
    ba0, ba1, ba2, bg0, bg1, bg2 = b_a[r, 0], b_a[r, 1], b_a[r, 2], b_g[r, 0], b_g[r, 1], b_g[r, 2]
    if s == 0:
        return load_t(pos[r], v[r], C[r]), ba0, ba1, ba2, bg0, bg1, bg2, 0.0, 0.0, 0.0
    d = X[r, s - 1]
    lat, lon, h = pos[r, 0], pos[r, 1], pos[r, 2]
    d0, d1, d2 = 0.0, 0.0, 0.0
    if p >= 0:  # nav.state.position_plus
        x0 = load_t(pos[r], v[r], C[r])
        d0, d1, d2 = d[p], d[p + 1], d[p + 2]
        lat, lon, h = lat + d0 / (x0[17] + h), lon + d1 / ((x0[18] + h) * x0[16]), h - d2
    x = state_t(lat, lon, h, v[r, 0] + d[vo], v[r, 1] + d[vo + 1], v[r, 2] + d[vo + 2],
                mul_t(exp_t(d[a], d[a + 1], d[a + 2]), matrix_t(C[r])))
    if ba >= 0:
        ba0, ba1, ba2 = ba0 + d[ba], ba1 + d[ba + 1], ba2 + d[ba + 2]
    if bg >= 0:
        bg0, bg1, bg2 = bg0 + d[bg], bg1 + d[bg + 1], bg2 + d[bg + 2]
    return x, ba0, ba1, ba2, bg0, bg1, bg2, d0, d1, d2


@njit(cache=True, error_model="numpy")
def points_span(pos, v, C, b_a, b_g, X, f, w, dt, j0, j1, pos_o, v_o, C_o, off):
    """The mean and the offsets ``X`` (R, 2n, n) of each run through steps ``[j0, j1)`` (eqs 35-38) into
    ``pos_o``, ``v_o`` (R, 2n+1, 3), ``C_o`` (R, 2n+1, 3, 3); no position block (position unperturbed)."""
    for r in range(pos.shape[0]):
        for s in range(X.shape[1] + 1):
            x, ba0, ba1, ba2, bg0, bg1, bg2, _, _, _ = point_start(pos, v, C, b_a, b_g, X, r, s, off)
            for j in range(j0, j1):  # eq 38, the point compensating its own biases
                x = cycle_t(x, f[r, j, 0] - ba0, f[r, j, 1] - ba1, f[r, j, 2] - ba2,
                            w[r, j, 0] - bg0, w[r, j, 1] - bg1, w[r, j, 2] - bg2, dt[j])
            store_t(x, pos_o[r, s], v_o[r, s], C_o[r, s])


@njit(cache=True, error_model="numpy")
def points_span_position(pos, v, C, b_a, b_g, X, f, w, dt, j0, j1, pos_o, v_o, C_o, dp_o, off):
    """:func:`points_span` for a layout with a position block: point s starts at ``pos ⊕ dp``, and
    its position offset from point 0, NED [m], into ``dp_o`` (R, 2n+1, 3): its ``dp`` plus the trapezoid
    integral of its velocity's difference from point 0's (eqs 28-30 in deviation form)."""
    vc = np.empty((j1 - j0 + 1, 3))
    for r in range(pos.shape[0]):
        for s in range(X.shape[1] + 1):
            x, ba0, ba1, ba2, bg0, bg1, bg2, d0, d1, d2 = point_start(pos, v, C, b_a, b_g, X, r, s, off)
            if s == 0:
                vc[0, 0], vc[0, 1], vc[0, 2] = x[3], x[4], x[5]
            for j in range(j0, j1):  # eq 38, the point compensating its own biases
                e0, e1, e2 = x[3] - vc[j - j0, 0], x[4] - vc[j - j0, 1], x[5] - vc[j - j0, 2]
                x = cycle_t(x, f[r, j, 0] - ba0, f[r, j, 1] - ba1, f[r, j, 2] - ba2,
                            w[r, j, 0] - bg0, w[r, j, 1] - bg1, w[r, j, 2] - bg2, dt[j])
                if s == 0:
                    vc[j - j0 + 1, 0], vc[j - j0 + 1, 1], vc[j - j0 + 1, 2] = x[3], x[4], x[5]
                else:
                    half = 0.5 * dt[j]
                    d0 += (e0 + (x[3] - vc[j - j0 + 1, 0])) * half
                    d1 += (e1 + (x[4] - vc[j - j0 + 1, 1])) * half
                    d2 += (e2 + (x[5] - vc[j - j0 + 1, 2])) * half
            store_t(x, pos_o[r, s], v_o[r, s], C_o[r, s])
            dp_o[r, s, 0], dp_o[r, s, 1], dp_o[r, s, 2] = d0, d1, d2

"""The papers' 12-state common-error Φ kernel, the runs in SIMD lanes (numba; called through
:mod:`nespm_cli.filters.kernels` from ``kernels.LANES_MIN`` runs up; fewer run by run in :mod:`.unrolled_12`,
the same bits).

``transition_lanes_12`` is :func:`nespm_cli.filters.compiled.spans.transition_span_common` for the
layout ``[dv, dpsi, b_a, b_g]`` (offsets -1, 0, 3, 6, 9), restructured for the machine: up to
:data:`~nespm_cli.filters.compiled.cycle_lanes.L` runs are the columns of one state table and of one table of Φ's
changing rows (velocity and attitude, 6 x 12; the bias rows stay the identity), and each IMU step runs all
of them at once, in loops over the runs that LLVM vectorises: F's entries
(:func:`~nespm_cli.filters.compiled.entries.va_entries_t`), Φ's rows column by column, then the
navigation cycle (:func:`~nespm_cli.filters.compiled.cycle_lanes.cycles_soa`). Each entry of Φ's changing rows is
the generic loop's sum in its order, ``0.0 + M[i, 0] Φ[0, k] + ... + M[i, 5] Φ[5, k] (+ M[i, k] for a bias
column)``, F's structural zeros included as ``0.0 · dt`` terms: the same IEEE operations in the same
order, so the same bits, zeros' signs included, and NaN where the loop gives NaN (its payload aside) for an
inf or NaN input (tests/test_compile_kernels.py). The lanes' IMU samples and the latitude's tangent (a
C-library call) are taken in a scalar loop. A block always computes 32 lanes (its spare lanes copy its
first run), so a few runs pay for 32: measured per run-step, about 0.3x the scalar kernel from 24 runs
up, 1.0x at 8, 1.9x at 4 and 6.8x at one run (benchmarks/README.md), hence ``kernels.LANES_MIN``.
"""
from __future__ import annotations

import math

import numpy as np

from nespm_cli.filters.compiled.cycle_lanes import (L, R0, R6, R9, R12, R25, R26, R27, R28, R29, R30, R52, R53, R54,
                                           R55, R56, R57, ROWS, cycles_soa)
from nespm_cli.filters.compiled.entries import va_entries_t
from nespm_cli.nav.kernels import helper, load_t, njit, store_t

#: rows of the entries table: F's 23 entries of :func:`va_entries_t`, per lane
ENTRIES = 23


@helper
def lane_t(T, s):
    """The 25-tuple of ``nav.kernels.cycle_t`` of lane ``s`` in the state table ``T``."""
    return (T[s], T[L + s], T[2 * L + s], T[3 * L + s], T[4 * L + s], T[5 * L + s], T[6 * L + s], T[7 * L + s],
            T[8 * L + s], T[9 * L + s], T[10 * L + s], T[11 * L + s], T[12 * L + s], T[13 * L + s], T[14 * L + s],
            T[15 * L + s], T[16 * L + s], T[17 * L + s], T[18 * L + s], T[19 * L + s], T[20 * L + s],
            T[21 * L + s], T[22 * L + s], T[23 * L + s], T[24 * L + s])


@helper
def entries_t(E, s):
    """The 23 entries of lane ``s`` in the entries table ``E``."""
    return (E[s], E[L + s], E[2 * L + s], E[3 * L + s], E[4 * L + s], E[5 * L + s], E[6 * L + s], E[7 * L + s],
            E[8 * L + s], E[9 * L + s], E[10 * L + s], E[11 * L + s], E[12 * L + s], E[13 * L + s], E[14 * L + s],
            E[15 * L + s], E[16 * L + s], E[17 * L + s], E[18 * L + s], E[19 * L + s], E[20 * L + s],
            E[21 * L + s], E[22 * L + s])


@helper
def load_block(T, pos, v, C, b_a, b_g, r0, n):
    """The state table ``T`` of the block of ``n`` runs from run ``r0``: rows 0-24 each run's cycle tuple
    (``nav.kernels.load_t``), 25-30 its ``b_a``, ``b_g``; the spare lanes a copy of run ``r0``."""
    for s in range(L):
        r = r0 + s if s < n else r0
        x = load_t(pos[r], v[r], C[r])
        for i in range(25):
            T[i * L + s] = x[i]
        T[R25 + s], T[R26 + s], T[R27 + s] = b_a[r, 0], b_a[r, 1], b_a[r, 2]
        T[R28 + s], T[R29 + s], T[R30 + s] = b_g[r, 0], b_g[r, 1], b_g[r, 2]


@helper
def imu_block(T, f, w, j, r0, n, tan_lat):
    """IMU step ``j`` of the block's runs into rows 52-57 (``f_b − b_a``, ``w_ib_b − b_g``) and ``tan_lat``
    (L,) the tangent of each lane's latitude: gathers and C-library calls, a scalar loop."""
    for s in range(L):
        r = r0 + s if s < n else r0
        T[R52 + s], T[R53 + s], T[R54 + s] = f[r, j, 0] - T[R25 + s], f[r, j, 1] - T[R26 + s], f[r, j, 2] - T[R27 + s]
        T[R55 + s], T[R56 + s], T[R57 + s] = w[r, j, 0] - T[R28 + s], w[r, j, 1] - T[R29 + s], w[r, j, 2] - T[R30 + s]
        tan_lat[s] = math.tan(T[R0 + s])


@helper
def entries_into(E, T, s, tan_lat, h):
    """Lane ``s``'s 23 entries of F (:func:`va_entries_t`, at its state and IMU sample in ``T``) into ``E``."""
    (E[s], E[L + s], E[2 * L + s], E[3 * L + s], E[4 * L + s], E[5 * L + s], E[6 * L + s], E[7 * L + s],
     E[8 * L + s], E[9 * L + s], E[10 * L + s], E[11 * L + s], E[12 * L + s], E[13 * L + s], E[14 * L + s],
     E[15 * L + s], E[16 * L + s], E[17 * L + s], E[18 * L + s], E[19 * L + s], E[20 * L + s],
     E[21 * L + s], E[22 * L + s]) = va_entries_t(lane_t(T, s), tan_lat, T[R52 + s], T[R53 + s], T[R54 + s], h)


@helper
def identity_rows(P, rows, m):
    """Every lane's ``rows`` changing rows of Φ (m x m) set to the identity's: entry (i, k) of lane s at
    (m i + k) L + s, 1 where i == k (q = (m + 1) i)."""
    for s in range(L):
        for q in range(rows * m):
            P[q * L + s] = 1.0 if q % (m + 1) == 0 else 0.0


@helper
def store_block(T, P, rows, pos, v, C, Phi, r0, n):
    """The block of ``n`` runs from ``r0`` back: each run's solution from the state table ``T``, its Φ
    (``Phi[r]``, m x m) from the ``rows`` changing rows in ``P`` and the identity's below them."""
    m = Phi.shape[1]
    for s in range(n):
        r = r0 + s
        store_t(lane_t(T, s), pos[r], v[r], C[r])
        for i in range(m):
            for k in range(m):
                Phi[r, i, k] = P[(m * i + k) * L + s] if i < rows else (1.0 if i == k else 0.0)


@helper
def column_t(e, z, m22, d33, d44, d55, V0, V1, V2, A0, A1, A2):
    """Column k of Φ's new velocity and attitude rows, ``M[0:6, 0:6] Φ[0:6, k]`` summed as the generic loop
    (``0.0 +`` each term in order, F's structural zeros as ``z`` = 0 · dt), from the 23 entries ``e`` of
    :func:`va_entries_t`, the diagonal entries ``m22``, ``d33`` ... ``d55`` (1 + 0 · dt) and the column's
    old entries ``V0 ... A2``."""
    (m00, m01, m02, m10, m11, m12, m20, m21, n04, n05, n13, n15, n23, n24, q31, q40, q51,
     t34, t35, t43, t45, t53, t54) = e
    return (0.0 + m00 * V0 + m01 * V1 + m02 * V2 + z * A0 + n04 * A1 + n05 * A2,
            0.0 + m10 * V0 + m11 * V1 + m12 * V2 + n13 * A0 + z * A1 + n15 * A2,
            0.0 + m20 * V0 + m21 * V1 + m22 * V2 + n23 * A0 + n24 * A1 + z * A2,
            0.0 + z * V0 + q31 * V1 + z * V2 + d33 * A0 + t34 * A1 + t35 * A2,
            0.0 + q40 * V0 + z * V1 + z * V2 + t43 * A0 + d44 * A1 + t45 * A2,
            0.0 + z * V0 + q51 * V1 + z * V2 + t53 * A0 + t54 * A1 + d55 * A2)


@helper
def add_column(P, q, M, d0, d1, d2, e0, e1, e2):
    """Φ's rows 0-5 of one lane and column (entry q of row 0, rows ``M`` apart) plus ``d0 ... e2``, in place."""
    P[q] += d0
    P[q + M] += d1
    P[q + 2 * M] += d2
    P[q + 3 * M] += e0
    P[q + 4 * M] += e1
    P[q + 5 * M] += e2


@njit(cache=True, error_model="numpy")
def transition_lanes_12(pos, v, C, b_a, b_g, f, w, dt, j0, j1, Phi):
    """Steps ``[j0, j1)`` in place on the solution; Φ (R, 12, 12) = Π (I + F dt) into ``Phi`` for the
    common error (model.system_matrix) of the 12 states: transition_span_common's numbers, the runs in
    lanes of :data:`~nespm_cli.filters.compiled.cycle_lanes.L` (the last block's spare lanes copy its first run)."""
    T = np.empty(ROWS * L)  # the state table (cycle_lanes)
    P = np.empty(72 * L)  # Φ's rows 0-5: entry (i, k) of lane s at (12 i + k) L + s
    E = np.empty(ENTRIES * L)  # F's entries at the step's start
    tan_lat = np.empty(L)
    M = 12 * L
    for r0 in range(0, pos.shape[0], L):
        n = min(L, pos.shape[0] - r0)
        load_block(T, pos, v, C, b_a, b_g, r0, n)
        identity_rows(P, 6, 12)
        for j in range(j0, j1):
            h = dt[j]
            imu_block(T, f, w, j, r0, n, tan_lat)
            for s in range(L):  # system_rows_s then identity_plus_dt: M = I + F dt, its non-structural entries
                entries_into(E, T, s, tan_lat[s], h)
            z = 0.0 * h  # a structural zero of F, times dt
            m22 = 0.0 * h + 1.0
            d33, d44, d55 = 0.0 * h + 1.0, 0.0 * h + 1.0, 0.0 * h + 1.0
            for k in range(12):  # transition_span_common's row loop, column by column (a column reads only itself)
                o = k * L
                for s in range(L):
                    d0, d1, d2, e0, e1, e2 = column_t(entries_t(E, s), z, m22, d33, d44, d55, P[o + s], P[o + M + s],
                                                      P[o + 2 * M + s], P[o + 3 * M + s], P[o + 4 * M + s],
                                                      P[o + 5 * M + s])
                    P[o + s], P[o + M + s], P[o + 2 * M + s] = d0, d1, d2
                    P[o + 3 * M + s], P[o + 4 * M + s], P[o + 5 * M + s] = e0, e1, e2
            for c in range(3):  # the bias columns: + M[i, k] (-C dt: b_a into the velocity rows, b_g into the attitude rows)
                ov, oa, oc = (6 + c) * L, (9 + c) * L, c * L
                for s in range(L):
                    c0, c1, c2 = -T[R6 + oc + s] * h, -T[R9 + oc + s] * h, -T[R12 + oc + s] * h
                    add_column(P, ov + s, M, c0, c1, c2, z, z, z)
                    add_column(P, oa + s, M, z, z, z, c0, c1, c2)
            cycles_soa(T, n, h)
        store_block(T, P, 6, pos, v, C, Phi, r0, n)

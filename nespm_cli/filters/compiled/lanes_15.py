"""The 15-state common-error Φ kernel (position in the state), the runs in SIMD lanes (numba; called through
:mod:`nespm_cli.filters.kernels` from ``kernels.LANES_MIN`` runs up; fewer run by run in
:func:`.spans.transition_span_position`, the same bits).

``transition_lanes_15`` is :func:`.spans.transition_span_position` for the layout ``[dp, dv, dpsi, b_a, b_g]``
(offsets 0, 3, 6, 9, 12) restructured as :mod:`.lanes_12`: up to :data:`~.cycle_lanes.L` runs are the columns
of one state table and of one table of Φ's changing rows (position, velocity and attitude, 9 x 15; the bias
rows stay the identity), and each IMU step forms F's entries (with the vertical gravity gradient), Φ's
columns and the navigation cycle of all lanes in vectorised loops. Each entry of Φ's changing rows is
``transition_span_position``'s sum in its order (F's structural zeros skipped, the bias columns' ``-C dt``
before the gravity gradient's term, the position rows the integral of the velocity rows): the same bits
(tests/test_compile_kernels.py).
"""
from __future__ import annotations

import numpy as np

from nespm_cli.filters.compiled.cycle_lanes import L, R0, R2, R6, R9, R12, R15, ROWS, cycles_soa
from nespm_cli.filters.compiled.lanes_12 import (ENTRIES, entries_into, entries_t, identity_rows, imu_block, load_block,
                                                 store_block)
from nespm_cli.filters.compiled.spans import gravity_gradient_t
from nespm_cli.nav.kernels import helper, njit


@helper
def column_15_t(e, V0, V1, V2, A0, A1, A2):
    """Column k of Φ's new velocity and attitude rows of the 15 states, F's zeros skipped, the sums of
    ``spans.transition_span_position`` (before a bias column's ``-C dt`` and the gravity gradient's term),
    from the 23 entries ``e`` of :func:`va_entries_t` and the column's old entries ``V0 ... A2``."""
    (m00, m01, m02, m10, m11, m12, m20, m21, n04, n05, n13, n15, n23, n24, q31, q40, q51,
     t34, t35, t43, t45, t53, t54) = e
    return (m00 * V0 + m01 * V1 + m02 * V2 + n04 * A1 + n05 * A2,
            m10 * V0 + m11 * V1 + m12 * V2 + n13 * A0 + n15 * A2,
            m20 * V0 + m21 * V1 + V2 + n23 * A0 + n24 * A1,
            q31 * V1 + A0 + t34 * A1 + t35 * A2,
            q40 * V0 + t43 * A0 + A1 + t45 * A2,
            q51 * V1 + t53 * A0 + t54 * A1 + A2)


@helper
def put_column_15(P, q, M, h, g, p2, V0, V1, V2, d0, d1, d2, e0, e1, e2):
    """Write one lane's column (entry q of row 0, rows ``M`` apart) of Φ's rows 0-8: the position rows plus
    ``h`` times the old velocity rows, the velocity rows ``d`` (``d2`` plus ``g`` times the old ``p2``), the
    attitude rows ``e``."""
    P[q] += h * V0
    P[q + M] += h * V1
    P[q + 2 * M] += h * V2
    P[q + 3 * M], P[q + 4 * M], P[q + 5 * M] = d0, d1, d2 + g * p2
    P[q + 6 * M], P[q + 7 * M], P[q + 8 * M] = e0, e1, e2


@njit(cache=True, error_model="numpy")
def transition_lanes_15(pos, v, C, b_a, b_g, f, w, dt, j0, j1, Phi):
    """Steps ``[j0, j1)`` in place on the solution; Φ (R, 15, 15) = Π (I + F dt) into ``Phi`` for the
    common error of the 15 states: transition_span_position's numbers, the runs in lanes of
    :data:`~.cycle_lanes.L` (the last block's spare lanes copy its first run)."""
    T = np.empty(ROWS * L)  # the state table (cycle_lanes)
    P = np.empty(135 * L)  # Φ's rows 0-8: entry (i, k) of lane s at (15 i + k) L + s
    E = np.empty((ENTRIES + 1) * L)  # F's entries at the step's start, then g dt
    tan_lat = np.empty(L)
    M = 15 * L
    G = ENTRIES * L
    for r0 in range(0, pos.shape[0], L):
        n = min(L, pos.shape[0] - r0)
        load_block(T, pos, v, C, b_a, b_g, r0, n)
        identity_rows(P, 9, 15)
        for j in range(j0, j1):
            h = dt[j]
            imu_block(T, f, w, j, r0, n, tan_lat)
            for s in range(L):  # F's entries as in transition_span_position, and the gravity gradient times dt
                entries_into(E, T, s, tan_lat[s], h)
                E[G + s] = gravity_gradient_t(T[R0 + s], T[R2 + s], T[R15 + s]) * h
            for k in range(15):  # column by column (a column of Φ's new rows reads only that column)
                o = k * L
                c = (k - 9 if k < 12 else k - 12) * L  # a bias column's column of C
                for s in range(L):
                    p2 = P[o + 2 * M + s]
                    V0, V1, V2 = P[o + 3 * M + s], P[o + 4 * M + s], P[o + 5 * M + s]
                    d0, d1, d2, e0, e1, e2 = column_15_t(entries_t(E, s), V0, V1, V2, P[o + 6 * M + s],
                                                         P[o + 7 * M + s], P[o + 8 * M + s])
                    if k >= 9:  # + M[i, k]: -C dt, b_a into the velocity rows, b_g into the attitude rows
                        c0, c1, c2 = -T[R6 + c + s] * h, -T[R9 + c + s] * h, -T[R12 + c + s] * h
                        if k < 12:
                            d0, d1, d2 = d0 + c0, d1 + c1, d2 + c2
                        else:
                            e0, e1, e2 = e0 + c0, e1 + c1, e2 + c2
                    put_column_15(P, o + s, M, h, E[G + s], p2, V0, V1, V2, d0, d1, d2, e0, e1, e2)
            cycles_soa(T, n, h)
        store_block(T, P, 9, pos, v, C, Phi, r0, n)

"""The sigma/cubature points of one run through a time-update span, the points in SIMD lanes.

``points_span_soa`` is :func:`nespm_cli.filters.compiled.spans.points_span` restructured for the
machine: a run's 2n+1 points are the columns of one state table (structure of arrays, row stride
:data:`~nespm_cli.filters.compiled.cycle_lanes.L`), and each IMU step runs the navigation cycle of all
of them at once (:func:`~nespm_cli.filters.compiled.cycle_lanes.cycles_soa`), in loops over the points
that LLVM vectorises. The operations of each point are those of ``nav.kernels.cycle_t``, in the same
order (no contraction into fused multiply-adds, no reassociation): the same bits as the scalar
kernel and the NumPy reference ``strapdown.na_cycle`` (tests/test_points_kernel.py). The latitude's
sine and cosine are :func:`nespm_cli.nav.trig.sin_cos`, arithmetic that vectorises with the rest; only
the rare rotation above 0.01 rad (Rodrigues' sine and cosine) runs in a scalar loop between the vector
ones. Measured: ~2.4x the scalar kernel per point-cycle with the C library's latitude sines in a scalar
loop, 0.73x of that since (benchmarks/README.md).
"""
from __future__ import annotations

import numpy as np

from nespm_cli.filters.compiled.cycle_lanes import L, R0, R1, R2, R3, R4, R5, R25, R26, R27, R28, R29, R30, R46, R47, R48, \
    R52, R53, R54, R55, R56, R57, ROWS, cycles_soa
from nespm_cli.filters.compiled.spans import point_start
from nespm_cli.nav.kernels import njit


@njit(cache=True, error_model="numpy")
def points_span_soa(pos, v, C, b_a, b_g, X, f, w, dt, j0, j1, pos_o, v_o, C_o, dp_o, off):
    """spans.points_span, and with a position block (``off[0] >= 0``) points_span_position
    into ``dp_o`` (R, S, 3) (the same arguments and the same bits; ``dp_o`` untouched without the block),
    with the points of a run in the columns of a state table, IMU step by IMU step (``cycle_lanes.cycles_soa``;
    rows 46-51 the position offsets and the velocity differences from point 0): at most :data:`L` points."""
    S = X.shape[1] + 1
    position = off[0] >= 0
    T = np.empty(ROWS * L)
    for r in range(pos.shape[0]):
        for s in range(S):
            x, ba0, ba1, ba2, bg0, bg1, bg2, d0, d1, d2 = point_start(pos, v, C, b_a, b_g, X, r, s, off)
            for i in range(25):
                T[i * L + s] = x[i]
            T[R46 + s], T[R47 + s], T[R48 + s] = d0, d1, d2
            T[R25 + s], T[R26 + s], T[R27 + s], T[R28 + s], T[R29 + s], T[R30 + s] = ba0, ba1, ba2, bg0, bg1, bg2
        for s in range(L):
            if s >= S:  # the lanes past the last point: a copy of point 0, finite, never read back
                for i in range(31):
                    T[i * L + s] = T[i * L]
                T[R46 + s], T[R47 + s], T[R48 + s] = 0.0, 0.0, 0.0
        for j in range(j0, j1):
            if position:  # eqs 28-30 in deviation form: the velocity difference from point 0 before the step
                for s in range(L):
                    for i in range(3):
                        T[(49 + i) * L + s] = T[(3 + i) * L + s] - T[(3 + i) * L]
            F0, F1, F2, W0, W1, W2 = f[r, j, 0], f[r, j, 1], f[r, j, 2], w[r, j, 0], w[r, j, 1], w[r, j, 2]
            for s in range(L):  # each point's bias-compensated IMU sample (eq 38)
                T[R52 + s], T[R53 + s], T[R54 + s] = F0 - T[R25 + s], F1 - T[R26 + s], F2 - T[R27 + s]
                T[R55 + s], T[R56 + s], T[R57 + s] = W0 - T[R28 + s], W1 - T[R29 + s], W2 - T[R30 + s]
            cycles_soa(T, S, dt[j])
            if position:  # ... and after it: the trapezoid
                half = 0.5 * dt[j]
                for s in range(L):
                    for i in range(3):
                        T[(46 + i) * L + s] += (T[(49 + i) * L + s] + (T[(3 + i) * L + s] - T[(3 + i) * L])) * half
        for s in range(S):
            pos_o[r, s, 0], pos_o[r, s, 1], pos_o[r, s, 2] = T[R0 + s], T[R1 + s], T[R2 + s]
            v_o[r, s, 0], v_o[r, s, 1], v_o[r, s, 2] = T[R3 + s], T[R4 + s], T[R5 + s]
            for i in range(3):
                for k in range(3):
                    C_o[r, s, i, k] = T[(6 + 3 * i + k) * L + s]
            if position:
                for i in range(3):
                    dp_o[r, s, i] = T[(46 + i) * L + s] if s > 0 else 0.0

"""The sigma/cubature points of a batch through a time-update span, the points in SIMD lanes.

``points_span_soa`` is :func:`nespm_cli.filters.compiled.spans.points_span` restructured for the
machine: points are the columns of a state table (structure of arrays, row stride
:data:`~nespm_cli.filters.compiled.cycle_lanes.L` = 32), and each IMU step runs the navigation cycle of all
of them at once (:func:`~nespm_cli.filters.compiled.cycle_lanes.cycles_soa`), in loops over the lanes
that LLVM vectorises. The operations of each point are those of ``nav.kernels.cycle_t``, in the same
order (no contraction into fused multiply-adds, no reassociation): the same bits as the scalar
kernel and the NumPy reference ``strapdown.na_cycle`` (tests/test_points_kernel.py). The latitude's
sine and cosine are :func:`nespm_cli.nav.trig.sin_cos`, arithmetic that vectorises with the rest; only
the rare rotation above 0.01 rad (Rodrigues' sine and cosine) runs in a scalar loop between the vector
ones. Measured: ~2.4x the scalar kernel per point-cycle with the C library's latitude sines in a scalar
loop, 0.73x of that since (benchmarks/README.md).

A table costs its 32 lanes whatever they hold. Without a position block the batch's points fill the
tables in order, a run's points running on into the next table (the 12 states' 25 points: 25 tables
for 32 runs instead of 32; each lane takes its own run's IMU sample, at most three runs a table), 0.80x
per run-step at 50 runs; with one (31 points, and the position offsets need point 0 in the table) and
for a layout of 16 points or fewer, a table holds one run.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.filters.compiled.cycle_lanes import L, R0, R1, R2, R3, R4, R5, R25, R26, R27, R28, R29, R30, R46, R47, R48, \
    R52, R53, R54, R55, R56, R57, ROWS, cycles_soa, pick
from nespm_cli.filters.compiled.spans import point_start
from nespm_cli.nav.kernels import njit


@njit(cache=True, error_model="numpy")
def points_span_soa(pos, v, C, b_a, b_g, X, f, w, dt, j0, j1, pos_o, v_o, C_o, dp_o, off):
    """spans.points_span, and with a position block (``off[0] >= 0``) points_span_position
    into ``dp_o`` (R, S, 3) (the same arguments and the same bits; ``dp_o`` untouched without the block),
    with the points in the columns of state tables, IMU step by IMU step (``cycle_lanes.cycles_soa``;
    rows 46-51 the position offsets and the velocity differences from point 0): at most :data:`L` points
    per run. Without the position block a table holds the next :data:`L` points of the batch, whatever
    their runs (each lane with its run's IMU sample, at most three runs a table): the 12 states' 25 points
    per run fill every lane but the last table's, instead of 25 of every 32. With it, or with 16 points or
    fewer (more than three runs would share a table), a table holds one run's points, point 0 in lane 0."""
    S = X.shape[1] + 1
    position = off[0] >= 0
    per = S if position or 2 * S <= L else L  # the lanes of a table in use (the last table's: fewer)
    R = pos.shape[0]
    T = np.empty(ROWS * L)
    for k0 in range(0, R * S, per):
        n = min(per, R * S - k0)
        ra, p0 = k0 // S, k0 % S  # a table's first run and its first point there; the next runs follow
        rb, rc = min(ra + 1, R - 1), min(ra + 2, R - 1)
        sb, sc = min(S - p0, L), min(2 * S - p0, L)  # the lanes where the second and third runs start
        r, p = ra, p0
        for s in range(n):
            x, ba0, ba1, ba2, bg0, bg1, bg2, d0, d1, d2 = point_start(pos, v, C, b_a, b_g, X, r, p, off)
            for i in range(25):
                T[i * L + s] = x[i]
            T[R46 + s], T[R47 + s], T[R48 + s] = d0, d1, d2
            T[R25 + s], T[R26 + s], T[R27 + s], T[R28 + s], T[R29 + s], T[R30 + s] = ba0, ba1, ba2, bg0, bg1, bg2
            r, p = (r + 1, 0) if p == S - 1 else (r, p + 1)
        for s in range(n, L):  # the lanes past the last point: a copy of lane 0, finite, never read back
            for i in range(31):
                T[i * L + s] = T[i * L]
            T[R46 + s], T[R47 + s], T[R48 + s] = 0.0, 0.0, 0.0
        for j in range(j0, j1):
            if position:  # eqs 28-30 in deviation form: the velocity difference from point 0 before the step
                for s in range(L):
                    for i in range(3):
                        T[(49 + i) * L + s] = T[(3 + i) * L + s] - T[(3 + i) * L]
            a0, a1, a2, a3, a4, a5 = f[ra, j, 0], f[ra, j, 1], f[ra, j, 2], w[ra, j, 0], w[ra, j, 1], w[ra, j, 2]
            b0, b1, b2, b3, b4, b5 = f[rb, j, 0], f[rb, j, 1], f[rb, j, 2], w[rb, j, 0], w[rb, j, 1], w[rb, j, 2]
            c0, c1, c2, c3, c4, c5 = f[rc, j, 0], f[rc, j, 1], f[rc, j, 2], w[rc, j, 0], w[rc, j, 1], w[rc, j, 2]
            for s in range(L):  # each point's IMU sample, its run's, compensated with its own biases (eq 38)
                T[R52 + s] = pick(s, sb, a0, pick(s, sc, b0, c0)) - T[R25 + s]
                T[R53 + s] = pick(s, sb, a1, pick(s, sc, b1, c1)) - T[R26 + s]
                T[R54 + s] = pick(s, sb, a2, pick(s, sc, b2, c2)) - T[R27 + s]
                T[R55 + s] = pick(s, sb, a3, pick(s, sc, b3, c3)) - T[R28 + s]
                T[R56 + s] = pick(s, sb, a4, pick(s, sc, b4, c4)) - T[R29 + s]
                T[R57 + s] = pick(s, sb, a5, pick(s, sc, b5, c5)) - T[R30 + s]
            cycles_soa(T, n, dt[j])
            if position:  # ... and after it: the trapezoid
                half = 0.5 * dt[j]
                for s in range(L):
                    for i in range(3):
                        T[(46 + i) * L + s] += (T[(49 + i) * L + s] + (T[(3 + i) * L + s] - T[(3 + i) * L])) * half
        r, p = ra, p0
        for s in range(n):
            pos_o[r, p, 0], pos_o[r, p, 1], pos_o[r, p, 2] = T[R0 + s], T[R1 + s], T[R2 + s]
            v_o[r, p, 0], v_o[r, p, 1], v_o[r, p, 2] = T[R3 + s], T[R4 + s], T[R5 + s]
            for i in range(3):
                for k in range(3):
                    C_o[r, p, i, k] = T[(6 + 3 * i + k) * L + s]
            if position:
                for i in range(3):
                    dp_o[r, p, i] = T[(46 + i) * L + s] if p > 0 else 0.0
            r, p = (r + 1, 0) if p == S - 1 else (r, p + 1)

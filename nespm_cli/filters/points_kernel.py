"""The sigma/cubature points of one run through a time-update span, the points in SIMD lanes.

``points_span_soa`` is :func:`nespm_cli.filters.transition_kernel.points_span` restructured for the
machine: a run's 2n+1 points are the columns of one state table (structure of arrays, row stride
:data:`L`), and each IMU step runs the navigation cycle of all of them at once (:func:`cycles_soa`), in
loops over the points that LLVM vectorises (the row stride is a compile-time constant, so the rows
provably do not overlap). The operations of each point are those of ``nav.kernels.cycle_t``, in the
same order (no contraction into fused multiply-adds, no reassociation): the same bits as the scalar
kernel and the NumPy reference ``strapdown.na_cycle`` (tests/test_points_kernel.py). Only the sines
and cosines (latitude, the rare rotation above 0.01 rad) run in scalar loops between the vector ones.
Measured: ~2.4x the scalar kernel per point-cycle (benchmarks/README.md).
"""
from __future__ import annotations

import math

import numpy as np

from nespm_cli.filters.transition_kernel import point_start
from nespm_cli.nav.earth import A, E2, F, GAMMA_E, K_SOMIGLIANA, OMEGA_IE
from nespm_cli.nav.kernels import GRAV_M, SERIES2, exp_from, mul_t, njit

try:  # numba is a dependency; this module is imported only where it is installed (filters.kernels)
    from numba.core import types
    from numba.extending import intrinsic
except ImportError:  # pragma: no cover
    intrinsic = None

L = 32  # the row stride of the points' state table: the most points of one run (12 states: 25, 15: 31)


if intrinsic is not None:
    @intrinsic
    def fma(typingctx, x, y, z):
        """``x y + z`` rounded once (LLVM's ``llvm.fma.f64``: the FMA instruction, vectorised), float64."""
        sig = types.float64(types.float64, types.float64, types.float64)

        def codegen(context, builder, signature, args):
            return builder.fma(*args)

        return sig, codegen


@njit(cache=True, error_model="numpy", inline="always")
def div_by(x, q, r):
    """``x / q`` to the bit (IEEE division, round to nearest) for a constant ``q`` with ``r`` = fl(1/q),
    without a division: ``y = fl(x r)`` is within one ulp of x/q, the remainder ``x − y q`` is exact in
    one FMA, and ``fl(y + (x − y q) r)`` is the correctly rounded quotient (Markstein's theorem; not at
    the edges of the range: x/q subnormal, x infinite, which the points never reach; NaN stays NaN).
    3 FMA-unit operations against one division (~5x their throughput on this CPU)."""
    y = x * r
    return fma(fma(-y, q, x), r, y)


@njit(cache=True, error_model="numpy", inline="always")
def series_ab(th2):
    """exp_t's series coefficients ``(a, b)`` for the squared angle ``th2`` (rotations.exp_so3 below 0.01 rad):
    ``th2 / 6`` ... ``th2 / 56`` as :func:`div_by` (the same bits)."""
    a = 1.0 - div_by(th2, 6.0, 1.0 / 6.0) * (1.0 - div_by(th2, 20.0, 1.0 / 20.0) * (1.0 - div_by(th2, 42.0, 1.0 / 42.0)))
    b = 0.5 - div_by(th2, 24.0, 1.0 / 24.0) * (1.0 - div_by(th2, 30.0, 1.0 / 30.0) * (1.0 - div_by(th2, 56.0, 1.0 / 56.0)))
    return a, b


@njit(cache=True, error_model="numpy", inline="always")
def rodrigues_fix(T, S):
    """exp_t's Rodrigues coefficients (angle ≥ 0.01 rad) into rows 35-36 where the point's row 34 asks for them."""
    for s in range(S):
        th2 = T[34 * L + s]
        if th2 >= SERIES2:
            th = math.sqrt(th2)
            T[35 * L + s] = math.sin(th) / th
            T[36 * L + s] = (1.0 - math.cos(th)) / (th * th)


@njit(cache=True, error_model="numpy")
def cycles_soa(T, S, F0, F1, F2, W0, W1, W2, dt):
    """One navigation cycle (nav.kernels.cycle_t: the same operations in the same order) of the S points
    whose states are the columns of ``T`` (46, S): rows 0-24 the 25-tuple of cycle_t, 25-30 the points'
    ``b_a``, ``b_g``, 31-45 scratch (row 37: sin 2·lat, formed with the new latitude's sine and cosine
    for the next step). The loops without calls run over all :data:`L` lanes (a constant trip count,
    vectorised by LLVM: the points in SIMD lanes; the lanes past the S points hold copies of point 0),
    the sines and cosines over the S points in scalar loops between them."""
    half = 0.5 * dt
    for s in range(L):  # eq 25 and the series coefficients of exp(w_nb* dt/2)
        u0, u1, u2 = T[19 * L + s] + T[22 * L + s], T[20 * L + s] + T[23 * L + s], T[21 * L + s] + T[24 * L + s]
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = (T[6 * L + s], T[7 * L + s], T[8 * L + s], T[9 * L + s], T[10 * L + s], T[11 * L + s],
                                                       T[12 * L + s], T[13 * L + s], T[14 * L + s])
        p0 = ((W0 - T[28 * L + s]) - ((c00 * u0 + c10 * u1) + c20 * u2)) * half
        p1 = ((W1 - T[29 * L + s]) - ((c01 * u0 + c11 * u1) + c21 * u2)) * half
        p2 = ((W2 - T[30 * L + s]) - ((c02 * u0 + c12 * u1) + c22 * u2)) * half
        th2 = p0 * p0 + p1 * p1 + p2 * p2
        a, b = series_ab(th2)
        T[31 * L + s], T[32 * L + s], T[33 * L + s], T[34 * L + s], T[35 * L + s], T[36 * L + s] = p0, p1, p2, th2, a, b
    rodrigues_fix(T, S)
    for s in range(L):  # eqs 24, 26-30
        lat, h = T[0 * L + s], T[2 * L + s]
        v0, v1, v2 = T[3 * L + s], T[4 * L + s], T[5 * L + s]
        C = (T[6 * L + s], T[7 * L + s], T[8 * L + s], T[9 * L + s], T[10 * L + s], T[11 * L + s], T[12 * L + s], T[13 * L + s], T[14 * L + s])
        sl, R_N = T[15 * L + s], T[17 * L + s]
        ie0, ie1, ie2, en0, en1, en2 = T[19 * L + s], T[20 * L + s], T[21 * L + s], T[22 * L + s], T[23 * L + s], T[24 * L + s]
        s00, s01, s02, s10, s11, s12, s20, s21, s22 = mul_t(C, exp_from(T[31 * L + s], T[32 * L + s], T[33 * L + s], T[34 * L + s],
                                                                         T[35 * L + s], T[36 * L + s]))
        s2 = sl * sl
        g0 = GAMMA_E * (1.0 + K_SOMIGLIANA * s2) / math.sqrt(1.0 - E2 * s2)
        gN = -8.08e-9 * h * T[37 * L + s]
        gD = g0 * (1.0 - 2.0 / A * (1.0 + F + GRAV_M - 2.0 * F * s2) * h + 3.0 * h * h / A**2)
        f0, f1, f2 = F0 - T[25 * L + s], F1 - T[26 * L + s], F2 - T[27 * L + s]
        a0, a1, a2 = en0 + 2.0 * ie0, en1 + 2.0 * ie1, en2 + 2.0 * ie2
        vd0 = (((s00 * f0 + s01 * f1) + s02 * f2) + gN) - (a1 * v2 - a2 * v1)
        vd1 = (((s10 * f0 + s11 * f1) + s12 * f2) + 0.0) - (a2 * v0 - a0 * v2)
        vd2 = (((s20 * f0 + s21 * f1) + s22 * f2) + gD) - (a0 * v1 - a1 * v0)
        n0, n1, n2 = v0 + vd0 * dt, v1 + vd1 * dt, v2 + vd2 * dt
        h1 = h + (-n2 + -v2) * half
        T[38 * L + s] = lat + (v0 / (R_N + h) + n0 / (R_N + h1)) * half
        T[39 * L + s], T[40 * L + s], T[41 * L + s], T[42 * L + s] = h1, n0, n1, n2
    for s in range(S):
        T[44 * L + s] = math.sin(T[38 * L + s])
        T[45 * L + s] = math.cos(T[38 * L + s])
        T[37 * L + s] = math.sin(2.0 * T[38 * L + s])  # gravity_t's sin(2 lat) of the next step
    for s in range(L):  # earth_t at the new state, eq 32 and the series coefficients of exp(w_nb dt)
        lat1, h1, n0, n1 = T[38 * L + s], T[39 * L + s], T[40 * L + s], T[41 * L + s]
        sl, cl = T[44 * L + s], T[45 * L + s]
        den = 1.0 - E2 * (sl * sl)
        R_N = A * (1.0 - E2) / (den * math.sqrt(den))
        R_E = A / math.sqrt(den)
        e4, e5, e6 = OMEGA_IE * cl, 0.0, -OMEGA_IE * sl
        e7, e8, e9 = n1 / (R_E + h1), -n0 / (R_N + h1), -n1 * sl / cl / (R_E + h1)
        T[1 * L + s] = T[1 * L + s] + (T[4 * L + s] / ((T[18 * L + s] + T[2 * L + s]) * T[16 * L + s]) + n1 / ((R_E + h1) * cl)) * half
        u0, u1, u2 = e4 + e7, e5 + e8, e6 + e9
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = (T[6 * L + s], T[7 * L + s], T[8 * L + s], T[9 * L + s], T[10 * L + s], T[11 * L + s],
                                                       T[12 * L + s], T[13 * L + s], T[14 * L + s])
        p0 = ((W0 - T[28 * L + s]) - ((c00 * u0 + c10 * u1) + c20 * u2)) * dt
        p1 = ((W1 - T[29 * L + s]) - ((c01 * u0 + c11 * u1) + c21 * u2)) * dt
        p2 = ((W2 - T[30 * L + s]) - ((c02 * u0 + c12 * u1) + c22 * u2)) * dt
        th2 = p0 * p0 + p1 * p1 + p2 * p2
        a, b = series_ab(th2)
        T[31 * L + s], T[32 * L + s], T[33 * L + s], T[34 * L + s], T[35 * L + s], T[36 * L + s] = p0, p1, p2, th2, a, b
        T[0 * L + s], T[2 * L + s], T[3 * L + s], T[4 * L + s], T[5 * L + s] = lat1, h1, n0, n1, T[42 * L + s]
        T[15 * L + s], T[16 * L + s], T[17 * L + s], T[18 * L + s] = sl, cl, R_N, R_E
        T[19 * L + s], T[20 * L + s], T[21 * L + s], T[22 * L + s], T[23 * L + s], T[24 * L + s] = e4, e5, e6, e7, e8, e9
    rodrigues_fix(T, S)
    for s in range(L):  # eq 31: C_{k+1} = C exp(w_nb dt)
        C = (T[6 * L + s], T[7 * L + s], T[8 * L + s], T[9 * L + s], T[10 * L + s], T[11 * L + s], T[12 * L + s], T[13 * L + s], T[14 * L + s])
        E = exp_from(T[31 * L + s], T[32 * L + s], T[33 * L + s], T[34 * L + s], T[35 * L + s], T[36 * L + s])
        c = mul_t(C, E)
        for i in range(9):
            T[(6 + i) * L + s] = c[i]


@njit(cache=True, error_model="numpy")
def points_span_soa(pos, v, C, b_a, b_g, X, f, w, dt, j0, j1, pos_o, v_o, C_o, dp_o, off):
    """transition_kernel.points_span, and with a position block (``off[0] >= 0``) points_span_position
    into ``dp_o`` (R, S, 3) (the same arguments and the same bits; ``dp_o`` untouched without the block),
    with the points of a run in the columns of a state table, IMU step by IMU step (:func:`cycles_soa`;
    rows 46-51 the position offsets and the velocity differences from point 0): at most :data:`L` points."""
    S = X.shape[1] + 1
    position = off[0] >= 0
    T = np.empty(52 * L)
    for r in range(pos.shape[0]):
        for s in range(S):
            x, ba0, ba1, ba2, bg0, bg1, bg2, d0, d1, d2 = point_start(pos, v, C, b_a, b_g, X, r, s, off)
            for i in range(25):
                T[i * L + s] = x[i]
            T[46 * L + s], T[47 * L + s], T[48 * L + s] = d0, d1, d2
            T[25 * L + s], T[26 * L + s], T[27 * L + s], T[28 * L + s], T[29 * L + s], T[30 * L + s] = ba0, ba1, ba2, bg0, bg1, bg2
        for s in range(L):
            if s >= S:  # the lanes past the last point: a copy of point 0, finite, never read back
                for i in range(31):
                    T[i * L + s] = T[i * L]
                T[46 * L + s], T[47 * L + s], T[48 * L + s] = 0.0, 0.0, 0.0
                T[44 * L + s], T[45 * L + s] = T[15 * L], T[16 * L]
            T[37 * L + s] = math.sin(2.0 * T[s])  # gravity_t's sin(2 lat) of the first step
        for j in range(j0, j1):
            if position:  # eqs 28-30 in deviation form: the velocity difference from point 0 before the step
                for s in range(L):
                    for i in range(3):
                        T[(49 + i) * L + s] = T[(3 + i) * L + s] - T[(3 + i) * L]
            cycles_soa(T, S, f[r, j, 0], f[r, j, 1], f[r, j, 2], w[r, j, 0], w[r, j, 1], w[r, j, 2], dt[j])
            if position:  # ... and after it: the trapezoid
                half = 0.5 * dt[j]
                for s in range(L):
                    for i in range(3):
                        T[(46 + i) * L + s] += (T[(49 + i) * L + s] + (T[(3 + i) * L + s] - T[(3 + i) * L])) * half
        for s in range(S):
            pos_o[r, s, 0], pos_o[r, s, 1], pos_o[r, s, 2] = T[0 * L + s], T[1 * L + s], T[2 * L + s]
            v_o[r, s, 0], v_o[r, s, 1], v_o[r, s, 2] = T[3 * L + s], T[4 * L + s], T[5 * L + s]
            for i in range(3):
                for k in range(3):
                    C_o[r, s, i, k] = T[(6 + 3 * i + k) * L + s]
            if position:
                for i in range(3):
                    dp_o[r, s, i] = T[(46 + i) * L + s] if s > 0 else 0.0

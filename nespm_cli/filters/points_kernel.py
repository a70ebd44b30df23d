"""The sigma/cubature points of one run through a time-update span, the points in SIMD lanes.

``points_span_soa`` is :func:`nespm_cli.filters.transition_kernel.points_span` restructured for the
machine: a run's 2n+1 points are the columns of one state table (structure of arrays, row stride
:data:`L`), and each IMU step runs the navigation cycle of all of them at once (:func:`cycles_soa`), in
loops over the points that LLVM vectorises (the row stride is a compile-time constant, so the rows
provably do not overlap). The operations of each point are those of ``nav.kernels.cycle_t``, in the
same order (no contraction into fused multiply-adds, no reassociation): the same bits as the scalar
kernel and the NumPy reference ``strapdown.na_cycle`` (tests/test_points_kernel.py). The latitude's
sine and cosine are :func:`nespm_cli.nav.trig.sin_cos`, arithmetic that vectorises with the rest; only
the rare rotation above 0.01 rad (Rodrigues' sine and cosine) runs in a scalar loop between the vector
ones. Measured: ~2.4x the scalar kernel per point-cycle with the C library's latitude sines in a scalar
loop, 0.73x of that since (benchmarks/README.md).
"""
from __future__ import annotations

import math

import numpy as np

from nespm_cli.filters.transition_kernel import point_start
from nespm_cli.nav.earth import A, E2, F, GAMMA_E, K_SOMIGLIANA, OMEGA_IE
from nespm_cli.nav.kernels import GRAV_M, SERIES2, exp_from, helper, mul_t, njit, sin_cos_t

try:  # numba is a dependency; this module is imported only where it is installed (filters.kernels)
    from numba.core import types
    from numba.extending import intrinsic
except ImportError:  # pragma: no cover
    intrinsic = None

L = 32  # the row stride of the points' state table: the most points of one run (12 states: 25, 15: 31)
#: ``Rk`` = k · L, where row k of the state table starts: a named constant, so numba types and lowers one
#: addition per table access instead of ``k * L + s``'s two (~0.3 of the points kernel's 3.3 CPU-s to compile)
(R0, R1, R2, R3, R4, R5, R6, R7, R8, R9, R10, R11, R12, R13, R14, R15, R16, R17, R18, R19, R20, R21, R22,
 R23, R24, R25, R26, R27, R28, R29, R30, R31, R32, R33, R34, R35, R36, R37, R38, R39, R40, R41, R42, R43,
 R44, R45, R46, R47, R48, R49, R50, R51) = [k * L for k in range(52)]


if intrinsic is not None:
    @intrinsic
    def fma(typingctx, x, y, z):
        """``x y + z`` rounded once (LLVM's ``llvm.fma.f64``: the FMA instruction, vectorised), float64."""
        sig = types.float64(types.float64, types.float64, types.float64)

        def codegen(context, builder, signature, args):
            return builder.fma(*args)

        return sig, codegen


@helper(python=True)
def div_by(x, q, r):
    """``x / q`` to the bit (IEEE division, round to nearest) for a constant ``q`` with ``r`` = fl(1/q),
    without a division: ``y = fl(x r)`` is within one ulp of x/q, the remainder ``x − y q`` is exact in
    one FMA, and ``fl(y + (x − y q) r)`` is the correctly rounded quotient (Markstein's theorem; not at
    the edges of the range: x/q subnormal, x infinite, which the points never reach; NaN stays NaN).
    3 FMA-unit operations against one division (~5x their throughput on this CPU)."""
    y = x * r
    return fma(fma(-y, q, x), r, y)


@helper(python=True)
def series_ab(th2):
    """exp_t's series coefficients ``(a, b)`` for the squared angle ``th2`` (rotations.exp_so3 below 0.01 rad):
    ``th2 / 6`` ... ``th2 / 56`` as :func:`div_by` (the same bits)."""
    a = 1.0 - div_by(th2, 6.0, 1.0 / 6.0) * (1.0 - div_by(th2, 20.0, 1.0 / 20.0) * (1.0 - div_by(th2, 42.0, 1.0 / 42.0)))
    b = 0.5 - div_by(th2, 24.0, 1.0 / 24.0) * (1.0 - div_by(th2, 30.0, 1.0 / 30.0) * (1.0 - div_by(th2, 56.0, 1.0 / 56.0)))
    return a, b


@helper
def rodrigues_fix(T, S):
    """exp_t's Rodrigues coefficients (angle ≥ 0.01 rad) into rows 35-36 where the point's row 34 asks for them."""
    for s in range(S):
        th2 = T[R34 + s]
        if th2 >= SERIES2:
            th = math.sqrt(th2)
            T[R35 + s] = math.sin(th) / th
            T[R36 + s] = (1.0 - math.cos(th)) / (th * th)


@njit(cache=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)  # called by points_span_soa only
def cycles_soa(T, S, F0, F1, F2, W0, W1, W2, dt):
    """One navigation cycle (nav.kernels.cycle_t: the same operations in the same order) of the S points
    whose states are the columns of ``T`` (46, S): rows 0-24 the 25-tuple of cycle_t, 25-30 the points'
    ``b_a``, ``b_g``, 31-43 scratch. The loops without calls run over all :data:`L` lanes (a constant trip
    count, vectorised by LLVM: the points in SIMD lanes; the lanes past the S points hold copies of
    point 0), Rodrigues' sines and cosines over the S points in a scalar loop between them."""
    half = 0.5 * dt
    for s in range(L):  # eq 25 and the series coefficients of exp(w_nb* dt/2)
        u0, u1, u2 = T[R19 + s] + T[R22 + s], T[R20 + s] + T[R23 + s], T[R21 + s] + T[R24 + s]
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = (T[R6 + s], T[R7 + s], T[R8 + s], T[R9 + s], T[R10 + s], T[R11 + s],
                                                       T[R12 + s], T[R13 + s], T[R14 + s])
        p0 = ((W0 - T[R28 + s]) - ((c00 * u0 + c10 * u1) + c20 * u2)) * half
        p1 = ((W1 - T[R29 + s]) - ((c01 * u0 + c11 * u1) + c21 * u2)) * half
        p2 = ((W2 - T[R30 + s]) - ((c02 * u0 + c12 * u1) + c22 * u2)) * half
        th2 = p0 * p0 + p1 * p1 + p2 * p2
        a, b = series_ab(th2)
        T[R31 + s], T[R32 + s], T[R33 + s], T[R34 + s], T[R35 + s], T[R36 + s] = p0, p1, p2, th2, a, b
    rodrigues_fix(T, S)
    for s in range(L):  # eqs 24, 26-30
        lat, h = T[R0 + s], T[R2 + s]
        v0, v1, v2 = T[R3 + s], T[R4 + s], T[R5 + s]
        C = (T[R6 + s], T[R7 + s], T[R8 + s], T[R9 + s], T[R10 + s], T[R11 + s], T[R12 + s], T[R13 + s], T[R14 + s])
        sl, cl, R_N = T[R15 + s], T[R16 + s], T[R17 + s]
        ie0, ie1, ie2, en0, en1, en2 = T[R19 + s], T[R20 + s], T[R21 + s], T[R22 + s], T[R23 + s], T[R24 + s]
        s00, s01, s02, s10, s11, s12, s20, s21, s22 = mul_t(C, exp_from(T[R31 + s], T[R32 + s], T[R33 + s], T[R34 + s],
                                                                         T[R35 + s], T[R36 + s]))
        s2 = sl * sl
        g0 = GAMMA_E * (1.0 + K_SOMIGLIANA * s2) / math.sqrt(1.0 - E2 * s2)
        gN = -8.08e-9 * h * (2.0 * sl * cl)
        gD = g0 * (1.0 - 2.0 / A * (1.0 + F + GRAV_M - 2.0 * F * s2) * h + 3.0 * h * h / A**2)
        f0, f1, f2 = F0 - T[R25 + s], F1 - T[R26 + s], F2 - T[R27 + s]
        a0, a1, a2 = en0 + 2.0 * ie0, en1 + 2.0 * ie1, en2 + 2.0 * ie2
        vd0 = (((s00 * f0 + s01 * f1) + s02 * f2) + gN) - (a1 * v2 - a2 * v1)
        vd1 = (((s10 * f0 + s11 * f1) + s12 * f2) + 0.0) - (a2 * v0 - a0 * v2)
        vd2 = (((s20 * f0 + s21 * f1) + s22 * f2) + gD) - (a0 * v1 - a1 * v0)
        n0, n1, n2 = v0 + vd0 * dt, v1 + vd1 * dt, v2 + vd2 * dt
        h1 = h + (-n2 + -v2) * half
        T[R38 + s] = lat + (v0 / (R_N + h) + n0 / (R_N + h1)) * half
        T[R39 + s], T[R40 + s], T[R41 + s], T[R42 + s] = h1, n0, n1, n2
    for s in range(L):  # earth_t at the new state, eq 32 and the series coefficients of exp(w_nb dt)
        lat1, h1, n0, n1 = T[R38 + s], T[R39 + s], T[R40 + s], T[R41 + s]
        sl, cl = sin_cos_t(lat1)
        den = 1.0 - E2 * (sl * sl)
        R_N = A * (1.0 - E2) / (den * math.sqrt(den))
        R_E = A / math.sqrt(den)
        e4, e5, e6 = OMEGA_IE * cl, 0.0, -OMEGA_IE * sl
        e7, e8, e9 = n1 / (R_E + h1), -n0 / (R_N + h1), -n1 * sl / cl / (R_E + h1)
        T[R1 + s] = T[R1 + s] + (T[R4 + s] / ((T[R18 + s] + T[R2 + s]) * T[R16 + s]) + n1 / ((R_E + h1) * cl)) * half
        u0, u1, u2 = e4 + e7, e5 + e8, e6 + e9
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = (T[R6 + s], T[R7 + s], T[R8 + s], T[R9 + s], T[R10 + s], T[R11 + s],
                                                       T[R12 + s], T[R13 + s], T[R14 + s])
        p0 = ((W0 - T[R28 + s]) - ((c00 * u0 + c10 * u1) + c20 * u2)) * dt
        p1 = ((W1 - T[R29 + s]) - ((c01 * u0 + c11 * u1) + c21 * u2)) * dt
        p2 = ((W2 - T[R30 + s]) - ((c02 * u0 + c12 * u1) + c22 * u2)) * dt
        th2 = p0 * p0 + p1 * p1 + p2 * p2
        a, b = series_ab(th2)
        T[R31 + s], T[R32 + s], T[R33 + s], T[R34 + s], T[R35 + s], T[R36 + s] = p0, p1, p2, th2, a, b
        T[R0 + s], T[R2 + s], T[R3 + s], T[R4 + s], T[R5 + s] = lat1, h1, n0, n1, T[R42 + s]
        T[R15 + s], T[R16 + s], T[R17 + s], T[R18 + s] = sl, cl, R_N, R_E
        T[R19 + s], T[R20 + s], T[R21 + s], T[R22 + s], T[R23 + s], T[R24 + s] = e4, e5, e6, e7, e8, e9
    rodrigues_fix(T, S)
    for s in range(L):  # eq 31: C_{k+1} = C exp(w_nb dt)
        C = (T[R6 + s], T[R7 + s], T[R8 + s], T[R9 + s], T[R10 + s], T[R11 + s], T[R12 + s], T[R13 + s], T[R14 + s])
        E = exp_from(T[R31 + s], T[R32 + s], T[R33 + s], T[R34 + s], T[R35 + s], T[R36 + s])
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
            cycles_soa(T, S, f[r, j, 0], f[r, j, 1], f[r, j, 2], w[r, j, 0], w[r, j, 1], w[r, j, 2], dt[j])
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

"""One navigation cycle of many states at once, the states in SIMD lanes (numba; :mod:`.points`,
:mod:`.lanes_12`, :mod:`.lanes_15`).

A state table ``T`` holds up to :data:`L` states as its columns (structure of arrays, row stride
:data:`L`): rows 0-24 the 25-tuple of ``nav.kernels.cycle_t``, 25-30 ``b_a``, ``b_g`` (the points'
kernel's), 31-45 scratch, 46-51 the caller's, 52-57 each lane's bias-compensated IMU sample
``f_b − b_a``, ``w_ib_b − b_g`` (:data:`RF`). :func:`cycles_soa` runs the cycle of every lane in loops
over the lanes that LLVM vectorises (the row stride is a compile-time constant, so the rows provably do
not overlap), with the operations of ``cycle_t`` in the same order (no contraction into fused
multiply-adds, no reassociation): the same bits as the scalar kernel and the NumPy reference
``strapdown.na_cycle``. The lanes are sigma/cubature points (:mod:`.points`: of one run or of up to
three, each point with its run's IMU sample and its own biases) or the runs themselves (:mod:`.lanes_12`,
:mod:`.lanes_15`: each run's IMU).
"""
from __future__ import annotations

import math

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
 R44, R45, R46, R47, R48, R49, R50, R51, R52, R53, R54, R55, R56, R57) = [k * L for k in range(58)]
#: the rows of the lanes' bias-compensated IMU sample: f_b − b_a (3), w_ib_b − b_g (3)
RF = R52
#: rows in a state table
ROWS = 58


if intrinsic is not None:
    @intrinsic
    def fma(typingctx, x, y, z):
        """``x y + z`` rounded once (LLVM's ``llvm.fma.f64``: the FMA instruction, vectorised), float64."""
        sig = types.float64(types.float64, types.float64, types.float64)

        def codegen(context, builder, signature, args):
            return builder.fma(*args)

        return sig, codegen

    @intrinsic
    def pick(typingctx, lane, first, x, y):
        """``x`` where ``lane < first``, else ``y`` (int64 lane and bound, float64 values): LLVM's ``select``
        on a comparison, without the branch a conditional expression gives numba's IR (vectorised either way;
        this compiles faster)."""
        sig = types.float64(types.int64, types.int64, types.float64, types.float64)

        def codegen(context, builder, signature, args):
            lane, first, x, y = args
            return builder.select(builder.icmp_signed("<", lane, first), x, y)

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


@njit(cache=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)  # called by kernels only
def cycles_soa(T, S, dt):
    """One navigation cycle (nav.kernels.cycle_t: the same operations in the same order) of the S lanes
    whose states are the columns of the state table ``T`` (:data:`ROWS` · :data:`L`, module docstring), each
    with its bias-compensated IMU sample in rows :data:`RF` ... RF + 5, over the step ``dt`` [s]; rows 31-45
    scratch. The loops without calls run over all :data:`L` lanes (a constant trip count, vectorised by
    LLVM; the lanes past the S hold finite copies, never read back), Rodrigues' sines and cosines over
    the S lanes in a scalar loop between them."""
    half = 0.5 * dt
    for s in range(L):  # eq 25 and the series coefficients of exp(w_nb* dt/2)
        u0, u1, u2 = T[R19 + s] + T[R22 + s], T[R20 + s] + T[R23 + s], T[R21 + s] + T[R24 + s]
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = (T[R6 + s], T[R7 + s], T[R8 + s], T[R9 + s], T[R10 + s], T[R11 + s],
                                                       T[R12 + s], T[R13 + s], T[R14 + s])
        p0 = (T[R55 + s] - ((c00 * u0 + c10 * u1) + c20 * u2)) * half
        p1 = (T[R56 + s] - ((c01 * u0 + c11 * u1) + c21 * u2)) * half
        p2 = (T[R57 + s] - ((c02 * u0 + c12 * u1) + c22 * u2)) * half
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
        f0, f1, f2 = T[R52 + s], T[R53 + s], T[R54 + s]
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
        p0 = (T[R55 + s] - ((c00 * u0 + c10 * u1) + c20 * u2)) * dt
        p1 = (T[R56 + s] - ((c01 * u0 + c11 * u1) + c21 * u2)) * dt
        p2 = (T[R57 + s] - ((c02 * u0 + c12 * u1) + c22 * u2)) * dt
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

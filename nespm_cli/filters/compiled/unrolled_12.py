"""The papers' 12-state common-error Φ kernel, unrolled, run by run (numba; called through
:mod:`nespm_cli.filters.kernels` for fewer than ``kernels.LANES_MIN`` runs; from there :mod:`.lanes_12`, the
same bits).

``transition_span_12`` is :func:`nespm_cli.filters.compiled.spans.transition_span_common` for the
layout ``[dv, dpsi, b_a, b_g]`` (offsets -1, 0, 3, 6, 9) with its loops written out: the 36 entries of
the velocity/attitude block of ``I + F dt`` and the 18 of its bias columns are scalars, and each entry
of Φ's changing rows is the same sum in the same order, ``0.0 + M[i, 0] Φ[0, k] + ... + M[i, 5] Φ[5, k]
(+ M[i, k] for a bias column)``, F's structural zeros included as ``0.0 · dt`` terms. The same IEEE
operations in the same order, so the same bits, zeros' signs included, and NaN where the loop gives NaN
(its payload aside) for an inf or NaN input (tests/test_compile_kernels.py). Why: the generic loop's
runtime bounds cost numba and LLVM about 1.3 CPU-s more to compile (benchmarks/README.md, the compile
section), and every ``mc`` of the default filters compiles this kernel on a machine's first run.
"""
from __future__ import annotations

import math

from nespm_cli.filters.compiled.entries import va_entries_t
from nespm_cli.nav.kernels import cycle_t, load_t, njit, store_t


@njit(cache=True, error_model="numpy")
def transition_span_12(pos, v, C, b_a, b_g, f, w, dt, j0, j1, Phi):
    """Steps ``[j0, j1)`` in place on the solution; Φ (R, 12, 12) = Π (I + F dt) into ``Phi`` for the
    common error (model.system_matrix) of the 12 states: transition_span_common's numbers, unrolled."""
    for r in range(pos.shape[0]):
        P = Phi[r]
        for i in range(12):
            for k in range(12):
                P[i, k] = 1.0 if i == k else 0.0
        x = load_t(pos[r], v[r], C[r])
        ba0, ba1, ba2, bg0, bg1, bg2 = b_a[r, 0], b_a[r, 1], b_a[r, 2], b_g[r, 0], b_g[r, 1], b_g[r, 2]
        for j in range(j0, j1):
            f0, f1, f2 = f[r, j, 0] - ba0, f[r, j, 1] - ba1, f[r, j, 2] - ba2
            h = dt[j]
            # system_rows_s: F's velocity and attitude rows, then identity_plus_dt: M = I + F dt
            (m00, m01, m02, m10, m11, m12, m20, m21, n04, n05, n13, n15, n23, n24, q31, q40, q51,
             t34, t35, t43, t45, t53, t54) = va_entries_t(x, math.tan(x[0]), f0, f1, f2, h)
            z = 0.0 * h  # a structural zero of F, times dt
            m22 = 0.0 * h + 1.0
            d33, d44, d55 = 0.0 * h + 1.0, 0.0 * h + 1.0, 0.0 * h + 1.0
            b00, b01, b02, b10, b11, b12 = -x[6] * h, -x[7] * h, -x[8] * h, -x[9] * h, -x[10] * h, -x[11] * h
            b20, b21, b22 = -x[12] * h, -x[13] * h, -x[14] * h
            # transition_span_common's row loop, column by column (a column of Φ's new rows reads only that column)
            for k in range(12):
                V0, V1, V2, A0, A1, A2 = P[0, k], P[1, k], P[2, k], P[3, k], P[4, k], P[5, k]
                d0 = 0.0 + m00 * V0 + m01 * V1 + m02 * V2 + z * A0 + n04 * A1 + n05 * A2
                d1 = 0.0 + m10 * V0 + m11 * V1 + m12 * V2 + n13 * A0 + z * A1 + n15 * A2
                d2 = 0.0 + m20 * V0 + m21 * V1 + m22 * V2 + n23 * A0 + n24 * A1 + z * A2
                e0 = 0.0 + z * V0 + q31 * V1 + z * V2 + d33 * A0 + t34 * A1 + t35 * A2
                e1 = 0.0 + q40 * V0 + z * V1 + z * V2 + t43 * A0 + d44 * A1 + t45 * A2
                e2 = 0.0 + z * V0 + q51 * V1 + z * V2 + t53 * A0 + t54 * A1 + d55 * A2
                if k >= 6:  # the bias columns: + M[i, k] (-C dt: b_a into the velocity rows, b_g into the attitude rows)
                    c = k - 6 if k < 9 else k - 9
                    if c == 0:
                        c0, c1, c2 = b00, b10, b20
                    elif c == 1:
                        c0, c1, c2 = b01, b11, b21
                    else:
                        c0, c1, c2 = b02, b12, b22
                    if k < 9:
                        d0, d1, d2, e0, e1, e2 = d0 + c0, d1 + c1, d2 + c2, e0 + z, e1 + z, e2 + z
                    else:
                        d0, d1, d2, e0, e1, e2 = d0 + z, d1 + z, d2 + z, e0 + c0, e1 + c1, e2 + c2
                P[0, k], P[1, k], P[2, k], P[3, k], P[4, k], P[5, k] = d0, d1, d2, e0, e1, e2
            x = cycle_t(x, f0, f1, f2, w[r, j, 0] - bg0, w[r, j, 1] - bg1, w[r, j, 2] - bg2, h)
        store_t(x, pos[r], v[r], C[r])

"""The scalar entries of ``I + F dt``'s velocity and attitude rows for the common error (numba helper;
model.system_matrix's F, ukf-nespm.md's error model), shared by the unrolled Φ kernels of the papers'
12 states (:mod:`.unrolled_12`) and of the 15 states (``transition_span_position`` in
:mod:`.spans`). Each entry is the sum the generic loop (``system_rows_s`` then
``identity_plus_dt``) forms, in its order, so the kernels keep its bits (tests/test_compile_kernels.py).
"""
from __future__ import annotations

from nespm_cli.nav.kernels import helper


@helper
def va_entries_t(x, tan_lat, f0, f1, f2, h):
    """The non-structural entries of ``M = I + F dt`` on the velocity (rows 0-2) and attitude (rows 3-5)
    rows, columns ``[dv, dpsi]``, at the solution tuple ``x`` (``nav.kernels.load_t``) with ``tan_lat`` =
    ``math.tan(x[0])`` (the caller's: a kernel with its lanes in SIMD takes it in a scalar loop), the
    bias-compensated specific force ``f0, f1, f2`` [m/s²] and the step ``h`` [s]:
    ``(m00, m01, m02, m10, m11, m12, m20, m21, n04, n05, n13, n15, n23, n24, q31, q40, q51, t34, t35, t43,
    t45, t53, t54)``: ``m`` the velocity block (``m22 = 1 + 0 dt`` is the caller's), ``n`` the velocity rows'
    attitude columns (``[f^n ×] dt``), ``q`` the attitude rows' velocity columns (``-J dt``), ``t`` the
    attitude block's off-diagonal (``-[ω_in ×] dt``)."""
    ht = x[2]
    J01 = 1.0 / (x[18] + ht)
    J10 = -1.0 / (x[17] + ht)
    J21 = -tan_lat / (x[18] + ht)
    u0, u1, u2 = 2.0 * x[19] + x[22], 2.0 * x[20] + x[23], 2.0 * x[21] + x[24]
    a01, a02, a12 = u2, -u1, u0
    v0, v1, v2 = x[3], x[4], x[5]
    m00 = -v2 * J10 * h + 1.0
    m01 = (a01 + v1 * J21) * h
    m02 = a02 * h
    m10 = (-a01 + 0.0) * h
    m11 = (v2 * J01 + -v0 * J21) * h + 1.0
    m12 = a12 * h
    m20 = (-a02 + v0 * J10) * h
    m21 = (-a12 + -v1 * J01) * h
    fn0 = x[6] * f0 + x[7] * f1 + x[8] * f2
    fn1 = x[9] * f0 + x[10] * f1 + x[11] * f2
    fn2 = x[12] * f0 + x[13] * f1 + x[14] * f2
    n04, n05, n13, n15, n23, n24 = fn2 * h, -fn1 * h, -fn2 * h, fn0 * h, fn1 * h, -fn0 * h
    q31, q40, q51 = -J01 * h, -J10 * h, -J21 * h
    w0, w1, w2 = x[19] + x[22], x[20] + x[23], x[21] + x[24]
    t34, t35, t43, t45, t53, t54 = w2 * h, -w1 * h, -w2 * h, w0 * h, w1 * h, -w0 * h
    return (m00, m01, m02, m10, m11, m12, m20, m21, n04, n05, n13, n15, n23, n24, q31, q40, q51,
            t34, t35, t43, t45, t53, t54)


__all__ = ["va_entries_t"]

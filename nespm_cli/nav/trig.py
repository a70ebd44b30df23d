"""Sine and cosine of a latitude in one polynomial: the same bits in NumPy and in the compiled kernels,
and vectorisable there.

The navigation cycle needs ``sin L`` and ``cos L`` of every state at every IMU step (the radii, gravity,
the earth and transport rates, eqs 25-32). The C library's ``sin`` and ``cos`` are calls the compiler
cannot put in SIMD lanes: in the sigma-point kernel (25 points per run, 100 steps per second) they were
a third of its time. :func:`sin_cos` is arithmetic only (``floor``, ``sqrt`` and the four operations,
no branch), so a compiled loop over the points vectorises it, and NumPy evaluates the very same
operations in the same order: the NumPy reference (:mod:`.earth`, :mod:`.strapdown`) and the kernels
(:mod:`.kernels`, the filters' points kernel) agree bit for bit, as they did with the C library.

The method (the textbook one of fdlibm's kernels, with coefficients of our own): ``x = k π/2 + r``
with ``|r| ≤ π/4`` and ``k`` in {-1, 0, 1} (π/2 split into 33 + 53 bits, ``x − k · PIO2_HI`` exact),
the Taylor series of ``sin r`` to ``r^17`` and of ``cos r`` to ``r^16`` (truncation below 0.03 ulp at
π/4) in Estrin's scheme (a third of Horner's latency, which the scalar kernels' IMU steps wait on),
``cos r`` summed as ``w + ((1 − w) − r²/2) + …`` with ``w = 1 − r²/2`` (the rounding of the large term
carried), and the quadrant applied by exact multiplications by 0 and ±1.

Accuracy against the C library's correctly rounded values (tests/test_trig.py): within 1 ulp on
``|x| ≤ π/2 − 1e-9``, equal in about 90 % of the arguments; at the poles themselves ``cos L`` (~6e-17)
is off by less than 1e-25. ``sin(-0.0)`` is ``+0.0``. An extended-precision ``x`` (``np.longdouble``:
tests that difference positions) is reduced and summed in its own precision with these float64
constants: about float64's accuracy. The choice, and why (docs/conventions.md, "Sines of latitude"):
the same bits in both implementations and the points in SIMD lanes, for at most 1 ulp from ``np.sin``.
"""
from __future__ import annotations

import math

import numpy as np

PIO2_HI = 1.5707963267341256  # π/2 with its significand cut to 33 bits: k · PIO2_HI is exact for |k| < 2^20
PIO2_LO = 6.077100506506192e-11  # π/2 − PIO2_HI, rounded
TWO_OVER_PI = 0.6366197723675814  # 2/π, rounded
#: sin r = r + r³ (S1 + r² (S2 + …)): (−1)^k / (2k+1)!, k = 1..8
S1, S2, S3, S4, S5, S6, S7, S8 = [(-1.0) ** k / math.factorial(2 * k + 1) for k in range(1, 9)]
#: cos r = 1 − r²/2 + r⁴ (C2 + r² (C3 + …)): (−1)^k / (2k)!, k = 2..8
C2, C3, C4, C5, C6, C7, C8 = [(-1.0) ** k / math.factorial(2 * k) for k in range(2, 9)]


def sin_cos(x):
    """``(sin x, cos x)`` of a latitude ``x`` [rad] (a float, or an array: elementwise, the shape of ``x``):
    :func:`sin_cos_core` without NumPy's warning where it returns NaN (``|x| > 3π/4``)."""
    with np.errstate(invalid="ignore"):
        return sin_cos_core(x)


def sin_cos_core(x):
    """``(sin x, cos x)`` by the reduction and series of the module docstring; NaN beyond ``|x| > 3π/4``,
    where no latitude is (a diverged solution's shows as lost, not as a wrong sine). Only arithmetic,
    ``np.floor`` and ``np.sqrt``, about 50 array operations: numba compiles it
    (:data:`nespm_cli.nav.kernels.sin_cos_t`) to the same bits, in SIMD lanes inside a loop."""
    k = np.floor(x * TWO_OVER_PI + 0.5)  # the nearest integer: -1, 0 or 1 for a latitude
    r = (x - k * PIO2_HI) - k * PIO2_LO
    z = r * r
    z2 = z * z
    z4 = z2 * z2  # Estrin's scheme
    ps = r + r * z * (((S1 + S2 * z) + (S3 + S4 * z) * z2) + ((S5 + S6 * z) + (S7 + S8 * z) * z2) * z4)
    hz = 0.5 * z
    w = 1.0 - hz
    pc = w + (((1.0 - w) - hz) + z2 * (((C2 + C3 * z) + (C4 + C5 * z) * z2) + ((C6 + C7 * z) + C8 * z2) * z4))
    even = 1.0 - k * k  # k = 0: (sin r, cos r); k = ±1: (±cos r, ∓sin r)
    nan = 0.0 * np.sqrt(even)  # 0, or NaN where |k| > 1 (formed beside the series, off its critical path)
    return (even * ps + k * pc) + nan, (even * pc - k * ps) + nan


__all__ = ["PIO2_HI", "PIO2_LO", "TWO_OVER_PI", "sin_cos", "sin_cos_core"]

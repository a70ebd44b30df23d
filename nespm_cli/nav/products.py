"""3x3 products written as elementwise sums, batched over leading axes (no BLAS).

``C @ E`` through ``np.matmul`` goes to the BLAS library for stacked matrices, whose kernels
(fused multiply-adds, summation order) differ between libraries and CPUs, so the last bit
of the navigation cycle would depend on the machine. These products are plain IEEE
multiplies and adds in a fixed order, ``(x0 y0 + x1 y1) + x2 y2``, the order the compiled
loop (:mod:`nespm_cli.nav.kernels`) uses too: the NumPy reference and the compiled filters
then agree to the bit on the navigation cycle, which matters for ``ukf-nespm``, whose mean
weighs the sigma points' round-off by ~4e4 (α = 1e-3).
"""
from __future__ import annotations

import numpy as np


def mat_mul(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """``X @ Y`` for (..., 3, 3) matrices (broadcast) -> (..., 3, 3)."""
    return (X[..., :, 0:1] * Y[..., 0:1, :] + X[..., :, 1:2] * Y[..., 1:2, :]) + X[..., :, 2:3] * Y[..., 2:3, :]


def mat_vec(C: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``C @ x`` for (..., 3, 3) and (..., 3) -> (..., 3)."""
    return (C[..., :, 0] * x[..., 0, None] + C[..., :, 1] * x[..., 1, None]) + C[..., :, 2] * x[..., 2, None]


def matT_vec(C: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``C^T @ x`` for (..., 3, 3) and (..., 3) -> (..., 3)."""
    return (C[..., 0, :] * x[..., 0, None] + C[..., 1, :] * x[..., 1, None]) + C[..., 2, :] * x[..., 2, None]

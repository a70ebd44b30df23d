"""Third-degree spherical-radial cubature rule (Arasaratnam & Haykin 2009), from deviations.

For an n-dimensional Gaussian N(x̄, P), ``P = L Lᵀ`` (Cholesky), the rule uses the 2n points
``x̄ + ξ_i`` with offsets

    ξ_i = +√n · L[:, i],   ξ_{n+i} = −√n · L[:, i]     (i = 0 .. n−1)

all with the weight ``w = 1 / (2n)``; no centre point and no tuning parameters. It integrates
every polynomial of degree ≤ 3 exactly (so the moments of a linear map are exact, and the
mean of a quadratic one).

As for the unscented transform (:mod:`nespm_cli.filters.unscented`, the house rule), the
moments are never formed from large cancelling sums of whole point images. The caller
passes the *deviations* ``d_i = y_i − y_ref`` of the point images from the image of a
reference point (the mean itself, mapped, or propagated as in ``ckf-nespm``); then

    m   = Σ w d_i                       (each ± pair summed first, as ``unscented.moments``)
    P   = Σ w (d_i − m)(d_i − m)ᵀ  =  Σ w d_i d_iᵀ − m mᵀ

so ``y_ref + m`` is the mean and P the exact weighted covariance about it. P is computed in
the centred (two-pass) form on the left, which is algebraically the right-hand side, is
positive semi-definite by construction and never subtracts two large matrices.

Shapes: a leading batch axis B (runs), 2n points, a state / b measurement components.
Units are those of the deviations (the filters: SI, ``[dv m/s, dpsi rad, b_a m/s², b_g rad/s]``).
"""
from __future__ import annotations

import numpy as np


def cubature_weight(n: int) -> float:
    """The weight of every cubature point, ``1 / (2n)``."""
    return 0.5 / n


def cubature_offsets(L: np.ndarray) -> np.ndarray:
    """The 2n cubature offsets (B, 2n, n) from Cholesky factors ``L`` (B, n, n), ``P = L Lᵀ``.

    Row i is ``+√n · L[:, i]`` for i < n and ``−√n · L[:, i − n]`` after.
    """
    n = L.shape[-1]
    cols = np.sqrt(n) * np.swapaxes(L, -1, -2)  # row i = column i of L
    return np.concatenate([cols, -cols], axis=-2)


def _mean(d: np.ndarray, w: float) -> np.ndarray:
    """``Σ w d_i`` (B, a) of deviations (B, 2n, a), each ± pair summed first."""
    n = d.shape[-2] // 2
    # the pair sums are the small (second-order) part of the images: for a linear map they are
    # exactly zero, so the mean is exactly the reference image and P exactly Σ w d dᵀ
    return w * (d[..., :n, :] + d[..., n:, :]).sum(axis=-2)


def cubature_moments(dx: np.ndarray, dz: np.ndarray | None = None):
    """Mean offset and covariance from the deviations ``dx`` (B, 2n, a) of the 2n point images.

    Returns ``(m, P)``: ``m`` (B, a) the mean minus the reference image, ``P`` (B, a, a) the
    weighted covariance about the mean (exactly symmetric). With ``dz`` (B, 2n, b), the
    deviations of the same points' measurement images, returns ``(m, P, mz, Pzz, Pxz)`` with
    ``mz`` (B, b), ``Pzz`` (B, b, b) and the cross covariance ``Pxz`` (B, a, b).
    """
    if dx.shape[-2] % 2:
        raise ValueError(f"cubature_moments: expected 2n points, got {dx.shape[-2]}")
    w = cubature_weight(dx.shape[-2] // 2)
    m = _mean(dx, w)
    Dx = dx - m[..., None, :]
    P = w * (np.swapaxes(Dx, -1, -2) @ Dx)
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    if dz is None:
        return m, P
    mz = _mean(dz, w)
    Dz = dz - mz[..., None, :]
    Pzz = w * (np.swapaxes(Dz, -1, -2) @ Dz)
    Pzz = 0.5 * (Pzz + np.swapaxes(Pzz, -1, -2))
    Pxz = w * (np.swapaxes(Dx, -1, -2) @ Dz)
    return m, P, mz, Pzz, Pxz


__all__ = ["cubature_moments", "cubature_offsets", "cubature_weight"]

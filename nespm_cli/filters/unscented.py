"""Scaled unscented transform (anukf.md / ukf-nespm.md eqs 5-23), formed from deviations.

With the papers' alpha = 1e-3 and n = 12, ``n + lambda = alpha² (n + kappa) = 1.2e-5``:
the centre mean weight is about −1e6 and the others about +4e4. Summing ``w_i y_i``
directly would cancel ~1e6-sized terms. Every moment here is instead computed from the
deviations ``d_i = y_i − y_0`` of the 2n outer points from the centre point, which is
algebraically identical:

    mean = y_0 + Σ_{i≥1} w_i d_i =: y_0 + m
    cov  = Σ_{i≥1} w_i d_i d_iᵀ + (W_c − 2) m mᵀ,   W_c = Σ_all w_c = 2 − α² + β

(the centre enters only through W_c, a number of order one).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class UTWeights:
    n: int
    alpha: float
    beta: float
    kappa: float

    @property
    def c(self) -> float:
        """n + lambda = alpha² (n + kappa)."""
        return self.alpha**2 * (self.n + self.kappa)

    @property
    def w(self) -> float:
        """Weight of every outer point, 1 / (2 (n + lambda)) (eq 7)."""
        return 0.5 / self.c

    @property
    def Wc(self) -> float:
        """Sum of all covariance weights: 1 + (1 − alpha² + beta) (eq 6 with Wan & van der Merwe's sign)."""
        return 2.0 - self.alpha**2 + self.beta


def sigma_offsets(L: np.ndarray, weights: UTWeights) -> np.ndarray:
    """Outer sigma-point offsets (B, 2n, n) from Cholesky factors ``L`` (B, n, n), P = L Lᵀ.

    Offsets ``+sqrt(n+λ) L[:, i]`` for i < n and ``−sqrt(n+λ) L[:, i−n]`` after (eqs 9-10).
    The centre point (offset 0) is implicit.
    """
    cols = np.sqrt(weights.c) * np.swapaxes(L, -1, -2)  # row i = column i of L
    return np.concatenate([cols, -cols], axis=-2)


def moments(dx: np.ndarray, weights: UTWeights, dz: np.ndarray | None = None):
    """Mean offset and covariance from outer deviations ``dx`` (B, 2n, a).

    Returns ``(m, P)`` with ``m`` (B, a) the mean minus the centre image and ``P`` (B, a, a);
    with ``dz`` (B, 2n, b) also returns ``(mz, Pzz, Pxz)``.
    """
    w = weights.w
    k = weights.Wc - 2.0
    n = dx.shape[-2] // 2
    # each ± pair first: their sum is the small second-order part, so the mean of a linear
    # map is exactly zero and the large first-order parts never meet the big weight
    m = w * (dx[..., :n, :] + dx[..., n:, :]).sum(axis=-2)
    P = w * (np.swapaxes(dx, -1, -2) @ dx) + k * (m[..., :, None] * m[..., None, :])
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    if dz is None:
        return m, P
    mz = w * (dz[..., :n, :] + dz[..., n:, :]).sum(axis=-2)
    Pzz = w * (np.swapaxes(dz, -1, -2) @ dz) + k * (mz[..., :, None] * mz[..., None, :])
    Pzz = 0.5 * (Pzz + np.swapaxes(Pzz, -1, -2))
    Pxz = w * (np.swapaxes(dx, -1, -2) @ dz) + k * (m[..., :, None] * mz[..., None, :])
    return m, P, mz, Pzz, Pxz


def safe_cholesky(P: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """Batched Cholesky of ``P`` (B, n, n); runs that fail are flagged in ``bad`` (B,) in place.

    A non-finite or non-positive-definite matrix marks its run bad and is replaced by the
    identity so that the other runs of the batch go on.
    """
    finite = np.isfinite(P).all(axis=(-2, -1))
    bad |= ~finite
    if bad.any():
        P = np.where(bad[:, None, None], np.eye(P.shape[-1]), P)
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    # rare path: find the failing runs one by one, flag them and carry on
    for i in np.flatnonzero(~bad):
        try:
            np.linalg.cholesky(P[i])
        except np.linalg.LinAlgError:
            bad[i] = True
    P = np.where(bad[:, None, None], np.eye(P.shape[-1]), P)
    return np.linalg.cholesky(P)

"""Adaptive measurement-noise estimators, batched over runs (docs/filters.md, "Adaptive measurement noise").

Each function is one paper's equation, for B runs of one sensor with m rows (shapes below);
:mod:`nespm_cli.filters.adaptive_ekfs` runs them inside the EKF's measurement update.

* :func:`iae_r` — innovation-based adaptive estimation (Mohamed & Schwarz 1999, eq 27 with the
  windowed innovation covariance of eq 21): ``R̂ = Ĉ_ν − H P⁻ Hᵀ``.
* :func:`sage_husa_r` — Sage-Husa (Sage & Husa 1969) with a forgetting factor:
  ``R_k = (1 − d) R_{k−1} + d (ν νᵀ − H P⁻ Hᵀ)``.
* :func:`vb_update` — the variational-Bayes update of Särkkä & Nummenmaa (2009): a diagonal R with
  an inverse-gamma posterior per row, fixed-point iterations of the Kalman update and of
  ``β = β⁻ + ½ (z − H x)ᵢ² + ½ (H P Hᵀ)ᵢᵢ``, the prediction ``α⁻ = ρ α``, ``β⁻ = ρ β``.
* :func:`bounded` — the projection that keeps an estimate positive definite: its eigenvalues
  in the frame whitened by the nominal R clipped to ``[floor, ceiling]``.

A row a sensor masks in a measurement (a lost beam: zero Jacobian row and zero innovation,
:func:`valid_rows`) is not adapted: it keeps the nominal R and is uncoupled from the others.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.filters.model import joseph_update


def _t(a: np.ndarray) -> np.ndarray:
    return np.swapaxes(a, -1, -2)


def valid_rows(H: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """(B, m) whether each row is a real measurement: not a masked row (an all-zero Jacobian row
    ``H`` (B, m, n) with a zero innovation ``nu`` (B, m))."""
    return ~((H == 0.0).all(axis=-1) & (nu == 0.0))


def pair_mask(valid: np.ndarray) -> np.ndarray:
    """(B, m, m) element (i, j) adapted: rows i and j both valid (``valid`` (B, m))."""
    return valid[..., :, None] & valid[..., None, :]


def bounded(R_hat: np.ndarray, R0: np.ndarray, floor: float, ceiling: float) -> np.ndarray:
    """``R_hat`` (B, m, m) made symmetric positive definite relative to the nominal ``R0`` (B, m, m):
    with ``L = chol(R0)``, the eigenvalues of ``L⁻¹ R̂ L⁻ᵀ`` are clipped to ``[floor, ceiling]``
    (so ``floor R0 ≤ R ≤ ceiling R0`` in the Loewner order). (B, m, m)."""
    d = np.einsum("...ii->...i", R0)
    diagonal = not np.any(R0 - d[..., :, None] * np.eye(R0.shape[-1]))
    if diagonal:  # every built-in sensor: L = diag(√r)
        s = np.sqrt(d)
        W = R_hat / (s[..., :, None] * s[..., None, :])
    else:
        L = np.linalg.cholesky(R0)
        Li = np.linalg.inv(L)
        W = Li @ R_hat @ _t(Li)
    lam, V = np.linalg.eigh(0.5 * (W + _t(W)))
    lam = np.clip(np.nan_to_num(lam, nan=1.0), floor, ceiling)
    W = (V * lam[..., None, :]) @ _t(V)
    out = W * (s[..., :, None] * s[..., None, :]) if diagonal else L @ W @ _t(L)
    return 0.5 * (out + _t(out))


def iae_r(nu_outer: np.ndarray, hph: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mohamed & Schwarz (1999) eqs 21 and 27 over a window of N measurements: ``R̂ = Ĉ_ν − H P⁻ Hᵀ``
    with ``Ĉ_ν = (1/N) Σ ν_j ν_jᵀ``, the ``H P⁻ Hᵀ`` averaged over the same window (the window's
    mean predicted innovation covariance; the paper's current-epoch term when P is steady).

    Args:
        nu_outer: (N, B, m, m) ``ν_j ν_jᵀ`` of the window's innovations.
        hph: (N, B, m, m) ``H_j P_j⁻ H_jᵀ`` at the same measurements.
        weight: (N, B, m, m) 1 where element (i, j) of measurement j counts (0: masked or missing).
    Returns ``(R̂, count)``: (B, m, m) the estimate (0 where nothing counts) and (B, m, m) the counts.
    """
    count = weight.sum(axis=0)
    s = (weight * (nu_outer - hph)).sum(axis=0)
    return np.where(count > 0, s / np.maximum(count, 1), 0.0), count


def sage_husa_r(R_prev: np.ndarray, e: np.ndarray, hph: np.ndarray, d: float, sign: float = -1.0) -> np.ndarray:
    """Sage-Husa with a forgetting factor b, ``d = 1 − b`` (a fading memory of ``1/(1 − b)``
    measurements), (B, m, m) from ``R_prev`` (B, m, m), ``e`` (B, m), ``hph`` (B, m, m):

    * innovation form (``sign = −1``): ``R_k = (1 − d) R_{k−1} + d (ν νᵀ − H P⁻ Hᵀ)`` with ``e = ν``
      the innovation and ``hph = H P⁻ Hᵀ`` (Sage & Husa 1969; can lose definiteness);
    * residual form (``sign = +1``): ``R_k = (1 − d) R_{k−1} + d (ε εᵀ + H P⁺ Hᵀ)`` with ``e = ε = ν − H x⁺``
      the post-fit residual and ``hph = H P⁺ Hᵀ`` (Akhlaghi et al. 2017; positive definite)."""
    return (1.0 - d) * R_prev + d * (e[..., :, None] * e[..., None, :] + sign * hph)


def vb_update(P: np.ndarray, H: np.ndarray, nu: np.ndarray, alpha: np.ndarray, beta: np.ndarray, rho: float,
              iterations: int, valid: np.ndarray, R_fixed: np.ndarray):
    """Särkkä & Nummenmaa (2009), one measurement: the joint update of the state and a diagonal R.

    Prediction ``α⁻ = ρ α``, ``β⁻ = ρ β``; update ``α = α⁻ + ½``; then ``iterations`` times:
    ``R = diag(β / α)``, the Kalman update ``(x, P⁺)`` with that R (Joseph form), and
    ``β = β⁻ + ½ (ν − H x)ᵢ² + ½ (H P⁺ Hᵀ)ᵢᵢ`` (computed in the m-dimensional measurement space:
    ``H x = A S⁻¹ ν``, ``H P⁺ Hᵀ = A − A S⁻¹ A`` with ``A = H P Hᵀ``). The last iteration's update
    (Joseph form) is returned.

    Args:
        P: (B, n, n) prior covariance; H: (B, m, n); nu: (B, m) innovation (at x = 0).
        alpha, beta: (B, m) the inverse-gamma parameters after the previous measurement.
        rho: forgetting factor in (0, 1); iterations: fixed-point iterations (≥ 1).
        valid: (B, m) rows adapted (others keep ``α, β`` and use ``R_fixed``'s row).
        R_fixed: (B, m, m) the nominal R (its diagonal used on rows not valid).
    Returns ``(x, P⁺, S, R, alpha, beta)``: (B, n), (B, n, n), (B, m, m), (B, m, m) the R used, (B, m) × 2.
    """
    a_pred, b_pred = rho * alpha, rho * beta
    a_new = a_pred + 0.5
    b_new = b_pred.copy()
    r0 = np.einsum("...ii->...i", R_fixed)
    m = nu.shape[-1]
    eye = np.eye(m)
    beta_it = b_pred * (a_new / np.maximum(a_pred, 1e-300))  # first R: the predicted mean β⁻/α⁻
    A = H @ P @ _t(H)  # (B, m, m): the iterations need only the measurement space
    for _ in range(max(int(iterations), 1)):
        r = np.where(valid, beta_it / a_new, r0)
        S = A + r[..., :, None] * eye
        SiA = np.linalg.solve(S, A)  # S⁻¹ H P Hᵀ; H x = A S⁻¹ ν and H P⁺ Hᵀ = A − A S⁻¹ A (optimal gain)
        res = nu - (_t(SiA) @ nu[..., None])[..., 0]
        hph = np.einsum("...ii->...i", A - A @ SiA)
        b_new = b_pred + 0.5 * res**2 + 0.5 * hph
        beta_it = b_new
    Rm = r[..., :, None] * eye
    x, P_post, S = joseph_update(P, H, nu, Rm)  # the state update with the last iteration's R
    alpha = np.where(valid, a_new, alpha)
    beta = np.where(valid, b_new, beta)
    return x, P_post, S, Rm, alpha, beta


__all__ = ["bounded", "iae_r", "pair_mask", "sage_husa_r", "valid_rows", "vb_update"]

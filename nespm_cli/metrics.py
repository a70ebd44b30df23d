"""Error metrics at the GT epochs: VRMSE and MRMSE (anukf.md eqs 50-53), NEES.

* velocity error: ``v_nav − v_GT``, norm in m/s;
* misalignment: the Euler angles of ``C_b^n (C_b^n,GT)ᵀ`` (eq 53), norm in rad;
* NEES: ``eᵀ P6⁻¹ e`` of the 6 states [δv, δψ] with ``e = truth ⊖ nav`` and ``P6`` the
  filter's posterior covariance block; 6 on average for a consistent filter.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .earth import ned_offset
from .rotations import attitude_minus, dcm_to_euler


@dataclass
class EpochErrors:
    """Per-run, per-epoch errors (R, N) plus horizontal position errors (R, N, 2) [m]."""

    vel: np.ndarray
    att: np.ndarray
    nees: np.ndarray
    ne: np.ndarray


def epoch_errors(out, v_true: np.ndarray, C_true: np.ndarray, pos_true: np.ndarray) -> EpochErrors:
    """Errors of a :class:`filters.FilterOutput` against truth at the N epochs.

    Args:
        v_true: (N, 3) NED velocity; C_true: (N, 3, 3); pos_true: (N, 3).
    """
    dv = out.v_n - v_true
    vel = np.linalg.norm(dv, axis=-1)
    C_mis = out.C_bn @ np.swapaxes(C_true, -1, -2)  # eq 53
    att = np.linalg.norm(dcm_to_euler(C_mis), axis=-1)
    e = np.concatenate([-dv, attitude_minus(C_true, out.C_bn)], axis=-1)  # truth ⊖ nav
    if np.isnan(out.P6).all():
        nees = np.full(vel.shape, np.nan)
    else:
        with np.errstate(all="ignore"):
            try:
                sol = np.linalg.solve(out.P6, e[..., None])[..., 0]
            except np.linalg.LinAlgError:
                sol = (np.linalg.pinv(out.P6) @ e[..., None])[..., 0]
        nees = (e * sol).sum(axis=-1)
    ne = ned_offset(out.pos, pos_true)[..., :2]
    return EpochErrors(vel, att, nees, ne)


def run_metrics(err: EpochErrors, diverged: np.ndarray) -> dict[str, np.ndarray]:
    """Per-run summary (R,) arrays; every error sum of a diverged run is NaN."""
    n = err.vel.shape[1]
    bad = np.asarray(diverged, dtype=bool)
    nan_if_bad = lambda x: np.where(bad, np.nan, x)  # noqa: E731
    sse_vel = nan_if_bad((err.vel**2).sum(axis=1))
    sse_att = nan_if_bad((err.att**2).sum(axis=1))
    return {
        "vrmse": np.sqrt(sse_vel / n),
        "mrmse": np.sqrt(sse_att / n),
        "sse_vel": sse_vel,
        "sse_att": sse_att,
        "n_samples": np.full(len(bad), n, dtype=np.int64),
        "max_vel_err": nan_if_bad(err.vel.max(axis=1)),
        "max_att_err": nan_if_bad(err.att.max(axis=1)),
        "nees": nan_if_bad(err.nees.mean(axis=1)),
        "diverged": bad,
    }


def rmse(sse: np.ndarray, n: np.ndarray) -> float:
    """Eq 50 over a set of runs: sqrt(Σ sse / Σ n), NaN entries (diverged) left out."""
    ok = np.isfinite(sse)
    return float(np.sqrt(sse[ok].sum() / n[ok].sum())) if ok.any() else float("nan")


def nees_band(dof: int, runs: int, p: float = 0.95) -> tuple[float, float]:
    """Two-sided ``p`` band of the mean NEES over ``runs`` runs for ``dof`` states (chi² / runs)."""
    from scipy.stats import chi2

    a = (1.0 - p) / 2.0
    k = dof * runs
    return float(chi2.ppf(a, k) / runs), float(chi2.ppf(1.0 - a, k) / runs)

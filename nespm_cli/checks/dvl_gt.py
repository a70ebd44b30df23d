"""DVL against ground truth: lever arm, scale factor, misalignment and time offset.

Model, fitted jointly by least squares on the GT epochs (N ~ 400 at 1 Hz):

    dvl(t_k) = (1 + s) exp(-[d x]) [C_bn(t_k - tau)^T v_n(t_k - tau) + w_nb^b(t_k - tau) x l] + noise

* ``tau`` [s], **time offset** = DVL stamp minus the GT time it describes: the sample stamped
  ``t_k`` measured the motion at GT time ``t_k - tau`` (``tau > 0``: DVL stamps late). A
  correction *subtracts* ``tau`` from the DVL stamps.
* ``s`` [-], **scale factor error**: the DVL reads ``(1 + s)`` times the true velocity.
* ``d`` (3,) [rad], **misalignment**: the small rotation from the body axes to the DVL axes,
  ``C_dvl^b = exp([d x])``, so a body vector ``v`` reads ``exp(-[d x]) v ~ v - d x v = v + [v x] d``
  in DVL axes (``d_z > 0``: the DVL x axis points to starboard of the hull's).
* ``l`` (3,) [m], **lever arm**, body axes, IMU -> DVL (as :func:`nav.dvl.dvl_velocity`).

The GT is evaluated at shifted times with a not-a-knot cubic spline of ``v_n`` and scipy's
``RotationSpline`` of the attitude, whose first derivative gives ``w_nb^b``. (On the embedded
tracks that rate is ~40x closer to the analytic one than a spline through the 2 s central
differences of :func:`nav.dvl.body_rate_from_attitude`, which biased the lever arm x by ~6 mm;
so at ``tau = 0`` the model differs slightly from :func:`data.tracks.dvl_lever_arm_fit`.)
``tau`` is grid-searched (the model linearized at ``s = d = 0`` is solved at every grid value
at once, no loop over epochs or offsets); a parabola through the residual-sum
curve around its minimum gives the sub-grid ``tau`` and, from its curvature, the std.
(l, s, d) are then refined by Gauss-Newton on the exact model at that ``tau``.

Uncertainties: least-squares covariance ``sigma^2 (J^T J)^-1`` (``sigma^2`` the residual
variance), and for ``tau`` the profile curvature ``sigma_tau^2 = 2 sigma^2 / RSS''``; all are
inflated by ``sqrt((1 + rho) / (1 - rho))`` for the residual's lag-1 autocorrelation ``rho``
(largest over the axes), as :func:`data.tracks.lever_arm_std` does. The (l, s, d) stds are
conditional on ``tau``. A weak zero-mean prior (:data:`PRIOR_STD`: 5 m, 0.1, 0.1 rad) keeps
the solution finite on tracks that cannot determine every parameter (no turns: lever arm x, y;
no vertical or lateral body velocity: roll misalignment); it shifts a determined parameter
by (std / prior std)^2 of its value, negligible. A parameter the data narrow by less than half
its prior std, or a ``tau`` whose minimum lies on the search edge (or a flat curve), is
*undetermined*: its value is meaningless (shrunk towards 0) and its std is ``None``.
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline

from nespm_cli.data.track import Track
from nespm_cli.data.tracks import dvl_lever_arm_fit
from nespm_cli.errors import NespmError
from nespm_cli.nav.dvl import dvl_velocity
from nespm_cli.nav.rotations import exp_so3, log_so3, skew

PARAMS = ("lever_arm_x", "lever_arm_y", "lever_arm_z", "scale_factor",
          "misalignment_x", "misalignment_y", "misalignment_z")
#: 1-sigma of the weak zero-mean prior on (l [m], s, d [rad]) that keeps a fit on a track without
#: turns finite; a parameter whose posterior std is above half its prior std is "undetermined".
PRIOR_STD = np.array([5.0, 5.0, 5.0, 0.1, 0.1, 0.1, 0.1])


def gt_at(track: Track, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(u, w)`` (..., 3): ``C_bn^T v_n`` [m/s] and ``w_nb^b`` [rad/s] at ``times`` (...,) [s]."""
    t = np.asarray(track.t, dtype=float)
    shape = np.shape(times)
    spline = RotationSpline(t, Rotation.from_matrix(track.C_bn))
    v = CubicSpline(t, track.v_n, axis=0, bc_type="not-a-knot")(times)
    C_at = spline(np.ravel(times)).as_matrix().reshape(shape + (3, 3))
    w = spline(np.ravel(times), 1).reshape(shape + (3,))  # body-frame rate of the spline (R_i exp(phi(t)))
    return np.einsum("...ji,...j->...i", C_at, v), w


def _solve(J: np.ndarray, b: np.ndarray, prior_w: np.ndarray, theta0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched step ``d`` minimizing ``|J d - b|^2 + |prior_w * (theta0 + d)|^2``.

    J (..., M, P), b (..., M), prior_w (P,), theta0 (..., P). Returns ``d`` (..., P) and the
    unit covariance ``(J^T J + diag(prior_w^2))^-1`` (..., P, P).
    """
    Jt = np.swapaxes(J, -1, -2)
    A = Jt @ J + np.diag(prior_w**2)
    rhs = (Jt @ b[..., None])[..., 0] - prior_w**2 * theta0
    sc = np.sqrt(np.diagonal(A, axis1=-2, axis2=-1))
    inv = np.linalg.inv(A / (sc[..., :, None] * sc[..., None, :])) / (sc[..., :, None] * sc[..., None, :])
    return (inv @ rhs[..., None])[..., 0], inv


def _inflation(resid: np.ndarray) -> float:
    """``sqrt((1 + rho) / (1 - rho))`` for the largest per-axis lag-1 autocorrelation of resid (K, 3)."""
    r = resid - resid.mean(axis=0)
    den = (r * r).sum(axis=0)
    rho = np.where(den > 0, (r[1:] * r[:-1]).sum(axis=0) / np.where(den > 0, den, 1.0), 0.0)
    rho_max = min(float(rho.max()), 0.99)
    return float(np.sqrt(max((1 + rho_max) / (1 - rho_max), 1.0)))


def _model(u: np.ndarray, w: np.ndarray, lever: np.ndarray, scale: float, mis: np.ndarray) -> np.ndarray:
    """Modelled DVL (..., 3) [m/s] from ``u = C^T v_n``, ``w`` (..., 3) and the parameters."""
    return (1.0 + scale) * (dvl_velocity(np.eye(3), u, w, lever) @ exp_so3(-mis).T)


def _floats(x) -> list[float | None]:
    return [None if v is None or not np.isfinite(v) else float(v) for v in np.atleast_1d(x)]


def fit_dvl_to_gt(track: Track, max_offset: float = 2.0, step: float = 0.01, gn_iters: int = 4) -> dict:
    """Fit lever arm, scale factor, misalignment and time offset of ``track.dvl`` to its GT.

    Args:
        track: GT (``t`` (N,), ``v_n``, ``euler``) and body-frame DVL (N, 3) [m/s] on the same epochs.
        max_offset: the time offset is searched over ``[-max_offset, max_offset]`` [s]; only the
            epochs with ``t_k -+ max_offset`` inside the GT span are used (same set for every offset).
        step: grid step of the search [s].
        gn_iters: Gauss-Newton iterations on the exact model at the found offset.

    Returns a plain-JSON dict (see the module docstring for the model and signs):
    ``lever_arm``, ``lever_arm_std`` (3 each) [m, body]; ``scale_factor``, ``scale_factor_std``
    [-]; ``misalignment_deg``, ``misalignment_std_deg`` (3 each) [deg]; ``time_offset_s``,
    ``time_offset_std_s`` [s] (the value to subtract from the DVL stamps); ``offset_curve``
    ``{"tau_s": [...], "rms": [...]}`` [s, m/s] (RMS over all axes of the linearized fit's
    residual at each searched offset); ``resid_std_before`` (3) [m/s] (per-axis std after
    :func:`data.tracks.dvl_lever_arm_fit` alone, all epochs); ``resid_std_after`` (3) and
    ``resid_rms_after`` [m/s] (after the full fit, epochs used); ``epochs_used``;
    ``inflation`` (the autocorrelation factor applied to every std); ``undetermined`` (names
    from :data:`PARAMS`, plus ``"time_offset"``, the track does not determine; their std is
    None, see the module docstring); ``time_offset_at_edge`` (the grid minimum is an end of the
    search, whatever the curvature) and ``max_offset_s`` (the search's half-width [s]).

    Raises NespmError when fewer than 20 epochs remain inside the search margins.
    """
    t = np.asarray(track.t, dtype=float)
    dvl = np.asarray(track.dvl, dtype=float)
    ok = (t - max_offset >= t[0]) & (t + max_offset <= t[-1]) & np.isfinite(dvl).all(axis=1)  # NaN: no DVL
    if ok.sum() < 20:
        raise NespmError(f"track {track.number}: {int(ok.sum())} epochs inside the +-{max_offset:g} s offset "
                         "search margins, need at least 20")
    _, r0 = dvl_lever_arm_fit(track)
    prior_w = max(float(np.sqrt(np.nanmean(r0**2))) if np.isfinite(r0).any() else 0.0, 1e-4) / PRIOR_STD  # prior rows weighted like the data
    taus = np.round(np.arange(-max_offset, max_offset + step / 2, step), 10)
    u, w = gt_at(track, t[ok][None, :] - taus[:, None])  # (G, K, 3)
    G, K = u.shape[:2]
    J = np.concatenate([skew(w), u[..., None], skew(u)], axis=-1).reshape(G, 3 * K, 7)
    b = (dvl[ok][None] - u).reshape(G, 3 * K)
    theta, _ = _solve(J, b, prior_w, np.zeros((G, 7)))
    rss = (((J @ theta[..., None])[..., 0] - b) ** 2).sum(axis=-1)

    # parabola through the RSS curve around its minimum: sub-grid offset and curvature
    g = int(np.argmin(rss))
    lo, hi = max(g - 5, 0), min(g + 6, G)
    a2, a1, _ = np.polyfit(taus[lo:hi] - taus[g], rss[lo:hi], 2)
    edge = g in (0, G - 1) or a2 <= 0
    tau = float(taus[g] if edge else taus[g] + np.clip(-a1 / (2 * a2), taus[lo] - taus[g], taus[hi - 1] - taus[g]))

    # Gauss-Newton on the exact model at tau, from the linearized solution at the grid minimum
    u, w = gt_at(track, t[ok] - tau)
    lever, scale, mis = theta[g, :3].copy(), float(theta[g, 3]), theta[g, 4:].copy()
    for it in range(gn_iters + 1):  # the last pass only evaluates residual and covariance
        R, z = exp_so3(-mis), dvl_velocity(np.eye(3), u, w, lever)
        J1 = np.concatenate([(1 + scale) * R @ skew(w), (z @ R.T)[..., None], (1 + scale) * R @ skew(z)], axis=-1)
        r = dvl[ok] - _model(u, w, lever, scale, mis)
        d, cov = _solve(J1.reshape(-1, 7), r.ravel(), prior_w, np.r_[lever, scale, mis])
        if it < gn_iters:  # right perturbation of the misalignment: exp(-[d_new x]) = exp(-[d x]) exp(-[dd x])
            lever, scale, mis = lever + d[:3], scale + float(d[3]), -log_so3(R @ exp_so3(-d[4:]))
    infl = _inflation(r)
    sigma2 = float((r**2).sum() / max(3 * K - 8, 1))
    undet = np.sqrt(np.diag(cov)) * prior_w > 0.5  # posterior std > half the prior std
    std = np.where(undet, np.nan, infl * np.sqrt(sigma2 * np.diag(cov)))
    tau_std = np.nan if edge else infl * float(np.sqrt(2 * sigma2 / (2 * a2)))
    names = [p for p, u_ in zip(PARAMS, undet) if u_] + (["time_offset"] if edge else [])
    return {
        "lever_arm": _floats(lever), "lever_arm_std": _floats(std[:3]),
        "scale_factor": float(scale), "scale_factor_std": _floats(std[3])[0],
        "misalignment_deg": _floats(np.degrees(mis)), "misalignment_std_deg": _floats(np.degrees(std[4:])),
        "time_offset_s": tau, "time_offset_std_s": _floats(tau_std)[0],
        "offset_curve": {"tau_s": _floats(taus), "rms": _floats(np.sqrt(rss / (3 * K)))},
        "resid_std_before": _floats(r0.std(axis=0)), "resid_std_after": _floats(r.std(axis=0)),
        "resid_rms_after": float(np.sqrt(np.mean(r**2))), "epochs_used": int(K),
        "inflation": infl, "undetermined": names,
        "time_offset_at_edge": bool(g in (0, G - 1)), "max_offset_s": float(max_offset),
    }


def dvl_residual(track: Track, fit: dict) -> np.ndarray:
    """Residual ``dvl - model`` (N, 3) [m/s] of ``track`` under a :func:`fit_dvl_to_gt` dict.

    Uses ``lever_arm`` [m], ``scale_factor``, ``misalignment_deg`` [deg] and ``time_offset_s``
    [s]; epochs whose GT time ``t_k - tau`` falls outside the GT span are NaN.
    """
    t = np.asarray(track.t, dtype=float)
    tau = float(fit["time_offset_s"])
    u, w = gt_at(track, t - tau)
    out = np.asarray(track.dvl, dtype=float) - _model(
        u, w, np.asarray(fit["lever_arm"], dtype=float), float(fit["scale_factor"]),
        np.radians(np.asarray(fit["misalignment_deg"], dtype=float)))
    out[(t - tau < t[0]) | (t - tau > t[-1])] = np.nan
    return out

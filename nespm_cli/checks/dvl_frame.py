"""The DVL's own noise and the frame its vector is in, from the data (``nespm check``, DVL part).

* **Own noise** (:func:`nespm_cli.data.conventions.own_noise`, also used at load): the DVL's white noise per axis from its second difference
  alone, ``std = 1.4826 MAD(d2) / sqrt(6)`` (white noise keeps ``sqrt(6)`` of its std in ``d2``;
  motion slow against the 1 Hz rate cancels in it; the MAD ignores the turns' rarer large steps).
  It needs no GT, so a DVL in the wrong frame or with the wrong attitude does not inflate it.
* **Frame test** (:func:`frame_candidates`): the DVL against each reading of the truth it could
  be, each with its own time offset (searched on :data:`FRAME_OFFSETS`):

  - ``body``: the body-frame truth ``C_bn^T v_n + w_nb^b x l`` as declared (lever arm ``l`` fitted
    by least squares at every offset, all offsets at once);
  - ``axes``: the same under the best of the other 47 signed permutations ``A`` of the DVL's axes
    (``body = A dvl``, as ``dvl.axes`` / ``--imu-axes`` write it), lever arm fitted the same way;
  - ``ned``, ``enu``: the earth-frame truth ``v_n`` and its ENU reading ``[v_e, v_n, -v_d]``.

  Each is scored by the RMS residual over the three axes [m/s] at its best offset. The full
  :func:`dvl_gt.fit_dvl_to_gt` fit (scale, misalignment) is not repeated per candidate: a wrong
  frame makes residuals of the order of the speed, far above what those small terms absorb.
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from nespm_cli.checks.dvl_gt import gt_at
from nespm_cli.data.conventions import ENU_OF_NED, own_noise  # noqa: F401  (own_noise: moved to the data layer)
from nespm_cli.data.corrections import axes_text
from nespm_cli.data.track import Track
from nespm_cli.nav.rotations import signed_permutations, skew

FRAME_OFFSETS = np.round(np.arange(-2.0, 2.0 + 1e-9, 0.1), 10)  # [s] offsets searched per candidate
LEVER_PRIOR_STD = 5.0  # [m] weak prior keeping the lever arm finite on a track without turns (as dvl_gt's)


def _best(rms: np.ndarray) -> tuple[float, float]:
    """``(rms, offset)`` at the minimum of an RMS curve (G,) over :data:`FRAME_OFFSETS`."""
    g = int(np.argmin(rms))
    return float(rms[g]), float(FRAME_OFFSETS[g])


def frame_candidates(track: Track) -> dict:
    """The DVL against the body, permuted-axes, NED and ENU truths (module docstring).

    Uses the epochs whose GT time ``t_k - offset`` stays inside the GT span for every searched
    offset and where the DVL is finite (needs at least 20, else returns None values).

    Returns ``{"body": {"rms", "offset_s"}, "axes": {"axes", "rms", "offset_s"}, "ned": {...},
    "enu": {...}}`` (rms [m/s], offset [s] = DVL stamp minus GT time); ``axes`` holds the best
    signed permutation other than the identity, as text (``"x,-y,-z"``).
    """
    t = np.asarray(track.t, dtype=float)
    dvl = np.asarray(track.dvl, dtype=float)
    m = FRAME_OFFSETS[-1]
    ok = (t - m >= t[0]) & (t + m <= t[-1]) & np.isfinite(dvl).all(axis=1)
    empty = {"rms": None, "offset_s": None}
    if ok.sum() < 20:
        return {"body": empty, "axes": {"axes": None, **empty}, "ned": empty, "enu": empty}
    d = dvl[ok]  # (K, 3)
    T = t[ok][None, :] - FRAME_OFFSETS[:, None]  # (G, K)
    u, w = gt_at(track, T)  # (G, K, 3) each
    v = CubicSpline(t, track.v_n, axis=0, bc_type="not-a-knot")(T)  # (G, K, 3)
    K = d.shape[0]

    # body candidates: body = A d = u + w x l = u + skew(w) l; l by least squares per (A, offset)
    A = signed_permutations()  # (P, 3, 3), the identity first
    b = np.einsum("pij,kj->pki", A, d)[:, None] - u[None]  # (P, G, K, 3)
    S = skew(w)  # (G, K, 3, 3)
    N0 = np.einsum("gkji,gkjl->gil", S, S)  # (G, 3, 3)
    N = N0 + np.eye(3) * (np.sqrt(np.mean(b[0] ** 2)) / LEVER_PRIOR_STD) ** 2
    rhs = np.einsum("gkji,pgkj->pgi", S, b)  # (P, G, 3)
    lever = np.linalg.solve(N[None], rhs[..., None])[..., 0]  # (P, G, 3)
    rss = (b**2).sum(axis=(2, 3)) - 2 * (lever * rhs).sum(-1) + np.einsum("pgi,gij,pgj->pg", lever, N0, lever)
    rms_body = np.sqrt(np.maximum(rss, 0.0) / (3 * K))  # (P, G)
    p = 1 + int(np.argmin(rms_body[1:].min(axis=1)))
    rms_ned = np.sqrt(((d[None] - v) ** 2).mean(axis=(1, 2)))
    rms_enu = np.sqrt(((d[None] - v @ ENU_OF_NED.T) ** 2).mean(axis=(1, 2)))
    out = {}
    for key, curve in (("body", rms_body[0]), ("axes", rms_body[p]), ("ned", rms_ned), ("enu", rms_enu)):
        r, o = _best(curve)
        out[key] = {"rms": r, "offset_s": o}
    out["axes"]["axes"] = axes_text(A[p])
    return out

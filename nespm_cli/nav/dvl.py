"""The DVL measurement model and the body rate it needs, written once.

A DVL at lever arm ``l`` (body axes, from the IMU) measures the body-frame velocity of its
own mounting point:

    v_dvl^b = C_bn^T v_n + w_nb^b x l            (anukf.md eq 33 at x = 0)

``w_nb^b`` is the body rate relative to NED. When only an attitude history is known it is
recovered by inverting eq 31 of ukf-nespm.md, ``C_{k+1} = C_k exp([w_nb dt x])``:

    w_nb^b = log(C_k^T C_{k+1}) / dt             (:func:`body_rate_step`)

:func:`body_rate_from_attitude` applies it as a central difference over a sampled attitude
(the 1 Hz GT analysis of ``data.tracks``); :func:`body_rate_at_epochs` as the one-sided
step that ends at each epoch of a dense (100 Hz) truth, which is exactly the rate the
synthesized IMU step applies (``experiments.mc`` synthetic DVL). Both share the primitive.

Shapes follow docs/conventions.md: batch axes first, vectors (..., 3), DCMs (..., 3, 3).
"""
from __future__ import annotations

import numpy as np

from nespm_cli.nav.rotations import log_so3
from nespm_cli.nav.strapdown import cross


def dvl_velocity(C_bn: np.ndarray, v_n: np.ndarray, w_nb_b: np.ndarray, lever: np.ndarray) -> np.ndarray:
    """Body-frame DVL velocity ``C_bn^T v_n + w_nb^b x l`` [m/s] (..., 3).

    Args:
        C_bn: (..., 3, 3) body -> NED DCM.
        v_n: (..., 3) NED velocity of the IMU [m/s].
        w_nb_b: (..., 3) body rate relative to NED, in body axes [rad/s].
        lever: (3,) or (..., 3) DVL lever arm in body axes [m] (broadcasts against ``w_nb_b``).
    """
    C_bn = np.asarray(C_bn, dtype=float)
    v_n = np.asarray(v_n, dtype=float)
    w_nb_b = np.asarray(w_nb_b, dtype=float)
    lever = np.asarray(lever, dtype=float)
    v_b = (np.swapaxes(C_bn, -1, -2) @ v_n[..., None])[..., 0]
    return v_b + cross(w_nb_b, np.broadcast_to(lever, w_nb_b.shape))


def body_rate_step(C0: np.ndarray, C1: np.ndarray, dt: float | np.ndarray) -> np.ndarray:
    """Constant body rate w_nb^b [rad/s] (..., 3) that turns ``C0`` into ``C1`` in ``dt`` [s].

    Eq 31 inverted: ``log(C0^T C1) / dt``; ``dt`` scalar or (...,).
    """
    dt = np.asarray(dt, dtype=float)
    return log_so3(np.swapaxes(C0, -1, -2) @ C1) / dt[..., None]


def body_rate_from_attitude(t: np.ndarray, C_bn: np.ndarray) -> np.ndarray:
    """Body rate w_nb^b [rad/s] (N, 3) from an attitude sequence by finite differences.

    Interior epochs: ``log(C_{k-1}^T C_{k+1}) / (t_{k+1} - t_{k-1})`` (central); the first and
    last epochs use the one-sided difference. ``t`` (N,) [s], ``C_bn`` (N, 3, 3), N >= 2.
    Exact for a constant body rate.
    """
    t = np.asarray(t, dtype=float)
    C_bn = np.asarray(C_bn, dtype=float)
    w = np.empty((len(t), 3))
    w[1:-1] = body_rate_step(C_bn[:-2], C_bn[2:], t[2:] - t[:-2])
    w[0] = body_rate_step(C_bn[0], C_bn[1], t[1] - t[0])
    w[-1] = body_rate_step(C_bn[-2], C_bn[-1], t[-1] - t[-2])
    return w


def body_rate_at_epochs(C_bn: np.ndarray, dt: np.ndarray, epoch_index: np.ndarray) -> np.ndarray:
    """True w_nb^b (N, 3) at the epochs ``epoch_index`` (N,) of a dense truth, from the step
    that ends there (eq 31 inverted over that step).

    ``C_bn`` (M+1, 3, 3) and ``dt`` (M,) are the dense truth (``synthesis.ImuTruth``). An epoch
    at sample 0 has no step before it and takes the value of the second epoch.
    """
    e = np.asarray(epoch_index)
    j = np.maximum(e - 1, 0)
    w = body_rate_step(C_bn[j], C_bn[j + 1], np.asarray(dt)[j])
    w[e == 0] = w[1] if len(w) > 1 else 0.0
    return w

"""The posterior Cramér–Rao bound (PCRB) of the error state along the true trajectory.

Tichavský, Muravchik and Nehorai (IEEE TSP 46(5), 1998) give the Bayesian information
recursion ``J_{k+1} = D22 − D21 (J_k + D11)⁻¹ D12``. For additive Gaussian noise with the
Jacobians ``Φ_k``, ``H_k`` taken along the true trajectory (the expectation over the state is
then a point: the truth is the same in every run) it is the information form of the Riccati
recursion of a Kalman filter run with those Jacobians and the *true* noise statistics. It is
computed here in covariance form, ``P = J⁻¹``, because the process noise of the position and
bias blocks is singular (zero), which the information form cannot take::

    P⁻ = D (Φ P Φᵀ + Q) D          (D: a bias step of the schedule, else I)
    P  = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ,   K = P⁻ Hᵀ (H P⁻ Hᵀ + R)⁻¹

The model is not written a second time: Φ is the EKF's own ``Π (I + F dt)``
(:meth:`nespm_cli.filters.protocol.ErrorStateFilter.transition`, compiled where numba is)
on the navigation solution of the clean IMU started at the truth (it reproduces the truth to
~1e-11), and ``H`` is each sensor's own Jacobian (:meth:`Measurement.H`) there; the update is
the Kalman update of the covariance (:func:`riccati_update`). The solution is never
corrected (there is nothing to correct).

Batched over B *patterns*: what may differ between Monte Carlo runs (the measurements that
exist, the noise levels of the dynamic schedule, the bias steps) enters per pattern; the
Jacobians are shared. The caller (:mod:`nespm_cli.experiments.pcrb_table`) says what the
patterns are and averages. Shapes: M IMU steps, N GT epochs, n states of the layout.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from nespm_cli.filters.model import FilterConfig
from nespm_cli.filters.protocol import ErrorStateFilter, ImuData
from nespm_cli.filters.timeline import Timeline
from nespm_cli.nav.state import NavState, StateLayout
from nespm_cli.sensors.source import Channel, Context

#: ``process(t0, t1)`` -> ``(q, D)``: the variances (B, n) or (n,) of the white process noise over the
#: span from ``t0`` to ``t1`` [s since the first epoch] (diagonal in the error coordinates: the
#: IMU's noise is isotropic per block, so ``G Q Gᵀ = Q``), and a diagonal (B, n) applied to the
#: state at its end (a bias step of the schedule), or None
Process = Callable[[float, float], tuple]


class TrueTrajectory(ErrorStateFilter):
    """The navigation solution of the clean IMU from the truth, never corrected: its
    :meth:`transition` gives Φ along the true trajectory (not a registered filter)."""

    name = "pcrb"

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:  # pragma: no cover - not a filter
        raise NotImplementedError

    def update(self, measurement, j_last: int):  # pragma: no cover - not a filter
        raise NotImplementedError


@dataclass
class Bound:
    """The PCRB of B patterns at the N GT epochs (posterior: after the epoch's measurements):
    ``diag`` (B, N, n) its variances [SI units²]."""

    diag: np.ndarray


def riccati_predict(P: np.ndarray, Phi: np.ndarray, Q: np.ndarray, D: np.ndarray | None = None) -> np.ndarray:
    """``D (Φ P Φᵀ + Q) D`` symmetrized: ``P`` (B, n, n), ``Phi`` (n, n) (shared: two matrix
    products over the whole batch) or (B, n, n), ``Q`` (n, n) or (B, n, n), ``D`` (B, n) or None."""
    B, n = P.shape[0], P.shape[-1]
    if Phi.ndim == 2:
        X = (P.reshape(B * n, n) @ Phi.T).reshape(B, n, n)  # P Φᵀ
        P = (Phi @ X.transpose(1, 0, 2).reshape(n, B * n)).reshape(n, B, n).transpose(1, 0, 2) + Q
    else:
        P = Phi @ P @ np.swapaxes(Phi, -1, -2) + Q
    if D is not None:
        P = D[..., :, None] * P * D[..., None, :]
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def riccati_update(P: np.ndarray, H: np.ndarray, Rm: np.ndarray, ok: np.ndarray | None = None) -> np.ndarray:
    """The posterior of ``P`` (B, n, n) after a measurement with Jacobian ``H`` (B, m, n) or (1, m, n)
    and noise ``Rm`` (m, m) or (B, m, m), in the patterns where ``ok`` (B,) (None: all):
    ``P − P Hᵀ S⁻¹ H P`` with ``S = H P Hᵀ + R`` (solved, not inverted), symmetrized. The same
    posterior as the EKF's Joseph form (:func:`nespm_cli.filters.model.joseph_update`) with the
    optimal gain (tests/test_pcrb.py: 4e-13 relative on the papers' track)."""
    PHt = P @ np.swapaxes(H, -1, -2)
    S = H @ PHt + Rm
    KPt = np.linalg.solve(S, np.swapaxes(PHt, -1, -2))  # S⁻¹ H P  (B, m, n)
    Pu = P - PHt @ KPt
    Pu = 0.5 * (Pu + np.swapaxes(Pu, -1, -2))
    if ok is None:
        return Pu
    return np.where(np.asarray(ok, dtype=bool)[:, None, None], Pu, P)


def noise_within_span(Phi: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The white noise of a span, ``diag(q)`` with ``q`` (n,) or (B, n) its variances over the span,
    injected uniformly over it, at its end: ``Q + (A Q + Q Aᵀ)/2 + A Q Aᵀ/3`` with ``A = Φ − I``
    (``Φ`` (n, n) the span's transition), the integral ``∫ e^{F s} (Q/T) e^{Fᵀ s} ds`` for F
    constant over the span (exact for ``dp' = dv``: the velocity noise's ``q T³/3`` in position,
    ``q T²/2`` between them); docs/pcrb.md. Returns (n, n) or (B, n, n)."""
    n = Phi.shape[-1]
    A = Phi - np.eye(n)
    q = np.asarray(q, dtype=float)
    AQ = A * q[..., None, :]
    outer = np.einsum("ik,jk->kij", A, A).reshape(n, n * n)  # A Q Aᵀ = Σ_k q_k a_k a_kᵀ
    AQA = (q @ outer).reshape(q.shape[:-1] + (n, n))
    return 0.5 * (AQ + np.swapaxes(AQ, -1, -2)) + AQA / 3.0 + q[..., None, :] * np.eye(n)


def pcrb(layout: StateLayout, truth_nav0: NavState, f: np.ndarray, w: np.ndarray, dt: np.ndarray,
         epoch_index: np.ndarray, channels: list[Channel], P0: np.ndarray, process: Process,
         per_step: bool = False, within_span: bool = True, r_factors: list | None = None) -> Bound:
    """The PCRB of the error state of ``layout`` at every GT epoch, for B patterns.

    Args:
        layout: the error-state blocks (any layout of :mod:`nespm_cli.nav.state`).
        truth_nav0: the truth at the first epoch (one run: shapes (1, 3), (1, 3, 3); zero biases).
        f, w: (M, 3) the clean IMU [m/s², rad/s]; dt (M,) the step durations [s].
        epoch_index: (N,) the IMU sample of each GT epoch.
        channels: the sensors' channels (:class:`Channel`) with B rows (``z`` (B, K, m), ``ok``
            (B, K)): the error-free values (only their NaN components matter: a masked component)
            and where each measurement exists in each pattern; each sensor's measurement model
            must carry the true noise (its ``R``).
        P0: (n, n) or (B, n, n) the true initial error covariance (may be singular).
        process: the true process noise and bias steps of a span (:data:`Process`).
        per_step: one time update per IMU step (the exact discretization of white noise) instead
            of one per span between events (the filters' ``--time-update dvl``).
        within_span: the white noise of a span propagated inside it (:func:`noise_within_span`);
            False: added at its end, as the filters add their Q (their Riccati recursion exactly).
        r_factors: per channel, (B, K) the factor on its R's std at each measurement in each pattern (a
            sensor's ``noise_schedule``: :meth:`Sensor.noise_factor`), or None (1: the R of its model);
            None: every sensor's R as its model gives it. The time-varying Q comes through ``process``.

    Returns:
        :class:`Bound` with ``diag`` (B, N, n).
    """
    n = layout.n
    B = channels[0].ok.shape[0] if channels else (P0.shape[0] if np.ndim(P0) == 3 else 1)
    line = Timeline(dt, epoch_index, channels)
    fx, wx = line.expand(np.asarray(f, float)[None]), line.expand(np.asarray(w, float)[None])
    tgrid = np.concatenate([[0.0], np.cumsum(line.dt)])
    t0 = tgrid[line.epochs[0]]
    cfg = FilterConfig(state=layout.name)
    traj = TrueTrajectory(cfg, truth_nav0, ImuData(fx, wx, line.dt))
    P = np.broadcast_to(np.asarray(P0, dtype=float), (B, n, n)).copy()
    N = len(epoch_index)
    diag = np.empty((B, N, n))

    def record(k: int) -> None:
        diag[:, k] = np.einsum("bii->bi", P)

    record(0)
    for a, b, _k, epoch, todo in line.spans():
        for j0, j1 in (((j, j + 1) for j in range(a, b)) if per_step else ((a, b),)):
            Phi = traj.transition(j0, j1)[0]
            q, D = process(float(tgrid[j0] - t0), float(tgrid[j1] - t0))
            Q = noise_within_span(Phi, q) if within_span else np.asarray(q)[..., None, :] * np.eye(n)
            P = riccati_predict(P, Phi, Q, D)
        nav = traj.nav
        for c, i in todo:
            ch = channels[c]
            ok = ch.ok[:, i]
            if not ok.any():
                continue
            navb = NavState(*(np.broadcast_to(x, (B,) + x.shape[1:]) for x in
                              (nav.pos, nav.v_n, nav.C_bn, nav.b_a, nav.b_g)))
            ctx = Context(np.broadcast_to(fx[:, b - 1], (B, 3)), np.broadcast_to(wx[:, b - 1], (B, 3)))
            meas = ch.sensor.measurement(ch.z[:, i], navb, ctx, layout)
            Rm = meas.R
            fac = None if r_factors is None else r_factors[c]
            if fac is not None:  # the schedule's R(t) of each pattern
                Rm = np.asarray(Rm, dtype=float) * np.square(np.asarray(fac, dtype=float)[:, i])[:, None, None]
            P = riccati_update(P, meas.H(navb), Rm, ok)
        if epoch is not None:
            record(epoch)
    return Bound(diag)


__all__ = ["Bound", "Process", "TrueTrajectory", "noise_within_span", "pcrb", "riccati_predict", "riccati_update"]

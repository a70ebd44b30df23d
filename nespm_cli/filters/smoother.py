"""Fixed-interval Rauch-Tung-Striebel smoother for the closed-loop error-state filters.

A closed-loop filter resets its error estimate to zero after every feedback, so the smoother works on
the error of each event's solution (Groves 2nd ed. §3.4.2 for the RTS recursion; the error-state
form follows from it because the feedback is a change of origin). At event k (the initial epoch, then
every time the filter stops: a GT epoch or a measurement time) the forward pass records, per run:

* ``Phi[k]`` (R, n, n): the error transition over the span ending at event k (the product of the
  filter's own Φ over its time updates there; identity at k = 0);
* ``P_prior[k]``, ``P_post[k]`` (R, n, n): the covariance after the time update and after the
  event's measurement updates (equal where no measurement was applied);
* ``corr[k]`` (R, n): the correction the updates fed back, ``nav_post ⊖ nav_prior`` in the filter's
  error coordinates;
* the solution after the updates.

Backward (:func:`rts_backward`), with ``e_s[K-1] = 0`` and ``P_s[K-1] = P_post[K-1]``::

    G_k     = P_post[k] Φ[k+1]ᵀ P_prior[k+1]⁻¹
    e_s[k]  = G_k (e_s[k+1] + corr[k+1])        # e_s[k+1] + corr[k+1]: the smoothed error about
    P_s[k]  = P_post[k] + G_k (P_s[k+1] − P_prior[k+1]) G_kᵀ      # event k+1's prior solution

and the smoothed solution is ``nav_post[k] ⊕ e_s[k]`` (the filter's own retraction). For a linear
Gaussian model this is the batch least-squares solution (tests/test_smoother.py); for the INS
the usual first-order approximations of an error-state filter apply (corrections composed by
addition, Φ evaluated on the forward solution).

Which filters: those that propagate their covariance as ``Φ P Φᵀ + Q`` and expose the hooks of
:class:`~nespm_cli.filters.protocol.ErrorStateFilter` (``smoothable``: ``ekf``, ``anekf``,
``iekf``); the sigma-point filters would need their cross-covariance (not built). The smoothed
solution of a filter ``f`` is reported as the pseudo-filter ``f-rts`` (its errors beside the
filter's, on the same realizations): how far a causal filter is from hindsight.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nespm_cli.nav.state import position_plus

#: suffix of a smoothed pseudo-filter's name (``ekf`` -> ``ekf-rts``)
SMOOTHED_SUFFIX = "-rts"


def smoothed_name(filt: str) -> str:
    """The name of the smoothed pseudo-filter of ``filt``."""
    return filt + SMOOTHED_SUFFIX


def smoothed_of(name: str) -> str | None:
    """The filter a smoothed pseudo-filter ``name`` smooths, or None if ``name`` is a causal filter."""
    return name[: -len(SMOOTHED_SUFFIX)] if name.endswith(SMOOTHED_SUFFIX) else None


def _swap(A: np.ndarray) -> np.ndarray:
    return np.swapaxes(A, -1, -2)


def smoother_gain(P_post: np.ndarray, Phi_next: np.ndarray, P_prior_next: np.ndarray) -> np.ndarray:
    """``G = P_post Φᵀ P_prior⁻¹`` (R, n, n), solved (``Gᵀ = P_prior⁻¹ Φ P_post``, P symmetric);
    runs whose prior is singular (a sanitized diverged run) get the pseudo-inverse."""
    B = Phi_next @ P_post
    with np.errstate(all="ignore"):
        try:
            return _swap(np.linalg.solve(P_prior_next, B))
        except np.linalg.LinAlgError:
            return _swap(np.linalg.pinv(P_prior_next, hermitian=True) @ B)


def rts_backward(Phi: np.ndarray, P_prior: np.ndarray, P_post: np.ndarray, corr: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The RTS recursion over K events of an error-state filter (module docstring).

    Args:
        Phi: (K, R, n, n) transition over the span ending at each event (``Phi[0]`` unused).
        P_prior, P_post: (K, R, n, n) covariance before and after each event's updates.
        corr: (K, R, n) the correction fed back at each event.

    Returns:
        ``(e_s, P_s)``: (K, R, n) the smoothed error about each event's posterior solution and
        (K, R, n, n) its covariance (symmetrized).
    """
    K = Phi.shape[0]
    e_s = np.zeros(corr.shape)
    P_s = np.empty(P_post.shape)
    P_s[-1] = P_post[-1]
    with np.errstate(all="ignore"):
        for k in range(K - 2, -1, -1):
            G = smoother_gain(P_post[k], Phi[k + 1], P_prior[k + 1])
            e_s[k] = (G @ (e_s[k + 1] + corr[k + 1])[..., None])[..., 0]
            P = P_post[k] + G @ (P_s[k + 1] - P_prior[k + 1]) @ _swap(G)
            P_s[k] = 0.5 * (P + _swap(P))
    return e_s, P_s


def dead_reckoned_position(pos: np.ndarray, dv: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The filter's position ``pos`` (R, N, 3) ``[lat, lon, h]`` moved by the trapezoid integral over
    the epoch times ``t`` (N,) [s] of a velocity change ``dv`` (R, N, 3) NED [m/s] (zero at the first
    epoch): the smoothed position of a layout without a position block, whose position is dead
    reckoned from its velocity."""
    step = 0.5 * (dv[:, 1:] + dv[:, :-1]) * np.diff(t)[None, :, None]
    dp = np.concatenate([np.zeros_like(dv[:, :1]), np.cumsum(step, axis=1)], axis=1)
    return position_plus(pos, dp)


@dataclass
class SmootherRecord:
    """What the forward pass of one filter keeps for the smoother (module docstring): per event the
    arrays of :func:`rts_backward` and the solution after the event, and ``epoch`` the GT epoch of
    each event (−1 for a measurement time between epochs)."""

    Phi: list = field(default_factory=list)
    P_prior: list = field(default_factory=list)
    P_post: list = field(default_factory=list)
    corr: list = field(default_factory=list)
    nav: list = field(default_factory=list)
    epoch: list = field(default_factory=list)
    _span: np.ndarray | None = None
    _nav_prior: object = None

    def start(self, filt) -> None:
        """The initial epoch (event 0): the filter's initial solution and covariance."""
        P = np.array(filt.smoother_covariance(), copy=True)
        self.Phi.append(np.broadcast_to(np.eye(P.shape[-1]), P.shape).copy())
        self.P_prior.append(P)
        self.P_post.append(P)
        self.corr.append(np.zeros(P.shape[:-1]))
        self.nav.append(filt.state().copy())
        self.epoch.append(0)

    def begin_span(self) -> None:
        """A new span starts: Φ over it is accumulated by :meth:`add_transition`."""
        self._span = None

    def add_transition(self, Phi: np.ndarray) -> None:
        """Compose the Φ of one time update into the span's (``Φ_span ← Φ Φ_span``)."""
        self._span = np.array(Phi, copy=True) if self._span is None else Phi @ self._span

    def prior(self, filt) -> None:
        """After the span's time updates: the prior covariance and solution."""
        self.P_prior.append(np.array(filt.smoother_covariance(), copy=True))
        self._nav_prior = filt.state().copy()

    def posterior(self, filt, epoch: int | None) -> None:
        """After the event's measurement updates (if any): the posterior, the correction, the solution."""
        P = self.P_prior[-1]
        n = P.shape[-1]
        self.Phi.append(self._span if self._span is not None else np.broadcast_to(np.eye(n), P.shape).copy())
        nav = filt.state().copy()
        self.P_post.append(np.array(filt.smoother_covariance(), copy=True))
        with np.errstate(all="ignore"):
            self.corr.append(filt.smoother_error(nav, self._nav_prior))
        self.nav.append(nav)
        self.epoch.append(-1 if epoch is None else int(epoch))

    def smooth(self, filt, n_epochs: int) -> tuple[list, np.ndarray]:
        """Run :func:`rts_backward` and return ``(navs, P)``: the smoothed solution at each of the
        ``n_epochs`` GT epochs (a list of :class:`~nespm_cli.nav.state.NavState`) and its covariance
        (R, N, n, n) in the common error coordinates (``filt.smoother_to_common``)."""
        e_s, P_s = rts_backward(np.stack(self.Phi), np.stack(self.P_prior), np.stack(self.P_post),
                                np.stack(self.corr))
        navs: list = [None] * n_epochs
        R, n = e_s.shape[1], e_s.shape[2]
        P = np.full((R, n_epochs, n, n), np.nan)
        with np.errstate(all="ignore"):
            for k, ep in enumerate(self.epoch):
                if ep < 0:
                    continue
                nav = self.nav[k].copy()
                filt.smoother_retract(nav, e_s[k])
                navs[ep] = nav
                P[:, ep] = filt.smoother_to_common(P_s[k], nav)
        return navs, P


__all__ = ["SMOOTHED_SUFFIX", "SmootherRecord", "dead_reckoned_position", "rts_backward", "smoothed_name", "smoothed_of", "smoother_gain"]

"""A cubature Kalman filter (CKF) as an nespm filter plugin, registered as ``ckf-example``.

Written only against nespm's public filter protocol (docs/plugins.md):
``nespm_cli.filters.protocol`` (the base class and its helpers), ``nespm_cli.filters.registry``
(``register``) and ``nespm_cli.sensors`` (the measurement interface).

Run it beside the EKF::

    nespm mc --filter-plugin examples/ckf_filter.py --filters ekf,ckf-example --tracks 5 --runs 8
    nespm mc ... --filter-option ckf-example.q_scale=2     # its own option (``option_defaults``)

The filter (Arasaratnam & Haykin 2009, third-degree spherical-radial cubature rule):

* n error states (12 by default, any ``--state`` layout); 2n cubature points ``ξ_i = ±√n · L[:, i]`` with ``P = L Lᵀ``
  (the i-th column of the Cholesky factor), every weight ``1 / (2n)``; no centre point, no
  tuning parameters (unlike the scaled UT's α, β, κ).
* Error-state, closed loop like the built-ins: the state mean is zero between steps, the
  points are offsets around the navigation solution.
* Time update: the navigation solution runs the strapdown over the span while the
  transition Φ = Π (I + F dt) is accumulated (``transition``, the same linearised
  transition as the built-in ``ukf``); the points go through Φ, ``P ← Σ w (Φξ − m)(Φξ − m)ᵀ + Q``.
  With a linear map the cubature rule is exact, so this prediction equals the EKF's
  ``Φ P Φᵀ + Q`` up to round-off.
* Measurement update: the points go through the measurement's nonlinear model ``h``
  (for the DVL, anukf.md eq 33 as a change from x = 0); cross and innovation covariances
  from the same weights; ``P ← P − K S Kᵀ``; the estimate is fed back into the solution.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.sensors import Measurement
from nespm_cli.filters.protocol import ErrorStateFilter
from nespm_cli.filters.registry import register


def cubature_points(L: np.ndarray) -> np.ndarray:
    """The 2n cubature offsets (R, 2n, n) from Cholesky factors ``L`` (R, n, n)."""
    n = L.shape[-1]
    cols = np.sqrt(n) * np.swapaxes(L, -1, -2)  # row i = column i of L
    return np.concatenate([cols, -cols], axis=-2)


def cubature_moments(Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (R, a) and deviations (R, 2n, a) of the point images Y (R, 2n, a), weights 1/(2n)."""
    m = Y.mean(axis=-2)
    return m, Y - m[..., None, :]


@register("ckf-example")
class CubatureKF(ErrorStateFilter):
    """Error-state CKF: cubature points through the linearised transition and the nonlinear measurement.

    Its own option ``q_scale`` (default 1): the process noise Q is multiplied by it, a common tuning
    knob (``--filter-option ckf-example.q_scale=2``; recorded in the manifest, sweepable as
    ``sweep --param ckf-example.q_scale``)."""

    option_defaults = {"q_scale": 1.0}

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        Q = self.options["q_scale"] * self.process_noise(self.span(j0, j1), k)  # before the solution moves
        Phi = self.transition(j0, j1)  # moves self.nav through steps [j0, j1)
        X = cubature_points(self.cholesky())
        Y = X @ np.swapaxes(Phi, -1, -2)
        m, D = cubature_moments(Y)
        self.P = np.swapaxes(D, -1, -2) @ D / D.shape[-2] + Q
        self.feedback(m)
        self.symmetrize()

    def update(self, measurement: Measurement, j_last: int):
        nav = self.state()
        nu = measurement.innovation(nav)  # (R, m)
        X = cubature_points(self.cholesky())  # (R, 2n, n)
        dz = measurement.h(X, nav)  # (R, 2n, m)
        mx, Dx = cubature_moments(X)
        mz, Dz = cubature_moments(dz)
        w = 1.0 / X.shape[-2]
        S = w * (np.swapaxes(Dz, -1, -2) @ Dz) + measurement.R
        Pxz = w * (np.swapaxes(Dx, -1, -2) @ Dz)
        K = np.swapaxes(np.linalg.solve(S, np.swapaxes(Pxz, -1, -2)), -1, -2)
        x = mx + (K @ (nu - mz)[..., None])[..., 0]
        self.P = self.P - K @ S @ np.swapaxes(K, -1, -2)
        self.symmetrize()
        self.feedback(x)
        return nu - mz, S  # the innovation and its covariance, for the NIS

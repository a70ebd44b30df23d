"""``ukf`` and ``ukf-nespm``: error-state unscented Kalman filters (scaled UT, :mod:`.unscented`).

* ``ukf``: sigma points through the same Φ as the EKF (anukf.md eqs 5-23); with a linear
  propagation its prediction equals the EKF's.
* ``ukf-nespm``: every sigma point is added to the mean solution (eqs 35-37), carried
  through ``na_cycle`` with the IMU compensated by its own biases (eq 38), and read back
  with ⊖ against the propagated mean (eqs 39-40).

Both update with the measurement's nonlinear model ``h`` on sigma points (DVL: anukf.md eq 33).
"""
from __future__ import annotations

import numpy as np

from nespm_cli.filters.model import BA, BG
from nespm_cli.filters.protocol import ErrorStateFilter
from nespm_cli.filters.registry import register
from nespm_cli.filters.unscented import moments, sigma_offsets
from nespm_cli.nav.rotations import attitude_minus


@register("ukf")
class UKF(ErrorStateFilter):
    """Closed-loop error-state UKF, sigma points through the linearised transition Φ."""

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        span = self.span(j0, j1)
        Q = self.process_noise(span, k)
        Phi = self.transition(j0, j1)
        L = self.cholesky()
        X = sigma_offsets(L, self.ut)
        Y = X @ np.swapaxes(Phi, -1, -2)
        m, P = moments(Y, self.ut)
        self.P = P + Q
        self.feedback(m)
        self.symmetrize()

    def update(self, measurement, j_last: int) -> None:
        nav = self.nav
        nu = measurement.innovation(nav)
        Rm = measurement.R
        L = self.cholesky()
        X = sigma_offsets(L, self.ut)
        dz = measurement.h(X, nav)
        m, _, mz, Pzz, Pxz = moments(X, self.ut, dz)
        S = Pzz + Rm
        K = np.swapaxes(np.linalg.solve(S, np.swapaxes(Pxz, -1, -2)), -1, -2)
        x = m + (K @ (nu - mz)[..., None])[..., 0]
        self.P = self.P - K @ S @ np.swapaxes(K, -1, -2)
        self.symmetrize()
        self.feedback(x)


@register("ukf-nespm")
class UKFNespm(UKF):
    """UKF whose sigma points each run the full strapdown over the span (eqs 35-40)."""

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        span = self.span(j0, j1)
        Q = self.process_noise(span, k)
        nav = self.nav
        L = self.cholesky()
        X = sigma_offsets(L, self.ut)  # (R, 2n, 12)
        pos, v, C = self.points_through_cycle(X, j0, j1)  # eqs 35-38
        dv = v[:, 1:] - v[:, :1]  # eq 39
        dpsi = attitude_minus(C[:, 1:], C[:, :1])  # eq 40: ⊖
        Y = np.concatenate([dv, dpsi, X[..., BA], X[..., BG]], axis=-1)
        m, P = moments(Y, self.ut)
        nav.pos, nav.v_n, nav.C_bn = pos[:, 0], v[:, 0], C[:, 0]
        self.feedback(m)
        self.P = P + Q

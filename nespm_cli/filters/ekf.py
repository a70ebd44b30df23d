"""``ekf``: linearised error-state Kalman filter.

Time update: Φ = Π (I + F dt) accumulated at the IMU rate over the span, ``P ← Φ P Φᵀ + Q``.
Measurement update: the measurement's Jacobian H (DVL: eq 33 at x = 0), Joseph form, one
measurement at a time.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.filters.model import joseph_update
from nespm_cli.filters.protocol import ErrorStateFilter
from nespm_cli.filters.registry import register


@register("ekf")
class EKF(ErrorStateFilter):
    """Closed-loop error-state EKF (state mean zero between steps)."""

    smoothable = True

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        span = self.span(j0, j1)
        Q = self.process_noise(span, k)
        Phi = self.transition(j0, j1)
        self.last_transition = Phi
        self.P = Phi @ self.P @ np.swapaxes(Phi, -1, -2) + Q
        self.symmetrize()

    def update(self, measurement, j_last: int) -> None:
        nav = self.nav
        nu = measurement.innovation(nav)
        x, self.P, S = joseph_update(self.P, measurement.H(nav), nu, measurement.R)
        self.feedback(x)
        return nu, S

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

from nespm_cli.filters.protocol import ErrorStateFilter
from nespm_cli.filters.registry import register
from nespm_cli.filters.unscented import moments, sigma_offsets
from nespm_cli.nav.rotations import attitude_minus


@register("ukf")
class UKF(ErrorStateFilter):
    """Closed-loop error-state UKF, sigma points through the linearised transition Φ.

    The point set is two methods, :meth:`offsets` and :meth:`point_moments` (the scaled UT
    here); ``ckf`` and ``ckf-nespm`` are these classes with the cubature rule instead.
    """

    #: FilterConfig fields this filter takes per filter (``--filter-option ukf.alpha=0.5``)
    tunable = ("alpha", "beta", "kappa")

    def offsets(self, L: np.ndarray) -> np.ndarray:
        """Outer point offsets (R, S, n) from Cholesky factors ``L`` (R, n, n) of P."""
        return sigma_offsets(L, self.ut)

    def point_moments(self, dx: np.ndarray, dz: np.ndarray | None = None):
        """Mean offset and covariance of point deviations ``dx`` (and images ``dz``): ``(m, P)``
        or ``(m, P, mz, Pzz, Pxz)`` (:func:`nespm_cli.filters.unscented.moments`)."""
        return moments(dx, self.ut, dz)

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        Q = self.process_noise(self.span(j0, j1), k)  # before the solution moves
        Phi = self.transition(j0, j1)
        X = self.offsets(self.cholesky())
        m, P = self.point_moments(X @ np.swapaxes(Phi, -1, -2))
        self.P = P + Q
        self.feedback(m)
        self.symmetrize()

    def update(self, measurement, j_last: int) -> None:
        nav = self.nav
        nu = measurement.innovation(nav)
        X = self.offsets(self.cholesky())
        dz = measurement.h(X, nav)  # (R, S, m): h(x) − h(0)
        m, _, mz, Pzz, Pxz = self.point_moments(X, dz)
        S = Pzz + measurement.R
        K = np.swapaxes(np.linalg.solve(S, np.swapaxes(Pxz, -1, -2)), -1, -2)  # Pxz S⁻¹
        x = m + (K @ (nu - mz)[..., None])[..., 0]
        self.P = self.P - K @ S @ np.swapaxes(K, -1, -2)
        self.symmetrize()
        self.feedback(x)
        return nu - mz, S


@register("ukf-nespm")
class UKFNespm(UKF):
    """UKF whose sigma points each run the full strapdown over the span (eqs 35-40)."""

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        Q = self.process_noise(self.span(j0, j1), k)
        nav, lay = self.nav, self.layout
        X = self.offsets(self.cholesky())  # (R, S, n)
        pos, v, C, dp = self.points_through_cycle(X, j0, j1)  # eqs 35-38
        blocks = {
            "pos": lambda: dp[:, 1:],  # the position offsets, integrated as deviations
            "vel": lambda: v[:, 1:] - v[:, :1],  # eq 39
            "att": lambda: attitude_minus(C[:, 1:], C[:, :1]),  # eq 40: ⊖
            "ba": lambda: X[..., lay.slice("ba")],  # biases: constant over the span
            "bg": lambda: X[..., lay.slice("bg")],
        }
        Y = np.concatenate([blocks[b]() for b in lay.blocks], axis=-1)
        m, P = self.point_moments(Y)
        nav.pos, nav.v_n, nav.C_bn = pos[:, 0], v[:, 0], C[:, 0]
        self.feedback(m)
        self.P = P + Q

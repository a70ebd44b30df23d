"""``ckf`` and ``ckf-nespm``: error-state cubature Kalman filters (:mod:`.cubature`).

Third-degree spherical-radial rule (Arasaratnam & Haykin 2009): 2n = 24 points
``±√n · L[:, i]`` (``P = L Lᵀ``), every weight ``1/(2n)``, no centre point, no tuning
(``cfg.alpha``, ``beta``, ``kappa`` are not used). Closed loop like the other built-ins:
the state ``x = [dv (m/s), dpsi (rad), b_a (m/s²), b_g (rad/s)]`` (R, 12) is zero between
steps and the points are offsets (R, 24, 12) around the navigation solution.

* ``ckf``: the points go through the same linearised transition Φ = Π (I + F dt) as the
  ``ekf`` and ``ukf``; the rule is exact for a linear map, so its prediction is the EKF's
  ``Φ P Φᵀ + Q`` to round-off.
* ``ckf-nespm``: the mean solution (the reference, weight 0) and every point added to it
  (ukf-nespm.md eqs 35-37) are carried through ``na_cycle`` over the span, each with the IMU
  compensated by its own biases (eq 38), and read back with ⊖ against the propagated
  reference (eqs 39-40); mean and covariance from these deviations with the cubature
  weights; the mean offset is fed back. The IMU-rate loop over the points is the shared
  ``ErrorStateFilter.points_through_cycle`` (compiled, or the NumPy reference: the same bits).

Both update with the measurement's nonlinear model ``h`` on the cubature points (DVL:
anukf.md eq 33), ``P ← P − K S Kᵀ``, and feed the estimate back.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.filters.cubature import cubature_moments, cubature_offsets
from nespm_cli.filters.measurements import Measurement
from nespm_cli.filters.model import BA, BG
from nespm_cli.filters.protocol import ErrorStateFilter
from nespm_cli.filters.registry import register
from nespm_cli.nav.rotations import attitude_minus


@register("ckf")
class CKF(ErrorStateFilter):
    """Closed-loop error-state CKF, cubature points through the linearised transition Φ."""

    adaptive_of = None
    needs_noise_std = False

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        Q = self.process_noise(self.span(j0, j1), k)  # before the solution moves
        Phi = self.transition(j0, j1)  # moves self.nav through steps [j0, j1)
        X = cubature_offsets(self.cholesky())  # (R, 2n, 12)
        Y = X @ np.swapaxes(Phi, -1, -2)  # deviations from the image of the mean (0)
        m, P = cubature_moments(Y)
        self.P = P + Q
        self.feedback(m)
        self.symmetrize()

    def update(self, measurement: Measurement, j_last: int) -> None:
        nav = self.nav
        nu = measurement.innovation(nav)  # (R, m)
        X = cubature_offsets(self.cholesky())  # (R, 2n, 12)
        dz = measurement.h(X, nav)  # (R, 2n, m): h(x) − h(0)
        m, _, mz, Pzz, Pxz = cubature_moments(X, dz)
        S = Pzz + measurement.R
        K = np.swapaxes(np.linalg.solve(S, np.swapaxes(Pxz, -1, -2)), -1, -2)  # Pxz S⁻¹
        x = m + (K @ (nu - mz)[..., None])[..., 0]
        self.P = self.P - K @ S @ np.swapaxes(K, -1, -2)
        self.symmetrize()
        self.feedback(x)


@register("ckf-nespm")
class CKFNespm(CKF):
    """CKF whose cubature points each run the full strapdown over the span (eqs 35-40)."""

    adaptive_of = None
    needs_noise_std = False

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        Q = self.process_noise(self.span(j0, j1), k)
        nav = self.nav
        X = cubature_offsets(self.cholesky())  # (R, 2n, 12)
        pos, v, C = self.points_through_cycle(X, j0, j1)  # eqs 35-38, compiled where the base is
        dv = v[:, 1:] - v[:, :1]  # eq 39
        dpsi = attitude_minus(C[:, 1:], C[:, :1])  # eq 40: ⊖
        Y = np.concatenate([dv, dpsi, X[..., BA], X[..., BG]], axis=-1)  # biases: constant over the span
        m, P = cubature_moments(Y)
        nav.pos, nav.v_n, nav.C_bn = pos[:, 0], v[:, 0], C[:, 0]
        self.feedback(m)
        self.P = P + Q
        self.symmetrize()

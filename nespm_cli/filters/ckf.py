"""``ckf`` and ``ckf-nespm``: error-state cubature Kalman filters (:mod:`.cubature`).

Third-degree spherical-radial rule (Arasaratnam & Haykin 2009): 2n points (24 for the 12 states)
``±√n · L[:, i]`` (``P = L Lᵀ``), every weight ``1/(2n)``, no centre point, no tuning
(``cfg.alpha``, ``beta``, ``kappa`` are not used). Closed loop like the other built-ins:
the state (any layout; the papers' ``x = [dv (m/s), dpsi (rad), b_a (m/s²), b_g (rad/s)]``,
(R, 12)) is zero between steps and the points are offsets (R, 2n, n) around the navigation solution.

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
anukf.md eq 33), ``P ← P − K S Kᵀ``, and feed the estimate back. The filter steps are the
UKF's (:mod:`.ukf`); only the point set differs (:class:`CubatureRule`).
"""
from __future__ import annotations

import numpy as np

from nespm_cli.filters.cubature import cubature_moments, cubature_offsets
from nespm_cli.filters.registry import register
from nespm_cli.filters.ukf import UKF, UKFNespm


class CubatureRule:
    """The third-degree spherical-radial point set for the sigma-point filters of :mod:`.ukf`."""

    tunable = ()  # no alpha, beta, kappa: the cubature rule has no tuning

    def offsets(self, L: np.ndarray) -> np.ndarray:
        """The 2n cubature offsets (R, 2n, n) ``±√n L[:, i]``."""
        return cubature_offsets(L)

    def point_moments(self, dx: np.ndarray, dz: np.ndarray | None = None):
        """Moments with the equal weights 1/(2n) (:func:`nespm_cli.filters.cubature.cubature_moments`)."""
        return cubature_moments(dx, dz)


@register("ckf")
class CKF(CubatureRule, UKF):
    """Closed-loop error-state CKF, cubature points through the linearised transition Φ."""


@register("ckf-nespm")
class CKFNespm(CubatureRule, UKFNespm):
    """CKF whose cubature points each run the full strapdown over the span (eqs 35-40)."""

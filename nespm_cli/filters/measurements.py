"""Measurement protocol of the INS/DVL filters (pyins' ``compute_matrices`` pattern).

A measurement object holds one epoch's observation of R runs and tells a filter how it
depends on the 12-state error ``x = [dv, dpsi, b_a, b_g]`` (:mod:`nespm_cli.filters.model`)
around the current navigation solution ``nav``:

* ``z`` (R, m): the measured values;
* ``predict(nav)`` (R, m): the predicted measurement at x = 0 (the navigation solution);
* ``innovation(nav)`` (R, m): ``z − predict(nav)``;
* ``h(X, nav)`` (R, S, m): the nonlinear model's *change* from x = 0, ``h(x) − h(0)``, for
  S error-state points ``X`` (R, S, 12) per run (sigma / cubature point offsets);
* ``H(nav)`` (R, m, 12): the Jacobian of ``h`` at x = 0;
* ``R`` (m, m) or (R, m, m): the measurement noise covariance.

A filter's ``update(measurement, j_last)`` uses only these, so it never knows which sensor
it is updating with. The runner (:func:`nespm_cli.filters.engine.run_filter`) builds a
:class:`DvlMeasurement` at every DVL epoch.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.nav.dvl import dvl_velocity
from nespm_cli.filters.model import NavState, dvl_H, dvl_h, dvl_innovation


class Measurement:
    """Base class of a measurement (see the module docstring). Subclasses set ``z`` and ``R``
    and implement ``predict``, ``h`` and ``H``; ``innovation`` then follows."""

    #: (R, m) measured values
    z: np.ndarray
    #: (m, m) or (R, m, m) noise covariance
    R: np.ndarray

    def predict(self, nav: NavState) -> np.ndarray:
        """Predicted measurement at x = 0, (R, m)."""
        raise NotImplementedError

    def innovation(self, nav: NavState) -> np.ndarray:
        """Measured minus predicted at x = 0, (R, m)."""
        return self.z - self.predict(nav)

    def h(self, X: np.ndarray, nav: NavState) -> np.ndarray:
        """Change of the predicted measurement ``h(x) − h(0)`` for points X (R, S, 12) -> (R, S, m)."""
        raise NotImplementedError

    def H(self, nav: NavState) -> np.ndarray:
        """Jacobian of :meth:`h` at x = 0, (R, m, 12)."""
        raise NotImplementedError

    @property
    def dim(self) -> int:
        """m, the measurement's dimension."""
        return int(np.shape(self.z)[-1])


class DvlMeasurement(Measurement):
    """Body-frame DVL velocity (anukf.md eq 33): ``h(x) = C^T exp(−[dpsi×]) (v + dv) + (w_nb − b_g) × l``.

    Args:
        dvl_b: (R, 3) measured body-frame velocity [m/s].
        w_nb: (R, 3) body rate relative to NED from the compensated gyro [rad/s] (the
            lever-arm term), at the IMU sample ending the interval.
        lever: (3,) DVL position relative to the IMU, body frame [m].
        std: DVL noise std per axis [m/s]; ``R = I₃ std²``.
    """

    def __init__(self, dvl_b: np.ndarray, w_nb: np.ndarray, lever, std: float):
        self.z = dvl_b
        self.w_nb = w_nb
        self.lever = np.asarray(lever, dtype=float)
        self.std = std
        self.R = np.eye(3) * std**2

    def innovation(self, nav: NavState) -> np.ndarray:
        return dvl_innovation(nav, self.z, self.w_nb, self.lever)

    def predict(self, nav: NavState) -> np.ndarray:
        return dvl_velocity(nav.C_bn, nav.v_n, self.w_nb, self.lever)

    def h(self, X: np.ndarray, nav: NavState) -> np.ndarray:
        return dvl_h(X, nav, self.lever)

    def H(self, nav: NavState) -> np.ndarray:
        return dvl_H(nav, self.lever)


__all__ = ["DvlMeasurement", "Measurement"]

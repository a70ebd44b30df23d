"""What a filter asks of one measurement (pyins' ``compute_matrices`` pattern, navlie's models).

A :class:`Measurement` holds one time's observation of R runs by one sensor and tells a filter
how it depends on the error state ``x`` (the blocks of a
:class:`~nespm_cli.nav.state.StateLayout`, ``nav ⊕ x = truth``) around the navigation solution:

* ``z`` (R, m): the measured values;
* ``predict(nav)`` (R, m): the predicted measurement at x = 0;
* ``innovation(nav)`` (R, m): measured minus predicted (``z − predict`` unless a sensor needs
  another difference, e.g. a position fix in local metres);
* ``h(X, nav)`` (R, S, m): the nonlinear model's *change* from x = 0, ``h(x) − h(0)``, for S
  error-state points ``X`` (R, S, n) (sigma / cubature offsets);
* ``H(nav)`` (R, m, n): the Jacobian of ``h`` at x = 0 (zero columns for the blocks it does not see);
* ``R`` (m, m) or (R, m, m): the noise covariance;
* ``H_invariant(nav)``: the Jacobian in the right-invariant coordinates of the ``iekf``
  (docs/iekf.md) where the sensor has a closed form, else None (the iekf then uses ``H T``).

A filter's ``update(measurement, j_last)`` uses only these, so no filter names a sensor.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.nav.state import NavState, StateLayout


class Measurement:
    """Base class: subclasses set ``z``, ``R`` and ``layout`` and implement ``predict``, ``h`` and
    ``H``; ``innovation`` and ``dim`` follow."""

    #: (R, m) measured values
    z: np.ndarray
    #: (m, m) or (R, m, m) noise covariance
    R: np.ndarray
    #: the error-state layout ``h`` and ``H`` are written for
    layout: StateLayout

    def predict(self, nav: NavState) -> np.ndarray:
        """Predicted measurement at x = 0, (R, m)."""
        raise NotImplementedError

    def innovation(self, nav: NavState) -> np.ndarray:
        """Measured minus predicted at x = 0, (R, m)."""
        return self.z - self.predict(nav)

    def h(self, X: np.ndarray, nav: NavState) -> np.ndarray:
        """Change of the predicted measurement ``h(x) − h(0)`` for points X (R, S, n) -> (R, S, m)."""
        raise NotImplementedError

    def H(self, nav: NavState) -> np.ndarray:
        """Jacobian of :meth:`h` at x = 0, (R, m, n)."""
        raise NotImplementedError

    def H_invariant(self, nav: NavState) -> np.ndarray | None:
        """Closed-form Jacobian in the iekf's invariant coordinates (R, m, n), or None."""
        return None

    @property
    def dim(self) -> int:
        """m, the measurement's dimension."""
        return int(np.shape(self.z)[-1])

    def zeros_H(self, nav: NavState) -> np.ndarray:
        """A zero Jacobian (R, m, n) to fill block by block."""
        return np.zeros(nav.v_n.shape[:-1] + (self.dim, self.layout.n))

    def block(self, X: np.ndarray, name: str) -> np.ndarray:
        """Block ``name`` of points ``X`` (..., n) -> (..., 3); zeros when the layout lacks it."""
        if self.layout.has(name):
            return X[..., self.layout.slice(name)]
        return np.zeros(X.shape[:-1] + (3,))


__all__ = ["Measurement"]

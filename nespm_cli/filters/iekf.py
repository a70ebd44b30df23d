"""``iekf``: right-invariant error-state EKF with bias states (an "imperfect" IEKF).

Sources: Barrau & Bonnabel, *The invariant extended Kalman filter as a stable observer*,
IEEE TAC 62(4), 2017 (right-invariant error, right-invariant observations ``Y = X⁻¹ b``);
A. Barrau, *Non-linear state error based extended Kalman filters with applications to
navigation*, PhD thesis, Mines ParisTech, 2015 (the "imperfect IEKF": biases appended as a
vector-space part of the state); Hartley et al., *Contact-aided invariant extended Kalman
filtering for robot state estimation*, IJRR 39(4), 2020 (the bias columns of the right-invariant
error dynamics). Derivations, choices and the coordinate map: docs/iekf.md.

State, shapes and units (R runs first; every function is batched over leading axes ``B``):

* group part ``X = (C_bn, v_n)``, the SE_2(3) extended pose without position (position is not a
  state, as in the common model), a 4x4 matrix ``[[C, v], [0, 1]]``;
* right-invariant error ``η = X_true X_nav⁻¹ = exp(ξ)``, with Lie-algebra coordinates
  ``ξ = [ρ (0:3) m/s, φ (3:6) rad]``: ``C_true = exp([φ×]) C_nav`` (so φ IS the common δψ) and
  ``v_true = exp([φ×]) v_nav + J_l(φ) ρ``;
* biases as in the common state: ``b_a (6:9)`` m/s², ``b_g (9:12)`` rad/s, residuals in the
  compensated IMU (``f_true = f_meas − b̂_a − b_a``);
* invariant state ``ξ = [ρ, φ, b_a, b_g]`` (R, 12), covariance ``P_inv`` (R, 12, 12).

The common 12-state error ``x = [δv, δψ, b_a, b_g]`` of :mod:`nespm_cli.filters.model` is, to
first order, ``x = T(v_nav) ξ`` with ``δv = ρ − [v×] φ`` (:func:`common_from_invariant`);
:meth:`IEKF.covariance` returns ``T P_inv Tᵀ``, so the engine's P6 / P_diag and the NEES are in
the common coordinates like every other filter's.

Public array-level functions: the filter uses :func:`invariant_retraction` (the feedback),
:func:`common_from_invariant`, :func:`covariance_to_common` and :func:`covariance_to_invariant`
(F_inv is :func:`nespm_cli.filters.model.invariant_system_matrix`, compiled in
:mod:`nespm_cli.filters.transition_kernel`); a measurement gives its Jacobian in these
coordinates where it has a closed form (``Measurement.H_invariant``: the DVL's,
:mod:`nespm_cli.sensors.dvl`), else the filter uses ``H T``. :func:`invariant_log` (the inverse of
the retraction) and :func:`invariant_from_common` are the exact maps the tests check the
Jacobians and the feedback against (tests/test_iekf.py). The filter serves the 12-state layout
only (``layouts``): another ``--state`` is refused in one line.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.filters.model import (BA, BG, DPSI, DV, N_STATES, FilterConfig, NavState, invariant_system_matrix,
                                     joseph_update)
from nespm_cli.filters.protocol import ErrorStateFilter, ImuData
from nespm_cli.filters.registry import register
from nespm_cli.nav.rotations import (exp_so3, exp_so3_minus_identity, log_so3, skew, so3_left_jacobian,
                                     so3_left_jacobian_inverse)
from nespm_cli.sensors.measurement import Measurement

def _swap(A: np.ndarray) -> np.ndarray:
    return np.swapaxes(A, -1, -2)


# --- the group: exponential (retraction) and logarithm ---------------------------------------------

def invariant_retraction(v_n: np.ndarray, C_bn: np.ndarray, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left-multiply the solution by ``exp(ξ)`` (the right-invariant feedback): ``X⁺ = exp(ξ) X``.

    ``C⁺ = exp([φ×]) C``, ``v⁺ = exp([φ×]) v + J_l(φ) ρ``, evaluated as
    ``v + (exp([φ×]) − I) v + J_l(φ) ρ`` (no cancellation of the large ``v``).

    Args:
        v_n: (B, 3) [m/s]; C_bn: (B, 3, 3); xi: (B, ≥6) with ``ρ = xi[..., 0:3]`` [m/s] and
            ``φ = xi[..., 3:6]`` [rad] (bias entries, if present, are ignored here).

    Returns:
        ``(v_n⁺, C_bn⁺)``.
    """
    rho, phi = xi[..., DV], xi[..., DPSI]
    dv = (exp_so3_minus_identity(phi) @ v_n[..., None])[..., 0] + (so3_left_jacobian(phi) @ rho[..., None])[..., 0]
    return v_n + dv, exp_so3(phi) @ C_bn


def invariant_log(C_true: np.ndarray, v_true: np.ndarray, C_nav: np.ndarray, v_nav: np.ndarray) -> np.ndarray:
    """Invariant error coordinates ``ξ = log(X_true X_nav⁻¹)`` = ``[ρ, φ]`` (..., 6).

    ``φ = log(C_true C_navᵀ)``, ``ρ = J_l(φ)⁻¹ (v_true − C_true C_navᵀ v_nav)``; the inverse of
    :func:`invariant_retraction`.
    """
    E = C_true @ _swap(C_nav)
    phi = log_so3(E)
    p = (v_true - v_nav) - ((E - np.eye(3)) @ v_nav[..., None])[..., 0]
    rho = (so3_left_jacobian_inverse(phi) @ p[..., None])[..., 0]
    return np.concatenate([rho, phi], axis=-1)


def invariant_feedback(nav: NavState, xi: np.ndarray) -> None:
    """Close the loop in place: ``X ← exp(ξ) X`` (:func:`invariant_retraction`), biases added to
    the compensation (``b̂ ← b̂ + b``). ``xi`` (B, 12); afterwards the estimate is zero."""
    nav.v_n, nav.C_bn = invariant_retraction(nav.v_n, nav.C_bn, xi)
    nav.b_a = nav.b_a + xi[..., BA]
    nav.b_g = nav.b_g + xi[..., BG]


# --- coordinate map between the invariant and the common error state ------------------------------

def common_from_invariant(v_n: np.ndarray) -> np.ndarray:
    """``T`` (B, 12, 12), the Jacobian at ξ = 0 of the common error as a function of the invariant one.

    ``x = T ξ``: ``δv = ρ − [v×] φ``, ``δψ = φ``, biases unchanged (from ``v_true − v_nav =
    (exp([φ×]) − I) v_nav + J_l(φ) ρ ≈ ρ + φ × v_nav``).
    """
    T = np.broadcast_to(np.eye(N_STATES), v_n.shape[:-1] + (N_STATES, N_STATES)).copy()
    T[..., DV, DPSI] = -skew(v_n)
    return T


def invariant_from_common(v_n: np.ndarray) -> np.ndarray:
    """``T⁻¹`` (B, 12, 12): ``ξ = T⁻¹ x``, ``ρ = δv + [v×] δψ``, ``φ = δψ``."""
    Ti = np.broadcast_to(np.eye(N_STATES), v_n.shape[:-1] + (N_STATES, N_STATES)).copy()
    Ti[..., DV, DPSI] = skew(v_n)
    return Ti


def covariance_to_common(P_inv: np.ndarray, v_n: np.ndarray) -> np.ndarray:
    """``P = T P_inv Tᵀ`` (B, 12, 12), symmetrized, with ``T`` of :func:`common_from_invariant`."""
    T = common_from_invariant(v_n)
    P = T @ P_inv @ _swap(T)
    return 0.5 * (P + _swap(P))


def covariance_to_invariant(P: np.ndarray, v_n: np.ndarray) -> np.ndarray:
    """``P_inv = T⁻¹ P T⁻ᵀ`` (B, 12, 12), symmetrized: a common-coordinate covariance (P0, the
    process noise Q) in the invariant coordinates at velocity ``v_n`` (B, 3)."""
    Ti = invariant_from_common(v_n)
    P_inv = Ti @ P @ _swap(Ti)
    return 0.5 * (P_inv + _swap(P_inv))


# --- the filter ---------------------------------------------------------------------------------

@register("iekf")
class IEKF(ErrorStateFilter):
    """Closed-loop right-invariant EKF: covariance ``P_inv`` held in ξ = [ρ, φ, b_a, b_g].

    ``self.P`` (what :meth:`covariance` returns and :meth:`check` tests) is kept equal to
    ``T P_inv Tᵀ`` at the current solution's velocity (:func:`covariance_to_common`).
    ``transition`` accumulates Φ_inv (``invariant_error``).
    """

    invariant_error = True
    smoothable = True
    per_run = ("P", "P_inv")
    #: the layouts this filter serves (the SE₂(3) error with position is not built yet)
    layouts = ("12",)

    def __init__(self, cfg: FilterConfig, nav0: NavState, imu: ImuData, noise_std=None):
        super().__init__(cfg, nav0, imu, noise_std)
        self.P_inv = covariance_to_invariant(self.P, self.nav.v_n)  # self.P = P0 exactly at epoch 0

    def _sync(self) -> None:
        self.P = covariance_to_common(self.P_inv, self.nav.v_n)

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        Q = self.process_noise(self.span(j0, j1), k)  # common coordinates, at the attitude before the span
        Phi = self.transition(j0, j1)  # Φ_inv: invariant_error is set
        self.last_transition = Phi
        # Q is added at the end of the span (as the EKF's P ← Φ P Φᵀ + Q): mapped with T there
        Q_inv = covariance_to_invariant(np.broadcast_to(Q, self.P_inv.shape), self.nav.v_n)
        self.P_inv = Phi @ self.P_inv @ _swap(Phi) + Q_inv
        self.P_inv = 0.5 * (self.P_inv + _swap(self.P_inv))
        self._sync()

    def smoother_covariance(self) -> np.ndarray:
        return self.P_inv

    def smoother_error(self, nav_to: NavState, nav_from: NavState) -> np.ndarray:
        xi = invariant_log(nav_to.C_bn, nav_to.v_n, nav_from.C_bn, nav_from.v_n)
        return np.concatenate([xi, nav_to.b_a - nav_from.b_a, nav_to.b_g - nav_from.b_g], axis=-1)

    def smoother_retract(self, nav: NavState, x: np.ndarray) -> None:
        invariant_feedback(nav, x)

    def smoother_to_common(self, P: np.ndarray, nav: NavState) -> np.ndarray:
        return covariance_to_common(P, nav.v_n)

    def measurement_jacobian(self, measurement: Measurement) -> np.ndarray:
        """H_inv (R, m, 12): the measurement's closed form where it has one (``H_invariant``; the
        DVL's), else ``H_common T`` (chain rule)."""
        H = measurement.H_invariant(self.nav)
        if H is not None:
            return H
        return measurement.H(self.nav) @ common_from_invariant(self.nav.v_n)

    def update(self, measurement: Measurement, j_last: int):
        nav = self.nav
        # the EKF's innovation z − h(X_nav) with the invariant Jacobian and covariance
        nu = measurement.innovation(nav)
        xi, self.P_inv, S = joseph_update(self.P_inv, self.measurement_jacobian(measurement), nu, measurement.R)
        invariant_feedback(nav, xi)
        self._sync()
        return nu, S

    def check(self) -> None:
        new = ~self.bad.copy()
        super().check()
        new &= self.bad
        if new.any():  # base reset these runs' solution and P (= P0); restart P_inv from them
            self.P_inv[new] = covariance_to_invariant(self.P[new], self.nav.v_n[new])


__all__ = ["IEKF", "common_from_invariant", "covariance_to_common", "covariance_to_invariant",
           "invariant_feedback", "invariant_from_common", "invariant_log", "invariant_retraction",
           "invariant_system_matrix"]

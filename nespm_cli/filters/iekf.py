"""``iekf``: right-invariant error-state EKF with bias states (an "imperfect" IEKF).

Sources: Barrau & Bonnabel, *The invariant extended Kalman filter as a stable observer*,
IEEE TAC 62(4), 2017 (right-invariant error, right-invariant observations ``Y = X⁻¹ b``);
A. Barrau, *Non-linear state error based extended Kalman filters with applications to
navigation*, PhD thesis, Mines ParisTech, 2015 (the "imperfect IEKF": biases appended as a
vector-space part of the state); Hartley et al., *Contact-aided invariant extended Kalman
filtering for robot state estimation*, IJRR 39(4), 2020 (the bias columns of the right-invariant
error dynamics). Derivations, choices and the coordinate map: docs/iekf.md.

State, shapes and units (R runs first; every function is batched over leading axes ``B``):

* ``--state 12`` (the papers'): group part ``X = (C_bn, v_n)``, the SE_2(3) extended pose without
  position, a 4x4 matrix ``[[C, v], [0, 1]]``; right-invariant error ``η = X_true X_nav⁻¹ =
  exp(ξ)``, ``ξ = [ρ (0:3) m/s, φ (3:6) rad]``: ``C_true = exp([φ×]) C_nav`` (so φ IS the common
  δψ) and ``v_true = exp([φ×]) v_nav + J_l(φ) ρ``; invariant state ``ξ = [ρ, φ, b_a, b_g]`` (R, 12);
* ``--state 15``: ``X = (C_bn, v_n, p)``, SE_2(3) with position, where the group position ``p`` is
  the solution's NED offset [m] from a fixed origin, the run's initial solution
  (:func:`group_position`; flat earth about it, docs/iekf.md); ``ξ = [ρ_p (0:3) m, ρ_v (3:6) m/s,
  φ (6:9) rad, b_a, b_g]`` (R, 15), ``p_true = exp([φ×]) p_nav + J_l(φ) ρ_p``;
* biases as in the common state: ``b_a`` m/s², ``b_g`` rad/s, residuals in the compensated IMU
  (``f_true = f_meas − b̂_a − b_a``); covariance ``P_inv`` (R, n, n) in ξ.

The common error ``x`` of :mod:`nespm_cli.filters.model` is, to first order, ``x = T ξ`` with
``δv = ρ_v − [v×] φ`` and, with position, ``δp = ρ_p − [p×] φ`` (:func:`common_from_invariant`);
:meth:`IEKF.covariance` returns ``T P_inv Tᵀ``, so the engine's P6 / P_diag and the NEES are in
the common coordinates like every other filter's.

Public array-level functions: the filter uses :func:`invariant_retraction` /
:func:`invariant_retraction_with_position` (the feedback), :func:`common_from_invariant`,
:func:`covariance_to_common`, :func:`covariance_to_invariant` and
:func:`invariant_measurement_jacobian` (F_inv is :func:`nespm_cli.filters.model.invariant_system_matrix`,
compiled in :mod:`nespm_cli.filters.compiled.spans`); a measurement gives its Jacobian in these
coordinates where it has a closed form free of the group position (``Measurement.H_invariant``: the
DVL's, :mod:`nespm_cli.sensors.dvl`), else the filter uses ``H T`` (depth and fixes: their
invariant Jacobian depends on ``p``). :func:`invariant_log` / :func:`invariant_log_with_position`
(the inverses of the retractions) and :func:`invariant_from_common` are the exact maps the tests
check the Jacobians and the feedback against (tests/test_iekf.py). The filter serves the layouts
12 and 15 (``layouts``): another ``--state`` is refused in one line.
"""
from __future__ import annotations

import numpy as np

from nespm_cli.filters import kernels
from nespm_cli.filters.model import (BA, BG, DPSI, DV, N_STATES, FilterConfig, NavState, invariant_system_matrix,
                                     joseph_update)
from nespm_cli.filters.protocol import ErrorStateFilter, ImuData
from nespm_cli.filters.registry import register
from nespm_cli.nav.earth import ned_offset
from nespm_cli.nav.rotations import (exp_so3, exp_so3_minus_identity, log_so3, skew, so3_left_jacobian,
                                     so3_left_jacobian_inverse)
from nespm_cli.nav.state import LAYOUT_12, LAYOUT_15, StateLayout, position_plus
from nespm_cli.nav.strapdown import na_cycle
from nespm_cli.sensors.measurement import Measurement

#: the 15-state invariant slots: ρ_p, ρ_v, φ, b_a, b_g (the common layout 15's order)
RP, RV, PHI, BA15, BG15 = (LAYOUT_15.slice(b) for b in ("pos", "vel", "att", "ba", "bg"))


def _swap(A: np.ndarray) -> np.ndarray:
    return np.swapaxes(A, -1, -2)


def _mv(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    return (A @ x[..., None])[..., 0]


def group_position(pos: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """The group position ``p`` (..., 3) [m] of the 15-state iekf: the NED offset of ``pos``
    ``[lat, lon, h]`` from the run's fixed ``origin`` (:func:`nespm_cli.nav.earth.ned_offset`;
    flat earth about the origin, docs/iekf.md)."""
    return ned_offset(pos, origin)


# --- the group: exponential (retraction) and logarithm ---------------------------------------------

def invariant_retraction(v_n: np.ndarray, C_bn: np.ndarray, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left-multiply the solution by ``exp(ξ)`` (the right-invariant feedback, 12 states): ``X⁺ = exp(ξ) X``.

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


def invariant_retraction_with_position(pos: np.ndarray, v_n: np.ndarray, C_bn: np.ndarray, xi: np.ndarray,
                                       origin: np.ndarray, p: np.ndarray | None = None
                                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``X⁺ = exp(ξ) X`` on SE_2(3) with position (15 states), ``xi`` (B, ≥9) = ``[ρ_p, ρ_v, φ, …]``.

    ``C⁺ = exp([φ×]) C``, ``v⁺ = v + (exp([φ×]) − I) v + J_l(φ) ρ_v`` and the position moved by
    ``δ = (exp([φ×]) − I) p + J_l(φ) ρ_p`` [m, NED] (``p⁺ = exp([φ×]) p + J_l(φ) ρ_p``), applied as
    ``pos ⊕ δ`` (:func:`nespm_cli.nav.state.position_plus`, metres at the solution), so the common
    ``δp = ned_offset(pos⁺, pos)`` is ``δ`` exactly. ``p`` = :func:`group_position` ``(pos, origin)``
    (computed unless given).

    Returns:
        ``(pos⁺, v_n⁺, C_bn⁺)``.
    """
    rho_p, rho_v, phi = xi[..., RP], xi[..., RV], xi[..., PHI]
    E1, Jl = exp_so3_minus_identity(phi), so3_left_jacobian(phi)
    d = _mv(E1, group_position(pos, origin) if p is None else p) + _mv(Jl, rho_p)
    return position_plus(pos, d), v_n + _mv(E1, v_n) + _mv(Jl, rho_v), exp_so3(phi) @ C_bn


def invariant_log(C_true: np.ndarray, v_true: np.ndarray, C_nav: np.ndarray, v_nav: np.ndarray) -> np.ndarray:
    """Invariant error coordinates ``ξ = log(X_true X_nav⁻¹)`` = ``[ρ, φ]`` (..., 6) (12 states).

    ``φ = log(C_true C_navᵀ)``, ``ρ = J_l(φ)⁻¹ (v_true − C_true C_navᵀ v_nav)``; the inverse of
    :func:`invariant_retraction`.
    """
    E = C_true @ _swap(C_nav)
    phi = log_so3(E)
    p = (v_true - v_nav) - ((E - np.eye(3)) @ v_nav[..., None])[..., 0]
    rho = (so3_left_jacobian_inverse(phi) @ p[..., None])[..., 0]
    return np.concatenate([rho, phi], axis=-1)


def invariant_log_with_position(pos_true: np.ndarray, C_true: np.ndarray, v_true: np.ndarray, pos_nav: np.ndarray,
                                C_nav: np.ndarray, v_nav: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """``ξ = log(X_true X_nav⁻¹)`` = ``[ρ_p, ρ_v, φ]`` (..., 9) on SE_2(3) with position: the inverse
    of :func:`invariant_retraction_with_position`, ``ρ_p = J_l(φ)⁻¹ (ned_offset(pos_true, pos_nav)
    − (C_true C_navᵀ − I) p_nav)``, ``p_nav`` = :func:`group_position` ``(pos_nav, origin)``."""
    E = C_true @ _swap(C_nav)
    phi = log_so3(E)
    E1 = E - np.eye(3)
    Ji = so3_left_jacobian_inverse(phi)
    rho_v = _mv(Ji, (v_true - v_nav) - _mv(E1, v_nav))
    rho_p = _mv(Ji, ned_offset(pos_true, pos_nav) - _mv(E1, group_position(pos_nav, origin)))
    return np.concatenate([rho_p, rho_v, phi], axis=-1)


def invariant_feedback(nav: NavState, xi: np.ndarray, origin: np.ndarray | None = None,
                       p: np.ndarray | None = None) -> None:
    """Close the loop in place: ``X ← exp(ξ) X`` (:func:`invariant_retraction`, or with ``origin``
    (B, 3), 15 states, :func:`invariant_retraction_with_position`, ``p`` the group position if
    known), biases added to the compensation (``b̂ ← b̂ + b``). ``xi`` (B, 12) or (B, 15);
    afterwards the estimate is zero."""
    if origin is None:
        nav.v_n, nav.C_bn = invariant_retraction(nav.v_n, nav.C_bn, xi)
        nav.b_a = nav.b_a + xi[..., BA]
        nav.b_g = nav.b_g + xi[..., BG]
        return
    nav.pos, nav.v_n, nav.C_bn = invariant_retraction_with_position(nav.pos, nav.v_n, nav.C_bn, xi, origin, p)
    nav.b_a = nav.b_a + xi[..., BA15]
    nav.b_g = nav.b_g + xi[..., BG15]


# --- coordinate map between the invariant and the common error state ------------------------------

def _T(v_n: np.ndarray, p: np.ndarray | None, sign: float) -> np.ndarray:
    if p is None:
        T = np.broadcast_to(np.eye(N_STATES), v_n.shape[:-1] + (N_STATES, N_STATES)).copy()
        T[..., DV, DPSI] = sign * skew(v_n)
        return T
    n = LAYOUT_15.n
    T = np.broadcast_to(np.eye(n), v_n.shape[:-1] + (n, n)).copy()
    T[..., RV, PHI] = sign * skew(v_n)
    T[..., RP, PHI] = sign * skew(np.broadcast_to(p, v_n.shape))
    return T


def common_from_invariant(v_n: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:
    """``T`` (B, n, n), the Jacobian at ξ = 0 of the common error as a function of the invariant one.

    12 states (``p`` None): ``x = T ξ``: ``δv = ρ − [v×] φ``, ``δψ = φ``, biases unchanged (from
    ``v_true − v_nav = (exp([φ×]) − I) v_nav + J_l(φ) ρ ≈ ρ + φ × v_nav``). 15 states (``p`` (B, 3)
    the group position, :func:`group_position`): also ``δp = ρ_p − [p×] φ``.
    """
    return _T(v_n, p, -1.0)


def invariant_from_common(v_n: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:
    """``T⁻¹`` (B, n, n): ``ξ = T⁻¹ x``, ``ρ = δv + [v×] δψ``, ``φ = δψ`` (and ``ρ_p = δp + [p×] δψ``)."""
    return _T(v_n, p, 1.0)


def covariance_to_common(P_inv: np.ndarray, v_n: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:
    """``P = T P_inv Tᵀ`` (B, n, n), symmetrized, with ``T`` of :func:`common_from_invariant`."""
    T = common_from_invariant(v_n, p)
    P = T @ P_inv @ _swap(T)
    return 0.5 * (P + _swap(P))


def covariance_to_invariant(P: np.ndarray, v_n: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:
    """``P_inv = T⁻¹ P T⁻ᵀ`` (B, n, n), symmetrized: a common-coordinate covariance (P0, the
    process noise Q) in the invariant coordinates at velocity ``v_n`` (B, 3) (and group position ``p``)."""
    Ti = invariant_from_common(v_n, p)
    P_inv = Ti @ P @ _swap(Ti)
    return 0.5 * (P_inv + _swap(P_inv))


def invariant_measurement_jacobian(measurement: Measurement, nav: NavState, p: np.ndarray | None = None) -> np.ndarray:
    """H_inv (B, m, n) of ``measurement`` at ``nav``: its closed form where it has one
    (``H_invariant``: the DVL's right-invariant observation, free of ``p``), else the chain rule
    ``H_common T(v, p)`` (depth and position fixes: parts of the left-invariant observation
    ``X b``, whose invariant Jacobian ``[I, 0, −[(p + C l)×]]`` depends on the state)."""
    H = measurement.H_invariant(nav)
    if H is not None:
        return H
    return measurement.H(nav) @ common_from_invariant(nav.v_n, p)


# --- the filter ---------------------------------------------------------------------------------

@register("iekf")
class IEKF(ErrorStateFilter):
    """Closed-loop right-invariant EKF: covariance ``P_inv`` held in ξ (12: ``[ρ, φ, b_a, b_g]``;
    15: ``[ρ_p, ρ_v, φ, b_a, b_g]``).

    ``self.P`` (what :meth:`covariance` returns and :meth:`check` tests) is kept equal to
    ``T P_inv Tᵀ`` at the current solution (:func:`covariance_to_common`). ``transition``
    accumulates Φ_inv (``invariant_error``). With 15 states ``origin`` (R, 3) is each run's
    initial solution, the origin of the group position (:func:`group_position`).
    """

    invariant_error = True
    smoothable = True
    per_run = ("P", "P_inv")
    #: the layouts this filter serves: SE₂(3) without (12) and with (15) position
    layouts = ("12", "15")

    def __init__(self, cfg: FilterConfig, nav0: NavState, imu: ImuData, noise_std=None):
        super().__init__(cfg, nav0, imu, noise_std)
        self.origin = np.array(self.nav.pos, dtype=float, copy=True) if self.layout.has("pos") else None
        self.P_inv = covariance_to_invariant(self.P, self.nav.v_n, self.group_position())  # P = P0 exactly at epoch 0

    def group_position(self, nav: NavState | None = None) -> np.ndarray | None:
        """(R, 3) the group position of ``nav`` (default the solution) [m], None with 12 states."""
        if self.origin is None:
            return None
        return group_position((self.nav if nav is None else nav).pos, self.origin)

    def _sync(self, p: np.ndarray | None = None) -> None:
        self.P = covariance_to_common(self.P_inv, self.nav.v_n, self.group_position() if p is None else p)

    def transition(self, j0: int, j1: int) -> np.ndarray:
        """Φ_inv over steps ``[j0, j1)`` (the solution moved through them): the base class's with 12
        states; with the position block F_inv at the group position of each step (compiled where
        :attr:`compiled`, :func:`nespm_cli.filters.kernels.transition` with the origin)."""
        if self.origin is None:
            return super().transition(j0, j1)
        if self.compiled:
            n = self.contiguous_nav()
            return kernels.transition(n.pos, n.v_n, n.C_bn, n.b_a, n.b_g, self.f, self.w, self.dt, j0, j1,
                                      invariant=True, layout=self.layout, origin=self.origin)
        Phi = np.broadcast_to(self.eye, self.P.shape).copy()
        for j in range(j0, j1):
            f, w = self.imu(j)
            n = self.nav
            F = invariant_system_matrix(n.pos, n.v_n, n.C_bn, self.layout, group_position(n.pos, self.origin))
            Phi = (self.eye + F * self.dt[j]) @ Phi
            n.pos, n.v_n, n.C_bn = na_cycle(n.pos, n.v_n, n.C_bn, f, w, self.dt[j])
        return Phi

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        Q = self.process_noise(self.span(j0, j1), k)  # common coordinates, at the attitude before the span
        Phi = self.transition(j0, j1)  # Φ_inv: invariant_error is set
        self.last_transition = Phi
        # Q is added at the end of the span (as the EKF's P ← Φ P Φᵀ + Q): mapped with T there
        p = self.group_position()
        Q_inv = covariance_to_invariant(np.broadcast_to(Q, self.P_inv.shape), self.nav.v_n, p)
        self.P_inv = Phi @ self.P_inv @ _swap(Phi) + Q_inv
        self.P_inv = 0.5 * (self.P_inv + _swap(self.P_inv))
        self._sync(p)

    def smoother_covariance(self) -> np.ndarray:
        return self.P_inv

    def smoother_error(self, nav_to: NavState, nav_from: NavState) -> np.ndarray:
        if self.origin is None:
            xi = invariant_log(nav_to.C_bn, nav_to.v_n, nav_from.C_bn, nav_from.v_n)
        else:
            xi = invariant_log_with_position(nav_to.pos, nav_to.C_bn, nav_to.v_n, nav_from.pos, nav_from.C_bn,
                                             nav_from.v_n, self.origin)
        return np.concatenate([xi, nav_to.b_a - nav_from.b_a, nav_to.b_g - nav_from.b_g], axis=-1)

    def smoother_retract(self, nav: NavState, x: np.ndarray) -> None:
        invariant_feedback(nav, x, self.origin)

    def smoother_to_common(self, P: np.ndarray, nav: NavState) -> np.ndarray:
        return covariance_to_common(P, nav.v_n, self.group_position(nav))

    def measurement_jacobian(self, measurement: Measurement, p: np.ndarray | None = None) -> np.ndarray:
        """H_inv (R, m, n): :func:`invariant_measurement_jacobian` at the solution (``p`` its group
        position, if already known)."""
        return invariant_measurement_jacobian(measurement, self.nav, self.group_position() if p is None else p)

    def update(self, measurement: Measurement, j_last: int):
        nav = self.nav
        # the EKF's innovation z − h(X_nav) with the invariant Jacobian and covariance
        nu = measurement.innovation(nav)
        p = self.group_position()
        H = self.measurement_jacobian(measurement, p)
        xi, self.P_inv, S = joseph_update(self.P_inv, H, nu, measurement.R)
        invariant_feedback(nav, xi, self.origin, p)
        self._sync()
        return nu, S

    def check(self) -> None:
        new = ~self.bad.copy()
        super().check()
        new &= self.bad
        if new.any():  # base reset these runs' solution and P (= P0); restart P_inv from them
            if self.origin is not None:  # and the origin at the reset solution (group position 0)
                self.origin[new] = self.nav.pos[new]
            p = None if self.origin is None else self.group_position()[new]
            self.P_inv[new] = covariance_to_invariant(self.P[new], self.nav.v_n[new], p)


__all__ = ["IEKF", "common_from_invariant", "covariance_to_common", "covariance_to_invariant", "group_position",
           "invariant_feedback", "invariant_from_common", "invariant_log", "invariant_log_with_position",
           "invariant_measurement_jacobian", "invariant_retraction", "invariant_retraction_with_position",
           "invariant_system_matrix"]

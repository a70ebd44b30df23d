"""Closed-loop INS/DVL filtering of a batch of Monte Carlo runs.

One loop over time (DVL intervals, and IMU steps inside them); every operation inside is
batched over the runs (and the sigma points). Filters:

* ``ins``: free inertial, no DVL update (no covariance).
* ``ekf``: transition matrix Φ = Π (I + F dt) accumulated at the IMU rate over the
  time-update span, ``P ← Φ P Φᵀ + Q``; linearised DVL update (H of eq 33), Joseph form.
* ``ukf``: sigma points through the same Φ (anukf.md eqs 5-23) and the nonlinear DVL
  model of anukf.md eq 33. With a linear propagation its prediction equals the EKF's.
* ``anekf``, ``anukf``, ``anukf-nespm``: the same three with Q from the ProcessNet noise
  std of each DVL interval's IMU window (anukf.md eqs 43-49, :mod:`nespm_cli.filters.adaptive`).
* ``ukf-nespm``: every sigma point is added to the mean solution (eqs 35-37), carried
  through ``na_cycle`` with the IMU compensated by its own biases (eq 38), and read back
  with ⊖ against the propagated mean (eqs 39-40); then the same UT update as ``ukf``.

After every time update and every DVL update the estimate is fed back into the
navigation solution and bias compensation (closed loop), so the state mean is zero
between steps and every sigma set is centred on the navigation solution.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from nespm_cli.filters.adaptive import adaptive_q
from nespm_cli.errors import NespmError
from nespm_cli.nav.rotations import attitude_minus, exp_so3
from nespm_cli.nav.strapdown import _rates, na_cycle
from nespm_cli.nav.earth import radii
from nespm_cli.filters.model import (BA, BG, DPSI, DV, N_STATES, FilterConfig, NavState, dvl_H, dvl_h,
                    dvl_innovation, feedback, process_noise, system_matrix)
from nespm_cli.filters.unscented import UTWeights, moments, safe_cholesky, sigma_offsets

FILTERS = ("ins", "ekf", "ukf", "ukf-nespm", "anekf", "anukf", "anukf-nespm")
#: adaptive filter -> its non-adaptive twin (same propagation and update, Q from ProcessNet)
ADAPTIVE = {"anekf": "ekf", "anukf": "ukf", "anukf-nespm": "ukf-nespm"}


@dataclass
class FilterOutput:
    """Per-epoch posterior of R runs at N GT epochs.

    ``pos`` (R, N, 3), ``v_n`` (R, N, 3), ``C_bn`` (R, N, 3, 3); ``P6`` (R, N, 6, 6) the
    [dv, dpsi] block and ``P_diag`` (R, N, 12) of the covariance (NaN for ``ins``);
    ``b_a``, ``b_g`` (R, N, 3) bias compensation; ``diverged`` (R,); ``dvl_used`` (N,);
    ``noise_std`` the adaptive filters' network std ``(std_a, std_g)`` (R, N-1, 3), else None.
    """

    pos: np.ndarray
    v_n: np.ndarray
    C_bn: np.ndarray
    P6: np.ndarray
    P_diag: np.ndarray
    b_a: np.ndarray
    b_g: np.ndarray
    diverged: np.ndarray
    dvl_used: np.ndarray
    noise_std: tuple | None = None


def _w_nb(nav: NavState, w_ib_comp: np.ndarray) -> np.ndarray:
    """Body rate relative to NED (B, 3) from the compensated gyro output."""
    R_N, R_E = radii(nav.pos[..., 0])
    w_ie, w_en = _rates(nav.pos[..., 0], nav.pos[..., 2], nav.v_n, R_N, R_E)
    return w_ib_comp - (np.swapaxes(nav.C_bn, -1, -2) @ (w_ie + w_en)[..., None])[..., 0]


class _Runner:
    def __init__(self, kind: str, cfg: FilterConfig, f_meas, w_meas, dt, nav0: NavState, noise_std=None):
        if kind not in FILTERS:
            raise NespmError(f"--filters: unknown filter {kind!r}; choose from {', '.join(FILTERS)}")
        if kind in ADAPTIVE and noise_std is None:
            raise NespmError(f"filter {kind} needs the network noise std (noise_std)")
        self.name = kind
        self.noise_std = noise_std if kind in ADAPTIVE else None
        kind = ADAPTIVE.get(kind, kind)
        self.kind, self.cfg = kind, cfg
        self.f, self.w, self.dt = f_meas, w_meas, dt
        self.nav = nav0.copy()
        R = nav0.v_n.shape[0]
        self.R = R
        self.P = np.broadcast_to(cfg.p0(), (R, N_STATES, N_STATES)).copy()
        self.bad = np.zeros(R, dtype=bool)
        self.ut = UTWeights(N_STATES, cfg.alpha, cfg.beta, cfg.kappa)
        self.lever = np.asarray(cfg.lever_arm, dtype=float)
        self.dt_imu = float(np.median(dt))
        self.eye = np.eye(N_STATES)

    # --- time update over IMU steps [j0, j1) -------------------------------------------
    def _imu(self, j):
        nav = self.nav
        return self.f[:, j] - nav.b_a, self.w[:, j] - nav.b_g

    def process_noise(self, span: float, k: int) -> np.ndarray:
        """Q of the time update in DVL interval ``k``: fixed, or adaptive (eqs 43-48)."""
        if self.noise_std is None:
            return process_noise(self.cfg, self.dt_imu, span)
        std_a, std_g = self.noise_std
        return adaptive_q(std_a[:, k], std_g[:, k], self.nav.C_bn, self.cfg, self.dt_imu, span)

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        span = float(self.dt[j0:j1].sum())
        if self.kind == "ins":
            for j in range(j0, j1):
                f, w = self._imu(j)
                n = self.nav
                n.pos, n.v_n, n.C_bn = na_cycle(n.pos, n.v_n, n.C_bn, f, w, self.dt[j])
            return
        Q = self.process_noise(span, k)
        if self.kind == "ukf-nespm":
            self._propagate_nespm(j0, j1, Q)
            return
        Phi = np.broadcast_to(self.eye, self.P.shape).copy()
        for j in range(j0, j1):
            f, w = self._imu(j)
            n = self.nav
            F = system_matrix(n.pos, n.v_n, n.C_bn, f)
            Phi = (self.eye + F * self.dt[j]) @ Phi
            n.pos, n.v_n, n.C_bn = na_cycle(n.pos, n.v_n, n.C_bn, f, w, self.dt[j])
        if self.kind == "ekf":
            self.P = Phi @ self.P @ np.swapaxes(Phi, -1, -2) + Q
        else:  # ukf: sigma points through the linearised model
            L = safe_cholesky(self.P, self.bad)
            X = sigma_offsets(L, self.ut)
            Y = X @ np.swapaxes(Phi, -1, -2)
            m, P = moments(Y, self.ut)
            self.P = P + Q
            feedback(self.nav, m)
        self.P = 0.5 * (self.P + np.swapaxes(self.P, -1, -2))

    def _propagate_nespm(self, j0: int, j1: int, Q: np.ndarray) -> None:
        nav = self.nav
        L = safe_cholesky(self.P, self.bad)
        X = sigma_offsets(L, self.ut)  # (R, 2n, 12)
        S = X.shape[1] + 1
        zero = np.zeros((self.R, 1, N_STATES))
        Xa = np.concatenate([zero, X], axis=1)  # (R, S, 12); point 0 is the mean
        pos = np.repeat(nav.pos[:, None], S, axis=1)  # eq 35: position unperturbed
        v = nav.v_n[:, None] + Xa[..., DV]  # eq 36
        C = exp_so3(Xa[..., DPSI]) @ nav.C_bn[:, None]  # eq 37: ⊕
        b_a = nav.b_a[:, None] + Xa[..., BA]
        b_g = nav.b_g[:, None] + Xa[..., BG]
        for j in range(j0, j1):  # eq 38 over the span, every sigma point compensating its biases
            pos, v, C = na_cycle(pos, v, C, self.f[:, j, None] - b_a, self.w[:, j, None] - b_g, self.dt[j])
        dv = v[:, 1:] - v[:, :1]  # eq 39
        dpsi = attitude_minus(C[:, 1:], C[:, :1])  # eq 40: ⊖
        Y = np.concatenate([dv, dpsi, X[..., BA], X[..., BG]], axis=-1)
        m, P = moments(Y, self.ut)
        nav.pos, nav.v_n, nav.C_bn = pos[:, 0], v[:, 0], C[:, 0]
        feedback(nav, m)
        self.P = P + Q

    # --- DVL update ---------------------------------------------------------------------
    def update(self, dvl_b: np.ndarray, j_last: int) -> None:
        nav = self.nav
        w_nb = _w_nb(nav, self.w[:, j_last] - nav.b_g)
        nu = dvl_innovation(nav, dvl_b, w_nb, self.lever)
        Rm = np.eye(3) * self.cfg.dvl_std**2
        if self.kind == "ekf":
            H = dvl_H(nav, self.lever)
            PHt = self.P @ np.swapaxes(H, -1, -2)
            S = H @ PHt + Rm
            K = np.linalg.solve(S, np.swapaxes(PHt, -1, -2))
            K = np.swapaxes(K, -1, -2)
            x = (K @ nu[..., None])[..., 0]
            IKH = self.eye - K @ H
            self.P = IKH @ self.P @ np.swapaxes(IKH, -1, -2) + K @ Rm @ np.swapaxes(K, -1, -2)
        else:
            L = safe_cholesky(self.P, self.bad)
            X = sigma_offsets(L, self.ut)
            dz = dvl_h(X, nav, self.lever)
            m, _, mz, Pzz, Pxz = moments(X, self.ut, dz)
            S = Pzz + Rm
            K = np.swapaxes(np.linalg.solve(S, np.swapaxes(Pxz, -1, -2)), -1, -2)
            x = m + (K @ (nu - mz)[..., None])[..., 0]
            self.P = self.P - K @ S @ np.swapaxes(K, -1, -2)
        self.P = 0.5 * (self.P + np.swapaxes(self.P, -1, -2))
        feedback(nav, x)

    def check(self) -> None:
        """Flag runs whose solution or covariance is non-finite or implausible; sanitize them."""
        nav = self.nav
        speed = np.linalg.norm(nav.v_n, axis=-1)
        bad_now = ~np.isfinite(speed) | ~np.isfinite(nav.C_bn).all(axis=(-2, -1))
        if self.kind != "ins":  # free inertial is allowed to drift: only a non-finite solution fails it
            bad_now |= speed > self.cfg.vel_limit
            bad_now |= ~np.isfinite(self.P).all(axis=(-2, -1))
            bad_now |= (np.einsum("...ii->...i", self.P) < 0).any(axis=-1)
        new = bad_now & ~self.bad
        self.bad |= bad_now
        if self.bad.any():
            b = self.bad
            nav.v_n[b] = 0.0
            nav.C_bn[b] = np.eye(3)
            nav.pos[b] = np.where(np.isfinite(nav.pos[b]), nav.pos[b], 0.0)
            nav.b_a[b] = 0.0
            nav.b_g[b] = 0.0
            if new.any() and self.kind != "ins":
                self.P[new] = self.cfg.p0()


def run_filter(
    kind: str,
    cfg: FilterConfig,
    f_meas: np.ndarray,
    w_meas: np.ndarray,
    dt: np.ndarray,
    epoch_index: np.ndarray,
    dvl: np.ndarray | None,
    dvl_mask: np.ndarray,
    nav0: NavState,
    noise_std: tuple[np.ndarray, np.ndarray] | None = None,
    progress: Callable[[int], None] | None = None,
) -> FilterOutput:
    """Run one filter over a batch of runs.

    Args:
        kind: ``ins``, ``ekf``, ``ukf`` or ``ukf-nespm``.
        f_meas, w_meas: (R, M, 3) corrupted IMU, step j from sample j to j+1.
        dt: (M,) step durations [s].
        epoch_index: (N,) IMU sample index of each GT epoch (starting at 0).
        dvl: (R, N, 3) body-frame DVL velocity at the epochs [m/s].
        dvl_mask: (N,) whether the DVL update is applied at each epoch (epoch 0 never).
        nav0: initial navigation solution of the R runs.
        noise_std: for the adaptive filters, ``(std_a, std_g)`` each (R, N-1, 3): the
            network's noise std per IMU sample in each DVL interval (``adaptive.predict_interval_std``).
        progress: optional ``progress(k)``, called after each of the N-1 epoch intervals with
            the number of intervals done (for a progress bar; it must not raise).
    """
    r = _Runner(kind, cfg, f_meas, w_meas, dt, nav0, noise_std)
    R, N = nav0.v_n.shape[0], len(epoch_index)
    out = FilterOutput(
        pos=np.empty((R, N, 3)), v_n=np.empty((R, N, 3)), C_bn=np.empty((R, N, 3, 3)),
        P6=np.full((R, N, 6, 6), np.nan), P_diag=np.full((R, N, 12), np.nan),
        b_a=np.empty((R, N, 3)), b_g=np.empty((R, N, 3)), diverged=r.bad,
        dvl_used=np.zeros(N, dtype=bool),
    )

    def record(k):
        n = r.nav
        out.pos[:, k], out.v_n[:, k], out.C_bn[:, k] = n.pos, n.v_n, n.C_bn
        out.b_a[:, k], out.b_g[:, k] = n.b_a, n.b_g
        if kind != "ins":
            out.P6[:, k] = r.P[:, :6, :6]
            out.P_diag[:, k] = np.einsum("...ii->...i", r.P)

    imu_mode = cfg.time_update == "imu"
    if cfg.time_update not in ("imu", "dvl"):
        raise NespmError(f"--time-update: unknown mode {cfg.time_update!r}; choose imu or dvl")
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        record(0)
        for k in range(N - 1):
            j0, j1 = int(epoch_index[k]), int(epoch_index[k + 1])
            if imu_mode and kind != "ins":
                for j in range(j0, j1):
                    r.propagate(j, j + 1, k)
            else:
                r.propagate(j0, j1, k)
            if kind != "ins" and dvl_mask[k + 1]:
                r.update(dvl[:, k + 1], j1 - 1)
                out.dvl_used[k + 1] = True
            r.check()
            record(k + 1)
            if progress is not None:
                progress(k + 1)
    out.diverged = r.bad
    out.noise_std = r.noise_std
    return out

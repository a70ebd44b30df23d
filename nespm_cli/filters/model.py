"""The 12-state INS/DVL error-state model shared by every filter.

Error state (ukf-nespm.md eq 33, anukf.md eq 24), ``x = [dv (0:3), dpsi (3:6), b_a (6:9), b_g (9:12)]``:

* ``dv``   = v_true − v_nav, NED [m/s];
* ``dpsi`` = C_true ⊖ C_nav = log(C_true C_nav^T), nav frame [rad];
* ``b_a``, ``b_g`` = residual biases still in the compensated IMU, body frame
  [m/s², rad/s]: f_true = f_meas − b̂_a − b_a.

So ``x`` is the correction: ``nav ⊕ x = truth``. After each update the estimate is fed
back (``feedback``) and reset to zero (closed loop).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE
from nespm_cli.learn.processnet import VALIDITY_CLIP
from nespm_cli.nav.dvl import dvl_velocity
from nespm_cli.nav.earth import d_w_en_d_v, gravity_n, radii, transport_rates
from nespm_cli.nav.rotations import attitude_plus, exp_so3, exp_so3_minus_identity, skew
from nespm_cli.nav.strapdown import cross

N_STATES = 12
DV, DPSI, BA, BG = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)


@dataclass(frozen=True)
class FilterConfig:
    """Filter tuning. Defaults, and why (docs/filters.md):

    * P0 equals the corruption protocol's std (the filter is told the truth about its
      initial errors): 0.25/0.25/0.05 m/s, 0.01 deg, 0.3 m/s², 7.3e-5 rad/s.
    * Q from the per-sample white-noise std at the IMU rate: PSD = std² · dt_imu, so a
      0.03 m/s² per-sample noise at 100 Hz is 0.003 m/s/√s of velocity random walk.
    * Bias random walks (not stated in the papers): 1e-3 m/s²/√s and 1e-6 rad/s/√s,
      small enough not to inflate the constant-bias case much, large enough for the
      filter to keep tracking biases over 400 s.
    * R: DVL std 0.02 m/s (the synthetic DVL noise); ``mc`` raises it to 0.1 m/s for the
      recorded DVL (its residual std against GT is 0.02-0.2 m/s).
    * alpha = 1e-3, beta = 2, kappa = 0 as in both papers.
    * adaptive filters: τ = the IMU step, τ_a = τ_g = the time-update span, network std
      clipped to [0.25, 24] x nominal, bias noise nominal (:mod:`nespm_cli.filters.adaptive`).
    * time_update ``dvl``: the time update spans one DVL interval (the papers' "cycle(s)"):
      sigma points are drawn once per interval and carried through every IMU step; ``imu``
      redraws them at every IMU step.
    """

    p0_vel: tuple = (0.25, 0.25, 0.05)
    p0_att_deg: tuple = (0.01, 0.01, 0.01)
    p0_acc_bias: float = 0.3
    p0_gyro_bias: float = 7.3e-5
    acc_noise: float = NOMINAL_ACC_NOISE  # m/s^2 per IMU sample
    gyro_noise: float = NOMINAL_GYRO_NOISE  # rad/s per IMU sample
    acc_bias_rw: float = 1e-3  # m/s^2/sqrt(s)
    gyro_bias_rw: float = 1e-6  # rad/s/sqrt(s)
    dvl_std: float = 0.02  # m/s
    alpha: float = 1e-3
    beta: float = 2.0
    kappa: float = 0.0
    time_update: str = "dvl"
    lever_arm: tuple = (0.0, 0.0, 0.0)  # m, body frame, DVL relative to the IMU
    vel_limit: float = 50.0  # m/s: |v_nav| beyond this marks the run diverged
    # adaptive filters (anekf, anukf, anukf-nespm), anukf.md eqs 43-48; see adaptive.py
    tau: float | None = None  # eq 44/46 factor [s]; None: the IMU step
    tau_a: float | None = None  # eq 45 [s]; None: the time-update span
    tau_g: float | None = None  # eq 47 [s]; None: the time-update span
    adaptive_bias: str = "nominal"  # bias blocks of eq 43: nominal, scaled (x (σ̂/σ)²) or paper
    q_clip: tuple = VALIDITY_CLIP  # validity bounds on the network std, x nominal std

    def p0(self) -> np.ndarray:
        """Initial covariance (12, 12); an overflowing std gives inf (the run then diverges)."""
        with np.errstate(over="ignore"):
            return np.diag(self._p0_diag())

    def _p0_diag(self) -> np.ndarray:
        return np.concatenate([
            np.asarray(self.p0_vel, float) ** 2,
            np.deg2rad(np.asarray(self.p0_att_deg, float)) ** 2,
            np.full(3, np.square(np.float64(self.p0_acc_bias))),
            np.full(3, np.square(np.float64(self.p0_gyro_bias))),
        ])

    def q_psd(self, dt_imu: float) -> np.ndarray:
        """Diagonal (12,) of the continuous noise PSD Q* (anukf.md eq 32)."""
        with np.errstate(over="ignore"):
            return np.concatenate([
                np.full(3, np.square(np.float64(self.acc_noise)) * dt_imu),
                np.full(3, np.square(np.float64(self.gyro_noise)) * dt_imu),
                np.full(3, np.square(np.float64(self.acc_bias_rw))),
                np.full(3, np.square(np.float64(self.gyro_bias_rw))),
            ])


@dataclass
class NavState:
    """Navigation solution of R runs (leading shape ``B``, usually (R,)).

    ``pos`` (B, 3), ``v_n`` (B, 3), ``C_bn`` (B, 3, 3) and the accumulated bias
    compensation ``b_a`` (B, 3) [m/s²], ``b_g`` (B, 3) [rad/s] subtracted from the IMU.
    """

    pos: np.ndarray
    v_n: np.ndarray
    C_bn: np.ndarray
    b_a: np.ndarray
    b_g: np.ndarray = field(default=None)

    def copy(self) -> "NavState":
        return NavState(self.pos.copy(), self.v_n.copy(), self.C_bn.copy(), self.b_a.copy(), self.b_g.copy())


def feedback(nav: NavState, x: np.ndarray) -> None:
    """Close the loop in place: ``nav ⊕ x`` for velocity and attitude, biases into the compensation.

    ``x`` (B, 12). After this the filter's state estimate is zero.
    """
    nav.v_n = nav.v_n + x[..., DV]
    nav.C_bn = attitude_plus(nav.C_bn, x[..., DPSI])
    nav.b_a = nav.b_a + x[..., BA]
    nav.b_g = nav.b_g + x[..., BG]


def system_matrix(pos: np.ndarray, v_n: np.ndarray, C_bn: np.ndarray, f_b: np.ndarray) -> np.ndarray:
    """Continuous error-state matrix F (B, 12, 12) of the state above (Groves 2nd ed. 14.2.4).

    Position errors are not states (as in the papers), so the gravity and earth-rate
    position couplings are dropped. ``f_b`` is the compensated specific force (B, 3).

    dv'   = (-[(2 w_ie + w_en) x] + [v x] J) dv - [f_n x] dpsi - C b_a
    dpsi' = -J dv - [w_in x] dpsi - C b_g        (J = d w_en / d v)
    """
    lat, h = pos[..., 0], pos[..., 2]
    R_N, R_E = radii(lat)
    w_ie, w_en = transport_rates(lat, h, v_n, R_N, R_E)
    J = d_w_en_d_v(pos)
    f_n = (C_bn @ f_b[..., None])[..., 0]
    F = np.zeros(v_n.shape[:-1] + (N_STATES, N_STATES))
    F[..., DV, DV] = -skew(2.0 * w_ie + w_en) + skew(v_n) @ J
    F[..., DV, DPSI] = -skew(f_n)
    F[..., DV, BA] = -C_bn
    F[..., DPSI, DV] = -J
    F[..., DPSI, DPSI] = -skew(w_ie + w_en)
    F[..., DPSI, BG] = -C_bn
    return F


def invariant_system_matrix(pos: np.ndarray, v_n: np.ndarray, C_bn: np.ndarray) -> np.ndarray:
    """Continuous right-invariant error matrix ``F_inv`` (B, 12, 12), ``ξ̇ = F_inv ξ`` (docs/iekf.md; the error of ``iekf``).

    ``F_inv = T⁻¹ F T + T⁻¹ Ṫ`` with the common F (:func:`nespm_cli.filters.model.system_matrix`),
    worked out in closed form; the specific force cancels (the group-affine part)::

        ρ̇ = −[(2ω_ie + ω_en)×] ρ + ([g×] + [v×][ω_ie×]) φ − C b_a − [v×] C b_g
        φ̇ = −J ρ + (J [v×] − [ω_in×]) φ − C b_g            (J = ∂ω_en/∂v, ω_in = ω_ie + ω_en)

    The earth-rate, transport-rate and Coriolis terms are not group-affine; they are kept as
    first-order terms. Gravity's position dependence and the position couplings of the earth
    and transport rates are dropped (position is not a state), as in the common F.

    Args:
        pos: (B, 3) [lat, lon, h]; v_n: (B, 3) [m/s]; C_bn: (B, 3, 3), the solution before the step.
    """
    lat, h = pos[..., 0], pos[..., 2]
    R_N, R_E = radii(lat)
    w_ie, w_en = transport_rates(lat, h, v_n, R_N, R_E)
    J = d_w_en_d_v(pos)
    V = skew(v_n)
    F = np.zeros(v_n.shape[:-1] + (N_STATES, N_STATES))
    F[..., DV, DV] = -skew(2.0 * w_ie + w_en)
    F[..., DV, DPSI] = skew(gravity_n(pos)) + V @ skew(w_ie)
    F[..., DV, BA] = -C_bn
    F[..., DV, BG] = -V @ C_bn
    F[..., DPSI, DV] = -J
    F[..., DPSI, DPSI] = J @ V - skew(w_ie + w_en)
    F[..., DPSI, BG] = -C_bn
    return F


def process_noise(cfg: FilterConfig, dt_imu: float, span: float) -> np.ndarray:
    """Discrete Q (12, 12) over ``span`` seconds: G Q* G^T · span (anukf.md eqs 30-32).

    G = blockdiag(C, C, I, I) and Q* is isotropic within each block, so G Q* G^T = Q*.
    """
    return np.diag(cfg.q_psd(dt_imu) * span)


def dvl_innovation(nav: NavState, dvl_b: np.ndarray, w_nb_b: np.ndarray, lever_arm: np.ndarray) -> np.ndarray:
    """Measured minus predicted body velocity at x = 0 (B, 3): dvl − C^T v − w_nb × l."""
    return dvl_b - dvl_velocity(nav.C_bn, nav.v_n, w_nb_b, lever_arm)


def dvl_h(x: np.ndarray, nav: NavState, lever_arm: np.ndarray) -> np.ndarray:
    """Nonlinear DVL model (anukf.md eq 33), as its change from x = 0.

    For sigma points ``x`` (B, S, 12) around ``nav`` (B,):
    ``h(x) − h(0) = C^T [(exp(−[dpsi x]) − I) v + exp(−[dpsi x]) dv] − b_g × l`` (B, S, 3),
    computed without forming the large common term ``C^T v``.
    """
    dv, dpsi, bg = x[..., DV], x[..., DPSI], x[..., BG]
    Em = exp_so3_minus_identity(-dpsi)  # (B, S, 3, 3)
    v = nav.v_n[..., None, :]
    dv_n = (Em @ (v + dv)[..., None])[..., 0] + dv
    out = (np.swapaxes(nav.C_bn, -1, -2)[..., None, :, :] @ dv_n[..., None])[..., 0]
    return out - cross(bg, np.broadcast_to(lever_arm, bg.shape))


def dvl_H(nav: NavState, lever_arm: np.ndarray) -> np.ndarray:
    """Jacobian of :func:`dvl_h` at x = 0 (B, 3, 12): [C^T, C^T [v x], 0, [l x]]."""
    Ct = np.swapaxes(nav.C_bn, -1, -2)
    H = np.zeros(nav.v_n.shape[:-1] + (3, N_STATES))
    H[..., :, DV] = Ct
    H[..., :, DPSI] = Ct @ skew(nav.v_n)
    H[..., :, BG] = skew(np.broadcast_to(lever_arm, nav.v_n.shape))
    return H


def joseph_update(P: np.ndarray, H: np.ndarray, nu: np.ndarray, Rm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linearised Kalman update in Joseph form, batched: ``(x, P⁺)``.

    ``P`` (B, n, n), ``H`` (B, m, n), innovation ``nu`` (B, m), ``Rm`` (m, m) or (B, m, m);
    ``K = P Hᵀ S⁻¹`` (S = H P Hᵀ + R, solved, not inverted), ``x = K ν`` (B, n),
    ``P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ`` symmetrized. Used by ``ekf`` (common error) and
    ``iekf`` (invariant error: its own H and P).
    """
    PHt = P @ np.swapaxes(H, -1, -2)
    S = H @ PHt + Rm
    K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)
    x = (K @ nu[..., None])[..., 0]
    IKH = np.eye(P.shape[-1]) - K @ H
    P = IKH @ P @ np.swapaxes(IKH, -1, -2) + K @ Rm @ np.swapaxes(K, -1, -2)
    return x, 0.5 * (P + np.swapaxes(P, -1, -2))


def initial_nav(pos: np.ndarray, v_true: np.ndarray, C_true: np.ndarray, dv0: np.ndarray, dpsi0: np.ndarray) -> NavState:
    """Corrupted initial solution of R runs: v = v_true + dv0, C = exp([dpsi0 x]) C_true."""
    R = dv0.shape[0]
    return NavState(
        pos=np.broadcast_to(pos, (R, 3)).copy(),
        v_n=v_true + dv0,
        C_bn=exp_so3(dpsi0) @ C_true,
        b_a=np.zeros((R, 3)),
        b_g=np.zeros((R, 3)),
    )

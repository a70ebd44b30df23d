"""The INS error-state model shared by every filter, for any layout of blocks.

Error state: the blocks of a :class:`~nespm_cli.nav.state.StateLayout` (``FilterConfig.state``,
``--state``). The papers' 12-state layout (ukf-nespm.md eq 33, anukf.md eq 24) is
``x = [dv (0:3), dpsi (3:6), b_a (6:9), b_g (9:12)]``; the 15-state one puts the position
first, ``[dp (0:3), dv, dpsi, b_a, b_g]``:

* ``dp``   = truth ⊖ nav position, NED [m] (:func:`nespm_cli.nav.earth.ned_offset`);
* ``dv``   = v_true − v_nav, NED [m/s];
* ``dpsi`` = C_true ⊖ C_nav = log(C_true C_nav^T), nav frame [rad];
* ``b_a``, ``b_g`` = residual biases still in the compensated IMU, body frame
  [m/s², rad/s]: f_true = f_meas − b̂_a − b_a.

So ``x`` is the correction: ``nav ⊕ x = truth``. After each update the estimate is fed
back (``feedback``) and reset to zero (closed loop). ``N_STATES``, ``DV``, ``DPSI``, ``BA`` and
``BG`` are the slices of the 12-state layout, the papers' (the ``iekf``'s 15-state slots are in :mod:`nespm_cli.filters.iekf`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE
from nespm_cli.filters.robust import ROBUST_OPTIONS, check_robust
from nespm_cli.learn.processnet import VALIDITY_CLIP
from nespm_cli.nav.earth import d_w_en_d_v, gravity_down_gradient, gravity_n, radii, transport_rates
from nespm_cli.nav.rotations import exp_so3, skew
from nespm_cli.nav.state import LAYOUT_12, LAYOUT_15, NavState, StateLayout, parse_layout, plus, position_plus

N_STATES = 12
DV, DPSI, BA, BG = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
POS_STD_FLOOR = 0.01  # [m] smallest initial position std told to a filter (a zero std makes P0 singular)


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
    * ``state``: the error-state layout (:mod:`nespm_cli.nav.state`): ``12`` (the papers'), ``15``
      (position first) or a comma list of blocks. ``p0_pos``: the initial position std [m] (N, E,
      D), at least :data:`POS_STD_FLOOR`; position has no process noise (it integrates velocity).
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
    state: str = "12"  # error-state layout (nav.state): 12, 15 or a comma list of blocks
    p0_pos: tuple = (POS_STD_FLOOR, POS_STD_FLOOR, POS_STD_FLOOR)  # m, N E D
    options: tuple = ()  # ((key, value), ...): a filter's own options (--filter-option; filters.options)
    r_scale: tuple = ()  # ((sensor key, factor), ...): this filter's R std of a sensor x factor (filters.options)
    levers: tuple = ()  # ((sensor key, axis 0-2, m), ...): this filter's model lever arm coordinates (filters.options)

    def r_factor(self, sensor: str) -> float:
        """The factor on sensor ``sensor``'s R std for this filter (1.0: the sensor's own R)."""
        return float(dict(self.r_scale).get(sensor.replace("-", "_"), 1.0))

    def robust_update(self) -> tuple[str, float, int]:
        """``(mode, gate_prob, gate_streak)`` of this filter's robust update (:mod:`nespm_cli.filters.robust`),
        from ``--filter-option NAME.robust``, ``NAME.gate_prob``, ``NAME.gate_streak`` in :attr:`options`;
        ``("none", 0.999, 3)`` unless given.
        Kept in ``options``, not in fields of their own, so a study's identity and manifest
        are unchanged without them. A bad value: one line naming the option."""
        o = {**ROBUST_OPTIONS, **dict(self.options)}
        return (check_robust("robust", o["robust"], "--filter-option robust"),
                check_robust("gate_prob", o["gate_prob"], "--filter-option gate_prob"),
                check_robust("gate_streak", o["gate_streak"], "--filter-option gate_streak"))

    def model_lever(self, sensor: str, lever) -> tuple | None:
        """Sensor ``sensor``'s lever arm (3,) [m, body] in this filter's model, from the sensor's own
        ``lever`` with this filter's coordinates over it; None when the filter sets none."""
        key = sensor.replace("-", "_")
        mine = [(a, v) for s, a, v in self.levers if s == key]
        if not mine:
            return None
        out = [float(x) for x in lever]
        for a, v in mine:
            out[int(a)] = float(v)
        return tuple(out)

    @property
    def layout(self) -> StateLayout:
        """The error-state layout of :attr:`state`."""
        return parse_layout(self.state)

    def p0(self) -> np.ndarray:
        """Initial covariance (n, n) of the layout; an overflowing std gives inf (the run then diverges)."""
        with np.errstate(over="ignore"):
            return np.diag(self._p0_diag())

    def _p0_diag(self) -> np.ndarray:
        blocks = {
            "pos": lambda: np.maximum(np.asarray(self.p0_pos, float), POS_STD_FLOOR) ** 2,
            "vel": lambda: np.asarray(self.p0_vel, float) ** 2,
            "att": lambda: np.deg2rad(np.asarray(self.p0_att_deg, float)) ** 2,
            "ba": lambda: np.full(3, np.square(np.float64(self.p0_acc_bias))),
            "bg": lambda: np.full(3, np.square(np.float64(self.p0_gyro_bias))),
        }
        return np.concatenate([blocks[b]() for b in self.layout.blocks])

    def q_psd(self, dt_imu: float) -> np.ndarray:
        """Diagonal (n,) of the continuous noise PSD Q* (anukf.md eq 32); position has none."""
        with np.errstate(over="ignore"):
            blocks = {
                "pos": lambda: np.zeros(3),
                "vel": lambda: np.full(3, np.square(np.float64(self.acc_noise)) * dt_imu),
                "att": lambda: np.full(3, np.square(np.float64(self.gyro_noise)) * dt_imu),
                "ba": lambda: np.full(3, np.square(np.float64(self.acc_bias_rw))),
                "bg": lambda: np.full(3, np.square(np.float64(self.gyro_bias_rw))),
            }
            return np.concatenate([blocks[b]() for b in self.layout.blocks])


def feedback(nav: NavState, x: np.ndarray, layout: StateLayout = LAYOUT_12) -> None:
    """Close the loop in place: ``nav ⊕ x`` per block of ``layout`` (:func:`nespm_cli.nav.state.plus`),
    biases into the compensation. ``x`` (B, n). After this the filter's state estimate is zero."""
    plus(nav, x, layout)


def system_matrix(pos: np.ndarray, v_n: np.ndarray, C_bn: np.ndarray, f_b: np.ndarray,
                  layout: StateLayout = LAYOUT_12) -> np.ndarray:
    """Continuous error-state matrix F (B, n, n) of ``layout`` (Groves 2nd ed. 14.2.4).

    ``f_b`` is the compensated specific force (B, 3); J = ∂ω_en/∂v::

        dv'   = (-[(2 w_ie + w_en) x] + [v x] J) dv - [f_n x] dpsi - C b_a   (+ γ dp_D, down row)
        dpsi' = -J dv - [w_in x] dpsi - C b_g
        dp'   = dv                                                          (with the position block)

    With the position block, the vertical gravity gradient γ = ∂g_D/∂D ≈ 2g/R
    (:func:`nespm_cli.nav.earth.gravity_down_gradient`) couples dp_D into dv_D; the other
    position couplings (the latitude dependence of the earth and transport rates, the
    horizontal deflection of gravity, the transport rate's rotation of dp) are of order
    ω_ie v / R ≈ 2e-11 s⁻² or v / R ≈ 3e-7 s⁻¹ and dropped (docs/filters.md). The papers' 12
    states keep no position coupling.
    """
    lat, h = pos[..., 0], pos[..., 2]
    R_N, R_E = radii(lat)
    w_ie, w_en = transport_rates(lat, h, v_n, R_N, R_E)
    J = d_w_en_d_v(pos)
    f_n = (C_bn @ f_b[..., None])[..., 0]
    n = layout.n
    F = np.zeros(v_n.shape[:-1] + (n, n))
    V, A = layout.slice("vel"), layout.slice("att")
    F[..., V, V] = -skew(2.0 * w_ie + w_en) + skew(v_n) @ J
    F[..., V, A] = -skew(f_n)
    if layout.has("ba"):
        F[..., V, layout.slice("ba")] = -C_bn
    F[..., A, V] = -J
    F[..., A, A] = -skew(w_ie + w_en)
    if layout.has("bg"):
        F[..., A, layout.slice("bg")] = -C_bn
    if layout.has("pos"):
        p = layout.slice("pos")
        F[..., p, V] = np.eye(3)
        F[..., V.start + 2, p.start + 2] = gravity_down_gradient(pos)
    return F


def invariant_system_matrix(pos: np.ndarray, v_n: np.ndarray, C_bn: np.ndarray, layout: StateLayout = LAYOUT_12,
                            p: np.ndarray | None = None) -> np.ndarray:
    """Continuous right-invariant error matrix ``F_inv`` (B, n, n), ``ξ̇ = F_inv ξ`` (docs/iekf.md; the error of ``iekf``).

    ``F_inv = T⁻¹ F T + T⁻¹ Ṫ`` with the common F (:func:`nespm_cli.filters.model.system_matrix`),
    worked out in closed form; the specific force cancels (the group-affine part). The papers' 12
    states (``layout`` 12, ξ = [ρ, φ, b_a, b_g])::

        ρ̇ = −[(2ω_ie + ω_en)×] ρ + ([g×] + [v×][ω_ie×]) φ − C b_a − [v×] C b_g
        φ̇ = −J ρ + (J [v×] − [ω_in×]) φ − C b_g            (J = ∂ω_en/∂v, ω_in = ω_ie + ω_en)

    The earth-rate, transport-rate and Coriolis terms are not group-affine; they are kept as
    first-order terms. With 12 states gravity's position dependence and the position couplings of
    the earth and transport rates are dropped (position is not a state), as in the common F.

    With the position block (``layout`` 15, ξ = [ρ_p, ρ_v, φ, b_a, b_g], the group position ``p``
    (B, 3) [m] the solution's NED offset from the run's fixed origin, iekf.py)::

        ρ̇_p = (I − [p×]J) ρ_v + [p×](J [v×] − [ω_in×]) φ − [p×] C b_g
        ρ̇_v = Γ ρ_p − [(2ω_ie + ω_en)×] ρ_v + ([g×] + [v×][ω_ie×] − Γ [p×]) φ − C b_a − [v×] C b_g
        φ̇  = −J ρ_v + (J [v×] − [ω_in×]) φ − C b_g          (Γ = γ e_D e_Dᵀ, γ = ∂g_D/∂D)

    i.e. the common 15-state F (its vertical gravity gradient γ; the O(v/R) position couplings it
    drops stay dropped) in these coordinates, with ``ṗ = v`` (flat earth about the origin).

    Args:
        pos: (B, 3) [lat, lon, h]; v_n: (B, 3) [m/s]; C_bn: (B, 3, 3), the solution before the step;
        layout: 12 or 15 (``pos, vel, att, ba, bg``); p: (B, 3) the group position [m], required
            with a position block.
    """
    lat, h = pos[..., 0], pos[..., 2]
    R_N, R_E = radii(lat)
    w_ie, w_en = transport_rates(lat, h, v_n, R_N, R_E)
    J = d_w_en_d_v(pos)
    V = skew(v_n)
    if not layout.has("pos"):
        F = np.zeros(v_n.shape[:-1] + (N_STATES, N_STATES))
        F[..., DV, DV] = -skew(2.0 * w_ie + w_en)
        F[..., DV, DPSI] = skew(gravity_n(pos)) + V @ skew(w_ie)
        F[..., DV, BA] = -C_bn
        F[..., DV, BG] = -V @ C_bn
        F[..., DPSI, DV] = -J
        F[..., DPSI, DPSI] = J @ V - skew(w_ie + w_en)
        F[..., DPSI, BG] = -C_bn
        return F
    if p is None:
        raise ValueError("invariant_system_matrix: a layout with a position block needs the group position p")
    if layout.blocks != LAYOUT_15.blocks:
        raise ValueError(f"invariant_system_matrix: layout {layout.name} (the invariant error serves 12 or 15)")
    Pp = skew(np.broadcast_to(p, v_n.shape))
    Pv, Va, A, Ba, Bg = (layout.slice(b) for b in ("pos", "vel", "att", "ba", "bg"))
    gamma = gravity_down_gradient(pos)
    W_phi = J @ V - skew(w_ie + w_en)  # the φ row's φ block, which ρ_p sees through [p×]
    F = np.zeros(v_n.shape[:-1] + (layout.n, layout.n))
    F[..., Pv, Va] = np.eye(3) - Pp @ J
    F[..., Pv, A] = Pp @ W_phi
    F[..., Pv, Bg] = -Pp @ C_bn
    F[..., Va.start + 2, Pv.start + 2] = gamma
    F[..., Va, Va] = -skew(2.0 * w_ie + w_en)
    F[..., Va, A] = skew(gravity_n(pos)) + V @ skew(w_ie)
    F[..., Va.start + 2, A] -= gamma[..., None] * Pp[..., 2, :]
    F[..., Va, Ba] = -C_bn
    F[..., Va, Bg] = -V @ C_bn
    F[..., A, Va] = -J
    F[..., A, A] = W_phi
    F[..., A, Bg] = -C_bn
    return F


def process_noise(cfg: FilterConfig, dt_imu: float, span: float) -> np.ndarray:
    """Discrete Q (n, n) of ``cfg.layout`` over ``span`` seconds: G Q* G^T · span (anukf.md eqs 30-32).

    G = blockdiag(C, C, I, I) and Q* is isotropic within each block, so G Q* G^T = Q*.
    """
    return np.diag(cfg.q_psd(dt_imu) * span)


def joseph_update(P: np.ndarray, H: np.ndarray, nu: np.ndarray, Rm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Linearised Kalman update in Joseph form, batched: ``(x, P⁺, S)``.

    ``P`` (B, n, n), ``H`` (B, m, n), innovation ``nu`` (B, m), ``Rm`` (m, m) or (B, m, m);
    ``K = P Hᵀ S⁻¹`` (S = H P Hᵀ + R, solved, not inverted), ``x = K ν`` (B, n),
    ``P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ`` symmetrized; ``S`` (B, m, m) the innovation
    covariance (for the NIS). Used by ``ekf`` (common error) and ``iekf`` (invariant error: its own H and P).
    """
    PHt = P @ np.swapaxes(H, -1, -2)
    S = H @ PHt + Rm
    K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)
    x = (K @ nu[..., None])[..., 0]
    IKH = np.eye(P.shape[-1]) - K @ H
    P = IKH @ P @ np.swapaxes(IKH, -1, -2) + K @ Rm @ np.swapaxes(K, -1, -2)
    return x, 0.5 * (P + np.swapaxes(P, -1, -2)), S


def initial_nav(pos: np.ndarray, v_true: np.ndarray, C_true: np.ndarray, dv0: np.ndarray, dpsi0: np.ndarray,
                dp0: np.ndarray | None = None) -> NavState:
    """Corrupted initial solution of R runs: v = v_true + dv0, C = exp([dpsi0 x]) C_true and, with
    ``dp0`` (R, 3) [m, NED], the position ``pos ⊕ dp0`` (the solution is ``dp0`` off the truth)."""
    R = dv0.shape[0]
    p = np.broadcast_to(pos, (R, 3)).copy()
    if dp0 is not None and np.any(dp0):
        p = position_plus(p, dp0)
    return NavState(
        pos=p,
        v_n=v_true + dv0,
        C_bn=exp_so3(dpsi0) @ C_true,
        b_a=np.zeros((R, 3)),
        b_g=np.zeros((R, 3)),
    )

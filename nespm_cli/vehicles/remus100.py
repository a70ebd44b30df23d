"""REMUS 100 six-degree-of-freedom model in Fossen's vector form (gp-ukf.md eqs 1-2).

    M nu_dot + C(nu) nu + D(nu) nu + g(eta) = tau        (eq 1)
    eta_dot = J(eta) nu                                  (eq 2)

with ``nu = [u, v, w, p, q, r]`` (body velocities, origin at the centre of buoyancy, x forward,
y starboard, z down) and the position / attitude in local NED.

State order (gp-ukf.md section 6): ``x = [u, v, w, p, q, r, X, Y, Z, theta, psi, phi]``
(m/s, rad/s, m, rad) -- note the Euler angles are stored **pitch, yaw, roll** as in the paper;
the attitude is ZYX: ``C_bn = Rz(psi) Ry(theta) Rx(phi)`` (docs/conventions.md). ``Z`` is depth
(positive down). Commands: ``cmd = [rpm, delta_s, delta_r]`` (propeller rev/min, stern-plane and
rudder angles in rad), the paper's order "RPM, elevator, rudder" (section 6, Fig 4).

Coefficients: Prestero (2001), "Verification of a six-degree of freedom simulation model for the
REMUS autonomous underwater vehicle", MIT/WHOI MS thesis. The thesis PDF was not available
offline; values were read from two independent public transcriptions of its coefficient tables
and ``remus.m`` appendix (table numbers quoted from the transcription that labels them) and
cross-checked against the GP-UKF authors' own implementation (github ArizaWilmerUTAS/
Path-Following, ``REMUS.m``, "based on Prestero 2001") and the coefficient file of Hall & Anstee
(2011, DSTO-TR-2576). See docs/remus100.md for every value and discrepancy.

Decomposition: ``M = M_RB + M_A`` (Prestero's mass matrix), ``C(nu) = C_RB(nu) + C_A(nu)`` from
the skew-symmetric formula of Fossen (2011, Handbook of Marine Craft Hydrodynamics, ch. 3 and 6) applied to ``M``; this formula *generates*
Prestero's added-mass cross terms (X_wq = Z_wdot, Y_ura = X_udot, M_uwa = -(Z_wdot - X_udot) the
Munk moment, ...; exactly, except M_rp / N_pq: 4.81 vs the published 4.86). ``D(nu) nu`` carries
the cross-flow drag, axial drag and rolling resistance and the body/fin *lift* terms, which are
Prestero's published combined coefficients (Y_uv, Y_ur, Z_uw, Z_uq, M_uw, M_uq, N_uv, N_ur)
minus the part that ``C_A`` already supplies, so the total force equals Prestero's equations.

Batched: every function takes leading batch axes (runs first); the RK4 step is one set of numpy
operations on (R, 12) arrays, no loop over runs.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

STATE_NAMES = ("u", "v", "w", "p", "q", "r", "X", "Y", "Z", "theta", "psi", "phi")
IU, IV, IW, IP, IQ, IR, IX, IY, IZ, ITHETA, IPSI, IPHI = range(12)
COMMAND_NAMES = ("rpm", "delta_s", "delta_r")
IRPM, IDS, IDR = range(3)


@dataclass(frozen=True)
class Remus100Params:
    """REMUS 100 parameters (SI units, origin at the centre of buoyancy).

    Unless stated otherwise: Prestero (2001) (see module docstring for how it was read).
    Hydrodynamic coefficient names follow Prestero: ``Yuv`` multiplies ``u*v`` in the Y force,
    ``Yvv`` multiplies ``v*|v|``, ``Yud`` is the added mass ``Y_udot`` etc.
    """

    # --- mass properties (Prestero App. A: measured weight / buoyancy, CG wrt CB, inertia) ---
    g: float = 9.81  # [m/s^2] gravity used by Prestero (m = W / g)
    W: float = 299.0  # [N] weight, Prestero (2.99e2)
    B: float = 306.0  # [N] buoyancy, Prestero (3.06e2); one transcription has 3.08e2, the GP-UKF
    #                   authors' REMUS.m 3.10e2, Hall & Anstee W + 0.75 lbf (docs/remus100.md)
    xg: float = 0.0  # [m] CG wrt CB, Prestero Table A.4
    yg: float = 0.0  # [m] Table A.4
    zg: float = 1.96e-2  # [m] Table A.4 (CG 1.96 cm below CB)
    Ixx: float = 1.77e-1  # [kg m^2] Prestero
    Iyy: float = 3.45  # [kg m^2] Prestero
    Izz: float = 3.45  # [kg m^2] Prestero
    # --- axial drag (Prestero) and cross-flow drag (Table C.2) ---
    Xuu: float = -1.62  # [kg/m]
    Yvv: float = -1.31e3  # [kg/m]
    Yrr: float = 6.32e-1  # [kg m/rad^2]
    Zww: float = -1.31e2  # [kg/m]  as printed (Hall & Anstee use -1.31e3, axisymmetry; docs)
    Zqq: float = -6.32e-1  # [kg m/rad^2]
    Mww: float = 3.18  # [kg]
    Mqq: float = -1.88e2  # [kg m^2/rad^2]
    Nvv: float = -3.18  # [kg]
    Nrr: float = -9.40e1  # [kg m^2/rad^2]
    # --- rolling resistance (Table C.3) ---
    Kpp: float = -1.30e-1  # [kg m^2/rad^2]
    # --- added mass (Table C.5) ---
    Xud: float = -9.30e-1  # [kg]
    Yvd: float = -3.55e1  # [kg]
    Yrd: float = 1.93  # [kg m/rad]
    Zwd: float = -3.55e1  # [kg]
    Zqd: float = -1.93  # [kg m/rad]
    Kpd: float = -7.04e-2  # [kg m^2/rad]
    Mwd: float = -1.93  # [kg m]
    Mqd: float = -4.88  # [kg m^2/rad]
    Nvd: float = 1.93  # [kg m]
    Nrd: float = -4.88  # [kg m^2/rad]
    # --- combined lift coefficients: body lift + fin lift + added-mass cross term
    #     (Prestero's combined non-linear force/moment table, Table B.1 of the transcription) ---
    Yuv: float = -2.86e1  # [kg/m]   body and fin lift
    Yur: float = 5.22  # [kg/rad]    added mass cross term and fin lift
    Zuw: float = -2.86e1  # [kg/m]
    Zuq: float = -5.22  # [kg/rad]
    Muw: float = 2.40e1  # [kg]      body and fin lift and Munk moment
    Muq: float = -2.00  # [kg m/rad]
    Nuv: float = -2.40e1  # [kg]
    Nur: float = -2.00  # [kg m/rad]
    # --- control fins (Table C.10) ---
    Yuudr: float = 9.64  # [kg/(m rad)]
    Zuuds: float = -9.64  # [kg/(m rad)]
    Muuds: float = -6.15  # [kg/rad]
    Nuudr: float = -6.15  # [kg/rad]
    # --- propeller (Table C.9: X_prop, K_prop at the nominal 1500 rpm) ---
    X_prop: float = 3.86  # [N]   thrust at rpm_nominal
    K_prop: float = -5.43e-1  # [N m] propeller torque at rpm_nominal
    rpm_nominal: float = 1500.0  # [rev/min] Prestero's nominal propeller speed
    # --- actuator limits (not in Prestero's tables; Fossen MSS remus100.m, max_ui / n_max) ---
    rpm_max: float = 1525.0  # [rev/min]
    rpm_min: float = 0.0  # [rev/min] no reverse thrust (the propeller model is for n >= 0)
    fin_max: float = float(np.radians(20.0))  # [rad] rudder and stern-plane saturation

    @property
    def m(self) -> float:
        """Mass [kg] = W / g (Prestero)."""
        return self.W / self.g

    @property
    def k_thrust(self) -> float:
        """Thrust coefficient [N/rpm^2]: ``T = k_thrust n |n|`` with T(rpm_nominal) = X_prop."""
        return self.X_prop / self.rpm_nominal**2

    @property
    def k_torque(self) -> float:
        """Torque coefficient [N m/rpm^2]: ``Q = k_torque n |n|`` with Q(rpm_nominal) = K_prop."""
        return self.K_prop / self.rpm_nominal**2


# ----------------------------------------------------------------------------- matrices


def _skew6(a: np.ndarray) -> np.ndarray:
    """``S(a)`` (..., 3, 3) with ``S(a) b = a x b``."""
    S = np.zeros(a.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -a[..., 2], a[..., 1]
    S[..., 1, 0], S[..., 1, 2] = a[..., 2], -a[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -a[..., 1], a[..., 0]
    return S


def rigid_body_mass(p: Remus100Params) -> np.ndarray:
    """M_RB (6, 6) (Fossen 2011, ch. 3) with the CG at ``r_g = [xg, yg, zg]`` from the CB."""
    m = p.m
    rg = np.array([p.xg, p.yg, p.zg])
    M = np.zeros((6, 6))
    M[:3, :3] = m * np.eye(3)
    M[:3, 3:] = -m * _skew6(rg)
    M[3:, :3] = m * _skew6(rg)
    M[3:, 3:] = np.diag([p.Ixx, p.Iyy, p.Izz])
    return M


def added_mass(p: Remus100Params) -> np.ndarray:
    """M_A (6, 6) = -[hydrodynamic added-mass derivatives] (Prestero Table C.5); symmetric."""
    A = np.zeros((6, 6))
    A[0, 0] = p.Xud
    A[1, 1], A[1, 5] = p.Yvd, p.Yrd
    A[2, 2], A[2, 4] = p.Zwd, p.Zqd
    A[3, 3] = p.Kpd
    A[4, 2], A[4, 4] = p.Mwd, p.Mqd
    A[5, 1], A[5, 5] = p.Nvd, p.Nrd
    return -A


def mass_matrix(p: Remus100Params) -> np.ndarray:
    """M = M_RB + M_A (6, 6) of eq 1 (Prestero's mass matrix)."""
    return rigid_body_mass(p) + added_mass(p)


def coriolis_matrix(M: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """C(nu) (..., 6, 6) for a symmetric mass matrix ``M`` (6, 6) (Fossen 2011, ch. 3 and 6).

    ``C = [[0, -S(a)], [-S(a), -S(b)]]`` with ``[a; b] = M nu``; skew-symmetric, so it does no
    work (``nu^T C nu = 0``). Linear in ``M``: ``C(M_RB + M_A) = C_RB + C_A``.
    """
    ab = np.einsum("ij,...j->...i", M, nu)
    Sa, Sb = _skew6(ab[..., :3]), _skew6(ab[..., 3:])
    C = np.zeros(nu.shape[:-1] + (6, 6))
    C[..., :3, 3:] = -Sa
    C[..., 3:, :3] = -Sa
    C[..., 3:, 3:] = -Sb
    return C


def _cross_term(M: np.ndarray, i: int, j: int, k: int) -> float:
    """Coefficient of ``nu_i nu_j`` (i != j) in component k of ``-C(nu) nu`` for mass matrix M."""
    ei, ej = np.eye(6)[i], np.eye(6)[j]
    return float(-(coriolis_matrix(M, ei)[k, j] + coriolis_matrix(M, ej)[k, i]))


@dataclass(frozen=True)
class LiftCoefficients:
    """Lift parts of Prestero's combined coefficients: combined minus the C_A-implied part.

    E.g. ``Muw = Muw_published - M_uwa`` where ``M_uwa = -(Z_wdot - X_udot)`` (Munk moment) comes
    out of :func:`coriolis_matrix` applied to M_A.
    """

    Yuv: float
    Yur: float
    Zuw: float
    Zuq: float
    Muw: float
    Muq: float
    Nuv: float
    Nur: float


def lift_coefficients(p: Remus100Params) -> LiftCoefficients:
    """Split Prestero's combined coefficients into C_A (added mass) + lift (body and fins)."""
    MA = added_mass(p)
    c = lambda i, j, k: _cross_term(MA, i, j, k)  # noqa: E731
    return LiftCoefficients(
        Yuv=p.Yuv - c(IU, IV, 1),
        Yur=p.Yur - c(IU, IR, 1),
        Zuw=p.Zuw - c(IU, IW, 2),
        Zuq=p.Zuq - c(IU, IQ, 2),
        Muw=p.Muw - c(IU, IW, 4),
        Muq=p.Muq - c(IU, IQ, 4),
        Nuv=p.Nuv - c(IU, IV, 5),
        Nur=p.Nur - c(IU, IR, 5),
    )


def damping_abs(p: Remus100Params, a: np.ndarray) -> np.ndarray:
    """Quadratic-drag part of D(nu) (..., 6, 6) evaluated at ``a = |nu|`` (linear in ``a``).

    Axial drag, cross-flow drag (Prestero Table C.2) and rolling resistance (Table C.3):
    ``-D_abs(|nu|) nu`` = ``[Xuu u|u|, Yvv v|v| + Yrr r|r|, Zww w|w| + Zqq q|q|, Kpp p|p|,
    Mww w|w| + Mqq q|q|, Nvv v|v| + Nrr r|r|]``.
    """
    D = np.zeros(a.shape[:-1] + (6, 6))
    D[..., 0, 0] = -p.Xuu * a[..., IU]
    D[..., 1, 1] = -p.Yvv * a[..., IV]
    D[..., 1, 5] = -p.Yrr * a[..., IR]
    D[..., 2, 2] = -p.Zww * a[..., IW]
    D[..., 2, 4] = -p.Zqq * a[..., IQ]
    D[..., 3, 3] = -p.Kpp * a[..., IP]
    D[..., 4, 2] = -p.Mww * a[..., IW]
    D[..., 4, 4] = -p.Mqq * a[..., IQ]
    D[..., 5, 1] = -p.Nvv * a[..., IV]
    D[..., 5, 5] = -p.Nrr * a[..., IR]
    return D


def damping_lift(p: Remus100Params, nu: np.ndarray, lift: LiftCoefficients | None = None) -> np.ndarray:
    """Body- and fin-lift part of D(nu) (..., 6, 6), linear in the surge speed ``u``.

    ``-D_lift(nu) nu = u * [0, Yuv v + Yur r, Zuw w + Zuq q, 0, Muw w + Muq q, Nuv v + Nur r]``
    with the lift coefficients of :func:`lift_coefficients`. For u > 0 this block is dissipative
    (both 2x2 forms are negative definite), see tests.
    """
    L = lift_coefficients(p) if lift is None else lift
    u = nu[..., IU]
    D = np.zeros(nu.shape[:-1] + (6, 6))
    D[..., 1, 1], D[..., 1, 5] = -L.Yuv * u, -L.Yur * u
    D[..., 2, 2], D[..., 2, 4] = -L.Zuw * u, -L.Zuq * u
    D[..., 4, 2], D[..., 4, 4] = -L.Muw * u, -L.Muq * u
    D[..., 5, 1], D[..., 5, 5] = -L.Nuv * u, -L.Nur * u
    return D


def damping_matrix(p: Remus100Params, nu: np.ndarray) -> np.ndarray:
    """D(nu) (..., 6, 6) of eq 1: quadratic drag plus lift."""
    return damping_abs(p, np.abs(nu)) + damping_lift(p, nu)


def restoring(p: Remus100Params, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """g(eta) (..., 6): gravity and buoyancy (Fossen 2011, ch. 4) with the CB at the origin."""
    st, ct, sp, cp = np.sin(theta), np.cos(theta), np.sin(phi), np.cos(phi)
    WB = p.W - p.B
    xW, yW, zW = p.xg * p.W, p.yg * p.W, p.zg * p.W
    return np.stack(
        [
            WB * st,
            -WB * ct * sp,
            -WB * ct * cp,
            -yW * ct * cp + zW * ct * sp,
            zW * st + xW * ct * cp,
            -xW * ct * sp - yW * st,
        ],
        axis=-1,
    )


def saturate(p: Remus100Params, cmd: np.ndarray) -> np.ndarray:
    """Commands (..., 3) ``[rpm, delta_s, delta_r]`` clipped to the actuator limits."""
    cmd = np.asarray(cmd, dtype=float)
    lo = np.array([p.rpm_min, -p.fin_max, -p.fin_max])
    hi = np.array([p.rpm_max, p.fin_max, p.fin_max])
    return np.clip(cmd, lo, hi)


def control_forces(p: Remus100Params, nu: np.ndarray, cmd: np.ndarray) -> np.ndarray:
    """tau (..., 6) of eq 1 from the (saturated) commands ``[rpm, delta_s, delta_r]``.

    Propeller: ``X = k_T n|n|``, ``K = k_Q n|n|`` (quadratic in rpm, calibrated to Prestero's
    X_prop / K_prop at 1500 rpm; the advance-ratio dependence is neglected). Fins (Table C.10):
    ``Y = Yuudr u^2 dr``, ``Z = Zuuds u^2 ds``, ``M = Muuds u^2 ds``, ``N = Nuudr u^2 dr``.
    """
    c = saturate(p, cmd)
    n = c[..., IRPM]
    nn = n * np.abs(n)
    uu = nu[..., IU] ** 2
    ds, dr = c[..., IDS], c[..., IDR]
    zero = np.zeros_like(nn * uu)
    return np.stack(
        [p.k_thrust * nn + zero, p.Yuudr * uu * dr, p.Zuuds * uu * ds, p.k_torque * nn + zero,
         p.Muuds * uu * ds, p.Nuudr * uu * dr],
        axis=-1,
    )


def kinematics(x: np.ndarray) -> np.ndarray:
    """eta_dot of eq 2 in the state order: ``[X_dot, Y_dot, Z_dot, theta_dot, psi_dot, phi_dot]``.

    Position rate ``C_bn [u, v, w]``; Euler-angle rates ``T(phi, theta) [p, q, r]`` (ZYX Euler
    angles, Fossen 2011 ch. 2). Singular at theta = +-90 deg (never approached by the vehicle).
    """
    u, v, w, p_, q, r = (x[..., i] for i in range(6))
    th, ps, ph = x[..., ITHETA], x[..., IPSI], x[..., IPHI]
    sth, cth, sps, cps, sph, cph = np.sin(th), np.cos(th), np.sin(ps), np.cos(ps), np.sin(ph), np.cos(ph)
    return _kinematics(u, v, w, p_, q, r, sth, cth, sps, cps, sph, cph)


def _kinematics(u, v, w, p_, q, r, sth, cth, sps, cps, sph, cph, out=None) -> np.ndarray:
    """eq 2 from precomputed sines/cosines; rotations applied roll, pitch, yaw in turn."""
    a = sph * v + cph * w  # z after the roll rotation
    b = cph * v - sph * w  # y after the roll rotation
    c = cth * u + sth * a  # x after the pitch rotation
    out = np.empty(np.shape(u) + (6,)) if out is None else out
    out[..., 0] = cps * c - sps * b
    out[..., 1] = sps * c + cps * b
    out[..., 2] = cth * a - sth * u
    qs = sph * q + cph * r
    icth = 1.0 / cth
    out[..., 3] = cph * q - sph * r
    out[..., 4] = qs * icth
    out[..., 5] = p_ + qs * (sth * icth)
    return out


# ----------------------------------------------------------------------------- the model


@dataclass
class Remus100:
    """The REMUS 100 model with precomputed matrices and a fast batched right-hand side.

    ``derivative`` evaluates ``nu_dot = M^-1 (tau - C(nu) nu - D(nu) nu - g(eta))`` as one
    matrix product ``Phi(x, cmd) @ Theta`` of a feature row (the products ``nu_i nu_j``,
    ``nu_i |nu_j|``, the three restoring-force shapes and the three control shapes) with a
    coefficient matrix built *from* :func:`coriolis_matrix`, :func:`damping_matrix`,
    :func:`restoring` and :func:`control_forces` at unit vectors (so both paths share one
    definition); ``derivative_reference`` is the literal eq 1 and the tests check they agree.
    """

    params: Remus100Params = field(default_factory=Remus100Params)

    def __post_init__(self) -> None:
        p = self.params
        self.M = mass_matrix(p)
        self.M_inv = np.linalg.inv(self.M)
        self.lift = lift_coefficients(p)
        E = np.eye(6)
        # M nu_dot = sum_ij nu_i nu_j Q[i, j] + sum_ij nu_i |nu_j| A[i, j] + G^T g_basis + T^T t_basis
        Q = np.zeros((6, 6, 6))
        A = np.zeros((6, 6, 6))
        for j in range(6):
            Cj = coriolis_matrix(self.M, E[j]) + damping_lift(p, E[j], self.lift)
            Aj = damping_abs(p, E[j])
            for i in range(6):
                Q[i, j] -= Cj[:, i]
                A[i, j] -= Aj[:, i]
        Q = Q + np.swapaxes(Q, 0, 1)  # symmetric in (i, j): use each unordered pair once
        iu, ju = np.triu_indices(6)
        Qp = np.where((iu == ju)[:, None], 0.5, 1.0) * Q[iu, ju]
        keep_q = np.flatnonzero(np.any(Qp != 0.0, axis=1))
        Ap = A.reshape(36, 6)
        keep_a = np.flatnonzero(np.any(Ap != 0.0, axis=1))
        # restoring shapes [sin th, cos th sin ph, cos th cos ph]: -g(eta) = -G.T @ basis
        WB, xW, yW, zW = p.W - p.B, p.xg * p.W, p.yg * p.W, p.zg * p.W  # as in restoring()
        G = np.array([
            [WB, 0.0, 0.0, 0.0, zW, -yW],
            [0.0, -WB, 0.0, zW, 0.0, -xW],
            [0.0, 0.0, -WB, -yW, xW, 0.0],
        ])
        # control shapes [n|n|, u^2 ds, u^2 dr]
        T = np.zeros((3, 6))
        T[0, 0], T[0, 3] = p.k_thrust, p.k_torque
        T[1, 2], T[1, 4] = p.Zuuds, p.Muuds
        T[2, 1], T[2, 5] = p.Yuudr, p.Nuudr
        coef = np.concatenate([Qp[keep_q], Ap[keep_a], -G, T], axis=0)
        self._qi, self._qj = iu[keep_q], ju[keep_q]
        self._ai, self._aj = keep_a // 6, keep_a % 6
        self._theta = np.ascontiguousarray(coef @ self.M_inv.T)  # (K, 6): nu_dot = Phi @ theta

    # --------------------------------------------------------------- right-hand sides

    def derivative(self, x: np.ndarray, cmd: np.ndarray) -> np.ndarray:
        """x_dot (R, 12) for states ``x`` (R, 12) and *saturated* commands ``cmd`` (R, 3).

        Use :func:`saturate` (or :meth:`rk4_step`, which saturates) before calling.
        """
        R = x.shape[0]
        nu = x[:, :6]
        th, ps, ph = x[:, ITHETA], x[:, IPSI], x[:, IPHI]
        sth, cth, sps, cps, sph, cph = np.sin(th), np.cos(th), np.sin(ps), np.cos(ps), np.sin(ph), np.cos(ph)
        nq, na = len(self._qi), len(self._ai)
        phi = np.empty((R, nq + na + 6))
        np.multiply(nu[:, self._qi], nu[:, self._qj], out=phi[:, :nq])
        np.multiply(nu[:, self._ai], np.abs(nu[:, self._aj]), out=phi[:, nq:nq + na])
        k = nq + na
        n = cmd[:, IRPM]
        uu = nu[:, IU] * nu[:, IU]
        phi[:, k] = sth
        phi[:, k + 1] = cth * sph
        phi[:, k + 2] = cth * cph
        phi[:, k + 3] = n * np.abs(n)
        phi[:, k + 4] = uu * cmd[:, IDS]
        phi[:, k + 5] = uu * cmd[:, IDR]
        out = np.empty((R, 12))
        out[:, :6] = np.einsum("rk,kj->rj", phi, self._theta)
        _kinematics(x[:, IU], x[:, IV], x[:, IW], x[:, IP], x[:, IQ], x[:, IR],
                    sth, cth, sps, cps, sph, cph, out=out[:, 6:])
        return out

    def derivative_reference(self, x: np.ndarray, cmd: np.ndarray) -> np.ndarray:
        """x_dot (..., 12) from the literal eq 1-2: ``M^-1 (tau - C nu - D nu - g)``, ``J nu``."""
        p = self.params
        nu = x[..., :6]
        C = coriolis_matrix(self.M, nu)
        D = damping_matrix(p, nu)
        g = restoring(p, x[..., ITHETA], x[..., IPHI])
        tau = control_forces(p, nu, cmd)
        rhs = tau - np.einsum("...ij,...j->...i", C + D, nu) - g
        nu_dot = np.einsum("ij,...j->...i", self.M_inv, rhs)
        return np.concatenate([nu_dot, kinematics(x)], axis=-1)

    def rk4_step(self, x: np.ndarray, cmd: np.ndarray, h: float) -> np.ndarray:
        """One classical RK4 step of length ``h`` [s] with commands held (zero-order hold).

        ``x`` (R, 12), ``cmd`` (R, 3) (saturated here). Returns the state at t + h (yaw unwrapped).
        """
        c = saturate(self.params, cmd)
        k1 = self.derivative(x, c)
        k2 = self.derivative(x + (0.5 * h) * k1, c)
        k3 = self.derivative(x + (0.5 * h) * k2, c)
        k4 = self.derivative(x + h * k3, c)
        return x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)

    # --------------------------------------------------------------- diagnostics

    def energy(self, x: np.ndarray) -> np.ndarray:
        """Mechanical energy (...,) [J]: ``0.5 nu^T M nu`` (incl. added mass) + hydrostatic potential.

        Potential ``-W z_G + B z_B`` (z down) with ``z_G = Z + (C_bn r_g)_z``, zero for a level
        vehicle at Z = 0. Along eq 1, ``dE/dt = nu^T tau - nu^T D(nu) nu`` (C is skew, g = grad).
        """
        p = self.params
        nu = x[..., :6]
        kin = 0.5 * np.einsum("...i,ij,...j->...", nu, self.M, nu)
        th, ph = x[..., ITHETA], x[..., IPHI]
        dzg = -np.sin(th) * p.xg + np.cos(th) * np.sin(ph) * p.yg + np.cos(th) * np.cos(ph) * p.zg
        pot = -p.W * (x[..., IZ] + dzg) + p.B * x[..., IZ] + p.W * p.zg
        return kin + pot

    def kinetic_energy(self, x: np.ndarray) -> np.ndarray:
        """``0.5 nu^T M nu`` (...,) [J] (rigid body + added mass)."""
        nu = x[..., :6]
        return 0.5 * np.einsum("...i,ij,...j->...", nu, self.M, nu)

    def steady_speed(self, rpm: float) -> float:
        """Straight-line surge speed [m/s] where thrust balances axial drag: ``k_T n^2 = -Xuu u^2``."""
        p = self.params
        return float(np.sqrt(p.k_thrust * rpm * abs(rpm) / -p.Xuu))

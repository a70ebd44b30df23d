"""``dvl``: the Doppler velocity log as a body-frame velocity (anukf.md eq 33), with its lever arm.

``y = C_bnᵀ v_n + ω_nb × l``: the velocity of the DVL's mounting point ``l`` (body frame, from the
IMU), ``ω_nb`` the body rate relative to NED from the compensated gyro of the IMU step that ends
at the measurement (:func:`body_rate`). Its change from x = 0 for error-state points
(:func:`dvl_h`), its Jacobian (:func:`dvl_H`) and, for the iekf's right-invariant error, the
closed forms of docs/iekf.md (:func:`invariant_dvl_h`, :func:`invariant_dvl_H`: the DVL is a
right-invariant observation, no attitude column).

Defaults keep the papers' numbers: the recorded DVL file (``--dvl recorded``) at the GT epochs,
or a synthetic one (``--dvl synthetic``: the truth's body velocity + lever-arm term + N(0, 0.02²)
per axis, drawn from the papers' stream 3); the filter's std is 0.1 m/s with the recorded DVL
and 0.02 m/s with the synthetic one unless ``--dvl-r-std`` (docs/filters.md). On the embedded tracks
(no ``--data-dir``) the "recorded" file is generated in code (:data:`EMBEDDED_SOURCE`, :func:`source_label`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nespm_cli.nav.dvl import dvl_velocity
from nespm_cli.nav.earth import radii_of_sin, transport_rates
from nespm_cli.nav.rotations import exp_so3_minus_identity, skew, so3_left_jacobian
from nespm_cli.nav.state import LAYOUT_12, NavState, StateLayout
from nespm_cli.nav.strapdown import cross
from nespm_cli.nav.trig import sin_cos
from nespm_cli.sensors.measurement import Measurement
from nespm_cli.sensors.source import Context, Sensor, SensorOptions, Truth

STREAM_DVL = 3  # the papers' DVL noise stream (data.corruption.STREAM_DVL)
#: the source word (manifest ``sensors``, the report's Run line) of a DVL read from an embedded track: no
#: recording, but the file :mod:`nespm_cli.data.embedded` generates in code (the truth + N(0, 0.02²), one draw
#: from ``default_rng(1000 + track)`` that every run shares)
EMBEDDED_SOURCE = "embedded"


def source_label(source: str, data_dir) -> str:
    """The source word of a sensor: ``source`` (``recorded``, ``synthetic``), except a ``recorded`` one on the
    embedded tracks (``data_dir`` None after :func:`nespm_cli.data.tracks.resolve_data_dir`): :data:`EMBEDDED_SOURCE`."""
    return EMBEDDED_SOURCE if source == "recorded" and data_dir is None else source


def body_rate(nav: NavState, w_ib_comp: np.ndarray) -> np.ndarray:
    """Body rate relative to NED (B, 3) [rad/s] from the compensated gyro output ``w_ib_comp`` (B, 3)."""
    sc = sin_cos(nav.pos[..., 0])
    R_N, R_E = radii_of_sin(sc[0])
    w_ie, w_en = transport_rates(nav.pos[..., 0], nav.pos[..., 2], nav.v_n, R_N, R_E, sc)
    return w_ib_comp - (np.swapaxes(nav.C_bn, -1, -2) @ (w_ie + w_en)[..., None])[..., 0]


def dvl_h(dv: np.ndarray, dpsi: np.ndarray, bg: np.ndarray, nav: NavState, lever: np.ndarray) -> np.ndarray:
    """Nonlinear DVL model (anukf.md eq 33) as its change from x = 0, for point blocks ``dv``,
    ``dpsi``, ``bg`` (B, S, 3) around ``nav`` (B,):
    ``h(x) − h(0) = C^T [(exp(−[dpsi x]) − I) v + exp(−[dpsi x]) dv] − b_g × l`` (B, S, 3),
    computed without forming the large common term ``C^T v``."""
    Em = exp_so3_minus_identity(-dpsi)  # (B, S, 3, 3)
    v = nav.v_n[..., None, :]
    dv_n = (Em @ (v + dv)[..., None])[..., 0] + dv
    out = (np.swapaxes(nav.C_bn, -1, -2)[..., None, :, :] @ dv_n[..., None])[..., 0]
    return out - cross(bg, np.broadcast_to(lever, bg.shape))


def dvl_H(nav: NavState, lever: np.ndarray, layout: StateLayout) -> np.ndarray:
    """Jacobian of :func:`dvl_h` at x = 0 (B, 3, n): ``[C^T, C^T [v x], [l x]]`` on the vel, att
    and bg blocks."""
    Ct = np.swapaxes(nav.C_bn, -1, -2)
    H = np.zeros(nav.v_n.shape[:-1] + (3, layout.n))
    H[..., :, layout.slice("vel")] = Ct
    H[..., :, layout.slice("att")] = Ct @ skew(nav.v_n)
    if layout.has("bg"):
        H[..., :, layout.slice("bg")] = skew(np.broadcast_to(lever, nav.v_n.shape))
    return H


def invariant_dvl_h(rho: np.ndarray, phi: np.ndarray, bg: np.ndarray, C_bn: np.ndarray, lever) -> np.ndarray:
    """The DVL model as its change from ξ = 0 for invariant point blocks ``ρ``, ``φ``, ``b_g`` (B, S, 3).

    ``y = C_trueᵀ v_true + (ω_nb − b_g) × l`` with ``X_true = exp(ξ) X_nav``: since
    ``exp(−[φ×]) J_l(φ) = J_l(−φ)``, ``y(ξ) − y(0) = Cᵀ J_l(−φ) ρ + l × b_g`` (B, S, 3) — the
    right-invariant observation ``Y = X⁻¹ b`` of Barrau & Bonnabel (2017).
    """
    v_b = (so3_left_jacobian(-phi) @ rho[..., None])[..., 0]
    out = (np.swapaxes(C_bn, -1, -2)[..., None, :, :] @ v_b[..., None])[..., 0]
    return out + cross(np.broadcast_to(lever, bg.shape), bg)


def invariant_dvl_H(C_bn: np.ndarray, lever, layout: StateLayout) -> np.ndarray:
    """Jacobian of :func:`invariant_dvl_h` at ξ = 0 (B, 3, n): ``[Cᵀ, 0, 0, [l×]]`` on ρ (the vel
    block) and b_g. No attitude column: the attitude error enters only through ρ. With the 15-state
    position block (ρ_p) the same, with a zero ρ_p column: ``Y = X⁻¹ b`` does not see the position,
    so H is free of the group position too (docs/iekf.md)."""
    B = C_bn.shape[:-2]
    H = np.zeros(B + (3, layout.n))
    H[..., :, layout.slice("vel")] = np.swapaxes(C_bn, -1, -2)
    if layout.has("bg"):
        H[..., :, layout.slice("bg")] = skew(np.broadcast_to(np.asarray(lever, dtype=float), B + (3,)))
    return H


class DvlMeasurement(Measurement):
    """Body-frame DVL velocity (anukf.md eq 33): ``h(x) = C^T exp(−[dpsi×]) (v + dv) + (w_nb − b_g) × l``.

    Args:
        dvl_b: (R, 3) measured body-frame velocity [m/s].
        w_nb: (R, 3) body rate relative to NED from the compensated gyro [rad/s] (the lever-arm term).
        lever: (3,) DVL position relative to the IMU, body frame [m].
        std: noise std per axis [m/s]; ``R = I₃ std²``.
        layout: the filter's error-state layout (default the papers' 12 states).
    """

    def __init__(self, dvl_b: np.ndarray, w_nb: np.ndarray, lever, std: float, layout: StateLayout = LAYOUT_12):
        self.z = dvl_b
        self.w_nb = w_nb
        self.lever = np.asarray(lever, dtype=float)
        self.std = std
        self.R = np.eye(3) * std**2
        self.layout = layout

    def innovation(self, nav: NavState) -> np.ndarray:
        return self.z - dvl_velocity(nav.C_bn, nav.v_n, self.w_nb, self.lever)

    def predict(self, nav: NavState) -> np.ndarray:
        return dvl_velocity(nav.C_bn, nav.v_n, self.w_nb, self.lever)

    def h(self, X: np.ndarray, nav: NavState) -> np.ndarray:
        return dvl_h(self.block(X, "vel"), self.block(X, "att"), self.block(X, "bg"), nav, self.lever)

    def H(self, nav: NavState) -> np.ndarray:
        return dvl_H(nav, self.lever, self.layout)

    def H_invariant(self, nav: NavState) -> np.ndarray:
        return invariant_dvl_H(nav.C_bn, self.lever, self.layout)


@dataclass(frozen=True)
class DvlOptions(SensorOptions):
    """DVL options (:class:`SensorOptions`); defaults: the track's file, the synthetic noise 0.02
    m/s, the filter std 0.1 m/s (recorded) / 0.02 m/s (synthetic), at the GT epochs."""

    source: str = "recorded"
    std: float = 0.02


class Dvl(Sensor):
    """The DVL (body-frame velocity of its mounting point)."""

    dim = 3
    labels = ("x", "y", "z")
    observes = ("vel", "att")
    Options = DvlOptions
    stream = STREAM_DVL
    default_interval = None  # at the GT epochs, as the papers' DVL

    def r_std(self) -> float:
        if self.opt.r_std is not None:
            return float(self.opt.r_std)
        return 0.02 if self.opt.source == "synthetic" else 0.1

    def true_values(self, truth: Truth) -> np.ndarray:
        return dvl_velocity(truth.C_bn, truth.v_n, truth.w_nb_b, np.asarray(self.opt.lever_arm, dtype=float))

    def recorded(self, track):
        channels = getattr(track, "channels", None) or {}
        if "dvl" in channels:
            return channels["dvl"]
        return np.asarray(track.t, dtype=float), np.asarray(track.dvl, dtype=float)

    def measurement(self, z: np.ndarray, nav: NavState, ctx: Context, layout: StateLayout) -> Measurement:
        return DvlMeasurement(z, body_rate(nav, ctx.w_ib_b), self.opt.lever_arm, self.r_std(), layout)


__all__ = ["Dvl", "DvlMeasurement", "DvlOptions", "STREAM_DVL", "body_rate", "dvl_H", "dvl_h", "invariant_dvl_H",
           "invariant_dvl_h"]

"""``depth``: a pressure depth sensor, the depth of its mounting point [m, positive down].

``y = D + (C_bn l)_D``: the vehicle's depth ``D = −h`` plus the down component of the lever arm
``l`` (body frame, from the IMU) turned into NED. With the error state ``nav ⊕ x = truth``:

    h(x) − h(0) = δp_D + ((exp([δψ×]) − I) C l)_D          H = [e_Dᵀ on pos, [u₁, −u₀, 0] on att]

with ``u = C l`` (``exp([δψ×]) u ≈ u − [u×] δψ``). It observes the position block (``--state 15``).
Defaults: 1 Hz on the IMU grid, std 0.05 m (the filter told the truth), from the truth
(``source synthetic``); ``source recorded`` reads ``DEPTH_trajectoryN.csv`` (``Time [s]``,
``Depth [m]``, NaN for none).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nespm_cli.nav.rotations import exp_so3_minus_identity
from nespm_cli.nav.state import NavState, StateLayout
from nespm_cli.sensors.measurement import Measurement
from nespm_cli.sensors.source import Context, Sensor, SensorOptions, Truth


def lever_down(C_bn: np.ndarray, lever: np.ndarray) -> np.ndarray:
    """``C_bn l`` (..., 3) [m]: the lever arm in NED."""
    return (C_bn @ np.broadcast_to(lever, C_bn.shape[:-2] + (3,))[..., None])[..., 0]


class DepthMeasurement(Measurement):
    """Depth of the sensor [m] of R runs: ``z`` (R, 1), ``R = std²``."""

    def __init__(self, z: np.ndarray, lever, std: float, layout: StateLayout):
        self.z = np.asarray(z, dtype=float)
        self.lever = np.asarray(lever, dtype=float)
        self.R = np.eye(1) * std**2
        self.layout = layout

    def predict(self, nav: NavState) -> np.ndarray:
        return (-nav.pos[..., 2] + lever_down(nav.C_bn, self.lever)[..., 2])[..., None]

    def h(self, X: np.ndarray, nav: NavState) -> np.ndarray:
        dp, dpsi = self.block(X, "pos"), self.block(X, "att")
        u = lever_down(nav.C_bn, self.lever)[..., None, :]  # (R, 1, 3)
        turn = (exp_so3_minus_identity(dpsi) @ np.broadcast_to(u, dpsi.shape)[..., None])[..., 0]
        return (dp[..., 2] + turn[..., 2])[..., None]

    def H(self, nav: NavState) -> np.ndarray:
        H = self.zeros_H(nav)
        H[..., 0, self.layout.slice("pos").start + 2] = 1.0
        u = lever_down(nav.C_bn, self.lever)
        a = self.layout.slice("att").start
        H[..., 0, a], H[..., 0, a + 1] = u[..., 1], -u[..., 0]
        return H

    def H_invariant(self, nav: NavState) -> None:
        """None: the iekf uses ``H T`` (docs/iekf.md). The depth is the down component of the
        left-invariant observation ``X b`` (the sensor's position ``p + C l``); in the iekf's
        right-invariant coordinates its Jacobian is ``[e_Dᵀ on ρ_p, e_Dᵀ (−[(p + C l)×]) on φ]``,
        which depends on the group position ``p`` that a measurement does not know."""
        return None


@dataclass(frozen=True)
class DepthOptions(SensorOptions):
    """Depth sensor options (:class:`SensorOptions`): std 0.05 m, at the GT epochs, from the truth."""

    std: float = 0.05


class Depth(Sensor):
    """Pressure depth [m, positive down] of the sensor's mounting point."""

    dim = 1
    labels = ("depth",)
    observes = ("pos",)
    Options = DepthOptions
    default_interval = None  # at the GT epochs (the track's own clock), like the DVL

    def true_values(self, truth: Truth) -> np.ndarray:
        u = lever_down(truth.C_bn, np.asarray(self.opt.lever_arm, dtype=float))
        return (-truth.pos[:, 2] + u[:, 2])[:, None]

    def measurement(self, z: np.ndarray, nav: NavState, ctx: Context, layout: StateLayout) -> Measurement:
        return DepthMeasurement(z, self.opt.lever_arm, self.r_std(), layout)


__all__ = ["Depth", "DepthMeasurement", "DepthOptions", "lever_down"]

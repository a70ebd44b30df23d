"""``heading``: a compass / magnetometer heading, the yaw of ``C_bn`` [rad internally].

``y = ψ(C_bn) = atan2(C₁₀, C₀₀)`` (the ZYX yaw of docs/conventions.md, in (−π, π]). With the
error state ``nav ⊕ x = truth``, ``C_true = exp([δψ×]) C_nav`` (δψ in the nav frame):

    h(x) − h(0) = wrap(ψ(exp([δψ×]) C) − ψ(C))           ν = wrap(z − ψ(C))

and, from ``d(exp([δψ×]) C) = [δψ×] C`` at δψ = 0 (``dC₀₀ = −δψ_D C₁₀ + δψ_E C₂₀``,
``dC₁₀ = δψ_D C₀₀ − δψ_N C₂₀``) and ``dψ = (C₀₀ dC₁₀ − C₁₀ dC₀₀) / (C₀₀² + C₁₀²)``:

    H_att = [−C₀₀ C₂₀, −C₁₀ C₂₀, C₀₀² + C₁₀²] / (C₀₀² + C₁₀²) = [cos ψ tan θ, sin ψ tan θ, 1]

(θ the pitch): level, the heading sees the down component of δψ alone; pitched, also the
horizontal ones. It observes the attitude block, so every layout (12, 15, ...) takes it; its
``H`` has no other column, so the iekf's ``H T`` is the same row on φ.

Options in **degrees** (a compass's datasheet unit): ``std`` (default 1°), ``r_std``, ``bias``
(std of a constant bias per run); ``scale`` is refused (a heading has no scale factor), the
lever arm has no effect. Default 1 Hz on the IMU clock, from the truth; ``source recorded``
reads ``HEADING_trajectoryN.csv`` (``Time [s]``, ``Heading [rad]``, NaN for none).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.nav.rotations import dcm_to_euler, exp_so3, wrap_angle
from nespm_cli.nav.state import NavState, StateLayout
from nespm_cli.sensors.measurement import Measurement
from nespm_cli.sensors.source import Context, Sensor, SensorOptions, Truth


def yaw_of(C_bn: np.ndarray) -> np.ndarray:
    """Yaw ψ [rad] (...,) in (−π, π] of ``C_bn`` (..., 3, 3) (:func:`~nespm_cli.nav.rotations.dcm_to_euler`)."""
    return dcm_to_euler(C_bn)[..., 2]


def heading_H_att(C_bn: np.ndarray) -> np.ndarray:
    """(..., 3) the heading's Jacobian on δψ (nav frame) at ``C_bn`` (..., 3, 3), module docstring."""
    c00, c10, c20 = C_bn[..., 0, 0], C_bn[..., 1, 0], C_bn[..., 2, 0]
    d = c00 * c00 + c10 * c10
    return np.stack([-c00 * c20 / d, -c10 * c20 / d, np.ones_like(d)], axis=-1)


class HeadingMeasurement(Measurement):
    """Heading of R runs: ``z`` (R, 1) [rad]; ``std`` [rad]; ``R = std²``; innovation wrapped to (−π, π]."""

    def __init__(self, z: np.ndarray, std: float, layout: StateLayout):
        self.z = np.asarray(z, dtype=float)
        self.R = np.eye(1) * float(std) ** 2
        self.layout = layout

    def predict(self, nav: NavState) -> np.ndarray:
        """(R, 1) the yaw of the solution [rad]."""
        return yaw_of(nav.C_bn)[..., None]

    def innovation(self, nav: NavState) -> np.ndarray:
        """(R, 1) ``wrap(z − ψ(C_nav))`` [rad]."""
        return wrap_angle(self.z - self.predict(nav))

    def h(self, X: np.ndarray, nav: NavState) -> np.ndarray:
        """(R, S, 1) ``wrap(ψ(exp([δψ×]) C) − ψ(C))`` for points X (R, S, n)."""
        turned = exp_so3(self.block(X, "att")) @ nav.C_bn[..., None, :, :]
        return wrap_angle(yaw_of(turned) - yaw_of(nav.C_bn)[..., None])[..., None]

    def H(self, nav: NavState) -> np.ndarray:
        """(R, 1, n): :func:`heading_H_att` on the attitude block, zeros elsewhere."""
        H = self.zeros_H(nav)
        H[..., 0, self.layout.slice("att")] = heading_H_att(nav.C_bn)
        return H


@dataclass(frozen=True)
class HeadingOptions(SensorOptions):
    """Heading options (:class:`SensorOptions`), ``std``, ``r_std`` and ``bias`` in **degrees**:
    std 1°, every 1 s, from the truth; ``scale`` must stay 0."""

    std: float = 1.0


class Heading(Sensor):
    """Compass / magnetometer heading, the yaw of the body [rad] (options in degrees)."""

    dim = 1
    labels = ("heading",)
    observes = ("att",)
    Options = HeadingOptions
    default_interval = 1.0
    has_lever = False  # a rotation only: no lever-arm option for a filter's model

    def __init__(self, options: HeadingOptions | None = None):
        super().__init__(options)
        if self.opt.scale:
            raise NespmError(f"--sensor-option {self.name or 'heading'}.scale={self.opt.scale!r}: a heading has no "
                             "scale factor; use bias (degrees) for a constant error")

    def noise_std(self) -> float:
        """The synthetic white noise std [rad] (``std`` is in degrees)."""
        return math.radians(float(self.opt.std))

    def r_std(self) -> float:
        """The filter's std [rad] (``r_std``, else ``std``, in degrees)."""
        return math.radians(float(self.opt.r_std if self.opt.r_std is not None else self.opt.std))

    def true_values(self, truth: Truth) -> np.ndarray:
        """(K, 1) the true yaw [rad]."""
        return yaw_of(truth.C_bn)[:, None]

    def synthesize(self, truth: Truth, seed: int, track: int, runs: np.ndarray) -> np.ndarray:
        """(R, K, 1) ``wrap(ψ + noise + bias)`` [rad]: noise (K,) then the run's bias from its stream."""
        clean = self.true_values(truth)
        K = clean.shape[0]
        gens = [self.rng(seed, track, int(r)) for r in runs]  # one generator per run: its own stream
        noise = np.stack([g.standard_normal((K, 1)) for g in gens]) if gens else np.empty((0, K, 1))
        out = clean + self.noise_std() * noise
        if self.opt.bias:
            bias = np.stack([g.standard_normal(1) for g in gens])[:, None, :]  # (R, 1, 1)
            out = out + math.radians(self.opt.bias) * bias
        return wrap_angle(out)

    def measurement(self, z: np.ndarray, nav: NavState, ctx: Context, layout: StateLayout) -> Measurement:
        return HeadingMeasurement(z, self.r_std(), layout)


__all__ = ["Heading", "HeadingMeasurement", "HeadingOptions", "heading_H_att", "yaw_of"]

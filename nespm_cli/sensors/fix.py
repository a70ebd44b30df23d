"""``fix``: a position fix (USBL, or GNSS at the surface), horizontal or 3-D.

The fix measures the position of its antenna or transponder ``l`` (body frame, from the IMU):
``p_fix = p ⊕ C_bn l``. Its values are ``[lat, lon]`` [rad] (``vertical = false``, a horizontal
fix) or ``[lat, lon, alt]`` [rad, rad, m]; the innovation is taken in local metres,

    ν = ned_offset(p_fix, p_nav) − C l          (first two components, or all three)
    h(x) − h(0) = δp + ((exp([δψ×]) − I) C l)    H = [I on pos, −[(C l)×] on att]

so it observes the position block (``--state 15``). Synthetic fixes come every ``interval``
seconds (default 60) with white noise ``std`` [m] horizontally (``vertical_std`` down), and
``surface_only`` keeps only those taken shallower than ``surface_depth`` (GNSS at the surface);
``source recorded`` reads ``FIX_trajectoryN.csv`` (``Time [s]``, ``Latitude [rad]``,
``Longitude [rad]`` and, for a 3-D fix, ``Altitude [m]``; NaN for none).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.nav.earth import ned_offset
from nespm_cli.nav.rotations import exp_so3_minus_identity, skew
from nespm_cli.nav.state import NavState, StateLayout, position_plus
from nespm_cli.sensors.depth import lever_down
from nespm_cli.sensors.measurement import Measurement
from nespm_cli.sensors.source import MIN_VARIANCE, Context, Sensor, SensorOptions, Truth


def fix_values(pos: np.ndarray, C_bn: np.ndarray, lever, m: int, errors: np.ndarray | None = None) -> np.ndarray:
    """The fix of an antenna at ``lever`` (body, from the IMU) on a vehicle at ``pos`` (..., 3),
    ``C_bn`` (..., 3, 3): ``pos ⊕ C_bn l`` (then ``⊕ errors``, NED metres (..., 3), if given),
    its first ``m`` components ``[lat, lon(, alt)]`` (..., m)."""
    p = position_plus(pos, lever_down(C_bn, np.asarray(lever, dtype=float)))
    if errors is not None:
        p = position_plus(np.broadcast_to(p, np.shape(errors)), errors)
    return p[..., :m]


class FixMeasurement(Measurement):
    """Position fix of R runs: ``z`` (R, m) ``[lat, lon(, alt)]``; ``std`` [m] per NED axis, (m,)
    for every run or (R, m) per run."""

    def __init__(self, z: np.ndarray, lever, std: np.ndarray, layout: StateLayout):
        self.z = np.asarray(z, dtype=float)
        self.lever = np.asarray(lever, dtype=float)
        var = np.asarray(std, dtype=float) ** 2
        self.R = var[..., None] * np.eye(var.shape[-1])
        self.layout = layout

    def predict(self, nav: NavState) -> np.ndarray:
        return position_plus(nav.pos, lever_down(nav.C_bn, self.lever))[..., : self.dim]

    def innovation(self, nav: NavState) -> np.ndarray:
        m = self.dim
        full = np.concatenate([self.z, nav.pos[..., m:]], axis=-1)  # a horizontal fix: no vertical part
        return (ned_offset(full, nav.pos) - lever_down(nav.C_bn, self.lever))[..., :m]

    def h(self, X: np.ndarray, nav: NavState) -> np.ndarray:
        dp, dpsi = self.block(X, "pos"), self.block(X, "att")
        u = np.broadcast_to(lever_down(nav.C_bn, self.lever)[..., None, :], dpsi.shape)
        turn = (exp_so3_minus_identity(dpsi) @ u[..., None])[..., 0]
        return (dp + turn)[..., : self.dim]

    def H(self, nav: NavState) -> np.ndarray:
        m = self.dim
        H = self.zeros_H(nav)
        p, a = self.layout.slice("pos"), self.layout.slice("att")
        H[..., :, p] = np.eye(3)[:m]
        H[..., :, a] = -skew(lever_down(nav.C_bn, self.lever))[..., :m, :]
        return H

    def H_invariant(self, nav: NavState) -> None:
        """None: the iekf uses ``H T`` (docs/iekf.md). A fix is the textbook left-invariant
        observation ``Y = X b``, ``b = (l, 0, 1)`` (the antenna's position ``p + C l``); with the
        right-invariant error its Jacobian ``[I on ρ_p, −[(p + C l)×] on φ]`` (first m rows) depends
        on the state, through the group position ``p`` that a measurement does not know."""
        return None


@dataclass(frozen=True)
class FixOptions(SensorOptions):
    """Position fix options (:class:`SensorOptions` and): ``vertical`` (a 3-D fix), ``vertical_std``
    [m] (None: ``std``), ``surface_only`` with ``surface_depth`` [m]. Defaults: horizontal, std 1 m,
    every 60 s."""

    std: float = 1.0
    vertical: bool = False
    vertical_std: float | None = None
    surface_only: bool = False
    surface_depth: float = 1.0


class Fix(Sensor):
    """A horizontal (default) or 3-D position fix."""

    labels = ("lat", "lon", "alt")
    observes = ("pos", "att")
    Options = FixOptions
    default_interval = 60.0

    def __init__(self, options: FixOptions | None = None):
        super().__init__(options)
        o = self.opt
        if o.vertical_std is not None and not (math.isfinite(o.vertical_std) and o.vertical_std**2 >= MIN_VARIANCE):
            raise NespmError(f"--sensor-option fix.vertical_std={o.vertical_std!r}: must be a positive std "
                             f"(at least {math.sqrt(MIN_VARIANCE):.2g}, so that its square does not underflow)")
        if not (math.isfinite(o.surface_depth) and o.surface_depth >= 0):
            raise NespmError(f"--sensor-option fix.surface_depth={o.surface_depth!r}: must be a depth >= 0 m")

    @property
    def dim(self) -> int:  # type: ignore[override]
        return 3 if self.opt.vertical else 2

    def recorded(self, track):
        """The track's recorded fixes; a file without altitude refused with ``vertical`` (one line)."""
        rec = super().recorded(track)
        if rec is not None and self.opt.vertical and np.shape(rec[1])[-1] == 2:
            raise NespmError(f"--sensor-option fix.vertical=true: track {track.number}'s recorded fix file has no "
                             "altitude column (FIX_trajectoryN.csv, docs/data-format.md); drop fix.vertical or "
                             "add the column")
        return rec

    def stds(self, filter_side: bool) -> np.ndarray:
        """Per-axis std [m] (m,): the synthetic noise, or the filter's with ``filter_side``."""
        h = self.r_std() if filter_side else self.noise_std()
        v = self.opt.vertical_std if self.opt.vertical_std is not None else h
        return np.array([h, h, v])[: self.dim]

    def R(self) -> np.ndarray:
        return np.diag(self.stds(True) ** 2)

    def true_values(self, truth: Truth) -> np.ndarray:
        return fix_values(truth.pos, truth.C_bn, self.opt.lever_arm, self.dim)

    def synthesize(self, truth: Truth, seed: int, track: int, runs: np.ndarray) -> np.ndarray:
        """Fixes (R, K, m): the antenna's true position moved by a NED error [m] of white noise
        (``std``, ``vertical_std``) plus a constant per-run ``bias`` (its own stream)."""
        K, m = len(truth.t), self.dim
        std = np.concatenate([self.stds(False), [0.0] * (3 - m)])
        errors = np.empty((len(runs), K, 3))
        for i, r in enumerate(runs):
            g = self.rng(seed, track, int(r))
            errors[i] = g.standard_normal((K, 3)) * std
            if self.opt.bias:
                errors[i] = errors[i] + g.standard_normal(3) * self.opt.bias * (std > 0)
        return fix_values(truth.pos, truth.C_bn, self.opt.lever_arm, m, errors)

    def available_extra(self, truth: Truth) -> np.ndarray | None:
        if not self.opt.surface_only:
            return None
        return -truth.pos[:, 2] <= self.opt.surface_depth

    def measurement(self, z: np.ndarray, nav: NavState, ctx: Context, layout: StateLayout) -> Measurement:
        return FixMeasurement(z, self.opt.lever_arm, self.stds(True), layout)


__all__ = ["Fix", "FixMeasurement", "FixOptions", "fix_values"]

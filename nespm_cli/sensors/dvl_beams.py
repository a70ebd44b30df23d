"""``dvl-beams``: the four Janus beam velocities of a DVL, each a scalar measurement (tightly coupled).

Beam ``i`` (1..4) points, in the body frame (x forward, y starboard, z down), at azimuth
``α_i = 45° + 90° (i − 1)`` from x towards y and at ``beam_angle`` θ from the body z axis
(the "X" Janus layout, docs/sensors.md has the table):

    b_i = [sin θ cos α_i, sin θ sin α_i, cos θ]          d_i = b_iᵀ (C_bnᵀ v_n + ω_nb × l)

the projection of the mounting point's velocity (the ``dvl`` sensor's model,
:func:`nespm_cli.nav.dvl.dvl_velocity`) on the beam, positive when the DVL moves along the beam.
Its change for error-state points is the beam matrix ``B`` (4, 3) times the DVL's
(:func:`~nespm_cli.sensors.dvl.dvl_h`), its Jacobian ``B`` times the DVL's ``H`` (and the iekf's
closed form ``B`` times the DVL's invariant ``H``).

**A lost beam** is a NaN component of the values (a NaN cell of the recorded file, a
``beam_outage`` window, a ``beam_dropout`` draw). The :class:`BeamMeasurement` keeps m = 4 and
masks that row: its H row and ``h`` row are zero, its innovation zero, its R row and column unit.
The row is then decoupled from the others (S has a unit diagonal entry and zero off-diagonals
there), so the gain's column is zero and the update is that of the available beams alone; runs
that miss different beams at the same time stay in one batched update. Its NIS ``νᵀ S⁻¹ ν``
gets 0 from the masked row: the dof of that measurement is the number of available beams.
A row with no beam at all is no measurement (the run is skipped, as any missing measurement).

**Noise.** Per beam white noise ``std`` [m/s]; its default (None) is the beam std whose
four-beam least-squares velocity has the body DVL's 0.02 m/s horizontally:
``σ_b = 0.02 √2 sin θ`` (:func:`equivalent_std`; 0.01195 m/s at 25°); the LS covariance is
``σ_b² (BᵀB)⁻¹ = σ_b² diag(1/(2 sin²θ), 1/(2 sin²θ), 1/(4 cos²θ))``, isotropic (exactly the
body DVL's ``0.02² I``) at θ = atan √2 = 54.7356°. The filter's std (``r_std`` None) is ``std``
for a synthetic source, and the beam std equivalent to the DVL's recorded 0.1 m/s for a
recorded one. ``bias`` and ``scale`` are drawn per run **and beam**.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.nav.dvl import dvl_velocity
from nespm_cli.nav.state import NavState, StateLayout
from nespm_cli.sensors.dvl import body_rate, dvl_H, dvl_h, invariant_dvl_H
from nespm_cli.sensors.measurement import Measurement
from nespm_cli.sensors.source import Context, Sensor, SensorOptions, Truth, parse_windows

N_BEAMS = 4
DVL_STD_SYNTHETIC = 0.02  # [m/s] the body DVL's default synthetic noise (and filter std)
DVL_STD_RECORDED = 0.1  # [m/s] the body DVL's filter std with a recorded DVL
#: sub-stream of the per-beam dropout draws (1 is the common ``dropout``'s)
BEAM_DROPOUT_SUB = 2


def beam_directions(beam_angle_deg: float) -> np.ndarray:
    """Unit beam directions ``B`` (4, 3) in the body frame: row i-1 is beam i at azimuth
    45° + 90° (i − 1) from x towards y, ``beam_angle_deg`` [deg] from the body z (down) axis."""
    th = math.radians(beam_angle_deg)
    az = np.deg2rad(45.0 + 90.0 * np.arange(N_BEAMS))
    return np.column_stack([np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), np.full(N_BEAMS, np.cos(th))])


def equivalent_std(velocity_std: float, beam_angle_deg: float) -> float:
    """The beam std [m/s] whose four-beam least-squares velocity has std ``velocity_std`` [m/s] in
    the body x and y axes: ``velocity_std √2 sin θ`` (``(BᵀB)⁻¹`` has ``1/(2 sin²θ)`` there)."""
    return float(velocity_std * math.sqrt(2.0) * math.sin(math.radians(beam_angle_deg)))


def parse_beam_outage(text: str, where: str) -> list[tuple[tuple[int, ...], list[tuple[float, float]]]]:
    """``"1,2@180:240;3@300:310,400:410"`` -> ``[((1, 2), [(180, 240)]), ((3,), [(300, 310), (400, 410)])]``:
    beams (1..4) lost in windows [s since the first epoch], entries separated by ``;``. One-line
    :class:`NespmError` naming ``where`` on a bad entry."""
    out = []
    for part in str(text or "").split(";"):
        if not part.strip():
            continue
        m = re.fullmatch(r"\s*([0-9,\s]+)@(.+)", part)
        if m is None:
            raise NespmError(f"{where}: expected BEAMS@START:END[;BEAMS@START:END] (e.g. 1,2@180:240), "
                             f"got {part.strip()!r}")
        try:
            beams = tuple(sorted({int(b) for b in m.group(1).split(",") if b.strip()}))
        except ValueError:
            raise NespmError(f"{where}: beams are numbers 1..{N_BEAMS} separated by commas, "
                             f"got {m.group(1)!r}") from None
        if not beams or beams[0] < 1 or beams[-1] > N_BEAMS:
            raise NespmError(f"{where}: beams are numbered 1..{N_BEAMS}, got {m.group(1).strip()!r}")
        out.append((beams, parse_windows(m.group(2), where)))
    return out


def beam_window_mask(t: np.ndarray, entries) -> np.ndarray:
    """(K, 4) True where a beam is lost by an entry of :func:`parse_beam_outage` at times ``t`` (K,)
    [s]; a window is ``[start, end)`` as the common ``outage``."""
    t = np.asarray(t, dtype=float)
    lost = np.zeros((len(t), N_BEAMS), dtype=bool)
    for beams, windows in entries:
        inside = np.zeros(len(t), dtype=bool)
        for a, b in windows:
            inside |= (t >= a - 1e-9) & (t < b - 1e-9)
        lost[:, np.asarray(beams) - 1] |= inside[:, None]
    return lost


class BeamMeasurement(Measurement):
    """The four beam velocities of R runs (module docstring), NaN components masked.

    Args:
        z: (R, 4) measured beam velocities [m/s], NaN for a lost beam.
        w_nb: (R, 3) body rate relative to NED from the compensated gyro [rad/s].
        lever: (3,) DVL position from the IMU, body frame [m].
        B: (4, 3) unit beam directions in the body frame (:func:`beam_directions`).
        std: filter noise std per beam [m/s].
        layout: the filter's error-state layout.
    """

    def __init__(self, z: np.ndarray, w_nb: np.ndarray, lever, B: np.ndarray, std: float, layout: StateLayout):
        z = np.asarray(z, dtype=float)
        #: (R, 4) whether each beam is available
        self.mask = np.isfinite(z)
        self.z = np.where(self.mask, z, 0.0)
        self.w_nb = w_nb
        self.lever = np.asarray(lever, dtype=float)
        self.B = np.asarray(B, dtype=float)
        var = np.where(self.mask, float(std) ** 2, 1.0)  # unit variance on a masked row
        self.R = var[..., None] * np.eye(N_BEAMS)  # (R, 4, 4)
        self.layout = layout

    def predict(self, nav: NavState) -> np.ndarray:
        """(R, 4) ``B (C_bnᵀ v_n + ω_nb × l)`` [m/s] (every beam, masked or not)."""
        return dvl_velocity(nav.C_bn, nav.v_n, self.w_nb, self.lever) @ self.B.T

    def innovation(self, nav: NavState) -> np.ndarray:
        """(R, 4) measured minus predicted, zero on a masked row."""
        return np.where(self.mask, self.z - self.predict(nav), 0.0)

    def h(self, X: np.ndarray, nav: NavState) -> np.ndarray:
        """(R, S, 4) ``B (h_dvl(x) − h_dvl(0))`` for points X (R, S, n), zero on a masked row."""
        d = dvl_h(self.block(X, "vel"), self.block(X, "att"), self.block(X, "bg"), nav, self.lever)
        return np.where(self.mask[..., None, :], d @ self.B.T, 0.0)

    def H(self, nav: NavState) -> np.ndarray:
        """(R, 4, n) ``B H_dvl``, zero rows where masked."""
        return np.where(self.mask[..., None], self.B @ dvl_H(nav, self.lever, self.layout), 0.0)

    def H_invariant(self, nav: NavState) -> np.ndarray:
        """(R, 4, n) ``B H_dvl,inv`` (no attitude column), zero rows where masked."""
        return np.where(self.mask[..., None], self.B @ invariant_dvl_H(nav.C_bn, self.lever, self.layout), 0.0)


@dataclass(frozen=True)
class BeamOptions(SensorOptions):
    """DVL beam options (:class:`SensorOptions` and): ``beam_angle`` [deg] from the body z axis, in
    (0, 90), default 25; ``beam_outage`` ``BEAMS@START:END[;...]`` beams lost in windows [s];
    ``beam_dropout`` the probability each beam is lost, per run and time. ``std`` [m/s] per beam,
    None: :func:`equivalent_std` of 0.02 m/s. Default source synthetic, at the GT epochs."""

    std: float | None = None
    beam_angle: float = 25.0
    beam_outage: str = ""
    beam_dropout: float = 0.0


class DvlBeams(Sensor):
    """The four Janus beams of a DVL (module docstring)."""

    dim = N_BEAMS
    labels = ("beam1", "beam2", "beam3", "beam4")
    observes = ("vel", "att")
    Options = BeamOptions
    default_interval = None  # at the GT epochs, as the DVL

    def __init__(self, options: BeamOptions | None = None):
        super().__init__(options)
        o = self.opt
        name = f"--sensor-option {self.name or 'dvl-beams'}"
        if not (isinstance(o.beam_angle, (int, float)) and math.isfinite(o.beam_angle) and 0.0 < o.beam_angle < 90.0):
            raise NespmError(f"{name}.beam_angle={o.beam_angle!r}: must be an angle in (0, 90) degrees from the "
                             "body z axis (typically 20-30)")
        if not (isinstance(o.beam_dropout, (int, float)) and 0.0 <= o.beam_dropout < 1.0):
            raise NespmError(f"{name}.beam_dropout={o.beam_dropout!r}: must be a probability in [0, 1)")
        #: the parsed ``beam_outage`` entries
        self.outages = parse_beam_outage(o.beam_outage, f"{name}.beam_outage")
        #: (4, 3) unit beam directions, body frame
        self.B = beam_directions(o.beam_angle)

    def noise_std(self) -> float:
        if self.opt.std is not None:
            return float(self.opt.std)
        return equivalent_std(DVL_STD_SYNTHETIC, self.opt.beam_angle)

    def r_std(self) -> float:
        if self.opt.r_std is not None:
            return float(self.opt.r_std)
        if self.opt.source == "recorded" and self.opt.std is None:
            return equivalent_std(DVL_STD_RECORDED, self.opt.beam_angle)
        return self.noise_std()

    def true_values(self, truth: Truth) -> np.ndarray:
        """(K, 4) the beam velocities ``B (C_bnᵀ v_n + ω_nb × l)`` [m/s] at the truth."""
        v = dvl_velocity(truth.C_bn, truth.v_n, truth.w_nb_b, np.asarray(self.opt.lever_arm, dtype=float))
        return v @ self.B.T

    def synthesize(self, truth: Truth, seed: int, track: int, runs: np.ndarray) -> np.ndarray:
        """(R, K, 4): per beam ``d (1 + scale) + bias + noise``; noise (K, 4), then bias (4,) and scale
        (4,) from the run's stream (noise first, so bias or scale never move the noise draws)."""
        clean = self.true_values(truth)
        K = clean.shape[0]
        gens = [self.rng(seed, track, int(r)) for r in runs]  # one generator per run: its own stream
        noise = np.stack([g.standard_normal((K, N_BEAMS)) for g in gens]) if gens else np.empty((0, K, N_BEAMS))
        out = clean + self.noise_std() * noise
        if self.opt.bias or self.opt.scale:
            draws = np.stack([g.standard_normal(2 * N_BEAMS) for g in gens]).reshape(len(gens), 1, 2, N_BEAMS)
            out = out + clean * (draws[:, :, 1] * self.opt.scale) + draws[:, :, 0] * self.opt.bias
        return out

    def lose_components(self, values: np.ndarray, t: np.ndarray, seed: int, track: int,
                        runs: np.ndarray) -> np.ndarray:
        """NaN where a beam is lost: ``beam_outage`` windows (every run) and ``beam_dropout`` draws
        (per run, time and beam, from the sensor's sub-stream :data:`BEAM_DROPOUT_SUB`)."""
        lost = np.broadcast_to(beam_window_mask(t, self.outages), np.shape(values))
        if self.opt.beam_dropout > 0:
            u = np.stack([self.rng(seed, track, int(r), sub=BEAM_DROPOUT_SUB).random((len(t), N_BEAMS))
                          for r in runs]) if len(runs) else np.empty((0, len(t), N_BEAMS))
            lost = lost | (u < self.opt.beam_dropout)
        if not lost.any():
            return values
        return np.where(lost, np.nan, values)

    def present(self, values: np.ndarray) -> np.ndarray:
        """(R, K) a measurement wherever at least one beam is available."""
        return np.isfinite(values).any(axis=-1)

    def measurement(self, z: np.ndarray, nav: NavState, ctx: Context, layout: StateLayout) -> Measurement:
        return BeamMeasurement(z, body_rate(nav, ctx.w_ib_b), self.opt.lever_arm, self.B, self.r_std(), layout)


__all__ = ["BEAM_DROPOUT_SUB", "BeamMeasurement", "BeamOptions", "DvlBeams", "N_BEAMS", "beam_directions",
           "beam_window_mask", "equivalent_std", "parse_beam_outage"]

"""Virtual sensors of gp-ukf.md section 6: DVL, gyroscope, accelerometer, compass, depth sensor.

"Each sensor was simulated by a model comprising an additive noise source and digitalisation of
the measurement through a 12-bit ADC"; the measured vector is

    z = [u, v, w, p, q, r, Z, theta, psi, phi]         (MEASUREMENT_NAMES)

* DVL -> ``u, v, w`` (body velocity over ground, m/s);
* 3-axis gyroscope -> ``p, q, r`` (rad/s);
* depth (pressure) sensor -> ``Z`` (m, positive down);
* 3-axis accelerometer -> ``theta, phi`` as an inclinometer (rad): the paper's vector holds the
  angles, not the specific force, so the accelerometer is modelled by its tilt output;
* compass -> ``psi`` (rad, wrapped to (-pi, pi]).

Model of every component: ``z_i = Q_i(h_i(x) + sigma_i * xi_i)`` with ``xi ~ N(0, 1)`` and
``Q_i`` a 12-bit mid-tread quantiser over ``[lo_i, hi_i]`` (4096 levels, LSB
``(hi - lo) / 4095``, clipped at the ends). The paper gives neither noise levels nor ranges; the
defaults of :class:`SensorSuite` are documented choices (docs/remus100.md).

Noise is drawn from numpy Generators passed in (one per run, seeded from
``SeedSequence(seed, spawn_key=(run, stream))`` by :mod:`.simulate`), so a run's noise depends on
nothing but its seed and index.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from nespm_cli.nav.rotations import wrap_angle
from nespm_cli.vehicles.remus100 import IP, IPHI, IPSI, IQ, IR, ITHETA, IU, IV, IW, IZ

MEASUREMENT_NAMES = ("u", "v", "w", "p", "q", "r", "Z", "theta", "psi", "phi")
#: index into the 12-state vector of each measured component
MEASURED_STATES = (IU, IV, IW, IP, IQ, IR, IZ, ITHETA, IPSI, IPHI)
I_PSI_MEAS = 8  # position of psi in the measured vector (wrapped)


@dataclass(frozen=True)
class Channel:
    """One measured component: white noise std and the quantiser range.

    Attributes:
        sensor: the physical sensor ("dvl", "gyro", "depth", "accelerometer", "compass").
        sigma: additive white Gaussian noise std, in the component's unit.
        lo, hi: quantiser range [unit]; values outside are clipped (saturation).
    """

    sensor: str
    sigma: float
    lo: float
    hi: float


def _default_channels() -> tuple[Channel, ...]:
    dvl = Channel("dvl", 0.01, -2.5, 2.5)  # [m/s]: 1 cm/s noise; +-2.5 m/s (REMUS 100 max speed)
    gyro = Channel("gyro", 1.0e-3, -1.0, 1.0)  # [rad/s]: 0.057 deg/s; +-57 deg/s
    depth = Channel("depth", 0.05, 0.0, 100.0)  # [m]: 5 cm; 0-100 m (REMUS 100 depth rating)
    pitch = Channel("accelerometer", float(np.radians(0.2)), -np.pi / 2, np.pi / 2)  # [rad]
    compass = Channel("compass", float(np.radians(0.5)), -np.pi, np.pi)  # [rad]
    roll = Channel("accelerometer", float(np.radians(0.2)), -np.pi, np.pi)  # [rad]
    return (dvl, dvl, dvl, gyro, gyro, gyro, depth, pitch, compass, roll)


@dataclass(frozen=True)
class SensorSuite:
    """The 10 channels of the measured vector (order :data:`MEASUREMENT_NAMES`) and the ADC bits.

    Defaults (documented choices, see docs/remus100.md): DVL 0.01 m/s over +-2.5 m/s; gyro
    1e-3 rad/s over +-1 rad/s; depth 0.05 m over 0-100 m; pitch and roll (accelerometer tilt)
    0.2 deg over +-90 / +-180 deg; compass 0.5 deg over +-180 deg; 12 bits.
    """

    channels: tuple[Channel, ...] = field(default_factory=_default_channels)
    bits: int = 12

    def __post_init__(self) -> None:
        if len(self.channels) != len(MEASUREMENT_NAMES):
            raise ValueError(f"SensorSuite needs {len(MEASUREMENT_NAMES)} channels, got {len(self.channels)}")

    @property
    def sigma(self) -> np.ndarray:
        """(10,) noise std of every channel."""
        return np.array([c.sigma for c in self.channels])

    @property
    def lo(self) -> np.ndarray:
        return np.array([c.lo for c in self.channels])

    @property
    def hi(self) -> np.ndarray:
        return np.array([c.hi for c in self.channels])

    @property
    def lsb(self) -> np.ndarray:
        """(10,) quantisation step ``(hi - lo) / (2**bits - 1)``."""
        return (self.hi - self.lo) / (2**self.bits - 1)

    def noiseless(self) -> "SensorSuite":
        """The same ranges and bits with zero noise (quantisation only)."""
        return SensorSuite(tuple(Channel(c.sensor, 0.0, c.lo, c.hi) for c in self.channels), self.bits)


def true_measurement(x: np.ndarray) -> np.ndarray:
    """h(x) (..., 10): the measured components of states ``x`` (..., 12), psi wrapped."""
    h = x[..., list(MEASURED_STATES)]
    h[..., I_PSI_MEAS] = wrap_angle(h[..., I_PSI_MEAS])
    return h


def quantize(value: np.ndarray, lo: np.ndarray, hi: np.ndarray, bits: int = 12) -> np.ndarray:
    """Mid-tread ``bits``-bit ADC over ``[lo, hi]``: nearest of the ``2**bits`` levels
    ``lo + k (hi - lo) / (2**bits - 1)``, values outside the range clipped to the end levels."""
    levels = 2**bits - 1
    step = (hi - lo) / levels
    k = np.clip(np.rint((value - lo) / step), 0, levels)
    return lo + k * step


def draw_noise(rngs: Sequence[np.random.Generator], n_samples: int) -> np.ndarray:
    """Standard-normal draws (R, n_samples, 10), one Generator per run (row r from ``rngs[r]``).

    Runs are independent streams, so row r does not depend on the other runs in the batch.
    """
    return np.stack([g.standard_normal((n_samples, len(MEASUREMENT_NAMES))) for g in rngs])


def measure(x: np.ndarray, xi: np.ndarray, suite: SensorSuite) -> np.ndarray:
    """Measured vector z (..., 10) of states ``x`` (..., 12) with standard-normal draws ``xi`` (..., 10).

    ``z = Q(h(x) + sigma * xi)``; the compass reading is wrapped before quantisation.
    """
    y = true_measurement(x) + suite.sigma * xi
    y[..., I_PSI_MEAS] = wrap_angle(y[..., I_PSI_MEAS])
    return quantize(y, suite.lo, suite.hi, suite.bits)


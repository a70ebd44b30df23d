"""The track: ground truth and DVL of one run, as every loader and generator returns it (or, for recorded
data without a ground truth, its initial state only: :attr:`Track.truth`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nespm_cli.nav.rotations import euler_to_dcm


@dataclass(frozen=True, eq=False)
class Track:
    """One ground-truth track with its DVL record (all arrays read-only).

    Attributes:
        number: track number N (``TrajectoryN``).
        t: (N,) time [s], strictly increasing, as in the file (not shifted to 0).
        pos: (N, 3) ``[lat rad, lon rad, alt m]``, alt positive up (negative below the surface).
        v_n: (N, 3) NED velocity [m/s].
        euler: (N, 3) ``[roll, pitch, yaw]`` [rad], ZYX, body -> NED.
        dvl: (N, 3) body-frame DVL velocity [m/s] on the epochs ``t``; a NaN row is an epoch without
            a DVL measurement (NaN in all three columns of the file).
        imu: (M, 7) ``[t s, fx, fy, fz m/s^2, wx, wy, wz rad/s]`` recorded IMU, or None.
        source: the ``TrajectoryN`` folder the track was read from, or ``"embedded"``.
        channels: optional recorded sensor files, ``{name: (t, z)}`` with ``t`` (K,) the file time [s]
            (the clock of :attr:`t`, not shifted) and ``z`` (K, m) the values, a NaN row meaning no
            measurement at that stamp: ``"depth"`` (m = 1, depth [m] positive down) and ``"fix"``
            (m = 2 or 3, ``[lat rad, lon rad(, alt m)]``), see :mod:`nespm_cli.data.sensor_files`.
            Empty for the embedded tracks and when a folder has no such file.
        truth: False for a track without ground truth (a track spec without ``[gt]``, with ``[init]``;
            docs/data.md): ``t`` are then the DVL's epochs, ``pos``, ``v_n``, ``euler`` hold the initial
            state ``[init]`` in their first row and NaN in every other (nothing may be compared with them:
            errors against the truth are not produced), ``imu`` is the recorded IMU (required).
    """

    number: int
    t: np.ndarray
    pos: np.ndarray
    v_n: np.ndarray
    euler: np.ndarray
    dvl: np.ndarray
    imu: np.ndarray | None
    source: str
    channels: dict = field(default_factory=dict)
    truth: bool = True

    def __post_init__(self) -> None:
        n = len(self.t)
        for name in ("pos", "v_n", "euler", "dvl"):
            if np.shape(getattr(self, name)) != (n, 3):
                shape = np.shape(getattr(self, name))
                raise ValueError(f"Track.{name} must have shape ({n}, 3), got {shape}")
        if self.imu is not None and (np.ndim(self.imu) != 2 or np.shape(self.imu)[1] != 7):
            raise ValueError(f"Track.imu must have shape (M, 7), got {np.shape(self.imu)}")
        for name in ("t", "pos", "v_n", "euler", "dvl", "imu"):
            a = getattr(self, name)
            if a is not None:
                a = np.array(a, dtype=float)  # private copy, then frozen
                a.flags.writeable = False
                object.__setattr__(self, name, a)
        object.__setattr__(self, "channels", {str(k): _channel(k, v) for k, v in dict(self.channels or {}).items()})
        if not self.truth:
            if self.imu is None:
                raise ValueError("Track without truth needs its recorded imu")
            known = np.isfinite(np.column_stack([self.pos, self.v_n, self.euler]))
            if n == 0 or not known[0].all() or known[1:].any():
                raise ValueError("Track without truth: pos, v_n, euler must hold the initial state in their "
                                 "first row and NaN in every other")

    @property
    def C_bn(self) -> np.ndarray:
        """(N, 3, 3) body -> NED direction cosine matrices from :attr:`euler`."""
        return euler_to_dcm(self.euler)

    @property
    def initial(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(pos (3,), v_n (3,), euler (3,))`` at the first epoch: the truth's, or ``[init]`` without one."""
        return self.pos[0], self.v_n[0], self.euler[0]

    @property
    def duration(self) -> float:
        """Time span ``t[-1] - t[0]`` [s]."""
        return float(self.t[-1] - self.t[0])


def _channel(name, value) -> tuple[np.ndarray, np.ndarray]:
    """``(t (K,), z (K, m))`` private read-only float copies of a channel entry (a 1-D ``z`` is one column)."""
    try:
        t, z = value
    except (TypeError, ValueError):
        raise ValueError(f"Track.channels[{name!r}] must be a pair (t, z)") from None
    t, z = np.array(t, dtype=float), np.array(z, dtype=float)
    if z.ndim == 1:
        z = z.reshape(-1, 1)
    if t.ndim != 1 or z.ndim != 2 or len(z) != len(t):
        raise ValueError(f"Track.channels[{name!r}] must be t (K,) and z (K, m), got {t.shape} and {z.shape}")
    t.flags.writeable = False
    z.flags.writeable = False
    return t, z

"""100 Hz truth and clean IMU from 1 Hz ground truth (inverse strapdown).

The IMU grid divides every GT interval into ``substeps`` equal steps (100 by default;
the Snapir GT step is 400/399 s, so the IMU step is 10.025 ms), so that every GT and DVL
epoch is an IMU sample. Velocity is interpolated with a not-a-knot cubic spline and
attitude with a rotation spline (C2 in angle), both exact at the GT epochs; position is
integrated from velocity with the trapezoid of eqs 28-30. The clean specific force and
angular rate are then solved step by step from :func:`strapdown.na_cycle_inverse`, so
feeding them to ``na_cycle`` from the initial truth reproduces the truth to round-off.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nespm_cli.nav.earth import height_rate, lat_rate, lon_rate, radii
from nespm_cli.errors import NespmError
from nespm_cli.nav.rotations import euler_to_dcm
from nespm_cli.nav.strapdown import na_cycle_inverse

DEFAULT_IMU_RATE = 100.0  # [Hz] the synthesized IMU's rate (the papers')


@dataclass(frozen=True)
class ImuTruth:
    """A 100 Hz truth trajectory and the IMU that reproduces it.

    Attributes (M IMU steps, M+1 samples, N GT epochs):
        t: (M+1,) sample times [s].
        dt: (M,) step durations [s]; step j goes from sample j to j+1.
        pos, v_n: (M+1, 3) truth ``[lat, lon, h]`` and NED velocity.
        C_bn: (M+1, 3, 3) truth attitude.
        f_b, w_ib_b: (M, 3) clean specific force [m/s^2] and angular rate [rad/s] of step j.
        epoch_index: (N,) index into ``t`` of every GT epoch.
        exact: True when the IMU was synthesized (truth is exact), False for a recorded IMU.
        known: False for a track without ground truth (``Track.truth`` False): ``pos``, ``v_n``, ``C_bn``
            hold the initial state at the first epoch's sample and NaN at every other (what the filters
            start from; nothing to compare an estimate with).
    """

    t: np.ndarray
    dt: np.ndarray
    pos: np.ndarray
    v_n: np.ndarray
    C_bn: np.ndarray
    f_b: np.ndarray
    w_ib_b: np.ndarray
    epoch_index: np.ndarray
    exact: bool = True
    known: bool = True

    @property
    def steps(self) -> int:
        return len(self.dt)


def integrate_position(pos0: np.ndarray, v_n: np.ndarray, dt: np.ndarray, iters: int = 4) -> np.ndarray:
    """Integrate eqs 28-30 from ``pos0`` (3,) over velocities ``v_n`` (M+1, 3) -> (M+1, 3).

    This is :func:`strapdown.update_position` applied step after step (same rates
    :func:`earth.height_rate`, :func:`earth.lat_rate`, :func:`earth.lon_rate`, same reading
    of eq 29 with R_N at L_k for both trapezoid terms), kept as a separate function because
    a Python loop over 40,000 samples is slow: the recursion only depends on L_k through
    the slowly varying radii, so it is solved by a vectorized fixed-point iteration on
    cumulative sums (converged to round-off in about three passes).
    """
    half = 0.5 * dt
    rate_h = height_rate(v_n[:, 2])
    h = pos0[2] + np.concatenate([[0.0], np.cumsum((rate_h[1:] + rate_h[:-1]) * half)])
    lat = np.full(len(v_n), pos0[0])
    for _ in range(iters):
        R_N, _ = radii(lat[:-1])
        dlat = (lat_rate(v_n[:-1, 0], h[:-1], R_N) + lat_rate(v_n[1:, 0], h[1:], R_N)) * half
        lat = pos0[0] + np.concatenate([[0.0], np.cumsum(dlat)])
    _, R_E = radii(lat)
    rate = lon_rate(v_n[:, 1], lat, h, R_E)
    lon = pos0[1] + np.concatenate([[0.0], np.cumsum((rate[:-1] + rate[1:]) * half)])
    return np.stack([lat, lon, h], axis=-1)


def truth_on_grid(track, t: np.ndarray, epoch_index: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Truth ``(pos, v_n, C_bn)`` on the sample times ``t`` (M+1,) from the GT of ``track``.

    Velocity: not-a-knot cubic spline; attitude: rotation spline; both exact at the GT epochs
    (``t[epoch_index] == track.t``). Position: eqs 28-30 integrated from that velocity
    (:func:`integrate_position`) from the first GT position.
    """
    from scipy.interpolate import CubicSpline  # here: importing scipy costs ~0.4 s (CLI start-up)
    from scipy.spatial.transform import Rotation, RotationSpline

    t_gt = np.asarray(track.t, dtype=float)
    v_n = CubicSpline(t_gt, track.v_n, axis=0, bc_type="not-a-knot")(t)
    v_n[epoch_index] = track.v_n
    C_gt = euler_to_dcm(track.euler)
    C_bn = RotationSpline(t_gt, Rotation.from_matrix(C_gt))(t).as_matrix()
    C_bn[epoch_index] = C_gt
    pos = integrate_position(np.asarray(track.pos[0], dtype=float), v_n, np.diff(t))
    return pos, v_n, C_bn


def synthesize(track, substeps: int = 100) -> ImuTruth:
    """Build the 100 Hz truth and the clean IMU of ``track`` (a :class:`tracks.Track`).

    Cost: about 0.06 s for a 400 s track (39,900 steps), all vectorized. A track without ground truth
    (``track.truth`` False) is refused: the IMU is synthesized from the truth.
    """
    if not getattr(track, "truth", True):
        raise NespmError(f"--imu synthetic: track {track.number} has no ground truth to synthesize the IMU from "
                         "(its track spec has no [gt]); use --imu recorded")
    t_gt = np.asarray(track.t, dtype=float)
    n = len(t_gt)
    if n < 4:
        raise NespmError(f"track {track.number}: needs at least 4 GT epochs for IMU synthesis, has {n}")
    frac = np.arange(substeps) / substeps
    t = np.concatenate([(t_gt[:-1, None] + np.diff(t_gt)[:, None] * frac).ravel(), t_gt[-1:]])
    epoch_index = np.arange(n) * substeps
    t[epoch_index] = t_gt  # exact epochs
    pos, v_n, C_bn = truth_on_grid(track, t, epoch_index)
    dt = np.diff(t)
    f_b, w_ib_b = na_cycle_inverse(pos[:-1], v_n[:-1], C_bn[:-1], pos[1:], v_n[1:], C_bn[1:], dt)
    return ImuTruth(t, dt, pos, v_n, C_bn, f_b, w_ib_b, epoch_index, exact=True)


MERGE_TOL = 1e-6  # [s] an IMU sample this close to a GT epoch is taken to be at the epoch


def recorded_grid(t_imu: np.ndarray, t_gt: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The step grid of a recorded IMU between the first and last GT epoch.

    A recorded sample ``i`` holds the mean rate over ``(t_imu[i-1], t_imu[i]]`` (the same
    convention as the synthesized and simulated IMU files). The grid is the union of the IMU
    sample times and the GT epochs inside ``[t_gt[0], t_gt[-1]]``; the IMU step that straddles
    an epoch is split there into two steps with the same reading, so every epoch is a sample
    of the grid and no measurement is interpolated.

    Returns ``(t, sample, epoch_index)``: grid times (K+1,) [s], the recorded row (K,) whose
    reading each step takes, and the grid index (N,) of every GT epoch.
    Requires ``t_imu[0] <= t_gt[0]`` and ``t_gt[-1] <= t_imu[-1]`` (within :data:`MERGE_TOL`).
    """
    t_imu = np.asarray(t_imu, dtype=float)
    t_gt = np.asarray(t_gt, dtype=float)
    inside = t_imu[(t_imu > t_gt[0] + MERGE_TOL) & (t_imu < t_gt[-1] - MERGE_TOL)]
    # drop samples within MERGE_TOL of an epoch (the epoch's exact time is kept)
    j = np.clip(np.searchsorted(t_gt, inside), 1, len(t_gt) - 1)
    near = np.minimum(np.abs(inside - t_gt[j - 1]), np.abs(inside - t_gt[j])) <= MERGE_TOL
    t = np.union1d(inside[~near], t_gt)
    epoch_index = np.searchsorted(t, t_gt)
    # step [t[k], t[k+1]] takes the first sample stamped at or after its end
    sample = np.searchsorted(t_imu, t[1:] - MERGE_TOL, side="left")
    return t, np.minimum(sample, len(t_imu) - 1), epoch_index


def from_recorded(track) -> ImuTruth:
    """Use the track's recorded IMU (``track.imu``, (M, 7) ``[t, f, w]``) as the clean IMU.

    The steps are those of :func:`recorded_grid` (the IMU samples, split at the GT epochs);
    the truth on them is :func:`truth_on_grid` (splines through the GT, exact at the epochs,
    where the errors are measured; a track without ground truth: :attr:`ImuTruth.known` False, the
    initial state only). Runs start at the first GT epoch. Apply the track's
    corrections (:func:`nespm_cli.data.corrections.apply_corrections`) first.
    """
    if track.imu is None:
        raise NespmError(f"track {track.number}: --imu recorded needs IMU_trajectory{track.number}.csv")
    imu = np.asarray(track.imu, dtype=float)
    t_imu, t_gt = imu[:, 0], np.asarray(track.t, dtype=float)
    if t_imu[0] > t_gt[0] + MERGE_TOL or t_imu[-1] < t_gt[-1] - MERGE_TOL:
        raise NespmError(
            f"track {track.number}: recorded IMU covers {t_imu[0]:.3f}-{t_imu[-1]:.3f} s, GT "
            f"{t_gt[0]:.3f}-{t_gt[-1]:.3f} s (the IMU must cover the GT epochs; see --window)"
        )
    t, sample, idx = recorded_grid(t_imu, t_gt)
    known = getattr(track, "truth", True)
    if known:
        pos, vel, C = truth_on_grid(track, t, idx)
    else:  # no ground truth: the initial state at the first epoch, nothing elsewhere
        pos, vel, C = np.full((len(t), 3), np.nan), np.full((len(t), 3), np.nan), np.full((len(t), 3, 3), np.nan)
        pos[idx[0]], vel[idx[0]], C[idx[0]] = track.pos[0], track.v_n[0], euler_to_dcm(track.euler[0])
    return ImuTruth(t, np.diff(t), pos, vel, C, imu[sample, 1:4], imu[sample, 4:7], idx, exact=False, known=known)

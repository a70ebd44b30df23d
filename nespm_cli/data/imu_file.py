"""Checks of a recorded IMU table (``IMU_trajectoryN.csv``, or the ``[imu]`` file of a track spec) at load.

:func:`check_imu` runs, in order: time strictly increasing; a navigation-IMU rate (10 Hz - 2 kHz); a constant
step (:data:`IMU_STEP_TOL`); coverage of the GT span; per-sample magnitudes below :data:`IMU_MAX_ACC` and
:data:`IMU_MAX_GYRO`; then the **units against the ground truth** (:func:`check_imu_units`): a gyro logged in
deg/s read as rad/s, or an accelerometer in g read as m/s² (or the reverse), passes the per-sample limits,
so the IMU's own magnitudes are compared with what the GT says they must be:

* **gyro**: per GT interval, the mean recorded rate vector (the IMU samples stamped in that interval; noise
  averages down, the rate's direction is kept) against the GT's attitude rate ``log(C_k^T C_{k+1}) / dt``; the
  ratio of their RMS magnitudes over the span must lie in [1 / :data:`RATE_RATIO_MAX`, :data:`RATE_RATIO_MAX`]
  (a deg/rad factor is 57.3). The GT rate's RMS is floored at :data:`RATE_FLOOR` so that biases and noise on a
  track that hardly turns cannot make a ratio; the low side is judged only when the GT turns (RMS above
  :data:`RATE_TURNING`).
* **accelerometer**: the median |f| over the samples within [:data:`GRAVITY_MIN`, :data:`GRAVITY_MAX`] m/s²
  (local gravity ~9.8; 1 g read as m/s² gives ~1, m/s² read as g ~96).

Measured (gyro RMS ratio; median |f|): the 13 real Snapir IMU files 0.998-1.028 and 9.795-9.799 m/s²
(biases, noise and vibration included); simulated REMUS 100 runs (``nespm simulate``) 0.999 and 9.796;
synthesized IMUs of the 6 embedded tracks with the papers' noise and biases 0.9999-1.0001 and 9.78-9.81.
Every refusal is one line naming
the file, the columns and the unit key to fix (``imu.rate_unit`` of a track spec, or the A-KIT column's unit).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.nav.rotations import euler_to_dcm, log_so3

IMU_STEP_TOL = 0.01  # relative; a time step differing from the file's median step by more than 1 % is a gap
#                      or a non-constant rate (the real Snapir files vary by ~1e-9 relative, 40,000 rows)
IMU_MIN_STEP = 0.0005  # [s]; the median step must be above this (2 kHz) ...
IMU_MAX_STEP = 0.1  # [s]; ... and below this (10 Hz): the range of a navigation IMU (the real files: 100 Hz)
IMU_MAX_ACC = 200.0  # [m/s^2]; |ACC X/Y/Z| above this (~20 g) is a units mistake (mm/s^2, cm/s^2, mg ...)
IMU_MAX_GYRO = 20.0  # [rad/s]; |GYRO X/Y/Z| above this is a units mistake (deg/s ...); an AUV turns < 1 rad/s
RATE_RATIO_MAX = 8.0  # gyro RMS / GT attitude-rate RMS outside [1/8, 8]: a unit factor (deg/rad is 57.3)
RATE_FLOOR = 0.005  # [rad/s] (0.29 deg/s) the GT rate RMS is floored here for the high side (biases, noise)
RATE_TURNING = 0.02  # [rad/s] (1.1 deg/s) the low side is judged only when the GT turns at least this much
GRAVITY_MIN = 4.0  # [m/s^2] median |f| below this: not m/s^2 (g read as m/s^2 gives ~1)
GRAVITY_MAX = 25.0  # [m/s^2] median |f| above this: not m/s^2 (m/s^2 read as g gives ~96)


def check_imu(path: Path, imu: np.ndarray, gt_path: Path, t_gt: np.ndarray, cols: tuple, euler: np.ndarray | None = None,
              keys: tuple = ()) -> None:
    """Checks of a recorded IMU table ``imu`` (M, 7) ``[t s, f_b m/s² (3), w_ib_b rad/s (3)]``, already read.

    In order: time strictly increasing; the median step is a navigation-IMU rate; every step is the
    median step to within :data:`IMU_STEP_TOL`; the IMU covers the GT span ``t_gt`` (N,) (to one step, plus
    :data:`IMU_STEP_TOL` of it, at each end; a time offset applied later, e.g. by the recorded-IMU path, is
    checked there); |ACC| and |GYRO| below :data:`IMU_MAX_ACC` and :data:`IMU_MAX_GYRO`; with the GT attitude
    ``euler`` (N, 3) [rad], the units (:func:`check_imu_units`). ``cols`` name the columns in the messages,
    ``keys`` the spec's unit keys ``(acceleration, rate)`` (empty: an A-KIT file).
    """
    time_col = cols[0]
    t = imu[:, 0]
    bad = np.flatnonzero(np.diff(t) <= 0.0)
    if bad.size:
        r = int(bad[0]) + 1
        raise NespmError(f"{path}: data row {r + 1}, column '{time_col}': time {float(t[r])!r} is not after the "
                         f"previous row's {float(t[r - 1])!r} (must be strictly increasing)")
    dt = np.diff(t)
    step = float(np.median(dt))
    if not IMU_MIN_STEP < step < IMU_MAX_STEP:
        cause = ("time in milliseconds instead of seconds, or not the raw IMU record?" if step >= IMU_MAX_STEP
                 else "time in a unit other than seconds?")
        raise NespmError(
            f"{path}: column '{time_col}': median step {step:.6g} s ({1.0 / step:.6g} Hz) is outside "
            f"{IMU_MIN_STEP:g}-{IMU_MAX_STEP:g} s ({1.0 / IMU_MAX_STEP:g} Hz - {1.0 / IMU_MIN_STEP / 1000:g} kHz) "
            f"of a navigation IMU ({cause})"
        )
    bad = np.flatnonzero(np.abs(dt - step) > IMU_STEP_TOL * step)
    if bad.size:
        r = int(bad[0]) + 1  # 0-based index of the row that ends the irregular step
        raise NespmError(
            f"{path}: data row {r + 1}, column '{time_col}': step {float(dt[r - 1]):.6g} s after the previous row, "
            f"the file's step is {step:.6g} s (gap or non-constant rate; the IMU must be sampled at a constant rate)"
        )
    span = f"{float(t[0]):.6g}-{float(t[-1]):.6g} s"
    gt_span = f"{float(t_gt[0]):.6g}-{float(t_gt[-1]):.6g} s"
    for r, late in ((0, float(t[0] - t_gt[0])), (len(t) - 1, float(t_gt[-1] - t[-1]))):
        if late > step * (1.0 + IMU_STEP_TOL):  # one step (to the step tolerance) short is accepted
            what = "starts" if r == 0 else "ends"
            when = "after the first" if r == 0 else "before the last"
            raise NespmError(
                f"{path}: data row {r + 1}, column '{time_col}': the IMU covers {span} but {gt_path.name} spans "
                f"{gt_span}: it {what} {late:.6g} s {when} GT epoch (more than one IMU step, {step:.6g} s); "
                f"the IMU must cover the GT span"
            )
    limits = np.array([IMU_MAX_ACC] * 3 + [IMU_MAX_GYRO] * 3)
    big = np.abs(imu[:, 1:7]) > limits
    rows = np.flatnonzero(big.any(axis=1))
    if rows.size:
        r = int(rows[0])
        j = int(np.flatnonzero(big[r])[0])
        unit, cause = (("m/s^2", "specific force; mm/s^2, cm/s^2 or mg? m/s^2 expected") if j < 3
                       else ("rad/s", "angular rate; degrees per second? rad/s expected"))
        raise NespmError(
            f"{path}: data row {r + 1}, column '{cols[j + 1]}': |{float(imu[r, j + 1])!r}| > "
            f"{limits[j]:g} {unit} (implausible {cause})"
        )
    if euler is not None:
        check_imu_units(path, imu, t_gt, euler, cols, keys)


def imu_unit_figures(imu: np.ndarray, t_gt: np.ndarray, euler: np.ndarray) -> dict:
    """The figures of :func:`check_imu_units`: ``gyro_rms`` [rad/s] (RMS over the GT intervals of the mean
    recorded rate vector in each), ``gt_rate_rms`` [rad/s] (RMS of the GT's attitude rate over the same
    intervals), ``ratio`` (gyro_rms / max(gt_rate_rms, :data:`RATE_FLOOR`)) and ``median_f`` [m/s²]."""
    t, w = imu[:, 0], imu[:, 4:7]
    cs = np.vstack([np.zeros(3), np.cumsum(w, axis=0)])
    idx = np.searchsorted(t, t_gt, side="right")  # interval k holds samples idx[k] .. idx[k+1]-1: t in (t_k, t_k+1]
    n = np.diff(idx)
    ok = n > 0
    mean_w = (cs[idx[1:]] - cs[idx[:-1]])[ok] / n[ok, None]
    C = euler_to_dcm(euler)
    rate = log_so3(np.swapaxes(C[:-1], -1, -2) @ C[1:]) / np.diff(t_gt)[:, None]
    gyro_rms = float(np.sqrt(np.mean(np.sum(mean_w**2, axis=1)))) if ok.any() else 0.0
    gt_rms = float(np.sqrt(np.mean(np.sum(rate[ok] ** 2, axis=1)))) if ok.any() else 0.0
    return {"gyro_rms": gyro_rms, "gt_rate_rms": gt_rms, "ratio": gyro_rms / max(gt_rms, RATE_FLOOR),
            "median_f": float(np.median(np.linalg.norm(imu[:, 1:4], axis=1)))}


def check_imu_units(path: Path, imu: np.ndarray, t_gt: np.ndarray, euler: np.ndarray, cols: tuple,
                    keys: tuple = ()) -> None:
    """Refuse an IMU whose magnitudes contradict the GT (see the module docstring): one line naming ``path``,
    the columns ``cols`` and the unit to fix (``keys`` = the spec keys of the acceleration and rate units)."""
    fig = imu_unit_figures(imu, t_gt, euler)
    acc_key, rate_key = keys or ("", "")
    f = fig["median_f"]
    if not GRAVITY_MIN <= f <= GRAVITY_MAX:
        fix = (f"key '{acc_key}' declares the unit" if acc_key else "the A-KIT columns are m/s^2")
        guess = "an accelerometer in g read as m/s^2?" if f < GRAVITY_MIN else "m/s^2 read as g, or another unit?"
        raise NespmError(
            f"{path}: columns {', '.join(repr(c) for c in cols[1:4])}: median |specific force| {f:.4g} m/s^2 is "
            f"outside {GRAVITY_MIN:g}-{GRAVITY_MAX:g} m/s^2 around gravity (~9.8 m/s^2): {guess} ({fix}; convert "
            f"the values or {'change the key' if acc_key else 'the file'})")
    low = fig["gt_rate_rms"] >= RATE_TURNING and fig["gyro_rms"] < fig["gt_rate_rms"] / RATE_RATIO_MAX
    if fig["ratio"] > RATE_RATIO_MAX or low:
        ratio = fig["gyro_rms"] / max(fig["gt_rate_rms"], 1e-300)
        fix = (f"key '{rate_key}' declares the unit" if rate_key else "the A-KIT columns are rad/s")
        guess = ("a gyro in deg/s read as rad/s (x 57.3)?" if not low else "a gyro in rad/s read as deg/s (/ 57.3)?")
        raise NespmError(
            f"{path}: columns {', '.join(repr(c) for c in cols[4:7])}: RMS angular rate {fig['gyro_rms']:.4g} rad/s "
            f"over the GT intervals is {ratio:.3g}x the GT attitude's rate ({fig['gt_rate_rms']:.4g} rad/s; outside "
            f"1/{RATE_RATIO_MAX:g}-{RATE_RATIO_MAX:g}x): {guess} ({fix}; convert the values or "
            f"{'change the key' if rate_key else 'the file'})")

"""Ground-truth tracks: load, validate, summarize and write A-KIT style Snapir track folders.

A data folder holds ``TrajectoryN/GT_trajectoryN.csv`` and ``TrajectoryN/DVL_trajectoryN.csv``
(and optionally ``TrajectoryN/IMU_trajectoryN.csv``), with the exact headers in
:data:`GT_COLUMNS`, :data:`DVL_COLUMNS` and :data:`IMU_COLUMNS` (surrounding whitespace in a
header name is ignored, extra columns are ignored; a DVL row of three NaN is a missing epoch), and
optionally ``DEPTH_``/``FIX_trajectoryN.csv`` (:mod:`nespm_cli.data.sensor_files`, ``Track.channels``).
A folder holding a track spec (``nespm-data.toml``, :mod:`nespm_cli.data.track_spec`, docs/data.md) is read
through it instead: the files it names converted (:mod:`nespm_cli.data.track_spec.convert`), then checked alike.
Without a data folder (no ``--data-dir`` and no ``NESPM_DATA_DIR``) the deterministic embedded
tracks of :mod:`nespm_cli.data.embedded` are used.

Every validation failure raises :class:`~nespm_cli.errors.NespmError` with a one-line message
``"<file>: data row R, column 'C': ..."``; *data rows* are numbered from 1 after the header line
(so data row R is line R + 1 of the file when it has no blank lines).

Conventions: ``pos = [lat rad, lon rad, alt m]`` with the altitude positive up (negative below
the sea surface, as in the files; depth = -alt), ``v_n`` is NED [m/s], ``euler`` is
``[roll, pitch, yaw]`` [rad], ZYX, body -> NED (see :mod:`nespm_cli.nav.rotations`).
"""
from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from nespm_cli.data import conventions, plausibility
from nespm_cli.data.csvtable import QUOTE_LIMIT, read_table as _read_table, write_table as _write_csv  # noqa: F401
from nespm_cli.data.sensor_files import CHANNEL_KINDS, check_dvl_nan, dvl_at_epochs, read_channels, write_channels
from nespm_cli.data import track_spec  # the reader's public names: convert, data_checks
from nespm_cli.data.imu_file import (IMU_MAX_ACC, IMU_MAX_GYRO, IMU_MAX_STEP, IMU_MIN_STEP,  # noqa: F401
                                      IMU_STEP_TOL, check_imu, check_imu_units)
from nespm_cli.data.track import Track
from nespm_cli.data.track_spec import TrackSpec, find_spec, read_spec, spec_files, spec_tracks
from nespm_cli.errors import NespmError
from nespm_cli.nav.dvl import body_rate_from_attitude
from nespm_cli.nav.rotations import skew

ENV_DATA_DIR = "NESPM_DATA_DIR"
GT_COLUMNS = (
    "Time [s]",
    "Longitude [rad]",
    "Latitude [rad]",
    "Altitude [m]",
    "V North [m/s]",
    "V East [m/s]",
    "V Down [m/s]",
    "Roll [rad]",
    "Pitch [rad]",
    "Yaw [rad]",
)
DVL_COLUMNS = ("Time [s]", "DVL X [m/s]", "DVL Y [m/s]", "DVL Z [m/s]")
IMU_COLUMNS = (
    "Time [s]",
    "ACC X [m/s^2]",
    "ACC Y [m/s^2]",
    "ACC Z [m/s^2]",
    "GYRO X [rad/s]",
    "GYRO Y [rad/s]",
    "GYRO Z [rad/s]",
)
MAX_SPEED = 20.0  # [m/s]; a GT or DVL speed at or above this is rejected as a unit/column error
EPOCH_TOL = 1e-6  # [s]; GT and DVL time stamps must agree to this
_TRACK_DIR = re.compile(r"Trajectory(\d+)")


# ----------------------------------------------------------------------------- data folders


def resolve_data_dir(data_dir: str | Path | None) -> Path | None:
    """The data folder to use: ``data_dir`` (``--data-dir``), else ``$NESPM_DATA_DIR``, else None.

    None means the embedded tracks. An empty string counts as not given. Raises
    :class:`NespmError` if the chosen folder does not exist or is not a directory.
    """
    origin = ""
    if data_dir is None or str(data_dir).strip() == "":
        env = os.environ.get(ENV_DATA_DIR, "").strip()
        if not env:
            return None
        data_dir, origin = env, f" (from {ENV_DATA_DIR})"
    path = Path(data_dir).expanduser()
    _check_dir(path, origin)
    return path


def _check_dir(path: Path, origin: str = "") -> None:
    if not path.exists():
        raise NespmError(f"{path}: data directory not found{origin}")
    if not path.is_dir():
        raise NespmError(f"{path}: data directory is not a directory{origin}")


def available_tracks(data_dir: Path | None) -> list[int]:
    """Sorted track numbers in ``data_dir`` (``TrajectoryN`` sub-folders, or the GT files its track spec
    finds); None -> embedded [1..6].

    Raises :class:`NespmError` if the folder does not exist, holds no ``TrajectoryN`` folder, or
    holds two folders of one track (``Trajectory7`` and ``Trajectory07``).
    """
    if data_dir is None:
        from nespm_cli.data.embedded import EMBEDDED_TRACKS

        return list(EMBEDDED_TRACKS)
    if (spec := find_spec(Path(data_dir))) is not None:
        return spec_tracks(read_spec(spec))
    return sorted(_track_dirs(Path(data_dir)))


def _track_dirs(data_dir: Path) -> dict[int, Path]:
    """``{N: data_dir/TrajectoryN}`` with N as spelled in the folder name (``Trajectory07`` is 7)."""
    _check_dir(data_dir)
    found: dict[int, Path] = {}
    for p in sorted(data_dir.iterdir()):
        if (m := _TRACK_DIR.fullmatch(p.name)) and p.is_dir():
            if (n := int(m.group(1))) in found:
                raise NespmError(f"{data_dir}: {found[n].name} and {p.name} are both track {n}; keep one of them")
            found[n] = p
    if not found:
        raise NespmError(f"{data_dir}: no TrajectoryN folders found "
                         "(expected TrajectoryN/GT_trajectoryN.csv and TrajectoryN/DVL_trajectoryN.csv)")
    return found


def track_files(number: int, data_dir: str | Path | None, imu: bool = False) -> list[Path]:
    """The files track ``number`` of ``data_dir`` is read from by :func:`load_track`: its GT and DVL
    file (and IMU file with ``imu``, whether or not it exists; then the DEPTH and FIX files that
    exist), as spelled in the folder
    (``Trajectory07/GT_trajectory07.csv`` or ``.../GT_trajectory7.csv``; a missing file under the
    folder's spelling). ``data_dir`` None: the embedded tracks, no files (``$NESPM_DATA_DIR`` is not
    consulted: pass a resolved folder). Raises :class:`NespmError` as :func:`load_track` does on an
    unknown track or an ambiguous folder. A folder with a track spec: the spec file, then the files it names
    (:func:`nespm_cli.data.track_spec.files.spec_files`)."""
    if data_dir is None:
        return []
    if (spec := find_spec(folder := Path(data_dir).expanduser())) is not None:
        return spec_files(read_spec(spec), number, imu)
    gt, dvl, imu_path, *extra = _track_paths(number, folder)
    return [gt, dvl] + ([imu_path] if imu else []) + [p for p in extra if p.exists()]


def _track_paths(number: int, folder: Path) -> tuple[Path, ...]:
    """``(GT, DVL, IMU, DEPTH, FIX)`` paths of track ``number``: each ``{KIND}_trajectoryN.csv`` found in its
    folder with N equal to ``number`` (leading zeros allowed), else the name spelled like the folder."""
    dirs = _track_dirs(folder)
    if number not in dirs:
        raise NespmError(f"{folder}: no track {number} (available: {', '.join(map(str, sorted(dirs)))})")
    tdir = dirs[number]
    names = sorted(p.name for p in tdir.iterdir())
    out = []
    for kind in ("GT", "DVL", "IMU", *CHANNEL_KINDS.values()):
        pat = re.compile(rf"{kind}_trajectory(\d+)\.csv")
        hits = [n for n in names if (m := pat.fullmatch(n)) and int(m.group(1)) == number]
        if len(hits) > 1:
            raise NespmError(f"{tdir}: {hits[0]} and {hits[1]} are both the {kind} file of track {number}; keep one")
        out.append(tdir / (hits[0] if hits else f"{kind}_trajectory{tdir.name[len('Trajectory'):]}.csv"))
    return tuple(out)


def load_track(number: int, data_dir: str | Path | None = None, *, warnings: str | None = None,
               accept_residual: bool | None = None) -> Track:
    """Load and validate track ``number`` from ``data_dir`` (None -> ``$NESPM_DATA_DIR`` -> embedded).

    The files are those of :func:`track_files` (folder and file names may carry leading zeros), or those
    a track spec in the folder names, converted first (docs/data.md; the checks below run on the converted
    arrays, plus the spec's sign checks of :mod:`nespm_cli.data.track_spec.data_checks`; a spec without ``[gt]`` gives a
    track without truth, ``Track.truth`` False: :func:`_truth_free_track`). Raises :class:`NespmError`
    (one line, naming the file and first bad data row / column) on an unknown track number, two folders or
    files of one track, a missing or empty file, a missing column, non-numeric text, NaN/inf, time not
    strictly increasing, GT/DVL epochs that differ, |lat| > pi/2, |lon| > pi, or a speed >= 20 m/s (a DVL
    row of three NaN is a missing epoch, NaN in one or two is refused); and, for the IMU file if present
    (:func:`nespm_cli.data.imu_file.check_imu`), on a median time step outside (:data:`IMU_MIN_STEP`, :data:`IMU_MAX_STEP`) s
    (10 Hz - 2 kHz; e.g. time in ms), a step differing from the median by more than :data:`IMU_STEP_TOL`
    (a gap or non-constant rate), a time span that does not cover the GT span to within one IMU step at
    either end, or |ACC| > :data:`IMU_MAX_ACC` m/s^2 or |GYRO| > :data:`IMU_MAX_GYRO` rad/s (a units
    mistake); and the optional DEPTH / FIX files into ``Track.channels`` (:mod:`nespm_cli.data.sensor_files`).

    Then the physical plausibility checks of :mod:`nespm_cli.data.plausibility` (angle ranges and steps,
    altitude, epoch spacing and gaps, GT velocity against position increments, DVL against GT speed):
    an error raises :class:`NespmError`; warnings are handled per ``warnings``: ``"warn"`` (each once
    per file and message, as a :class:`~nespm_cli.data.plausibility.DataWarning`), ``"ignore"``, or
    ``"error"`` (raise); None -> the mode of :func:`~nespm_cli.data.plausibility.set_warning_mode`
    (``"warn"`` unless set). Then the conventions against the data (:mod:`nespm_cli.data.conventions`): a refusal
    unless ``accept_residual`` (None: the spec's ``gt.accept_residual``, else False) turns it into a warning.
    """
    folder = resolve_data_dir(data_dir)
    if folder is None:
        from nespm_cli.data.embedded import embedded_track

        return embedded_track(number)
    if (spec := find_spec(folder)) is not None:
        return _load_spec_track(read_spec(spec), number, warnings, accept_residual)
    gt_path, dvl_path, imu_path, *extra = _track_paths(number, folder)

    gt = _read_table(gt_path, GT_COLUMNS)
    _check_gt(gt_path, gt, GT_COLUMNS)
    dvl = _read_table(dvl_path, DVL_COLUMNS, nan_ok=DVL_COLUMNS[1:])
    dvl, channels = _check_dvl(dvl_path, dvl, DVL_COLUMNS, gt_path, gt[:, 0])
    imu = None
    if imu_path.exists():
        imu = _read_table(imu_path, IMU_COLUMNS)
        check_imu(imu_path, imu, gt_path, gt[:, 0], IMU_COLUMNS)
    channels.update(read_channels(dict(zip(CHANNEL_KINDS, extra)), gt[:, 0], gt_path.name))
    return _track(number, gt_path, gt, dvl_path, dvl, imu, channels, warnings, imu_path=imu_path,
                  conv=(conventions.Declared(), accept_residual))


def _load_spec_track(spec: TrackSpec, number: int, warnings: str | None, accept: bool | None = None) -> Track:
    """:func:`load_track` through a track spec: the files converted (:mod:`~nespm_cli.data.track_spec.convert`), then
    the A-KIT checks on the arrays (messages naming the user's file and column) and the spec's sign checks."""
    sp = track_spec.read_spec_track(spec, number)
    if sp.gt is None:
        return _truth_free_track(spec, sp, number)
    gt_cols, dvl_cols = track_spec.labels(sp.gt_names, GT_COLUMNS), track_spec.labels(sp.dvl_names, DVL_COLUMNS)
    _check_gt(sp.gt_path, sp.gt, gt_cols)
    track_spec.check_vertical_sign(spec.path, sp, gt_cols)
    t_gt = sp.gt[:, 0]
    dvl, channels = _check_dvl(sp.dvl_path, sp.dvl, dvl_cols, sp.gt_path, t_gt)
    if sp.imu is not None:
        check_imu(sp.imu_path, sp.imu, sp.gt_path, t_gt, track_spec.labels(sp.imu_names, IMU_COLUMNS))
    for name in sp.channels:
        channels[name] = track_spec.check_channel(spec.path, sp, name)
    names = dict(zip(GT_COLUMNS + DVL_COLUMNS, gt_cols + dvl_cols))
    return _track(number, sp.gt_path, sp.gt, sp.dvl_path, dvl, sp.imu, channels, warnings, names, sp.imu_path,
                  track_spec.labels(sp.imu_names, IMU_COLUMNS) if sp.imu is not None else IMU_COLUMNS,
                  ("imu.acceleration_unit", "imu.rate_unit"), track_spec.angle_hint(spec),
                  (conventions.declared_of(spec), accept))


def _truth_free_track(spec: TrackSpec, sp, number: int) -> Track:
    """A track of a spec without ``[gt]`` (``Track.truth`` False): its epochs the DVL's stamps from the initial
    state's time (``init.time``, else the first DVL stamp; an ``init.time`` that is no DVL stamp is an epoch
    without a measurement), the DVL, IMU and channel files checked as usual against those epochs (no check
    against a truth), ``pos``, ``v_n``, ``euler`` the initial state in the first row and NaN after."""
    dvl_cols = track_spec.labels(sp.dvl_names, DVL_COLUMNS)
    check_dvl_nan(sp.dvl_path, sp.dvl[:, 1:4], dvl_cols[1:4])
    _check_time(sp.dvl_path, sp.dvl[:, 0], dvl_cols[0])
    _check_speed(sp.dvl_path, sp.dvl[:, 1:4], dvl_cols[1:4])
    t0 = float(sp.dvl[0, 0]) if sp.init["time"] is None else sp.init["time"]
    dvl = sp.dvl[sp.dvl[:, 0] >= t0 - EPOCH_TOL]
    if len(dvl) < 3 or float(dvl[-1, 0]) <= t0:
        raise NespmError(f"{spec.path}: key 'init.time': {t0!r} s leaves {len(dvl)} DVL stamps of {sp.dvl_path.name} "
                         f"({float(sp.dvl[0, 0])!r} .. {float(sp.dvl[-1, 0])!r} s) from it; the track needs at least 3")
    if abs(float(dvl[0, 0]) - t0) > EPOCH_TOL:
        dvl = np.vstack([np.r_[t0, np.full(3, np.nan)], dvl])
    t = dvl[:, 0]
    try:
        check_imu(sp.imu_path, sp.imu, sp.dvl_path, t, track_spec.labels(sp.imu_names, IMU_COLUMNS))
    except NespmError as exc:  # its span against the DVL's epochs, not a GT
        raise NespmError(str(exc).replace("GT epoch", "epoch").replace("the GT span", "the DVL's epochs")) from None
    channels = {name: track_spec.check_channel(spec.path, sp, name, t) for name in sp.channels}
    nan = np.full((len(t), 3), np.nan)
    pos, v_n, euler = nan.copy(), nan.copy(), nan.copy()
    pos[0], v_n[0], euler[0] = sp.init["pos"], sp.init["v_n"], sp.init["euler"]
    return Track(number=number, t=t, pos=pos, v_n=v_n, euler=euler, dvl=dvl[:, 1:4], imu=sp.imu,
                 source=str(sp.dvl_path.parent), channels=channels, truth=False)


def _track(number, gt_path: Path, gt, dvl_path: Path, dvl, imu, channels: dict, warnings, names=None, imu_path=None,
           imu_cols=IMU_COLUMNS, imu_keys=(), hint=None, conv=(conventions.Declared(), None)) -> Track:
    """The plausibility checks (their columns renamed by ``names``, the units hint replaced by ``hint``), the
    conventions (``conv`` = (declared, accept): :func:`~nespm_cli.data.conventions.check_conventions`), the IMU's
    units against the GT (:func:`~nespm_cli.data.imu_file.check_imu_units`), then the :class:`Track`."""
    findings = track_spec.relabel(plausibility.check_track_arrays(gt_path, gt, dvl_path, dvl), names or {}, hint)
    errors = [f for f in findings if f.level == "error"]
    if errors:
        raise NespmError(errors[0].text)
    conventions.check_conventions(number, {"gt": gt_path, "dvl": dvl_path, "imu": imu_path}, gt[:, 0], gt[:, 7:10],
                                  gt[:, 4:7], dvl[:, 1:4], imu, *conv)
    if imu is not None:
        check_imu_units(imu_path, imu, gt[:, 0], gt[:, 7:10], imu_cols, imu_keys)
    plausibility.emit(findings, warnings)
    return Track(number=number, t=gt[:, 0], pos=gt[:, [2, 1, 3]], v_n=gt[:, 4:7], euler=gt[:, 7:10],
                 dvl=dvl[:, 1:4], imu=imu, source=str(gt_path.parent), channels=channels)


def load_tracks(
    numbers: Iterable[int] | None, data_dir: str | Path | None = None, *, warnings: str | None = None,
    accept_residual: bool | None = None) -> list[Track]:
    """Load several tracks (None -> every available track) from one data folder (or embedded);
    ``warnings`` and ``accept_residual`` as in :func:`load_track`."""
    folder = resolve_data_dir(data_dir)
    if numbers is None:
        numbers = available_tracks(folder)
    if folder is None:
        from nespm_cli.data.embedded import embedded_track

        return [embedded_track(int(n)) for n in numbers]
    return [load_track(int(n), folder, warnings=warnings, accept_residual=accept_residual) for n in numbers]


def write_akit(track: Track, folder: str | Path) -> Path:
    """Write ``track`` as ``folder/TrajectoryN/{GT,DVL[,IMU,DEPTH,FIX]}_trajectoryN.csv``; return that folder.

    Full precision (``%.17g``), exact headers, so :func:`load_track` reads back the same floats;
    each file is written atomically (:func:`nespm_cli.data.atomic.write_atomic`). A track without ground truth
    is refused (one line): the A-KIT layout needs its GT file.
    """
    if not track.truth:
        raise NespmError(f"track {track.number}: has no ground truth (a track spec without [gt]); the A-KIT layout "
                         "needs its GT file")
    tdir = Path(folder) / f"Trajectory{track.number}"
    tdir.mkdir(parents=True, exist_ok=True)
    gt = np.column_stack([track.t, track.pos[:, 1], track.pos[:, 0], track.pos[:, 2], track.v_n, track.euler])
    _write_csv(tdir / f"GT_trajectory{track.number}.csv", gt, GT_COLUMNS)
    own = track.channels.get("dvl")  # a DVL at its own stamps is written as it was read
    dvl = np.column_stack(own) if own is not None else np.column_stack([track.t, track.dvl])
    _write_csv(tdir / f"DVL_trajectory{track.number}.csv", dvl, DVL_COLUMNS)
    if track.imu is not None:
        _write_csv(tdir / f"IMU_trajectory{track.number}.csv", track.imu, IMU_COLUMNS)
    write_channels(track.channels, tdir, track.number)
    return tdir


# ----------------------------------------------------------------------------- validation


def _check_gt(path: Path, gt: np.ndarray, cols: tuple[str, ...]) -> None:
    """Time, latitude and longitude range and speed of a GT table (N, 10); ``cols`` name its columns."""
    _check_time(path, gt[:, 0], cols[0])
    _check_range(path, gt[:, 2], cols[2], np.pi / 2, "pi/2")
    _check_range(path, gt[:, 1], cols[1], np.pi, "pi")
    _check_speed(path, gt[:, 4:7], cols[4:7])


def _check_dvl(path: Path, dvl: np.ndarray, cols: tuple[str, ...], gt_path: Path,
               t_gt: np.ndarray) -> tuple[np.ndarray, dict]:
    """Check a DVL table (K, 4); return it on the GT epochs ``t_gt``, and ``{"dvl": (t, v)}`` if its stamps are
    its own (the filters use them as they are)."""
    check_dvl_nan(path, dvl[:, 1:4], cols[1:4])
    _check_time(path, dvl[:, 0], cols[0])
    channels = {}
    if not _on_epochs(dvl[:, 0], t_gt):
        if len(dvl) < 2:
            _check_epochs(path, dvl[:, 0], gt_path, t_gt)
        track_spec.stamps_checked(path, dvl[:, 0], t_gt, gt_path.name, cols[0])
        channels["dvl"] = (dvl[:, 0].copy(), dvl[:, 1:4].copy())
        dvl = np.column_stack([t_gt, dvl_at_epochs(dvl[:, 0], dvl[:, 1:4], t_gt)])
    _check_speed(path, dvl[:, 1:4], cols[1:4])
    return dvl, channels


def _check_time(path: Path, t: np.ndarray, col: str = "Time [s]") -> None:
    bad = np.flatnonzero(np.diff(t) <= 0.0)
    if bad.size:
        r = int(bad[0]) + 1  # 0-based index of the offending row
        raise NespmError(
            f"{path}: data row {r + 1}, column '{col}': time {float(t[r])!r} is not after the previous "
            f"row's {float(t[r - 1])!r} (must be strictly increasing)"
        )


def _on_epochs(t: np.ndarray, t_gt: np.ndarray) -> bool:
    """Whether DVL stamps ``t`` are the GT epochs (to :data:`EPOCH_TOL`)."""
    return len(t) == len(t_gt) and bool(np.all(np.abs(t - t_gt) <= EPOCH_TOL))


def _check_epochs(path: Path, t: np.ndarray, gt_path: Path, t_gt: np.ndarray) -> None:
    if len(t) != len(t_gt):
        raise NespmError(
            f"{path}: {len(t)} data rows but {gt_path.name} has {len(t_gt)} (DVL must be on the GT epochs)"
        )
    bad = np.flatnonzero(np.abs(t - t_gt) > EPOCH_TOL)
    if bad.size:
        r = int(bad[0])
        raise NespmError(
            f"{path}: data row {r + 1}, column 'Time [s]': time {float(t[r])!r} differs from {gt_path.name} "
            f"time {float(t_gt[r])!r} by more than {EPOCH_TOL:g} s"
        )


def _check_range(path: Path, x: np.ndarray, col: str, limit: float, limit_name: str) -> None:
    bad = np.flatnonzero(np.abs(x) > limit)
    if bad.size:
        r = int(bad[0])
        raise NespmError(
            f"{path}: data row {r + 1}, column '{col}': |{float(x[r])!r}| > {limit_name} (radians expected)"
        )


def _check_speed(path: Path, v: np.ndarray, cols: tuple[str, ...]) -> None:
    speed = np.linalg.norm(v, axis=1)
    bad = np.flatnonzero(speed >= MAX_SPEED)
    if bad.size:
        r = int(bad[0])
        raise NespmError(
            f"{path}: data row {r + 1}, columns {', '.join(repr(c) for c in cols)}: "
            f"speed {speed[r]:.4g} m/s >= {MAX_SPEED:g} m/s"
        )


# ----------------------------------------------------------------------------- analysis


def dvl_lever_arm_fit(track: Track) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares DVL lever arm ``l`` (3,) [m, body] and residual (N, 3) [m/s].

    Model: ``dvl ≈ C_bn^T v_n + w_nb^b x l`` with ``w_nb^b`` from :func:`nav.dvl.body_rate_from_attitude` on the GT
    attitude. The residual is ``dvl - C_bn^T v_n - w x l``. On a straight track (no rotation)
    ``l`` is not observable and the minimum-norm solution is returned. NaN DVL rows (missing epochs)
    are left out of the fit and give NaN residual rows.
    """
    C = track.C_bn
    w = body_rate_from_attitude(track.t, C)
    r0 = np.asarray(track.dvl) - np.einsum("nji,nj->ni", C, track.v_n)
    A = skew(w)  # w x l = [w x] l
    ok = np.isfinite(r0).all(axis=1)
    lever, *_ = np.linalg.lstsq(A[ok].reshape(-1, 3), r0[ok].reshape(-1), rcond=None)
    return lever, r0 - A @ lever


LEVER_MIN_TURN_DPS = 1.0  # [deg/s] RMS yaw rate below which turns do not determine the lever arm's x, y
LEVER_MAX_STD = 0.3  # [m] an x or y lever-arm std above this is reported as undetermined


def lever_arm_std(track: Track, resid: np.ndarray) -> np.ndarray:
    """1-sigma uncertainty (3,) [m] of the :func:`dvl_lever_arm_fit` lever arm.

    Least-squares covariance ``s^2 (A^T A)^-1`` with ``A = [w x]`` stacked over epochs and
    ``s^2`` the residual variance, inflated by ``sqrt((1 + rho) / (1 - rho))`` for the
    residual's lag-1 autocorrelation ``rho`` (largest over the axes): the 1 Hz residuals are
    far from white, and the white-noise formula would understate the std 2-4x.
    """
    w = body_rate_from_attitude(track.t, track.C_bn)
    resid = np.asarray(resid, dtype=float)
    ok = np.isfinite(resid).all(axis=1)  # NaN rows: DVL epochs missing
    A, resid = skew(w)[ok].reshape(-1, 3), resid[ok]
    dof = max(A.shape[0] - 3, 1)
    s2 = float((resid**2).sum() / dof)
    rho = []
    for i in range(3):
        r = resid[:, i] - resid[:, i].mean()
        den = float((r * r).sum())
        rho.append(float((r[1:] * r[:-1]).sum() / den) if den > 0 else 0.0)
    rho_max = min(max(rho), 0.99)
    inflation = np.sqrt(max((1 + rho_max) / (1 - rho_max), 1.0))
    cov = s2 * np.linalg.pinv(A.T @ A)
    return inflation * np.sqrt(np.clip(np.diag(cov), 0.0, None))


def track_summary(track: Track) -> dict:
    """Summary numbers of a track (plain Python types, JSON-ready).

    Keys: ``track``; ``duration_s`` [s]; ``epochs``; ``distance_m`` (horizontal, trapezoid
    integral of |v_N, v_E|) [m]; ``mean_speed`` (mean |v_n|) [m/s]; ``max_yaw_rate_dps`` (max
    |d unwrap(yaw)/dt|) [deg/s]; ``depth_min``, ``depth_max`` (depth = -alt) [m]; ``imu`` (bool);
    ``dvl_resid_std`` (RMS over the 3 axes of the per-axis residual std after the lever-arm fit)
    [m/s]; ``dvl_resid_std_xyz`` (the per-axis stds) [m/s]; ``lever_arm`` (x, y, z) [m, body];
    ``lever_arm_std`` (x, y, z) [m] (:func:`lever_arm_std`); ``yaw_rate_rms_dps`` [deg/s];
    ``lever_arm_warning``: None, or why the track's turns cannot determine the lever arm
    (RMS yaw rate below :data:`LEVER_MIN_TURN_DPS`, or an x/y std above :data:`LEVER_MAX_STD`).
    A track without ground truth: only ``track``, ``duration_s``, ``epochs``, ``imu`` are numbers, every figure
    of the truth NaN, and ``lever_arm_warning`` says so.
    """
    t = np.asarray(track.t)
    if not track.truth:
        nan, nan3 = float("nan"), (float("nan"),) * 3
        return {"track": int(track.number), "duration_s": track.duration, "epochs": int(len(t)), "imu": True,
                **{k: nan for k in ("distance_m", "mean_speed", "max_yaw_rate_dps", "depth_min", "depth_max",
                                    "dvl_resid_std", "yaw_rate_rms_dps")},
                "dvl_resid_std_xyz": nan3, "lever_arm": nan3, "lever_arm_std": nan3,
                "lever_arm_warning": f"track {track.number}: no ground truth (its track spec has no [gt]): distance, "
                                     "speed, depth, DVL residual and lever arm are not known"}
    v = np.asarray(track.v_n)
    hspeed = np.hypot(v[:, 0], v[:, 1])
    distance = float(np.sum(0.5 * (hspeed[1:] + hspeed[:-1]) * np.diff(t)))
    yaw_rate = np.diff(np.unwrap(track.euler[:, 2])) / np.diff(t)
    depth = -np.asarray(track.pos[:, 2])
    lever, resid = dvl_lever_arm_fit(track)
    std_xyz = resid[np.isfinite(resid).all(axis=1)].std(axis=0)
    lever_std = lever_arm_std(track, resid)
    yaw_rms = float(np.degrees(np.sqrt(np.mean(yaw_rate**2))))
    warning = None
    if yaw_rms < LEVER_MIN_TURN_DPS:
        warning = (f"track {track.number}: RMS yaw rate {yaw_rms:.2f} deg/s < {LEVER_MIN_TURN_DPS:g}: too few turns "
                   "to determine the DVL lever arm; do not use its fit")
    elif max(lever_std[:2]) > LEVER_MAX_STD:
        warning = (f"track {track.number}: lever-arm x/y std {max(lever_std[:2]):.2f} m > {LEVER_MAX_STD:g} m: "
                   "the fit is poorly determined")
    return {
        "track": int(track.number),
        "duration_s": track.duration,
        "epochs": int(len(t)),
        "distance_m": distance,
        "mean_speed": float(np.linalg.norm(v, axis=1).mean()),
        "max_yaw_rate_dps": float(np.degrees(np.abs(yaw_rate).max())),
        "depth_min": float(depth.min()),
        "depth_max": float(depth.max()),
        "imu": track.imu is not None,
        "dvl_resid_std": float(np.sqrt(np.mean(std_xyz**2))),
        "dvl_resid_std_xyz": tuple(float(s) for s in std_xyz),
        "lever_arm": tuple(float(x) for x in lever),
        "lever_arm_std": tuple(float(x) for x in lever_std),
        "yaw_rate_rms_dps": yaw_rms,
        "lever_arm_warning": warning,
    }

"""Optional per-sensor recorded files of a track folder ("channels"): read, validate and write them.

A ``TrajectoryN`` folder may hold, besides the GT and DVL files (:mod:`nespm_cli.data.tracks`):

* ``DEPTH_trajectoryN.csv``: columns exactly :data:`DEPTH_COLUMNS` (``Time [s]``, ``Depth [m]``, depth
  positive down) -> ``Track.channels["depth"] = (t (K,), z (K, 1))``;
* ``FIX_trajectoryN.csv``: columns exactly :data:`FIX_COLUMNS` (``Time [s]``, ``Latitude [rad]``,
  ``Longitude [rad]``), optionally with :data:`FIX_ALT_COLUMN` (``Altitude [m]``, positive up: a 3-D fix)
  -> ``Track.channels["fix"] = (t (K,), z (K, 2 or 3))`` as ``[lat, lon(, alt)]``;
* ``DVLBEAMS_trajectoryN.csv``: columns exactly :data:`BEAM_COLUMNS` (``Time [s]``, ``Beam 1 [m/s]`` ..
  ``Beam 4 [m/s]``, the Janus beam velocities of docs/sensors.md) -> ``Track.channels["dvl-beams"] =
  (t (K,), z (K, 4))``; a NaN cell is a lost beam (any subset of a row may be NaN);
* ``HEADING_trajectoryN.csv``: columns exactly :data:`HEADING_COLUMNS` (``Time [s]``, ``Heading [rad]``,
  the yaw of C_bn) -> ``Track.channels["heading"] = (t (K,), z (K, 1))``.

``t`` is the file's time [s] (the GT clock, not shifted); a row of NaN values is "no measurement at this
stamp" (NaN in some but not all values of a row is refused, except in the beam file). A header-only file
gives K = 0. Refused, each in one line naming the file and the 1-based data row (:func:`read_channel`): a
missing or unknown column, a beam file with other than four beam columns, non-numeric text, a non-finite
time, a stamp not after the previous row's (unsorted or a duplicate stamp), a stamp outside the GT span by
more than :data:`STAMP_TOL`, an infinite value, |lat| > pi/2, |lon| > pi, a depth outside
[:data:`DEPTH_MIN`, :data:`DEPTH_MAX`] m, |alt| > :data:`MAX_ABS_FIX_ALT` m, |beam| >
:data:`MAX_ABS_BEAM` m/s, |heading| > 2 pi.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from nespm_cli.data.csvtable import QUOTE_LIMIT, check_nan_rows, read_frame, require_columns, to_array, write_table
from nespm_cli.data.plausibility import printable
from nespm_cli.errors import NespmError

TIME = "Time [s]"
DEPTH_COLUMNS = (TIME, "Depth [m]")
FIX_COLUMNS = (TIME, "Latitude [rad]", "Longitude [rad]")
FIX_ALT_COLUMN = "Altitude [m]"
BEAM_COLUMNS = (TIME, "Beam 1 [m/s]", "Beam 2 [m/s]", "Beam 3 [m/s]", "Beam 4 [m/s]")
BEAM_COLUMN = re.compile(r"Beam \d+ \[m/s\]")  # what a beam column looks like (counted, then checked)
HEADING_COLUMNS = (TIME, "Heading [rad]")
#: channel name -> file kind (``{KIND}_trajectoryN.csv``), in the order the files are listed
CHANNEL_KINDS = {"depth": "DEPTH", "fix": "FIX", "dvl-beams": "DVLBEAMS", "heading": "HEADING"}
STAMP_TOL = 1e-6  # [s]; a stamp may lie this far outside the GT span [t_gt[0], t_gt[-1]]
DEPTH_MIN = -10.0  # [m]; shallower (above the surface) is a sign convention (altitude up) or units mistake
DEPTH_MAX = 12_000.0  # [m]; deeper than any ocean (~10,994 m): not metres
MAX_ABS_FIX_ALT = 12_000.0  # [m]; a 3-D fix's |altitude| beyond this is a units mistake
MAX_ABS_BEAM = 20.0  # [m/s]; the tracks' speed limit: a beam velocity beyond it is not m/s (cm/s, mm/s)
MAX_ABS_HEADING = 2.0 * np.pi  # [rad]; beyond a turn the heading is in degrees


def read_channel(name: str, path: Path, t_gt: np.ndarray, gt_name: str = "the GT file") -> tuple[np.ndarray, np.ndarray]:
    """``(t (K,), z (K, m))`` of the ``name`` (a key of :data:`CHANNEL_KINDS`) file ``path``, checked against
    the GT time ``t_gt`` (N,) [s] of the file ``gt_name``; raises :class:`NespmError` as the module says."""
    if name not in CHANNEL_KINDS:
        raise ValueError(f"unknown channel {name!r} (known: {', '.join(CHANNEL_KINDS)})")
    df = read_frame(path)
    allowed = {"depth": DEPTH_COLUMNS, "fix": FIX_COLUMNS + (FIX_ALT_COLUMN,), "dvl-beams": BEAM_COLUMNS,
               "heading": HEADING_COLUMNS}[name]
    for col in df.columns:
        if col not in allowed and not (name == "dvl-beams" and BEAM_COLUMN.fullmatch(col)):
            expected = ", ".join(f"'{c}'" for c in allowed)
            if name == "fix":
                expected = ", ".join(f"'{c}'" for c in FIX_COLUMNS) + f" and optionally '{FIX_ALT_COLUMN}'"
            raise NespmError(f"{path}: unknown column '{printable(col, QUOTE_LIMIT)}' (the columns must be exactly "
                             f"{expected})")
    if name == "dvl-beams":
        _check_beam_columns(path, [c for c in df.columns if c != TIME])
    columns = allowed if name != "fix" else FIX_COLUMNS + ((FIX_ALT_COLUMN,) * (FIX_ALT_COLUMN in df.columns))
    require_columns(path, df, columns)
    table = to_array(path, df, columns, nan_ok=columns[1:])
    t, z = table[:, 0], table[:, 1:]
    check_stamps(path, t, t_gt, gt_name)
    if name != "dvl-beams":  # a lost beam is a NaN cell of its own
        check_nan_rows(path, z, columns[1:], "no measurement at this stamp")
    if name == "depth":
        _check_bounds(path, z[:, 0], columns[1], DEPTH_MIN, DEPTH_MAX,
                      lambda v: f"{v!r} is outside {DEPTH_MIN:g} .. {DEPTH_MAX:g} m (metres, positive down, expected)")
    elif name == "fix":
        _check_bounds(path, z[:, 0], columns[1], -np.pi / 2, np.pi / 2, lambda v: f"|{v!r}| > pi/2 (radians expected)")
        _check_bounds(path, z[:, 1], columns[2], -np.pi, np.pi, lambda v: f"|{v!r}| > pi (radians expected)")
        if z.shape[1] == 3:
            _check_bounds(path, z[:, 2], columns[3], -MAX_ABS_FIX_ALT, MAX_ABS_FIX_ALT,
                          lambda v: f"|{v!r}| > {MAX_ABS_FIX_ALT:g} m (metres, positive up, expected)")
    elif name == "dvl-beams":
        for j, col in enumerate(columns[1:]):
            _check_bounds(path, z[:, j], col, -MAX_ABS_BEAM, MAX_ABS_BEAM,
                          lambda v: f"|{v!r}| > {MAX_ABS_BEAM:g} m/s (metres per second expected)")
    else:
        _check_bounds(path, z[:, 0], columns[1], -MAX_ABS_HEADING, MAX_ABS_HEADING,
                      lambda v: f"|{v!r}| > 2 pi (radians expected)")
    return t, z


def _check_beam_columns(path: Path, beams: list[str]) -> None:
    """Refuse a beam file whose beam columns (``beams``, the header less ``Time [s]``) are not the four
    of :data:`BEAM_COLUMNS`, in one line naming the file and what it has."""
    if sorted(beams) != sorted(BEAM_COLUMNS[1:]):
        have = ", ".join(f"'{printable(c, QUOTE_LIMIT)}'" for c in beams) or "none"
        raise NespmError(f"{path}: {len(beams)} beam column{'s' if len(beams) != 1 else ''} ({have}); a DVLBEAMS "
                         f"file has exactly four, '{BEAM_COLUMNS[1]}' .. '{BEAM_COLUMNS[4]}' (docs/data-format.md)")


def check_stamps(path: Path, t: np.ndarray, t_gt: np.ndarray, gt_name: str) -> None:
    """Stamps ``t`` (K,) strictly increasing (else "unsorted" or "duplicate stamp" at the row) and
    inside the GT span ``[t_gt[0], t_gt[-1]]`` to :data:`STAMP_TOL`."""
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0.0)
    if bad.size:
        r = int(bad[0]) + 1  # 0-based index of the offending row
        what = (f"duplicate stamp {float(t[r])!r} (the same as data row {r};" if dt[r - 1] == 0.0 else
                f"unsorted: stamp {float(t[r])!r} is before data row {r}'s {float(t[r - 1])!r} (")
        raise NespmError(f"{path}: data row {r + 1}, column '{TIME}': {what} stamps must be strictly increasing)")
    t0, t1 = float(t_gt[0]), float(t_gt[-1])
    out = np.flatnonzero((t < t0 - STAMP_TOL) | (t > t1 + STAMP_TOL))
    if out.size:
        r = int(out[0])
        raise NespmError(f"{path}: data row {r + 1}, column '{TIME}': stamp {float(t[r])!r} is outside the GT span "
                         f"{t0!r} .. {t1!r} s of {gt_name} (by more than {STAMP_TOL:g} s)")


def _check_bounds(path: Path, x: np.ndarray, col: str, lo: float, hi: float, say) -> None:
    """Refuse the first value of ``x`` outside [lo, hi] with the message ``say(value)``."""
    bad = np.flatnonzero((x < lo) | (x > hi))  # NaN (no measurement) compares False
    if bad.size:
        r = int(bad[0])
        raise NespmError(f"{path}: data row {r + 1}, column '{col}': {say(float(x[r]))}")


def read_channels(paths: dict[str, Path], t_gt: np.ndarray, gt_name: str = "the GT file") -> dict:
    """``{name: (t, z)}`` of the channel files ``{name: path}`` that exist (see :func:`read_channel`); a
    symbolic link that leads nowhere (a loop, or a missing target) is an error naming it, not "no file"."""
    for p in paths.values():
        check_link(p)
    return {name: read_channel(name, p, t_gt, gt_name) for name, p in paths.items() if p.exists()}


def check_link(path: Path) -> None:
    """Refuse ``path`` when it is a symbolic link that cannot be followed (one line naming it): a loop
    (ELOOP) or a link to a missing file; a path that is not a link, or a good link, passes."""
    import errno
    import os

    path = Path(path)
    if not path.is_symlink():
        return
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise NespmError(f"{path}: a symbolic link loop (following it never reaches a file); point it at the file or "
                             "remove it") from None
        if exc.errno == errno.ENOENT:
            raise NespmError(f"{path}: a symbolic link to {os.readlink(path)}, which does not exist; point it at "
                             "the file or remove it") from None
        raise NespmError(f"{path}: cannot follow the symbolic link ({exc.strerror or exc})") from None


def channel_columns(name: str, m: int) -> tuple[str, ...]:
    """The header of a ``name`` file whose values have ``m`` columns."""
    if name == "depth" and m == 1:
        return DEPTH_COLUMNS
    if name == "fix" and m in (2, 3):
        return FIX_COLUMNS + ((FIX_ALT_COLUMN,) if m == 3 else ())
    if name == "dvl-beams" and m == 4:
        return BEAM_COLUMNS
    if name == "heading" and m == 1:
        return HEADING_COLUMNS
    raise ValueError(f"channel {name!r} with {m} value column(s) has no file format")


def write_channels(channels: dict, tdir: Path, number: int) -> list[Path]:
    """Write the entries of ``channels`` named in :data:`CHANNEL_KINDS` as ``tdir/{KIND}_trajectory{number}.csv``
    (full precision, NaN as ``nan``, atomically); other names are not written. Returns the files written."""
    out = []
    for name, kind in CHANNEL_KINDS.items():
        if name in channels:
            t, z = (np.asarray(a, dtype=float) for a in channels[name])
            z = z.reshape(len(t), -1)
            path = Path(tdir) / f"{kind}_trajectory{number}.csv"
            write_table(path, np.column_stack([t, z]), channel_columns(name, z.shape[1]))
            out.append(path)
    return out


def dvl_at_epochs(t: np.ndarray, v: np.ndarray, t_gt: np.ndarray) -> np.ndarray:
    """A DVL recorded at its own stamps ``t`` (K,), velocities ``v`` (K, 3), on the GT epochs
    ``t_gt`` (N,) by linear interpolation between the two samples around each epoch (N, 3); NaN
    where either is missing (NaN) or they are more than twice the median DVL step apart. This is
    what the checks and plots read; the filters use the samples at their own times."""
    t, v, t_gt = (np.asarray(a, dtype=float) for a in (t, v, t_gt))
    j = np.clip(np.searchsorted(t, t_gt, side="right"), 1, len(t) - 1)
    t0, t1 = t[j - 1], t[j]
    w = np.clip((t_gt - t0) / (t1 - t0), 0.0, 1.0)[:, None]
    out = v[j - 1] * (1.0 - w) + v[j] * w
    step = float(np.median(np.diff(t))) if len(t) > 1 else np.inf
    far = (t1 - t0 > 2.0 * step + STAMP_TOL) | (t_gt < t[0] - STAMP_TOL) | (t_gt > t[-1] + STAMP_TOL)
    out[far] = np.nan
    return out


def check_dvl_nan(path: Path, velocity: np.ndarray, columns: tuple[str, ...]) -> None:
    """A DVL row may be NaN in all of ``columns`` (a missing epoch), not in some."""
    check_nan_rows(path, velocity, columns, "a missing epoch")

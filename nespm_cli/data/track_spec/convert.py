"""One track read through a track spec (:mod:`~nespm_cli.data.track_spec.schema`, docs/data.md): the files
read and converted with NumPy (whole columns at once, units and frames) into the A-KIT arrays.

:func:`read_spec_track` gives the arrays :func:`nespm_cli.data.tracks.load_track` checks as it checks an
A-KIT folder's: the GT (N, 10) ``[t s, lon rad, lat rad, alt m (up), v_N, v_E, v_D m/s, roll, pitch, yaw rad]``,
the DVL (K, 4) ``[t s, x, y, z m/s]`` in the body frame, the IMU (M, 7) ``[t s, f m/s², w rad/s]`` in the body
frame, the depth (K, 1) [m, down] and fix (K, 2|3) ``[lat, lon rad(, alt m up)]`` channels. Every time is on
the GT clock already: ``(stamp - time_zero) / ticks per second - time_offset``
(:func:`~nespm_cli.data.track_spec.units.to_seconds`), so the checks see the shifted stamps. Messages name the
file's own column with the bench's quantity it became: ``column 'pitch_deg as Pitch [rad]'`` (the value
shown is the converted one; a leading ``-`` marks a column whose sign was changed, as ``v_up`` becoming
``V Down``).

A spec without ``[gt]`` gives no GT arrays (``gt`` None) and its track's initial state instead
(``init``, :func:`init_state`: the ``[init]`` numbers in SI units); its IMU is required.

The checks only a spec's data need are :mod:`~nespm_cli.data.track_spec.data_checks`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nespm_cli.data.conventions import dvl_to_body
from nespm_cli.data.corrections import axes_matrix
from nespm_cli.data.csvtable import header_text, read_frame, to_array
from nespm_cli.data.plausibility import printable
from nespm_cli.data.track_spec.files import spec_file
from nespm_cli.data.track_spec.schema import FRAME_KEYS, UP_KEYS, VELOCITY_KEYS, TrackSpec, column_keys
from nespm_cli.data.track_spec.units import factor, scaled, to_seconds
from nespm_cli.errors import NespmError
from nespm_cli.nav.rotations import wrap_angle
from nespm_cli.nav.state import position_plus


@dataclass(frozen=True)
class SpecTrack:
    """One track's files read and converted to the A-KIT arrays (not yet checked). ``gt`` (N, 10), ``dvl``
    (K, 4), ``imu`` (M, 7) or None, column for column as in the A-KIT files; ``*_keys`` the spec key of each
    column (``gt.lat``), ``*_names`` the file's column it came from (``-`` in front: sign changed);
    ``channels`` ``{name: (path, t (K,), z (K, m), keys, names)}`` for ``"depth"`` and ``"fix"``. Without
    ``[gt]``: ``gt_path`` and ``gt`` None, ``init`` the track's initial state (:func:`init_state`)."""

    gt_path: Path | None
    gt: np.ndarray | None
    gt_keys: tuple
    gt_names: tuple
    dvl_path: Path
    dvl: np.ndarray
    dvl_keys: tuple
    dvl_names: tuple
    imu_path: Path | None = None
    imu: np.ndarray | None = None
    imu_keys: tuple = ()
    imu_names: tuple = ()
    channels: dict = field(default_factory=dict)
    init: dict | None = None


WRAP_LIMIT = 2.0 * np.pi + 1e-6  # [rad] roll and yaw of a non-radian column up to one turn (0-360 deg) are wrapped


def wrapped(angles: np.ndarray) -> np.ndarray:
    """Roll or yaw ``angles`` (...) [rad], after the unit conversion, wrapped to (-pi, pi]: values in [-pi, pi]
    unchanged bit for bit, values within one turn (:data:`WRAP_LIMIT`: a 0-360 deg heading) wrapped by
    :func:`nespm_cli.nav.rotations.wrap_angle`; beyond one turn left as they are (the range check refuses them:
    not an angle of that unit)."""
    a = np.asarray(angles, dtype=float)
    turn = (np.abs(a) > np.pi) & (np.abs(a) <= WRAP_LIMIT)
    return np.where(turn, wrap_angle(a), a)


def labels(names: tuple, bench: tuple) -> tuple:
    """``"<file column> as <bench column>"`` for each pair, the column names of a converted file's messages."""
    return tuple(f"{n} as {b}" for n, b in zip(names, bench))


def read_spec_track(spec: TrackSpec, number: int) -> SpecTrack:
    """Track ``number``'s files (:func:`~nespm_cli.data.track_spec.files.spec_file`) read and converted. Refused in
    one line naming the file: a missing or unreadable file, every missing column at once, fewer than 2 data
    rows in the GT, DVL or IMU file, text that is not a number, infinity, NaN where it is not "no measurement"
    (the DVL, depth and fix values may be NaN; times, the GT and the IMU may not). Without ``[gt]``: the
    initial state of ``[init]`` instead of the GT (checked first), the IMU file required."""
    out = _gt(spec, number) if spec.init is None else {"gt_path": None, "gt": None, "gt_keys": (), "gt_names": (),
                                                        "init": init_state(spec, number)}
    dvl_path = spec_file(spec, "dvl", number)
    c, _, names = _read(spec, "dvl", dvl_path, nan_ok=("x", "y", "z"), min_rows=2)
    tab = spec.tables["dvl"]
    vel, src, sign = _axes(np.column_stack([scaled(c[k], "speed", tab["speed_unit"]) for k in "xyz"]), tab["axes"])
    order = ("time",) + tuple("xyz"[j] for j in src)
    out.update(dvl_path=dvl_path, dvl=np.column_stack([_time(tab, c), vel]), dvl_keys=tuple(f"dvl.{k}" for k in order),
               dvl_names=_signed(names, order, (1,) + tuple(sign)))

    if "imu" in spec.tables and (imu_path := spec_file(spec, "imu", number)) is not None:
        c, _, names = _read(spec, "imu", imu_path, min_rows=2)
        tab = spec.tables["imu"]
        f, fsrc, fsign = _axes(np.column_stack([scaled(c[f"acc_{a}"], "acceleration", tab["acceleration_unit"])
                                                for a in "xyz"]), tab["axes"])
        w, wsrc, wsign = _axes(np.column_stack([scaled(c[f"gyro_{a}"], "rate", tab["rate_unit"]) for a in "xyz"]),
                               tab["axes"])
        order = ("time",) + tuple(f"acc_{'xyz'[j]}" for j in fsrc) + tuple(f"gyro_{'xyz'[j]}" for j in wsrc)
        out.update(imu_path=imu_path, imu=np.column_stack([_time(tab, c), f, w]),
                   imu_keys=tuple(f"imu.{k}" for k in order),
                   imu_names=_signed(names, order, (1,) + tuple(fsign) + tuple(wsign)))

    channels = {}
    for name in ("depth", "fix"):
        if name in spec.tables and (path := spec_file(spec, name, number)) is not None:
            channels[name] = _channel(spec, name, path)
    frame = spec.tables["dvl"]["frame"]
    if frame != "body":
        if out["gt"] is None:
            raise NespmError(f"{spec.path}: key 'dvl.frame': {frame!r} needs the truth's attitude to turn the DVL "
                             "into the body frame, and this spec has no [gt]; write body-frame (FRD) velocity")
        out["dvl"] = np.column_stack([out["dvl"][:, 0], dvl_to_body(out["dvl"][:, 0], out["dvl"][:, 1:4],
                                                                    out["gt"][:, 0], out["gt"][:, 7:10], frame)])
    return SpecTrack(**out, channels=channels)


def _gt(spec: TrackSpec, number: int) -> dict:
    """The :class:`SpecTrack` fields of track ``number``'s GT file, read and converted."""
    gt_path = spec_file(spec, "gt", number)
    c, _, names = _read(spec, "gt", gt_path, min_rows=2)
    tab = spec.tables["gt"]
    t = to_seconds(c["time"], tab["time_unit"], tab["time_zero"])
    lat, lon, alt, pk = _position(spec, "gt", c)
    vk = VELOCITY_KEYS[tab["velocity"]]
    v = np.column_stack([scaled(c[k], "speed", tab["speed_unit"]) for k in vk])
    sign_v = 1.0 if tab["velocity"] == "ned" else -1.0
    v[:, 2] *= sign_v
    euler = np.column_stack([scaled(c[k], "angle", tab["angle_unit"]) for k in ("roll", "pitch", "yaw")])
    if tab["angle_unit"] != "rad":  # radians are the bench's: a radian column is checked as it is
        euler[:, [0, 2]] = wrapped(euler[:, [0, 2]])
    for j, key in ((0, "roll_sign"), (1, "pitch_sign")):
        if tab[key] == "flipped":
            euler[:, j] = -euler[:, j]
    if tab["yaw_convention"] == "enu":  # 0 = east, counter-clockwise: psi_NED = pi/2 - psi_ENU
        euler[:, 2] = wrap_angle(np.pi / 2 - euler[:, 2])
    gt = np.column_stack([t, lon, lat, alt, v, euler])
    order = ("time", pk[1], pk[0], pk[2]) + vk + ("roll", "pitch", "yaw")
    signs = (1, 1, 1, 1 if pk[2] in UP_KEYS else -1, 1, 1, sign_v, 1, 1, 1)
    return {"gt_path": gt_path, "gt": gt, "gt_keys": tuple(f"gt.{k}" for k in order),
            "gt_names": _signed(names, order, signs)}


def _read(spec: TrackSpec, name: str, path: Path, nan_ok: tuple = (), min_rows: int = 0):
    """``({key: column (R,)}, keys, {key: file column})`` of table ``name``'s column keys in ``path``."""
    tab = spec.tables[name]
    keys = column_keys(name, tab)
    cols = tuple(tab[k] for k in keys)
    df = read_frame(path)
    missing = [k for k in keys if tab[k] not in df.columns]
    if missing:
        s = "s" if len(missing) > 1 else ""
        raise NespmError(f"{path}: missing column{s} {', '.join(repr(printable(tab[k], 40)) for k in missing)} (key{s} "
                         f"{', '.join(f'{name}.{k}' for k in missing)} of {spec.path.name}; header has: "
                         f"{header_text(df)})")
    for col in cols:
        if list(df.columns).count(col) > 1:
            raise NespmError(f"{path}: column '{printable(col, 40)}' appears more than once in the header")
    if len(df) < min_rows:
        raise NespmError(f"{path}: no data rows after the header" if len(df) == 0 else
                         f"{path}: needs at least {min_rows} data rows, has {len(df)}")
    table = to_array(path, df, cols, tuple(tab[k] for k in nan_ok))
    return {k: table[:, j] for j, k in enumerate(keys)}, keys, {k: tab[k] for k in keys}


def _time(tab: dict, c: dict) -> np.ndarray:
    """The ``time`` column of a sensor table on the GT clock [s] (its unit, zero and offset applied)."""
    return to_seconds(c["time"], tab["time_unit"], tab["time_zero"], tab["time_offset"])


def _signed(names: dict, order: tuple, signs: tuple) -> tuple:
    """The file column of each key of ``order``, ``-`` in front where the sign was changed."""
    return tuple(("-" if s < 0 else "") + names[k] for k, s in zip(order, signs))


def _axes(values: np.ndarray, text: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``values`` (R, 3) in the file's axes -> the body axes per ``axes`` (``"x,-y,-z"``: body axis i is the
    signed file axis at position i), by indexing (exact, a NaN stays in its own column); also the file axis
    (3,) and sign (3,) of each body axis."""
    A = axes_matrix(text)
    src = np.argmax(np.abs(A), axis=1)
    sign = A[np.arange(3), src]
    return values[:, src] * sign, src, sign


def _position(spec: TrackSpec, name: str, c: dict):
    """``(lat rad, lon rad, alt m up or None, (lat key, lon key, vertical key or ""))`` of table ``name``'s
    position columns: geodetic (angles, and ``alt`` up or ``depth`` down), or ``ned``/``enu`` metres about the
    spec's origin by :func:`nespm_cli.nav.state.position_plus` (the inverse of ``nav.earth.ned_offset``)."""
    tab = spec.tables[name]
    horizontal, vertical = FRAME_KEYS[tab["position"]]
    vkey = next((k for k in vertical if k in tab), "")
    sign = 1.0 if vkey in UP_KEYS else -1.0
    up = None if not vkey else sign * scaled(c[vkey], "length", tab["length_unit"])
    if tab["position"] == "geodetic":
        lat, lon = (scaled(c[k], "angle", tab["angle_unit"]) for k in horizontal)
        return lat, lon, up, ("lat", "lon", vkey)
    ne = np.column_stack([scaled(c[k], "length", tab["length_unit"]) for k in horizontal])
    down = np.zeros(len(ne)) if up is None else -up
    pos = position_plus(np.broadcast_to(spec.origin, (len(ne), 3)), np.column_stack([ne, down]))
    return pos[:, 0], pos[:, 1], (None if up is None else pos[:, 2]), ("north", "east", vkey)


def _channel(spec: TrackSpec, name: str, path: Path) -> tuple:
    """``(path, t, z, keys, names)`` of a depth or fix file, converted (depth [m] down; fix ``[lat, lon(, alt)]``)."""
    tab = spec.tables[name]
    value_keys = column_keys(name, tab)[1:]
    c, _, names = _read(spec, name, path, nan_ok=value_keys)
    if name == "depth":
        key = value_keys[0]
        z = scaled(c[key], "length", tab["length_unit"]) * (-1.0 if key in UP_KEYS else 1.0)
        return path, _time(tab, c), z[:, None], ("depth.time", f"depth.{key}"), \
            _signed(names, ("time", key), (1, -1 if key in UP_KEYS else 1))
    lat, lon, alt, pk = _position(spec, name, c)
    keys = ("time", pk[0], pk[1]) + ((pk[2],) if pk[2] else ())
    z = np.column_stack([lat, lon] + ([] if alt is None else [alt]))
    return path, _time(tab, c), z, tuple(f"fix.{k}" for k in keys), \
        _signed(names, keys, (1, 1, 1, 1 if pk[2] in UP_KEYS else -1))


# ----------------------------------------------------------------------------- a spec without [gt]

INIT_NEEDED = ("lat", "lon", "v_north", "v_east", "v_down", "roll", "pitch", "yaw")
INIT_UNITS = {"angle_unit": "deg", "length_unit": "m", "speed_unit": "m/s"}  # its own defaults ([defaults] not)


def init_state(spec: TrackSpec, number: int) -> dict:
    """Track ``number``'s initial state from ``[init]`` (its ``[init.N]`` over the common keys): ``{"time": s or
    None, "pos": [lat rad, lon rad, alt m up], "v_n": (3,) m/s NED, "euler": (3,) rad}``. Refused in one line
    naming the key: a missing key, a latitude beyond ±90°, a longitude beyond ±180°, a pitch beyond ±90°, a roll
    or yaw beyond one turn, a speed of 20 m/s or more."""
    own = (spec.init or {}).get(number, {})
    tab = {**INIT_UNITS, **spec.init[0], **own}
    where = f"init.{number}" if own else "init"
    for key in INIT_NEEDED + (("depth",) if "alt" not in tab and "depth" not in tab else ()):
        if key not in tab:
            raise NespmError(f"{spec.path}: key '{where}.{key}' is missing (track {number}'s initial state needs "
                             "lat, lon, depth or alt, v_north, v_east, v_down, roll, pitch, yaw)")
    ang = factor("angle", tab["angle_unit"])
    lat, lon, roll, pitch, yaw = (float(tab[k]) * ang for k in ("lat", "lon", "roll", "pitch", "yaw"))
    up = float(tab["alt"]) if "alt" in tab else -float(tab["depth"])
    v_n = np.array([float(tab[k]) for k in ("v_north", "v_east", "v_down")]) * factor("speed", tab["speed_unit"])
    for key, value, limit in (("lat", lat, math.pi / 2), ("lon", lon, math.pi), ("pitch", pitch, math.pi / 2),
                              ("roll", roll, 2 * math.pi), ("yaw", yaw, 2 * math.pi)):
        if abs(value) > limit + 1e-12:
            raise NespmError(f"{spec.path}: key '{where}.{key}': {tab[key]!r} {tab['angle_unit']} is beyond "
                             f"±{math.degrees(limit):g} degrees (angle_unit = {tab['angle_unit']!r})")
    if np.linalg.norm(v_n) >= 20.0:
        raise NespmError(f"{spec.path}: key '{where}.v_north': the initial speed {np.linalg.norm(v_n):.4g} m/s is "
                         "20 m/s or more (speed_unit?)")
    wrap = lambda a: math.remainder(a, 2 * math.pi)  # noqa: E731  (-pi, pi]
    return {"time": None if "time" not in tab else float(tab["time"]),
            "pos": np.array([lat, lon, up * factor("length", tab["length_unit"])]),
            "v_n": v_n, "euler": np.array([wrap(roll), pitch, wrap(yaw)])}



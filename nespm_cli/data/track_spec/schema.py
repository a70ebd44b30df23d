"""The track spec: a TOML file beside the data that maps a user's own files onto the bench's channels; its
keys (:data:`SCHEMA`), reading and checking it (:func:`read_spec`), and finding it (:func:`find_spec`).

A data folder (``--data-dir DIR``) that holds :data:`SPEC_NAME` (``DIR/nespm-data.toml``) is read through
it instead of the A-KIT layout (docs/data.md has the format and a complete example). The spec names, per
channel (``[gt]``, ``[dvl]``, ``[imu]``, ``[depth]``, ``[fix]``), the file of each track (``file =
"run{N}/nav.csv"``: ``{N}`` is the track number, leading zeros allowed, no other pattern), its columns, their
units (:data:`~nespm_cli.data.track_spec.units.UNITS`), the time base (``time_unit``, ``time_zero``) and
offset (``time_offset`` [s], stamp minus GT time), the position frame (``geodetic``, or ``ned`` / ``enu``
metres about ``[origin]``), the vertical's sign (by the key that names it: ``alt``/``up``/``altitude``
positive up, ``depth``/``down`` positive down) and the IMU's and DVL's axes (``axes = "x,-y,-z"``, the
``--imu-axes`` syntax).

Recorded data without a ground truth: a spec without ``[gt]`` gives, instead, the ``[init]`` table (the
initial state: numbers, not columns; :data:`INIT_KEYS`, per track in ``[init.N]``) with a recorded
``[imu]``; its tracks are the DVL files found, their epochs the DVL's stamps (:func:`truth_free`;
docs/data.md, "Recorded data without ground truth").

This module only reads and checks the TOML file: the files of each track are found by
:mod:`~nespm_cli.data.track_spec.files`, read and converted by :mod:`~nespm_cli.data.track_spec.convert`,
checked by :mod:`~nespm_cli.data.track_spec.data_checks` and :func:`nespm_cli.data.tracks.load_track`.
Every refusal is a :class:`~nespm_cli.errors.NespmError` with one line naming the spec file and its key
(``.../nespm-data.toml: key 'gt.angle_unit': 'degree' is not a unit of angle (rad, deg)``).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from nespm_cli.data.corrections import axes_matrix
from nespm_cli.data.csvtable import link_problem
from nespm_cli.data.plausibility import printable
from nespm_cli.data.toml_keys import BOOL, INT, NUM, STR, TABLE, checked_table, read_toml
from nespm_cli.data.track_spec.units import SI, unit_error, unit_kind
from nespm_cli.errors import NespmError

# ----------------------------------------------------------------------------- the spec

SPEC_NAME = "nespm-data.toml"  # found automatically in the data folder
UNIT = "a unit"
FRAMES = ("geodetic", "ned", "enu")
CHANNELS = ("gt", "dvl", "imu", "depth", "fix")
#: ``[init]`` (a spec without ``[gt]``): the initial state at the first epoch, numbers in its own units
INIT_KEYS = {"time": NUM, "lat": NUM, "lon": NUM, "alt": NUM, "depth": NUM, "v_north": NUM, "v_east": NUM,
             "v_down": NUM, "roll": NUM, "pitch": NUM, "yaw": NUM, "angle_unit": UNIT, "length_unit": UNIT,
             "speed_unit": UNIT}
_FILE = {"file": STR, "time": STR, "time_unit": UNIT, "time_zero": NUM}
_SENSOR = {**_FILE, "time_offset": NUM, "optional": BOOL}
_POSITION = {"position": FRAMES, "lat": STR, "lon": STR, "alt": STR, "depth": STR, "north": STR, "east": STR,
             "down": STR, "up": STR, "angle_unit": UNIT, "length_unit": UNIT}
SIGNS = ("normal", "flipped")  # gt.pitch_sign, gt.roll_sign: the file's angle as the bench's, or its negative
#: the conventions' defaults (docs/data-format.md; checked against the data at load: nespm_cli.data.conventions)
CONVENTION_DEFAULTS = {"gt": {"yaw_convention": "ned", "pitch_sign": "normal", "roll_sign": "normal",
                              "accept_residual": False}, "dvl": {"frame": "body"}}
#: every key of a spec: ``{table: {key: type or tuple of choices}}`` ("" is the top level)
SCHEMA = {
    "": {"track": INT, "defaults": TABLE, "origin": TABLE, "init": TABLE, **{name: TABLE for name in CHANNELS}},
    "defaults": {"time_unit": UNIT, "time_zero": NUM, "angle_unit": UNIT, "length_unit": UNIT, "speed_unit": UNIT,
                 "acceleration_unit": UNIT, "rate_unit": UNIT},
    "origin": {"lat_deg": NUM, "lon_deg": NUM, "alt_m": NUM},
    "gt": {**_FILE, **_POSITION, "velocity": ("ned", "enu"), "v_north": STR, "v_east": STR, "v_down": STR,
           "v_up": STR, "roll": STR, "pitch": STR, "yaw": STR, "speed_unit": UNIT, "yaw_convention": ("ned", "enu"),
           "pitch_sign": SIGNS, "roll_sign": SIGNS, "accept_residual": BOOL},
    "dvl": {**_FILE, "time_offset": NUM, "x": STR, "y": STR, "z": STR, "axes": STR, "speed_unit": UNIT,
            "frame": ("body", "ned", "enu")},
    "imu": {**_SENSOR, "acc_x": STR, "acc_y": STR, "acc_z": STR, "gyro_x": STR, "gyro_y": STR, "gyro_z": STR,
            "axes": STR, "acceleration_unit": UNIT, "rate_unit": UNIT},
    "depth": {**_SENSOR, "depth": STR, "altitude": STR, "length_unit": UNIT},
    "fix": {**_SENSOR, **_POSITION},
    "init": INIT_KEYS,
}
#: position keys per frame: (horizontal keys, the vertical keys that may name the one vertical column)
FRAME_KEYS = {"geodetic": (("lat", "lon"), ("alt", "depth")), "ned": (("north", "east"), ("down",)),
              "enu": (("north", "east"), ("up",))}
UP_KEYS = ("alt", "up", "altitude")  # a vertical named by one of these is positive up; "depth", "down": down
VELOCITY_KEYS = {"ned": ("v_north", "v_east", "v_down"), "enu": ("v_north", "v_east", "v_up")}


@dataclass(frozen=True)
class TrackSpec:
    """A read and checked spec: its ``path``, the data ``folder`` (its parent), the channel ``tables``
    (``{name: {key: value}}`` with every default filled in), the ``origin`` ``[lat rad, lon rad, alt m]``
    (None without one), the track number ``track`` of file names without ``{N}`` and the keys the file itself
    sets (``declared``: ``{"gt.angle_unit", ...}``, a ``[defaults]`` key counted in every table it fills);
    ``init`` the ``[init]`` table of a spec without ``[gt]`` (``{0: the keys for every track, N: track N's
    own}``, checked; None with ``[gt]``)."""

    path: Path
    folder: Path
    tables: dict
    origin: np.ndarray | None = None
    track: int = 1
    declared: frozenset = frozenset()
    init: dict | None = None

    @property
    def anchor(self) -> str:
        """The table whose files define the tracks: ``"gt"``, or ``"dvl"`` without a ground truth."""
        return "gt" if "gt" in self.tables else "dvl"


# ----------------------------------------------------------------------------- reading the spec


def find_spec(folder: Path) -> Path | None:
    """``folder/nespm-data.toml`` if it is there, else None. Refused: a folder of that name, and a symbolic link
    of that name that reaches no file (a loop or a broken link: the folder would otherwise be read without its
    spec, silently)."""
    path = Path(folder) / SPEC_NAME
    if path.is_file():
        return path
    if path.exists():
        raise NespmError(f"{path}: not a file (the track spec {SPEC_NAME} must be a TOML file)")
    if path.is_symlink():
        raise NespmError(f"{path}: {link_problem(path) or 'a symbolic link that reaches no file'}; the track spec "
                         f"{SPEC_NAME} must be a readable TOML file (remove the link to read the folder without it)")
    return None


def read_spec(path: Path) -> TrackSpec:
    """The spec ``path``, checked, defaults filled in. Refused in one line naming ``path`` and the key: an
    unreadable or invalid TOML file, an unknown key, a value of the wrong type, a bad unit or choice, no
    ``[dvl]``, no ``[gt]`` without both ``[init]`` and ``[imu]`` (:func:`truth_free`), ``[init]`` with ``[gt]``, a missing ``file``/``time``/column key, keys of another position frame or velocity
    frame, two verticals (``alt`` and ``depth``), two keys naming one column, a bad ``axes``, a local frame
    without ``[origin]`` (or an origin outside ±90°/±180°), a non-finite number, a file pattern that is
    absolute, climbs out of the folder (``..``), holds braces other than ``{N}``, or has ``{N}`` in some
    tables but not others; ``track`` with ``{N}`` patterns or below 1."""
    path = Path(path)
    raw = read_toml(path, "the track spec")
    _keys(path, "", raw)
    init = truth_free(path, raw)
    parts = {name: _keys(path, name, raw[name]) for name in SCHEMA if name and name != "init" and name in raw}
    defaults = {**{f"{k}_unit": u for k, u in SI.items()}, "time_zero": 0.0, **parts.get("defaults", {})}
    tables, declared = {}, set()
    for name in CHANNELS:
        if name in parts:
            tab = parts[name]
            declared |= {f"{name}.{k}" for k in SCHEMA[name] if k in tab or k in parts.get("defaults", {})}
            for key in SCHEMA[name]:
                if key not in tab and key in defaults:
                    tab[key] = defaults[key]
            tab = {"time_offset": 0.0, "optional": False, "position": "geodetic", "velocity": "ned", "axes": "x,y,z",
                   **CONVENTION_DEFAULTS.get(name, {}), **tab}
            tables[name] = _columns_checked(path, name, tab)
    origin = _origin(path, parts.get("origin"), tables)
    track = _patterns(path, raw.get("track"), tables)
    return TrackSpec(path, path.parent, tables, origin, track, frozenset(declared), init)


def truth_free(path: Path, raw: dict) -> dict | None:
    """The ``[init]`` of a spec without ``[gt]`` (``{0: keys, N: track N's keys}``, each key checked), or None
    with ``[gt]``. Refused in one line naming the table: no ``[dvl]``; no ``[gt]`` and no ``[init]`` or no
    ``[imu]`` (the filters start from ``[init]`` and run on the recorded IMU); ``[init]`` beside ``[gt]``."""
    if "dvl" not in raw:
        raise NespmError(f"{path}: no [dvl] table (the DVL is required; docs/data.md)")
    if "gt" in raw:
        if "init" in raw:
            raise NespmError(f"{path}: key 'init': applies only without [gt] (with a ground truth its first epoch "
                             "is the initial state); remove one of them")
        return None
    for name, why in (("init", "the initial state at the first epoch: lat, lon, depth or alt, v_north, v_east, "
                               "v_down, roll, pitch, yaw"), ("imu", "the recorded IMU the filters run on")):
        if name not in raw:
            raise NespmError(f"{path}: no [gt] table and no [{name}] table (without a ground truth give [init] "
                             f"and [imu]; [{name}]: {why}; docs/data.md)")
    raw_init = raw["init"]
    if not isinstance(raw_init, dict):
        raise NespmError(f"{path}: key 'init' must be a table ([init])")
    own = {k: v for k, v in raw_init.items() if not (isinstance(v, dict) and k.isdigit())}
    out = {0: _init_keys(path, "init", own)}
    for k, v in raw_init.items():
        if k not in own:
            if int(k) < 1:
                raise NespmError(f"{path}: key 'init.{k}': a track number is at least 1")
            out[int(k)] = _init_keys(path, f"init.{k}", v)
    return out


def _init_keys(path: Path, name: str, table: dict) -> dict:
    """One ``[init]`` (or ``[init.N]``) table's keys checked (types, units, one vertical)."""
    def unit(key: str, value, full: str) -> bool:
        if INIT_KEYS[key] != UNIT:
            return False
        why = unit_error(unit_kind(key), value)
        if why:
            raise NespmError(f"{path}: key '{full}': {printable(why, 120)}")
        return True

    tab = checked_table(path, name, table, INIT_KEYS, special=unit)
    if "alt" in tab and "depth" in tab:
        raise NespmError(f"{path}: key '{name}.alt' and '{name}.depth' are both given: one vertical, alt (positive "
                         "up) or depth (positive down)")
    return tab



def _keys(path: Path, name: str, table) -> dict:
    """The keys of one table, each checked against :data:`SCHEMA` (type, choices, unit, finite number)."""
    def unit(key: str, value, full: str) -> bool:
        if SCHEMA[name][key] != UNIT:
            return False
        why = unit_error(unit_kind(key), value)
        if why:
            raise NespmError(f"{path}: key '{full}': {printable(why, 120)}")
        return True

    return checked_table(path, name, table, SCHEMA[name], special=unit)


def column_keys(name: str, tab: dict) -> tuple[str, ...]:
    """The keys of table ``name`` that name a column, in reading order (``time`` first)."""
    if name in ("gt", "fix"):
        horizontal, vertical = FRAME_KEYS[tab["position"]]
        keys = horizontal + tuple(k for k in vertical if k in tab)
        if name == "gt":
            keys += VELOCITY_KEYS[tab["velocity"]] + ("roll", "pitch", "yaw")
    else:
        keys = {"dvl": ("x", "y", "z"), "imu": ("acc_x", "acc_y", "acc_z", "gyro_x", "gyro_y", "gyro_z"),
                "depth": tuple(k for k in ("depth", "altitude") if k in tab)}[name]
    return ("time",) + keys


def _columns_checked(path: Path, name: str, tab: dict) -> dict:
    """``tab`` with its column keys checked: every needed one given, none of another frame, one vertical."""
    def bad(key: str, what: str) -> NespmError:
        return NespmError(f"{path}: key '{name}.{key}' {what}")

    for key in ("file", "time"):
        if key not in tab:
            raise bad(key, "is missing (" + ("the file of each track, e.g. \"run{N}/nav.csv\")" if key == "file"
                                             else "the name of the file's time column)"))
    column_like = {k for k, v in SCHEMA[name].items() if v == STR and k not in ("file", "axes")}
    if name in ("gt", "fix"):
        frame = tab["position"]
        horizontal, vertical = FRAME_KEYS[frame]
        allowed = set(horizontal + vertical) | {"time", "roll", "pitch", "yaw"} | set(VELOCITY_KEYS[tab["velocity"]])
        needed = horizontal + (("roll", "pitch", "yaw") + VELOCITY_KEYS[tab["velocity"]] if name == "gt" else ())
        for key in sorted(column_like & set(tab) - allowed):
            frame_of = "velocity" if key.startswith("v_") else "position"
            own = VELOCITY_KEYS[tab["velocity"]] if key.startswith("v_") else horizontal + vertical
            raise bad(key, f"does not apply with {frame_of} = {tab[frame_of]!r} (that frame's columns: "
                      f"{', '.join(own)})")
        for key in needed:
            if key not in tab:
                raise bad(key, f"is missing (position = {frame!r} needs {', '.join(horizontal)} and "
                          f"{' or '.join(vertical)}" + ("; velocity, roll, pitch and yaw columns too)" if name == "gt"
                                                        else ")"))
        given = [k for k in vertical if k in tab]
        if name == "gt" and not given:
            raise bad(vertical[0], f"is missing (the vertical column: {' or '.join(vertical)}; "
                      f"{', '.join(k for k in vertical if k in UP_KEYS) or 'none'} positive up, "
                      f"{', '.join(k for k in vertical if k not in UP_KEYS) or 'none'} positive down)")
        if len(given) > 1:
            raise bad(given[1], f"and '{name}.{given[0]}' are both given: one vertical column, alt (positive up) "
                      "or depth (positive down)")
    else:
        needed = [k for k in column_like if k not in ("depth", "altitude")]
        for key in [k for k in SCHEMA[name] if k in needed]:
            if key not in tab:
                raise bad(key, "is missing")
        if name == "depth" and ("depth" in tab) == ("altitude" in tab):
            raise bad("depth", "or 'depth.altitude': give exactly one (depth positive down, altitude positive up)")
    seen: dict[str, str] = {}
    for key in column_keys(name, tab):
        if tab[key] in seen:
            raise bad(key, f"names column {printable(repr(tab[key]), 40)}, as '{name}.{seen[tab[key]]}' does")
        seen[tab[key]] = key
    if name in ("dvl", "imu"):
        try:
            axes_matrix(tab["axes"])
        except NespmError:
            raise bad("axes", f"{printable(repr(tab['axes']), 40)} is not a signed permutation of x,y,z (name each "
                      "of x, y, z once, optionally with '-', e.g. \"x,-y,-z\"; body axis i is the file's axis at "
                      "position i)") from None
    return tab


def _origin(path: Path, origin: dict | None, tables: dict) -> np.ndarray | None:
    """``[lat rad, lon rad, alt m]`` of ``[origin]``, required when a position is local (ned, enu)."""
    local = [n for n in ("gt", "fix") if n in tables and tables[n]["position"] != "geodetic"]
    if origin is None:
        if local:
            raise NespmError(f"{path}: no [origin] table ({local[0]}.position = {tables[local[0]]['position']!r} "
                             "is metres about an origin: give origin.lat_deg, origin.lon_deg, origin.alt_m)")
        return None
    for key, limit in (("lat_deg", 90.0), ("lon_deg", 180.0)):
        if key not in origin:
            raise NespmError(f"{path}: key 'origin.{key}' is missing (the origin of local positions, degrees)")
        if abs(origin[key]) > limit:
            raise NespmError(f"{path}: key 'origin.{key}' is outside ±{limit:g} degrees: {origin[key]!r}")
    return np.array([math.radians(origin["lat_deg"]), math.radians(origin["lon_deg"]), float(origin.get("alt_m", 0.0))])


def _patterns(path: Path, track, tables: dict) -> int:
    """Check every ``file`` pattern; the track number of patterns without ``{N}`` (``track``, default 1)."""
    with_n = {}
    for name, tab in tables.items():
        pat = tab["file"]
        p = PurePosixPath(pat)
        if p.is_absolute() or "\\" in pat or ".." in p.parts or re.match(r"[A-Za-z]:", pat):
            raise NespmError(f"{path}: key '{name}.file': {printable(repr(pat), 60)} must be a path inside the data "
                             "folder, relative, with '/' (no '..')")
        if re.sub(r"\{N\}", "", pat).count("{") or re.sub(r"\{N\}", "", pat).count("}"):
            raise NespmError(f"{path}: key '{name}.file': {printable(repr(pat), 60)}: only {{N}} (the track number) "
                             "may stand in braces")
        with_n[name] = "{N}" in pat
    if len(set(with_n.values())) > 1:
        a = next(n for n, v in with_n.items() if v)
        b = next(n for n, v in with_n.items() if not v)
        raise NespmError(f"{path}: key '{b}.file' has no {{N}} but '{a}.file' has: the patterns of one folder are all "
                         "per track ({N}) or all one track's")
    if track is not None and any(with_n.values()):
        raise NespmError(f"{path}: key 'track' applies only to file names without {{N}} (theirs is the track number)")
    track = 1 if track is None else track
    if track < 1:
        raise NespmError(f"{path}: key 'track' must be at least 1, got {track}")
    return track


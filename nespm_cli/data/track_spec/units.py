"""The units of a track spec (docs/data.md, "Units"): each unit a factor to the bench's unit, and the two
conversions the spec's reader applies to whole columns (:func:`scaled`, :func:`to_seconds`).

Nothing here reads a file or a spec: :mod:`~nespm_cli.data.track_spec.schema` checks that a spec's ``*_unit``
keys name a unit of :data:`UNITS`; :mod:`~nespm_cli.data.track_spec.convert` converts the files' columns with
the factors.
"""
from __future__ import annotations

import math

import numpy as np

# Every unit is a factor to the bench's unit (docs/conventions.md: s, rad, m, m/s, m/s², rad/s): value_SI =
# value x factor, except time, *divided* by its ticks per second (one correctly rounded division of a count of
# ms or us, :func:`to_seconds`). Length and speed factors are exact by definition (1 ft = 0.3048 m, 1 kn =
# 1852 m / 3600 s); 1 g is standard gravity.

STANDARD_GRAVITY = 9.80665  # [m/s^2] 1 g (the value of the unit g, not the local gravity of nav.earth)
#: unit kind -> {unit name: factor to the SI unit}; for ``"time"`` the ticks per second
UNITS: dict[str, dict[str, float]] = {
    "time": {"s": 1.0, "ms": 1e3, "us": 1e6, "ns": 1e9},
    "angle": {"rad": 1.0, "deg": math.pi / 180.0},
    "length": {"m": 1.0, "ft": 0.3048},
    "speed": {"m/s": 1.0, "cm/s": 0.01, "mm/s": 0.001, "ft/s": 0.3048, "kn": 1852.0 / 3600.0},
    "acceleration": {"m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0, "g": STANDARD_GRAVITY},
    "rate": {"rad/s": 1.0, "deg/s": math.pi / 180.0},
}
#: the SI unit of each kind (what the A-KIT files hold, and the default of a spec)
SI = {kind: next(iter(table)) for kind, table in UNITS.items()}


def unit_kind(key: str) -> str | None:
    """The unit kind a spec key names (``"angle_unit"`` -> ``"angle"``), or None if it names no unit."""
    kind = key[: -len("_unit")] if key.endswith("_unit") else None
    return kind if kind in UNITS else None


def factor(kind: str, unit: str) -> float:
    """The factor of ``unit`` of ``kind`` (:data:`UNITS`); raises KeyError on an unknown one."""
    return UNITS[kind][unit]


def unit_error(kind: str, unit) -> str | None:
    """Why ``unit`` is not a unit of ``kind`` (one phrase for a message), or None if it is one."""
    if isinstance(unit, str) and unit in UNITS[kind]:
        return None
    return f"{unit!r} is not a unit of {kind} ({', '.join(UNITS[kind])})"


def scaled(values: np.ndarray, kind: str, unit: str) -> np.ndarray:
    """``values`` in ``unit`` (of ``kind``, not time) as SI values (a new float array). The SI unit
    itself returns the values unchanged bit for bit."""
    f = factor(kind, unit)
    values = np.asarray(values, dtype=float)
    return values.copy() if f == 1.0 else values * f


def to_seconds(stamps: np.ndarray, unit: str, zero: float = 0.0, offset: float = 0.0) -> np.ndarray:
    """Stamps ``stamps`` counted in ``unit`` (``s``, ``ms``, ``us``, ``ns``) as GT time [s]:
    ``(stamps - zero) / ticks_per_second - offset``.

    ``zero`` is in ``unit`` (subtracted first, exactly for integer counts below 2**53, e.g. the UNIX
    time of the recording's start); ``offset`` [s] is the file's *stamp minus GT time*
    (docs/conventions.md), so a DVL stamped 0.07 s after the truth has ``offset = 0.07``. With the
    defaults and ``unit = "s"`` the stamps are returned unchanged bit for bit."""
    t = np.asarray(stamps, dtype=float) - float(zero)
    ticks = factor("time", unit)
    if ticks != 1.0:
        t = t / ticks
    return t - float(offset)

"""The checks only a track spec's data need (docs/data.md), on a track read and converted by
:mod:`~nespm_cli.data.track_spec.convert`: :func:`check_vertical_sign` (the GT's vertical position against its
vertical velocity), :func:`check_channel` (a depth or fix file's stamps, NaN rows, ranges as
:mod:`nespm_cli.data.sensor_files` checks them, and its vertical's sign against the GT's), and the messages
of the common checks in the file's own column names (:func:`relabel`, :func:`angle_hint`,
:func:`stamps_checked`). Every refusal is one line naming the file, its column and the spec key.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from nespm_cli.data.csvtable import check_nan_rows
from nespm_cli.data.sensor_files import (DEPTH_COLUMNS, DEPTH_MAX, DEPTH_MIN, FIX_ALT_COLUMN, FIX_COLUMNS,
                                         MAX_ABS_FIX_ALT, TIME, check_stamps)
from nespm_cli.data.track_spec.convert import SpecTrack, labels
from nespm_cli.data.track_spec.schema import UP_KEYS, TrackSpec
from nespm_cli.errors import NespmError

VERTICAL_SIGN_MIN = 0.02  # [m/s] RMS mismatch of GT vertical position and velocity below which no sign is judged
#                           (the 13 real Snapir tracks: 0.002-0.034 m/s as they are, 0.028-1.04 with the sign flipped)
DEPTH_SIGN_MIN = 1.0  # [m] median |depth - GT depth| below which a depth or fix altitude's sign is not judged


def angle_hint(spec: TrackSpec) -> str | None:
    """The text replacing the "(degrees instead of radians?)" hint of an angle finding when the spec declares
    ``gt.angle_unit`` (in ``[gt]`` or ``[defaults]``); None when it does not (the hint stays)."""
    if "gt.angle_unit" not in spec.declared:
        return None
    unit = spec.tables["gt"]["angle_unit"]
    if unit == "rad":
        return f"(key 'gt.angle_unit' of {spec.path.name} declares 'rad'; a column in degrees needs 'deg')"
    return (f"(after the declared gt.angle_unit = {unit!r} of {spec.path.name}; roll and yaw within one turn are "
            "wrapped, so the column holds other values)")


def stamps_checked(path: Path, t: np.ndarray, t_gt: np.ndarray, gt_name: str, label: str = TIME) -> None:
    """:func:`nespm_cli.data.sensor_files.check_stamps`, its message naming the time column ``label``."""
    try:
        check_stamps(path, t, t_gt, gt_name)
    except NespmError as exc:
        if label == TIME:
            raise
        raise NespmError(str(exc).replace(f"column '{TIME}'", f"column '{label}'", 1)) from None


def check_vertical_sign(spec_path: Path, track: SpecTrack, gt_labels: tuple) -> None:
    """Refuse a GT whose vertical position moves against its vertical velocity: the RMS over the epochs of
    ``|down increment - trapezoid integral of v_D| / dt`` [m/s] above :data:`VERTICAL_SIGN_MIN` and more than
    twice that with the position's sign flipped (a depth mapped as an altitude, ``down`` for ``up``, or the
    velocity's vertical sign wrong). Needs strictly increasing times (checked before)."""
    t, alt, vd = track.gt[:, 0], track.gt[:, 3], track.gt[:, 6]
    dt = np.diff(t)
    inc, integ = -np.diff(alt), 0.5 * (vd[1:] + vd[:-1]) * dt
    same, flip = (float(np.sqrt(np.mean(((inc + s * integ) / dt) ** 2))) for s in (-1.0, 1.0))
    if same > VERTICAL_SIGN_MIN and flip < 0.5 * same:
        key = track.gt_keys[3]
        raise NespmError(
            f"{track.gt_path}: columns '{gt_labels[3]}', '{gt_labels[6]}': the vertical position moves against the "
            f"vertical velocity (RMS mismatch {same:.3g} m/s, {flip:.3g} m/s with the position's sign flipped): "
            f"{spec_path.name} key '{key}' says positive {_direction(key)}; "
            "map an altitude as alt (or up), a depth as depth (or down), or check the velocity's vertical")


def check_channel(spec_path: Path, track: SpecTrack, name: str, t_ref: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``(t, z)`` of the converted depth or fix file ``track.channels[name]``, checked against the GT (its
    time [s] and altitude [m, up]): stamps (strictly increasing, in the GT span), NaN in all values of a row
    or none, the vertical's sign (:func:`_vertical_fit`), then the ranges of
    :mod:`nespm_cli.data.sensor_files` (depth within [DEPTH_MIN, DEPTH_MAX] m, |lat| <= pi/2, |lon| <= pi,
    |alt| <= MAX_ABS_FIX_ALT m). Without a GT (``track.gt`` None) the stamps are checked against the epochs
    ``t_ref`` (N,) [s] and no sign against a GT."""
    path, t, z, keys, names = track.channels[name]
    t_gt = track.gt[:, 0] if track.gt is not None else np.asarray(t_ref, dtype=float)
    bench = DEPTH_COLUMNS if name == "depth" else FIX_COLUMNS + ((FIX_ALT_COLUMN,) if z.shape[1] == 3 else ())
    lab = labels(names, bench)
    stamps_checked(path, t, t_gt, track.gt_path.name if track.gt is not None else "the DVL's epochs", lab[0])
    check_nan_rows(path, z, lab[1:], "no measurement at this stamp")
    if track.gt is not None and (name == "depth" or z.shape[1] == 3):
        alt_gt = track.gt[:, 3]
        j, sign = (0, -1.0) if name == "depth" else (2, 1.0)
        _vertical_fit(spec_path, path, z[:, j], sign * np.interp(t, t_gt, alt_gt), lab[j + 1], keys[j + 1],
                      track.gt_keys[3], name == "depth")
    if name == "depth":
        _bounds(path, z[:, 0], lab[1], DEPTH_MIN, DEPTH_MAX,
                lambda v: f"{v!r} is outside {DEPTH_MIN:g} .. {DEPTH_MAX:g} m (metres, positive down, expected)")
    else:
        _bounds(path, z[:, 0], lab[1], -np.pi / 2, np.pi / 2, lambda v: f"|{v!r}| > pi/2 (radians expected)")
        _bounds(path, z[:, 1], lab[2], -np.pi, np.pi, lambda v: f"|{v!r}| > pi (radians expected)")
        if z.shape[1] == 3:
            _bounds(path, z[:, 2], lab[3], -MAX_ABS_FIX_ALT, MAX_ABS_FIX_ALT,
                    lambda v: f"|{v!r}| > {MAX_ABS_FIX_ALT:g} m (metres, positive up, expected)")
    return t, z


def _vertical_fit(spec_path: Path, path: Path, value: np.ndarray, gt: np.ndarray, label: str, key: str, gt_key: str,
                  down: bool) -> None:
    """Refuse vertical values (K,) [m] that fit the negated GT vertical ``gt`` (K,) [m, the same sign
    convention: depth if ``down``, else altitude]: the median |value - gt| above :data:`DEPTH_SIGN_MIN` and
    more than twice the median |value + gt| (NaN rows, no measurement, left out). The file or the GT has the
    wrong sign: the message names both keys."""
    ok = np.isfinite(value)
    if not ok.any():
        return
    same, flip = float(np.median(np.abs(value[ok] - gt[ok]))), float(np.median(np.abs(value[ok] + gt[ok])))
    if same > DEPTH_SIGN_MIN and flip < 0.5 * same:
        is_, other = ("depth", "altitude") if down else ("altitude", "depth")
        raise NespmError(
            f"{path}: column '{label}': the values fit the GT's {other}, not its {is_}: median |value - GT {is_}| "
            f"{same:.3g} m, |value + GT {is_}| {flip:.3g} m; {spec_path.name} key '{key}' says positive "
            f"{'down' if down else 'up'} and '{gt_key}' says positive {_direction(gt_key)}: one of the two columns "
            "has the other sign (map it with the other key: alt/up/altitude positive up, depth/down positive down)")


def _direction(key: str) -> str:
    """``"up"`` or ``"down"``: the sign of the vertical named by the spec key ``key`` (``gt.depth``)."""
    return "up" if key.split(".")[-1] in UP_KEYS else "down"


def _bounds(path: Path, x: np.ndarray, col: str, lo: float, hi: float, say) -> None:
    """Refuse the first value of ``x`` outside [lo, hi] (NaN, no measurement, passes) with ``say(value)``."""
    bad = np.flatnonzero((x < lo) | (x > hi))
    if bad.size:
        r = int(bad[0])
        raise NespmError(f"{path}: data row {r + 1}, column '{col}': {say(float(x[r]))}")


UNITS_HINT = "(degrees instead of radians?)"


def relabel(findings: list, mapping: dict, hint: str | None = None) -> list:
    """Plausibility findings with their bench column names replaced by ``mapping`` (``{bench: label}``) and,
    with ``hint``, the units hint :data:`UNITS_HINT` replaced by it (the units were declared)."""
    out = []
    for f in findings:
        cols = f.column and ", ".join(mapping.get(c.strip(), c.strip()) for c in f.column.split(","))
        text = f.message.replace(UNITS_HINT, hint) if hint else f.message
        out.append(dataclasses.replace(f, column=cols, message=text))
    return out

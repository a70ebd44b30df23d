"""Corrections of a recorded track: IMU axis mapping, IMU and DVL time offsets, the window to use.

``nespm check`` estimates them from the data (docs/checking-data.md); ``mc``, ``run``, ``sweep``
and ``train`` apply them with ``--imu-axes``, ``--imu-time-offset``, ``--dvl-time-offset``,
``--window`` or per track with ``--corrections FILE`` (the ``corrections.json`` that ``check``
writes). Conventions (docs/conventions.md, "Recorded data"):

* ``imu_axes = "x,-y,z"``: corrected body axis i is the signed recorded axis named at
  position i, i.e. ``f_b = A f_recorded`` with ``A`` a signed permutation (:func:`axes_matrix`).
* a time offset is *stamp minus GT time* [s]: the sample stamped ``s`` was measured at GT time
  ``s - offset``; the correction subtracts it from the stamps.
* an IMU clock drift ``d`` [s/s] lets that offset grow with time: ``stamp - t_GT = offset + d t_GT``,
  so the correction is ``t_GT = (stamp - offset) / (1 + d)``. (The 2024-01 Snapir IMU files against
  the 2024-06 GT: ``d`` about -1/400, the GT's 400/399 s epoch step against 1 s.)
* ``window = (start, end)`` in the GT file's time [s]: only the GT epochs inside it are used.
  After the offsets, epochs at the ends that the shifted IMU or DVL does not cover are dropped
  too (at most ``ceil(|offset| / GT step)`` at each end).
"""
from __future__ import annotations

import dataclasses
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nespm_cli.data.plausibility import printable
from nespm_cli.data.track import Track
from nespm_cli.errors import NespmError

IDENTITY_AXES = "x,y,z"
MAX_TIME_OFFSET = 10.0  # [s] larger offsets are refused as an option mistake (the check searches +-4 s)


@dataclass(frozen=True)
class Corrections:
    """The corrections of one track (defaults: none)."""

    imu_axes: str = IDENTITY_AXES
    imu_time_offset: float = 0.0  # [s] IMU stamp minus GT time (at GT time 0)
    imu_time_drift: float = 0.0  # [s/s] growth of that offset per second of GT time
    dvl_time_offset: float = 0.0  # [s] DVL stamp minus GT time
    window: tuple | None = None  # (start, end) [s] in the GT file's time, or None: the whole track

    @property
    def is_identity(self) -> bool:
        """No correction at all (an identity axis mapping, no offsets, no window)."""
        return not self.options()

    def options(self) -> str:
        """The command-line options that apply these corrections (empty when there are none)."""
        out = []
        if axes_matrix(self.imu_axes).tolist() != np.eye(3).tolist():
            out.append(f"--imu-axes {self.imu_axes}")
        if self.imu_time_offset:
            out.append(f"--imu-time-offset {self.imu_time_offset:g}")
        if self.imu_time_drift:
            out.append(f"--imu-time-drift {self.imu_time_drift:g}")
        if self.dvl_time_offset:
            out.append(f"--dvl-time-offset {self.dvl_time_offset:g}")
        if self.window is not None:
            out.append(f"--window {self.window[0]:g}:{self.window[1]:g}")
        return " ".join(out)


def axes_matrix(text: str) -> np.ndarray:
    """The signed permutation (3, 3) of an axis mapping like ``"x,-y,z"``: ``f_b = A @ f_recorded``.

    Raises NespmError (one line) unless ``text`` names each of x, y, z once, each optionally
    with a sign.
    """
    parts = [p.strip().lower() for p in str(text).split(",")]
    A = np.zeros((3, 3))
    ok = len(parts) == 3
    for i, p in enumerate(parts if ok else []):
        sign = -1.0 if p.startswith("-") else 1.0
        axis = p.lstrip("+-")
        if axis not in ("x", "y", "z") or len(p) - len(axis) > 1:
            ok = False
            break
        A[i, "xyz".index(axis)] = sign
    if not ok or not np.allclose(np.abs(A).sum(axis=0), 1.0):
        raise NespmError(f"--imu-axes {text!r} is not a signed permutation of x,y,z "
                         "(name each of x, y, z once, optionally with '-', e.g. x,-y,z)")
    return A


def axes_text(A: np.ndarray) -> str:
    """Inverse of :func:`axes_matrix`: ``"x,-y,z"`` of a signed permutation (3, 3)."""
    out = []
    for row in np.asarray(A):
        j = int(np.argmax(np.abs(row)))
        out.append(("-" if row[j] < 0 else "") + "xyz"[j])
    return ",".join(out)


def parse_window(text: str | None) -> tuple | None:
    """``"20:400"`` -> ``(20.0, 400.0)``; None or ``""`` -> None. One-line error otherwise."""
    if text is None or str(text).strip() == "":
        return None
    try:
        a, b = (float(x) for x in str(text).split(":"))
    except ValueError:
        raise NespmError(f"--window {text!r}: expected START:END in seconds of the GT file, e.g. 20:400") from None
    if not (math.isfinite(a) and math.isfinite(b) and a < b):
        raise NespmError(f"--window {text!r}: START and END must be finite with START < END")
    return (a, b)


def check_offset(flag: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and abs(value) <= MAX_TIME_OFFSET):
        raise NespmError(f"{flag} {value:g}: must be a finite number of seconds within +-{MAX_TIME_OFFSET:g}")
    return value


MAX_TIME_DRIFT = 0.01  # [s/s] a clock 1 % off is refused as an option mistake


def check_drift(flag: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and abs(value) <= MAX_TIME_DRIFT):
        raise NespmError(f"{flag} {value:g}: must be a finite clock drift [s/s] within +-{MAX_TIME_DRIFT:g}")
    return value


TRACK_KEY = re.compile(r"[0-9]+")  # a track key: ASCII digits only ("²".isdigit() is True)


class _DuplicateKey(ValueError):
    """A JSON object names one key twice (``json`` would silently keep the last)."""


def _unique_object(pairs: list) -> dict:
    out = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


def _number(where: str, key: str, value) -> float:
    """``value`` (of ``key``) as a float; a JSON number only: a boolean, string, null, list or
    object is refused (``float(true)`` would be 1.0 s), so is an integer beyond float range."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise NespmError(f"{where}, key {key!r}: expected a number, got {_json_kind(value)}")
    try:
        return float(value)
    except OverflowError:
        raise NespmError(f"{where}, key {key!r}: number out of range") from None


def _json_kind(value) -> str:
    """What a JSON value is, for a message: ``the boolean true``, ``the string '1.5'``, ``null``, ..."""
    if isinstance(value, bool):
        return f"the boolean {str(value).lower()}"
    if isinstance(value, str):
        return f"the string {printable(value, 40)!r}"
    if value is None:
        return "null"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    return "an object" if isinstance(value, dict) else f"the number {value!r}"


def read_corrections(path: str | Path) -> dict[int, Corrections]:
    """Per-track corrections from a ``corrections.json`` written by ``nespm check``.

    Format: ``{"tracks": {"5": {"imu_axes": "x,-y,z", "imu_time_offset": -0.03, "imu_time_drift": 0.0,
    "dvl_time_offset": 0.0, "window": [20.0, 400.0]}, ...}}`` (every key of a track optional;
    offsets [s], drift [s/s], window [s] of the GT file's time or null).

    Raises NespmError (one line naming the file, and the track and key where there is one) on an
    unreadable file, text that is not UTF-8 or not JSON (nesting too deep included), a key that
    appears twice in one object, a track key that is not a track number (ASCII digits), two keys
    of one track (``"5"`` and ``"05"``), an unknown key, or a value of the wrong type (a boolean,
    string or null where a number is expected; ``imu_axes`` a string; ``window`` null or a list
    of two numbers) or out of range.
    """
    p = Path(path)
    name = f"--corrections {p}"
    try:
        raw = json.loads(p.read_text(encoding="utf-8"), object_pairs_hook=_unique_object)
    except OSError as exc:
        raise NespmError(f"{name}: cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise NespmError(f"{name}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except _DuplicateKey as exc:
        raise NespmError(f"{name}: key {printable(exc.args[0], 40)!r} appears twice in one object") from None
    except RecursionError:
        raise NespmError(f"{name}: not valid JSON (nested too deeply)") from None
    except ValueError as exc:
        raise NespmError(f"{name}: not valid JSON ({printable(exc, 100)})") from None
    tracks = raw.get("tracks") if isinstance(raw, dict) else None
    if not isinstance(tracks, dict):
        raise NespmError(f"{name}: expected an object with a 'tracks' object")
    out: dict[int, Corrections] = {}
    keys: dict[int, str] = {}
    known = {f.name for f in dataclasses.fields(Corrections)}
    for key, val in tracks.items():
        shown = printable(key, 40)
        if not TRACK_KEY.fullmatch(key):
            raise NespmError(f"{name}: key {shown!r} under 'tracks' is not a track number (ASCII digits, e.g. \"5\")")
        n = int(key)
        if n in keys:
            raise NespmError(f"{name}: keys {keys[n]!r} and {shown!r} are both track {n}; keep one")
        keys[n] = key
        where = f"{name}: track {shown}"
        if not isinstance(val, dict):
            raise NespmError(f"{where}: expected an object, got {_json_kind(val)}")
        bad = set(val) - known
        if bad:
            raise NespmError(f"{where}: unknown key {printable(sorted(bad)[0], 40)!r} "
                             f"(known: {', '.join(sorted(known))})")
        axes = val.get("imu_axes", IDENTITY_AXES)
        if not isinstance(axes, str):
            raise NespmError(f"{where}, key 'imu_axes': expected a string like \"x,-y,z\", got {_json_kind(axes)}")
        window = val.get("window")
        if window is not None:
            if not (isinstance(window, list) and len(window) == 2):
                raise NespmError(f"{where}, key 'window': expected null or [START, END] in seconds, "
                                 f"got {_json_kind(window)}")
            window = tuple(_number(where, "window", w) for w in window)
            if not (math.isfinite(window[0]) and math.isfinite(window[1]) and window[0] < window[1]):
                raise NespmError(f"{where}, key 'window': [{window[0]:g}, {window[1]:g}]: START and END must be "
                                 "finite with START < END")
        try:
            c = Corrections(
                imu_axes=axes,
                imu_time_offset=check_offset("imu_time_offset",
                                             _number(where, "imu_time_offset", val.get("imu_time_offset", 0.0))),
                imu_time_drift=check_drift("imu_time_drift",
                                           _number(where, "imu_time_drift", val.get("imu_time_drift", 0.0))),
                dvl_time_offset=check_offset("dvl_time_offset",
                                             _number(where, "dvl_time_offset", val.get("dvl_time_offset", 0.0))),
                window=window,
            )
            axes_matrix(c.imu_axes)
        except NespmError as exc:
            msg = str(exc)
            raise NespmError(msg if msg.startswith(where) else f"{where}: {msg}") from None
        out[n] = c
    return out


def write_corrections(per_track: dict[int, Corrections]) -> str:
    """The JSON text of :func:`read_corrections`'s format."""
    tracks = {}
    for n, c in sorted(per_track.items()):
        d = dataclasses.asdict(c)
        d["window"] = None if c.window is None else list(c.window)
        tracks[str(n)] = d
    return json.dumps({"tracks": tracks}, indent=2) + "\n"


def resolve(tracks, imu: str, corrections: str | None = None, imu_axes: str = IDENTITY_AXES,
            imu_time_offset: float = 0.0, dvl_time_offset: float = 0.0,
            window: str | None = None, imu_time_drift: float = 0.0) -> dict[int, Corrections]:
    """The corrections of every track: the ``corrections`` file's values (:func:`read_corrections`),
    each overridden for every track by an option given with a non-default value.

    With a synthesized IMU (``imu != "recorded"``) the file's IMU corrections are ignored and
    the IMU options are refused. Raises NespmError (one line) on a bad value, and when a file is
    given that has no entry for one of ``tracks`` (a track the check did not see is not silently
    left uncorrected).
    """
    per_track = read_corrections(corrections) if corrections else {}
    if corrections:
        missing = [int(n) for n in tracks if int(n) not in per_track]
        if missing:
            have = ", ".join(map(str, sorted(per_track))) or "none"
            raise NespmError(f"--corrections {Path(corrections)}: no entry for track {missing[0]} (the file has "
                             f"tracks: {have}); run `nespm check` on that track, or leave out --corrections")
    axes_matrix(imu_axes)
    imu_off = check_offset("--imu-time-offset", imu_time_offset)
    imu_drift = check_drift("--imu-time-drift", imu_time_drift)
    dvl_off = check_offset("--dvl-time-offset", dvl_time_offset)
    win = parse_window(window)
    if imu != "recorded" and (imu_off or imu_drift or imu_axes != IDENTITY_AXES):
        raise NespmError("--imu-axes, --imu-time-offset and --imu-time-drift correct a recorded IMU: "
                         "use them with --imu recorded")
    if imu != "recorded":  # a file's IMU corrections do not apply to a synthesized IMU
        per_track = {n: dataclasses.replace(c, imu_axes=IDENTITY_AXES, imu_time_offset=0.0, imu_time_drift=0.0)
                     for n, c in per_track.items()}
    out = {}
    for n in tracks:
        c = per_track.get(int(n), Corrections())
        out[int(n)] = dataclasses.replace(
            c,
            imu_axes=imu_axes if imu_axes != IDENTITY_AXES else c.imu_axes,
            imu_time_offset=imu_off if imu_off else c.imu_time_offset,
            imu_time_drift=imu_drift if imu_drift else c.imu_time_drift,
            dvl_time_offset=dvl_off if dvl_off else c.dvl_time_offset,
            window=win if win is not None else c.window,
        )
    return out


def apply_corrections(track: Track, corr: Corrections) -> Track:
    """The track as the corrections say it was measured (a new :class:`Track`).

    * IMU: axes mapped by :func:`axes_matrix`, stamps to GT time
      ``(stamp - imu_time_offset) / (1 + imu_time_drift)``;
    * DVL: re-sampled at the GT epochs from its stamps minus ``dvl_time_offset`` (linear
      interpolation between the 1 Hz samples; an epoch next to a missing, NaN, sample is NaN);
      a DVL recorded at its own stamps (``channels["dvl"]``) keeps its samples, stamps shifted;
    * epochs: those inside ``window`` and covered by the shifted IMU and DVL.

    Raises NespmError naming the track when fewer than 4 epochs remain.
    """
    if corr == Corrections():
        return track
    t = np.asarray(track.t, dtype=float)
    keep = np.ones(len(t), dtype=bool)
    if corr.window is not None:
        keep &= (t >= corr.window[0] - 1e-9) & (t <= corr.window[1] + 1e-9)
    dvl = np.asarray(track.dvl, dtype=float)
    if corr.dvl_time_offset:
        stamps = t - corr.dvl_time_offset  # GT time of each DVL sample
        keep &= (t >= stamps[0] - 1e-9) & (t <= stamps[-1] + 1e-9)
        dvl = np.stack([np.interp(t, stamps, dvl[:, i]) for i in range(3)], axis=-1)
    imu = None if track.imu is None else np.array(track.imu, dtype=float)
    if imu is not None:
        A = axes_matrix(corr.imu_axes)
        imu[:, 1:4] = imu[:, 1:4] @ A.T
        imu[:, 4:7] = imu[:, 4:7] @ A.T
        imu[:, 0] = (imu[:, 0] - corr.imu_time_offset) / (1.0 + corr.imu_time_drift)
        keep &= (t >= imu[0, 0] - 1e-9) & (t <= imu[-1, 0] + 1e-9)
    idx = np.flatnonzero(keep)
    if len(idx) < 4 or np.any(np.diff(idx) != 1):
        what = f"window {corr.window}" if corr.window is not None else "the time offsets"
        raise NespmError(f"track {track.number}: after {what} only {len(idx)} GT epochs remain (need at least 4)")
    s = slice(int(idx[0]), int(idx[-1]) + 1)
    channels = dict(track.channels)
    if corr.dvl_time_offset and "dvl" in channels:  # a DVL at its own stamps: to GT time, not re-sampled
        t_dvl, v_dvl = channels["dvl"]
        channels["dvl"] = (np.asarray(t_dvl, dtype=float) - corr.dvl_time_offset, v_dvl)
    return dataclasses.replace(track, t=t[s], pos=track.pos[s], v_n=track.v_n[s], euler=track.euler[s],
                               dvl=dvl[s], imu=imu, channels=channels)

"""Physical plausibility checks of a ground-truth track (GT and DVL arrays already read and finite,
except NaN DVL rows: epochs without a DVL measurement, skipped).

Each check is a pure, vectorized function returning a list of :class:`Finding` (empty: nothing
looks wrong). A finding is an ``"error"`` (the data cannot be what the columns say: degrees for
radians, milliseconds for seconds, a gap, swapped columns) or a ``"warning"`` (unusual, but a
legitimate track could do it: an irregular epoch step, a fast turn, an AUV far above the sea).
:func:`nespm_cli.data.tracks.load_track` raises :class:`~nespm_cli.errors.NespmError` on the first
error and hands the warnings to :func:`emit` (mode ``"warn"`` | ``"ignore"`` | ``"error"``, see
:func:`set_warning_mode`).

Units: time [s], angles [rad], lat/lon [rad], altitude [m] positive up, velocities [m/s].
Rows in findings are 1-based *data rows* (after the header), as in every loader message.

The thresholds were checked against the 13 real Snapir tracks (1 Hz, 400/399 s steps), the
embedded tracks and simulated REMUS 100 tracks, none of which gives a finding (measured maxima
are quoted next to each constant).
"""
from __future__ import annotations

import warnings as _warnings
from dataclasses import dataclass

import numpy as np

from nespm_cli.nav.earth import radii

# ----------------------------------------------------------------------------- thresholds

# Angles [rad]. An Euler angle in radians lies in [-pi, pi]; a small slack for rounding in files.
ANGLE_LIMIT = np.pi + 1e-6  # [rad]; beyond: degrees instead of radians (or another column)
PITCH_LIMIT = np.pi / 2 + 1e-6  # [rad]; ZYX pitch is in [-pi/2, pi/2] by construction
# Attitude rate between consecutive epochs, |unwrapped step| / dt [rad/s] (a +-2 pi wrap is no step).
# AUVs turn at up to ~14-18 deg/s in yaw; the real Snapir GT reaches 17.8 deg/s in yaw, 14.4 in
# pitch and 26.9 deg/s in roll (track 9, a short roll oscillation). 45 deg/s is beyond any
# AUV (and a 45 deg jump in one 1 Hz epoch means a wrong unit, a glitch or a wrong column).
ANGLE_RATE_ERROR = np.radians(45.0)  # [rad/s] error above this
# 35 deg/s: 1.3x the fastest real roll rate; a fast but possible manoeuvre (or a bad INS epoch).
ANGLE_RATE_WARN = np.radians(35.0)  # [rad/s] warning above this

# Altitude [m], positive up. The deepest ocean is ~10,994 m: |alt| above 11 km is a unit error
# (mm, cm, a factor on the column). An AUV is at most at the surface; +100 m is far above any sea
# surface reference (the real tracks: -35 .. 0 m), a sign convention (depth positive) or a unit issue.
MAX_ABS_ALT = 11_000.0  # [m] error beyond
MAX_ALT_UP = 100.0  # [m] warning above (a legitimate recording could use another height datum)

# Epoch spacing [s] of the GT (and so the DVL, which is on the same epochs).
# A navigation GT / DVL log is sampled at ~0.1-10 Hz (the real files: 1.0025 s). A median step above
# 10 s is typically time in milliseconds; below 0.01 s time in a coarser unit or not the GT log.
MAX_MEDIAN_STEP = 10.0  # [s] error above
MIN_MEDIAN_STEP = 0.01  # [s] error below
GAP_FACTOR = 5.0  # a step > 5x the median is a gap (lost epochs): the filters would diverge across it
STEP_TOL = 0.01  # relative; a step off the median by more than 1 % (not a gap) is a warning
#                  (the real files vary by 4e-14 relative; loggers with jitter may legitimately exceed it)

# GT velocity against its own position increments, per epoch [m/s] equivalent:
# | position increment (N, E, D in m) - trapezoid integral of v_n | / dt.
# The real GT (post-processed INS) gives an RMS of 0.01-0.10 m/s and a worst epoch of 1.1 m/s.
VEL_POS_WARN = 0.5  # [m/s] RMS over the epochs above this: warning (5x the worst real track)
# An error needs a mismatch of the order of the speed itself, as a unit factor or permuted velocity
# columns give (N/E swapped: ~1.3-1.7x the speed; knots: 0.94x; x2: 1x; x10: 9x): RMS above VEL_POS_ERROR m/s
# *and* above VEL_POS_ERROR_REL of the RMS speed derived from the positions (increment / dt), so that a slow
# track's noise cannot make an error (the real tracks: mismatch / speed <= 0.06).
VEL_POS_ERROR = 1.0  # [m/s]
VEL_POS_ERROR_REL = 0.5  # relative to the RMS speed from the positions

# DVL body speed against GT speed: median |dvl| / median |v_n|. The real tracks: 0.99-1.03 (currents and
# lever arm); outside [0.5, 2] means other units (knots, cm/s below the speed limit) or columns.
DVL_RATIO_MIN = 0.5
DVL_RATIO_MAX = 2.0
DVL_MIN_SPEED = 0.1  # [m/s] median GT speed below which the ratio is not meaningful (vehicle at rest)

# GT column names (as in nespm_cli.data.tracks.GT_COLUMNS); repeated here to keep this module standalone.
_TIME = "Time [s]"
_ANGLES = ("Roll [rad]", "Pitch [rad]", "Yaw [rad]")
_ALT = "Altitude [m]"
_VEL = "V North [m/s], V East [m/s], V Down [m/s]"
_DVL = "DVL X [m/s], DVL Y [m/s], DVL Z [m/s]"

WARNING_MODES = ("warn", "ignore", "error")


class DataWarning(UserWarning):
    """A data finding that a legitimate track could give (see :mod:`nespm_cli.data.plausibility`)."""


@dataclass(frozen=True)
class Finding:
    """One plausibility finding: ``level`` ``"error"`` | ``"warning"``, the file ``path``, the 1-based
    data ``row`` (or None: the whole column), the ``column`` name(s) (or None) and the ``message``."""

    level: str
    path: str
    row: int | None
    column: str | None
    message: str

    @property
    def text(self) -> str:
        """The one-line message ``"<file>: data row R, column 'C': <message>"``."""
        where = [str(self.path)]
        loc = []
        if self.row is not None:
            loc.append(f"data row {self.row}")
        if self.column is not None:
            names = [c.strip() for c in self.column.split(",")]
            loc.append(("columns " if len(names) > 1 else "column ") + ", ".join(f"'{c}'" for c in names))
        head = where[0] + (": " + ", ".join(loc) if loc else "")
        return printable(f"{head}: {self.message}", limit=1000)


def printable(text: object, limit: int = 60, cut: str = "end") -> str:
    """``text`` as one printable line: whitespace runs -> one space; every other non-printable character
    (NUL, control and format characters) -> ``?``, a run of n of them -> ``?xn``; cut to ``limit``
    characters: at the end (``cut="end"``, ending in ``...``) or in the middle (``cut="middle"``: the
    start and the end kept, e.g. a long path's head and the reason after it)."""
    s = str(text)
    out = []
    bad = 0
    for ch in s:
        if ch.isprintable() and not ch.isspace():
            if bad:
                out.append("?" if bad == 1 else f"?x{bad}")
                bad = 0
            out.append(ch)
        elif ch.isspace() and ch in " \t\n\r\x0b\x0c":
            if bad:
                out.append("?" if bad == 1 else f"?x{bad}")
                bad = 0
            if out and out[-1] != " ":
                out.append(" ")
        else:
            bad += 1
    if bad:
        out.append("?" if bad == 1 else f"?x{bad}")
    s = "".join(out).strip()
    if len(s) > limit and cut == "middle" and limit > 40:
        keep = limit - 5
        s = s[: keep // 3] + " ... " + s[len(s) - (keep - keep // 3):]
    elif len(s) > limit:
        s = s[: max(limit - 3, 0)] + "..."
    return s


# ----------------------------------------------------------------------------- checks


def check_epochs(path, t: np.ndarray) -> list[Finding]:
    """Epoch spacing of time ``t`` (N,) [s] (strictly increasing): the median step in
    [:data:`MIN_MEDIAN_STEP`, :data:`MAX_MEDIAN_STEP`] s (error), no step above :data:`GAP_FACTOR` x the
    median (error, the first such row), every step within :data:`STEP_TOL` of the median (warning)."""
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        return []
    dt = np.diff(t)
    step = float(np.median(dt))
    if step > MAX_MEDIAN_STEP or step < MIN_MEDIAN_STEP:
        cause = ("time in milliseconds instead of seconds?" if step > MAX_MEDIAN_STEP
                 else "time in a unit other than seconds, or not a 0.1-10 Hz navigation log?")
        return [Finding("error", str(path), None, _TIME,
                        f"median epoch step {step:.6g} s is outside {MIN_MEDIAN_STEP:g}-{MAX_MEDIAN_STEP:g} s "
                        f"of a GT/DVL log ({cause})")]
    out = []
    gaps = np.flatnonzero(dt > GAP_FACTOR * step)
    if gaps.size:
        k = int(gaps[0])
        out.append(Finding("error", str(path), k + 2, _TIME,
                           f"gap of {dt[k]:.6g} s after the previous row ({dt[k] / step:.4g}x the median step "
                           f"{step:.6g} s; {gaps.size} gap(s) in the file): epochs are missing"))
        return out
    odd = np.flatnonzero(np.abs(dt - step) > STEP_TOL * step)
    if odd.size:
        k = int(odd[np.argmax(np.abs(dt[odd] - step))])
        out.append(Finding("warning", str(path), k + 2, _TIME,
                           f"step {dt[k]:.6g} s after the previous row differs from the median step {step:.6g} s "
                           f"by {abs(dt[k] - step) / step:.2%} (> {STEP_TOL:.0%}; {odd.size} irregular step(s)): "
                           "irregular sampling?"))
    return out


def check_angles(path, t: np.ndarray, euler: np.ndarray) -> list[Finding]:
    """Roll/pitch/yaw ``euler`` (N, 3) [rad] at ``t`` (N,) [s]: each within +-:data:`ANGLE_LIMIT`, pitch
    within +-:data:`PITCH_LIMIT` (errors), and the unwrapped step rate between consecutive epochs below
    :data:`ANGLE_RATE_ERROR` (error) and :data:`ANGLE_RATE_WARN` (warning). One finding per column at most."""
    t = np.asarray(t, dtype=float)
    e = np.asarray(euler, dtype=float)
    out: list[Finding] = []
    for j, col in enumerate(_ANGLES):
        x = e[:, j]
        bad = np.flatnonzero(np.abs(x) > ANGLE_LIMIT)
        if bad.size:
            r = int(bad[0])
            out.append(Finding("error", str(path), r + 1, col,
                               f"|{x[r]:.6g}| > pi: not an angle in radians (degrees instead of radians?)"))
    if out:
        return out
    bad = np.flatnonzero(np.abs(e[:, 1]) > PITCH_LIMIT)
    if bad.size:
        r = int(bad[0])
        return [Finding("error", str(path), r + 1, _ANGLES[1],
                        f"|{e[r, 1]:.6g}| > pi/2: not a ZYX pitch in radians (degrees instead of radians?)")]
    if len(t) < 2:
        return out
    rate = np.abs(np.diff(np.unwrap(e, axis=0), axis=0)) / np.diff(t)[:, None]  # (N-1, 3) [rad/s]
    for j, col in enumerate(_ANGLES):
        k = int(np.argmax(rate[:, j]))
        r = float(rate[k, j])
        if r > ANGLE_RATE_ERROR:
            level, lim, why = "error", ANGLE_RATE_ERROR, "beyond any AUV (degrees instead of radians, a glitch or a wrong column?)"
        elif r > ANGLE_RATE_WARN:
            level, lim, why = "warning", ANGLE_RATE_WARN, "a very fast manoeuvre or a bad epoch?"
        else:
            continue
        n = int(np.count_nonzero(rate[:, j] > lim))
        out.append(Finding(level, str(path), k + 2, col,
                           f"step of {np.degrees(r * (t[k + 1] - t[k])):.4g} deg from the previous row "
                           f"({np.degrees(r):.4g} deg/s > {np.degrees(lim):.4g} deg/s; {n} such step(s)): {why}"))
    return out


def check_altitude(path, alt: np.ndarray) -> list[Finding]:
    """Altitude ``alt`` (N,) [m, positive up]: |alt| <= :data:`MAX_ABS_ALT` (error), alt <= :data:`MAX_ALT_UP`
    (warning)."""
    alt = np.asarray(alt, dtype=float)
    bad = np.flatnonzero(np.abs(alt) > MAX_ABS_ALT)
    if bad.size:
        r = int(bad[0])
        return [Finding("error", str(path), r + 1, _ALT,
                        f"|{alt[r]:.6g}| m > {MAX_ABS_ALT:g} m (deeper than any ocean: not metres, or a scaled column?)")]
    up = np.flatnonzero(alt > MAX_ALT_UP)
    if up.size:
        r = int(up[np.argmax(alt[up])])
        return [Finding("warning", str(path), r + 1, _ALT,
                        f"altitude {alt[r]:.6g} m > +{MAX_ALT_UP:g} m, far above the sea surface for an AUV "
                        "(depth positive down instead of altitude up, or another height datum?)")]
    return []


def _increments(t: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """NED position increments (N-1, 3) [m] of ``pos = [lat rad, lon rad, alt m]`` (alt up), with the radii of
    curvature at each interval's mid latitude, and the time steps (N-1,) [s]."""
    t = np.asarray(t, dtype=float)
    pos = np.asarray(pos, dtype=float)
    lat_m = 0.5 * (pos[1:, 0] + pos[:-1, 0])
    h_m = 0.5 * (pos[1:, 2] + pos[:-1, 2])
    R_N, R_E = radii(lat_m)
    dlon = (np.diff(pos[:, 1]) + np.pi) % (2.0 * np.pi) - np.pi  # across the +-pi meridian
    inc = np.column_stack([np.diff(pos[:, 0]) * (R_N + h_m), dlon * (R_E + h_m) * np.cos(lat_m), -np.diff(pos[:, 2])])
    return inc, np.diff(t)


def velocity_position_mismatch(t: np.ndarray, pos: np.ndarray, v_n: np.ndarray) -> np.ndarray:
    """Per-epoch mismatch (N-1,) [m/s]: |NED position increment - trapezoid integral of ``v_n``| / dt, with
    ``pos = [lat rad, lon rad, alt m]`` (alt up), the radii of curvature at the interval's mid latitude."""
    inc, dt = _increments(t, pos)
    v = np.asarray(v_n, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        integ = 0.5 * (v[1:] + v[:-1]) * dt[:, None]
        return np.linalg.norm(inc - integ, axis=1) / dt


def check_velocity_position(path, t: np.ndarray, pos: np.ndarray, v_n: np.ndarray) -> list[Finding]:
    """GT velocity ``v_n`` (N, 3) [m/s] against the GT position increments (see
    :func:`velocity_position_mismatch`): RMS above :data:`VEL_POS_WARN` -> warning; above :data:`VEL_POS_ERROR`
    and above :data:`VEL_POS_ERROR_REL` x the RMS speed of the positions (increment / dt) -> error. Names the
    worst row."""
    if len(t) < 2:
        return []
    mis = velocity_position_mismatch(t, pos, v_n)
    inc, dt = _increments(t, pos)
    with np.errstate(over="ignore", invalid="ignore"):
        rms = float(np.sqrt(np.mean(mis**2)))
        pos_speed = float(np.sqrt(np.mean(np.sum(inc**2, axis=1) / dt**2)))
    if not np.isfinite(rms):
        rms = float("inf")
    if rms <= VEL_POS_WARN:
        return []
    k = int(np.argmax(np.where(np.isfinite(mis), mis, np.inf))) if mis.size else 0
    if rms > VEL_POS_ERROR and not rms <= VEL_POS_ERROR_REL * pos_speed:
        level, why = "error", "velocity units or scale, or velocity or lat/lon columns swapped?"
    else:
        level, why = "warning", "GT velocity and position disagree"
    return [Finding(level, str(path), k + 2, _VEL,
                    f"velocity does not match the position increments: RMS mismatch {rms:.4g} m/s, speed from "
                    f"positions {pos_speed:.4g} m/s, worst {mis[k]:.4g} m/s at this row ({why})")]


def check_dvl_speed(path, dvl: np.ndarray, v_n: np.ndarray) -> list[Finding]:
    """Median |``dvl``| / median |``v_n``| within [:data:`DVL_RATIO_MIN`, :data:`DVL_RATIO_MAX`] (warning),
    over the epochs with a DVL measurement (NaN rows of ``dvl``, missing epochs, are skipped)."""
    dvl, v_n = np.asarray(dvl, dtype=float), np.asarray(v_n, dtype=float)
    ok = ~np.isnan(dvl).all(axis=1)
    if not ok.any():
        return []
    with np.errstate(over="ignore", invalid="ignore"):
        ds = float(np.median(np.linalg.norm(dvl[ok], axis=1)))
        gs = float(np.median(np.linalg.norm(v_n[ok], axis=1)))
    if not gs >= DVL_MIN_SPEED:
        return []
    ratio = ds / gs
    if DVL_RATIO_MIN <= ratio <= DVL_RATIO_MAX:
        return []
    return [Finding("warning", str(path), None, _DVL,
                    f"median DVL speed {ds:.4g} m/s is {ratio:.3g}x the median GT speed {gs:.4g} m/s "
                    f"(outside {DVL_RATIO_MIN:g}-{DVL_RATIO_MAX:g}x: DVL in other units or columns?)")]


def check_track_arrays(gt_path, gt: np.ndarray, dvl_path, dvl: np.ndarray) -> list[Finding]:
    """Every check on a GT table (N, 10) in the file's column order (time, lon, lat, alt, vN, vE, vD,
    roll, pitch, yaw) and a DVL table (N, 4) (time, x, y, z); errors first, in check order."""
    t = gt[:, 0]
    pos = gt[:, [2, 1, 3]]
    v_n = gt[:, 4:7]
    findings = (check_epochs(gt_path, t) + check_angles(gt_path, t, gt[:, 7:10]) + check_altitude(gt_path, gt[:, 3])
                + check_velocity_position(gt_path, t, pos, v_n) + check_dvl_speed(dvl_path, dvl[:, 1:4], v_n))
    return [f for f in findings if f.level == "error"] + [f for f in findings if f.level != "error"]


# ----------------------------------------------------------------------------- warning handling

_mode = "warn"
_emitted: set[tuple[str, str]] = set()


def _check_mode(mode: str) -> str:
    if mode not in WARNING_MODES:
        raise ValueError(f"warning mode must be one of {', '.join(WARNING_MODES)}, got {mode!r}")
    return mode


def set_warning_mode(mode: str) -> None:
    """Process-wide mode for data warnings when ``load_track(..., warnings=None)``: ``"warn"`` (default;
    each warning once per file and message as a :class:`DataWarning`), ``"ignore"`` or ``"error"``."""
    global _mode
    _mode = _check_mode(mode)


def get_warning_mode() -> str:
    """The mode set by :func:`set_warning_mode` (``"warn"`` unless set)."""
    return _mode


def emit(findings: list[Finding], mode: str | None = None) -> list[Finding]:
    """Handle the warnings among ``findings`` in ``mode`` (None -> :func:`get_warning_mode`).

    ``"warn"``: :func:`warnings.warn` each (``DataWarning``) not yet emitted in this process for the same
    (file, message); ``"ignore"``: nothing; ``"error"``: raise :class:`~nespm_cli.errors.NespmError` on the
    first. Returns the warnings.
    """
    from nespm_cli.errors import NespmError

    mode = _check_mode(_mode if mode is None else mode)
    warns = [f for f in findings if f.level == "warning"]
    if mode == "ignore" or not warns:
        return warns
    if mode == "error":
        raise NespmError(warns[0].text + " (a data warning, treated as an error)")
    for f in warns:
        key = (str(f.path), f.text)
        if key in _emitted:
            continue
        _emitted.add(key)
        _warnings.warn(f.text, DataWarning, stacklevel=3)
    return warns

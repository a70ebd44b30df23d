"""Attitude and frame conventions checked against the data at load (docs/checking-data.md, "Conventions").

A rotation leaves every speed magnitude unchanged, so the plausibility checks cannot see a truth whose yaw
is in the ENU convention, whose pitch or roll sign is flipped, whose attitude is in radians declared
degrees, or a DVL logged in the earth frame, or in other axes, than declared. The DVL sees them: its
vector against the truth's body-frame velocity ``C_bn^T v_n + w_nb^b x l`` (lever arm ``l`` fitted by least
squares, as :func:`nespm_cli.data.tracks.dvl_lever_arm_fit`) leaves a residual of the order of the speed
times the angle of the mistake. :func:`dvl_candidates` computes that residual (RMS per axis [m/s]) as
declared and under each candidate fix:

* ``yaw_enu``: the yaw in the ENU convention (0 = east, counter-clockwise): ``psi' = pi/2 - psi``;
* ``pitch_sign``, ``roll_sign``: the angle's sign flipped;
* ``angle_unit``: radians declared degrees (only when the spec declares ``deg``): ``x 180/pi``;
* ``dvl_ned``, ``dvl_enu``: the DVL vector in the earth frame (NED, or ENU ``[v_e, v_n, -v_d]``);
* ``dvl_axes``: the best of the 47 other signed permutations of the DVL's axes (``body = A dvl``, the
  ``dvl.axes`` syntax; FLU declared FRD is ``x,-y,-z``).

:func:`check_conventions` refuses (one line: the likely cause, the key to change, the residual as declared
and under the fix) when the residual as declared is above the bound and a fix brings it down to at most
:data:`FIX_RATIO` of it and within :data:`FIX_SIGMAS` DVL noise stds (the own noise of the DVL's second
difference, :func:`own_noise`); an unexplained residual above :data:`UNEXPLAINED` m/s is refused too.
Without a DVL (no finite DVL row) the truth's heading against its direction of travel does the same job
(:func:`course_candidates`). A roll beyond 90 deg at most epochs (the vehicle upside down: body axes FLU
declared FRD, or the reverse) is refused by :func:`check_roll`.

Constants measured on the 13 real Snapir tracks and the 6 embedded tracks (the script in
docs/checking-data.md): quoted next to each.
"""
from __future__ import annotations

import warnings as _warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nespm_cli.data.corrections import axes_text
from nespm_cli.data.plausibility import DataWarning, printable
from nespm_cli.errors import NespmError
from nespm_cli.nav.dvl import body_rate_from_attitude
from nespm_cli.nav.rotations import euler_to_dcm, signed_permutations, skew, wrap_angle

GRAVITY = 9.80665  # [m/s^2] the gravity of the specific-force test (the local value differs by < 0.3 %)
MIN_EPOCHS = 20  # epochs (finite DVL rows, moving epochs) a test needs; fewer: not judged
COURSE_MIN_SPEED = 0.3  # [m/s] horizontal speed from which the direction of travel is judged
# The DVL test (13 Snapir tracks and 6 embedded, as declared: residual 0.015-0.115 m/s, 0.96-13.6x the DVL's own
# noise 0.006-0.021 m/s; under any fix at least 0.95x the declared residual, the smallest a roll flip on Snapir 9).
# A convention mistake: yaw ENU 12-160x, radians-as-degrees 12-114x, earth-frame DVL 10-160x the declared residual
# of the correct file; a pitch flip 2.6-6.3x on the embedded tracks (1.0-5.9x on Snapir: the level tracks 2, 3, 10
# have |pitch| < 2 deg and the flip changes nothing measurable), DVL axes FLU 1.65-2.9x (Snapir 2.1-13.6x).
BOUND_SIGMAS = 1.5  # the declared residual must exceed this many DVL noise stds (correct embedded: 0.96-1.0)...
BOUND_FLOOR = 0.02  # [m/s] ...and this floor (a noise-free DVL is not judged below what the 1 Hz truth resolves)
FIX_RATIO = 0.65  # a fix explains it when it brings the residual to at most this fraction (correct files: >= 0.95)
UNEXPLAINED = 0.5  # [m/s] a declared residual above this is refused even when no fix explains it (Snapir <= 0.115)
# The IMU test (the exact IMU of the 6 embedded tracks: gyro 3.0-3.7e-5 rad/s, specific force 0.000-0.001 m/s^2 as
# declared; a roll flip 4.1-7.6e-3 rad/s and 0.166-0.338 m/s^2; a pitch flip >= 1.7e-3 rad/s, 0.25 m/s^2).
GYRO_BOUND = 1e-3  # [rad/s] declared gyro residual std above which a fix is looked for (a MEMS bias is not a std)
ACC_BOUND = 0.05  # [m/s^2] declared specific-force residual std above which a fix is looked for
# The course test (no DVL): heading against direction of travel, RMS 0.8-18.3 deg as declared (Snapir 11: currents),
# 78-132 deg under a yaw-ENU or radians-as-degrees mistake.
COURSE_BOUND = np.radians(40.0)  # [rad]
MAX_ROLL = np.pi / 2  # [rad] a roll beyond 90 deg is a vehicle upside down: body axes FLU read as FRD or the reverse
ENU_OF_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # v_enu = ENU_OF_NED v_ned


def own_noise(dvl: np.ndarray) -> np.ndarray:
    """White-noise std per axis (3,) [m/s] of a DVL series (N, 3) from its second difference alone:
    ``1.4826 MAD(d2) / sqrt(6)`` (white noise keeps ``sqrt(6)`` of its std in ``d2``; slow motion cancels; the
    MAD ignores the turns' rarer large steps). Differences over a NaN row (no measurement) are left out; NaN
    when fewer than 3 remain."""
    d2 = np.diff(np.asarray(dvl, dtype=float), n=2, axis=0)
    d2 = d2[np.isfinite(d2).all(axis=1)]
    if len(d2) < 3:
        return np.full(3, np.nan)
    return 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / np.sqrt(6.0)


def lever_residual(t: np.ndarray, euler: np.ndarray, v_n: np.ndarray, dvl: np.ndarray) -> np.ndarray:
    """RMS residual per axis (P, 3) [m/s] of DVL readings ``dvl`` (P, N, 3) against the body-frame truth of
    attitude ``euler`` (N, 3) [rad] and NED velocity ``v_n`` (N, 3) at ``t`` (N,) [s]: ``dvl - C_bn^T v_n -
    w x l`` with the lever arm ``l`` fitted per reading (minimum norm on a track without turns). Rows with a
    non-finite DVL (the same for every reading) are left out."""
    C = euler_to_dcm(euler)
    w = body_rate_from_attitude(t, C)
    dvl = np.asarray(dvl, dtype=float)
    ok = np.isfinite(dvl[0]).all(axis=1)
    u = np.einsum("nji,nj->ni", C, v_n)[ok]
    r0 = dvl[:, ok] - u[None]  # (P, K, 3)
    S = skew(w[ok])  # (K, 3, 3)
    N0 = np.einsum("kji,kjl->il", S, S)
    rhs = np.einsum("kji,pkj->pi", S, r0)
    lever = rhs @ np.linalg.pinv(N0).T  # (P, 3)
    resid = r0 - np.einsum("kij,pj->pki", S, lever)
    return np.sqrt(np.mean(resid**2, axis=1))


def attitude_candidates(euler: np.ndarray, unit_deg: bool) -> dict[str, np.ndarray]:
    """``{name: euler (N, 3) [rad]}``: the attitude as declared (``"declared"``) and under each attitude fix of
    the module docstring (``"angle_unit"`` only when the spec declared degrees, ``unit_deg``)."""
    e = np.asarray(euler, dtype=float)
    out = {"declared": e}
    y = e.copy()
    y[:, 2] = wrap_angle(np.pi / 2 - e[:, 2])
    out["yaw_enu"] = y
    for name, j in (("pitch_sign", 1), ("roll_sign", 0)):
        x = e.copy()
        x[:, j] = -e[:, j]
        out[name] = x
    if unit_deg:
        x = e * (180.0 / np.pi)
        x[:, [0, 2]] = wrap_angle(x[:, [0, 2]])
        out["angle_unit"] = x
    return out


def dvl_candidates(t: np.ndarray, euler: np.ndarray, v_n: np.ndarray, dvl: np.ndarray,
                   unit_deg: bool = False) -> dict[str, dict]:
    """The DVL residual (:func:`lever_residual`) as declared and under every fix: ``{name: {"rms": RMS over the
    axes [m/s], "xyz": (3,) per axis [m/s]}}``; ``"dvl_axes"`` also holds ``"A"`` (3, 3), the best signed
    permutation other than the identity (``body = A dvl``). ``t`` (N,) [s], ``euler``, ``v_n``, ``dvl`` (N, 3)."""
    t, v_n, dvl = (np.asarray(a, dtype=float) for a in (t, v_n, dvl))
    out = {}
    for name, e in attitude_candidates(euler, unit_deg).items():
        out[name] = lever_residual(t, e, v_n, dvl[None])[0]
    e = np.asarray(euler, dtype=float)
    C = euler_to_dcm(e)
    earth = np.stack([np.einsum("nji,nj->ni", C, dvl), np.einsum("nji,nj->ni", C, dvl @ ENU_OF_NED.T)])
    out["dvl_ned"], out["dvl_enu"] = lever_residual(t, e, v_n, earth)  # the body reading of an earth-frame DVL
    A = signed_permutations()[1:]
    per = lever_residual(t, e, v_n, np.einsum("pij,nj->pni", A, dvl))
    p = int(np.argmin(np.sqrt(np.mean(per**2, axis=1))))
    out["dvl_axes"] = per[p]
    res = {k: {"rms": float(np.sqrt(np.mean(x**2))), "xyz": x} for k, x in out.items()}
    res["dvl_axes"]["A"] = A[p]
    return res


def imu_candidates(t: np.ndarray, euler: np.ndarray, v_n: np.ndarray, imu: np.ndarray,
                   unit_deg: bool = False) -> dict[str, dict]:
    """The recorded IMU against each attitude reading (:func:`attitude_candidates`), per GT interval
    ``(t_k, t_k+1]``: the mean gyro [rad/s] against the attitude's rate ``log(C_k^T C_k+1) / dt``, and the mean
    specific force [m/s^2] against ``C^T (dv_n/dt - g_n)`` (``C`` the mean of the two ends' DCMs, ``g_n`` =
    [0, 0, :data:`GRAVITY`]). Returns ``{name: {"gyro": [rad/s], "acc": [m/s^2]}}``: the residual's std per axis
    (its mean left out: a sensor bias is no convention), RMS over the three axes, over the intervals holding
    samples. ``imu`` (M, 7) ``[t, f (3), w (3)]``."""
    from nespm_cli.nav.rotations import log_so3

    t, v_n, imu = (np.asarray(a, dtype=float) for a in (t, v_n, imu))
    cs = np.vstack([np.zeros(6), np.cumsum(imu[:, 1:7], axis=0)])
    idx = np.searchsorted(imu[:, 0], t, side="right")
    n = np.diff(idx)
    ok = n > 0
    mean = (cs[idx[1:]] - cs[idx[:-1]])[ok] / n[ok, None]  # (K, 6)
    dt = np.diff(t)[ok]
    a = (np.diff(v_n, axis=0)[ok] / dt[:, None]) - np.array([0.0, 0.0, GRAVITY])
    out = {}
    for name, e in attitude_candidates(euler, unit_deg).items():
        C = euler_to_dcm(e)
        C0, C1 = C[:-1][ok], C[1:][ok]
        rate = log_so3(np.swapaxes(C0, -1, -2) @ C1) / dt[:, None]
        f = np.einsum("kji,kj->ki", 0.5 * (C0 + C1), a)
        out[name] = {"gyro": float(np.sqrt(np.mean(np.var(mean[:, 3:] - rate, axis=0)))),
                     "acc": float(np.sqrt(np.mean(np.var(mean[:, :3] - f, axis=0))))}
    return out


def course_candidates(euler: np.ndarray, v_n: np.ndarray, unit_deg: bool = False) -> dict[str, float] | None:
    """The truth's heading against its direction of travel ``atan2(v_E, v_N)`` under each attitude reading
    (:func:`attitude_candidates`): ``{name: RMS wrapped difference [rad]}`` over the epochs moving at least
    :data:`COURSE_MIN_SPEED` m/s horizontally; None with fewer than :data:`MIN_EPOCHS` such epochs."""
    v = np.asarray(v_n, dtype=float)
    moving = np.hypot(v[:, 0], v[:, 1]) >= COURSE_MIN_SPEED
    if moving.sum() < MIN_EPOCHS:
        return None
    course = np.arctan2(v[moving, 1], v[moving, 0])
    return {name: float(np.sqrt(np.mean(wrap_angle(course - e[moving, 2]) ** 2)))
            for name, e in attitude_candidates(euler, unit_deg).items()}


# ----------------------------------------------------------------------------- the verdict at load

#: fix name -> (the likely cause, the spec key, its value under the fix given the declared one)
FIXES = {
    "yaw_enu": ("yaw looks like the ENU convention (0 = east, CCW)", "gt.yaw_convention",
                lambda v: "ned" if v == "enu" else "enu"),
    "pitch_sign": ("pitch sign looks flipped (nose down positive)", "gt.pitch_sign",
                   lambda v: "normal" if v == "flipped" else "flipped"),
    "roll_sign": ("roll sign looks flipped (port down positive)", "gt.roll_sign",
                  lambda v: "normal" if v == "flipped" else "flipped"),
    "angle_unit": ("attitude looks like radians declared degrees", "gt.angle_unit", lambda v: "rad"),
    "dvl_ned": ("DVL looks like earth-frame NED velocity declared body", "dvl.frame", lambda v: "ned"),
    "dvl_enu": ("DVL looks like earth-frame ENU velocity declared body", "dvl.frame", lambda v: "enu"),
    "dvl_axes": ("DVL axes look permuted (FLU for FRD is x,-y,-z)", "dvl.axes", None),
}
ACCEPT_KEY = "gt.accept_residual"
ACCEPT_HINT = f"to run anyway: --accept-residual (or {ACCEPT_KEY} = true)"
MESSAGE_LIMIT = 398  # [characters] a refusal's line; a longer path is shortened at its start (the CLI cuts at 400)


@dataclass(frozen=True)
class Declared:
    """What a track's files declare about its conventions: ``spec`` the track spec's file name (None: an A-KIT
    folder), ``values`` ``{key: value}`` of the keys of :data:`FIXES` (``"gt.yaw_convention": "ned"``, ...),
    ``unit_deg`` whether the truth's angles were declared in degrees, ``accept`` the spec's
    :data:`ACCEPT_KEY`."""

    spec: str | None = None
    values: dict = field(default_factory=dict)
    unit_deg: bool = False
    accept: bool = False


def declared_of(spec) -> Declared:
    """The :class:`Declared` of a :class:`~nespm_cli.data.track_spec.TrackSpec` (None: an A-KIT folder)."""
    if spec is None:
        return Declared()
    gt, dvl = spec.tables["gt"], spec.tables["dvl"]
    values = {"gt.yaw_convention": gt["yaw_convention"], "gt.pitch_sign": gt["pitch_sign"],
              "gt.roll_sign": gt["roll_sign"], "gt.angle_unit": gt["angle_unit"], "dvl.frame": dvl["frame"],
              "dvl.axes": dvl["axes"]}
    return Declared(spec.path.name, values, gt["angle_unit"] != "rad", bool(gt["accept_residual"]))


def _advice(name: str, declared: Declared, A: np.ndarray | None = None) -> str:
    """How to apply fix ``name``: the key and value to set (A-KIT: convert the file, or a track spec)."""
    cause, key, value = FIXES[name]
    if name == "dvl_axes":
        from nespm_cli.data.corrections import axes_matrix

        new = axes_text(A @ axes_matrix(declared.values.get("dvl.axes", "x,y,z")))
    else:
        new = value(declared.values.get(key))
    if declared.spec is not None:
        return f"set {key} = \"{new}\" in {declared.spec}"
    return f"convert the file, or read it through a track spec with {key} = \"{new}\""


def check_roll(euler: np.ndarray) -> str | None:
    """Why a roll beyond :data:`MAX_ROLL` is wrong (one sentence with the count and the worst row), or None."""
    roll = np.abs(np.asarray(euler, dtype=float)[:, 0])
    bad = np.flatnonzero(roll > MAX_ROLL)
    if not bad.size:
        return None
    r = int(bad[np.argmax(roll[bad])])
    return (f"column 'Roll [rad]': |roll| {np.degrees(roll[r]):.1f} deg beyond 90 deg at data row {r + 1} ({bad.size} "
            f"of {len(roll)} epochs): upside down, body axes FLU read as FRD or the reverse (a bag's frames.body)")


def judge(t, euler, v_n, dvl, imu, declared: Declared) -> tuple[str, str] | None:
    """``(file kind "gt"|"dvl"|"imu", sentence)`` of the first convention the data contradicts (module
    docstring: roll beyond 90 deg, the DVL test, or without a DVL the course test, then the IMU test), or None."""
    why = check_roll(euler)
    if why is not None:
        return "gt", why
    dvl = np.asarray(dvl, dtype=float)
    if np.isfinite(dvl).all(axis=1).sum() >= MIN_EPOCHS:
        c = dvl_candidates(t, euler, v_n, dvl, declared.unit_deg)
        dec = c["declared"]
        sigma = float(np.sqrt(np.mean(own_noise(dvl) ** 2)))
        bound = max(BOUND_SIGMAS * sigma if np.isfinite(sigma) else 0.0, BOUND_FLOOR)
        best = min((k for k in c if k != "declared"), key=lambda k: c[k]["rms"])
        per = ", ".join(f"{a} {x:.3f}" for a, x in zip("xyz", dec["xyz"]))
        head = f"DVL residual vs body velocity {dec['rms']:.3f} m/s RMS ({per}; noise {sigma:.4f}, bound {bound:.3f})"
        if dec["rms"] > bound and c[best]["rms"] <= FIX_RATIO * dec["rms"]:
            kind = "dvl" if best.startswith("dvl") else "gt"
            return kind, (f"{head}: {FIXES[best][0]}: {c[best]['rms']:.3f} m/s if so; "
                          f"{_advice(best, declared, c['dvl_axes'].get('A'))}")
        if dec["rms"] > UNEXPLAINED:
            ok = np.isfinite(dvl).all(axis=1)
            ratio = float(np.median(np.linalg.norm(dvl[ok], axis=1)) /
                          max(float(np.median(np.linalg.norm(np.asarray(v_n)[ok], axis=1))), 1e-9))
            return "dvl", (f"{head}, above {UNEXPLAINED:g}; no convention explains it (best {best} "
                           f"{c[best]['rms']:.3f}); DVL speed {ratio:.3g}x the truth's: units or scale?")
    else:
        c = course_candidates(euler, v_n, declared.unit_deg)
        if c is not None:
            best = min((k for k in c if k != "declared"), key=c.get)
            if c["declared"] > COURSE_BOUND and c[best] <= FIX_RATIO * c["declared"]:
                return "gt", (f"heading vs direction of travel {np.degrees(c['declared']):.1f} deg RMS (no DVL; "
                              f"bound {np.degrees(COURSE_BOUND):g}): {FIXES[best][0]}: "
                              f"{np.degrees(c[best]):.1f} deg if so; {_advice(best, declared)}")
    if imu is not None:
        c = imu_candidates(t, euler, v_n, imu, declared.unit_deg)
        dec = c["declared"]
        # The gyro alone refuses: the specific-force test (ACC_BOUND) is computed but not a refusal, as the real
        # recorded IMU of Snapir track 13 reads 0.127 m/s^2 as declared and 0.023 under a roll flip while its gyro
        # and its DVL agree with the declared attitude (vibration and lever-arm accelerations, not a convention).
        for what, bound, unit in (("gyro", GYRO_BOUND, "rad/s"),):
            best = min((k for k in c if k != "declared"), key=lambda k: c[k][what])
            # the fix must also bring it under the bound: an IMU with its own noise or vibration (the vehicle
            # simulator's: 0.20 m/s^2 as declared, 0.12 under a roll flip) is not read as a convention
            if dec[what] > bound and c[best][what] <= min(FIX_RATIO * dec[what], bound):
                words = "gyro vs attitude rates" if what == "gyro" else "specific force vs gravity and acceleration"
                return "gt", (f"IMU {words}: residual std {dec[what]:.3g} {unit} (bound {bound:g}): {FIXES[best][0]}: "
                              f"{c[best][what]:.3g} {unit} if so; {_advice(best, declared)}")
    return None


def one_line(path, text: str, limit: int = MESSAGE_LIMIT) -> str:
    """``"<path>: <text>"`` as one printable line of at most ``limit`` characters where it can be: a long path is
    shortened at its start (``.../Trajectory5/GT_trajectory5.csv``, whole components kept), never the text."""
    text = printable(text, limit=10**6)
    p = printable(path, limit=10**6)
    room = limit - len(text) - 2
    if len(p) > room:
        parts = p.split("/")
        tail = parts[-1]
        for part in reversed(parts[:-1]):
            if len(part) + len(tail) + 5 > room:
                break
            tail = f"{part}/{tail}"
        p = f".../{tail}"
    return f"{p}: {text}"


#: ``{(source folder, track number): the sentence}`` of every track loaded with a refusal accepted (this process)
ACCEPTED: dict[tuple[str, int], str] = {}


def check_conventions(number: int, paths: dict, t, euler, v_n, dvl, imu, declared: Declared,
                      accept: bool | None = None) -> str | None:
    """Refuse (:class:`NespmError`, one line: the file, the likely cause, the key, the residual as declared and
    under the fix) a track whose data contradict its declared conventions (:func:`judge`). ``paths`` ``{"gt",
    "dvl", "imu": Path}``; ``accept`` True (else None: the spec's :data:`ACCEPT_KEY`) turns the refusal into a
    :class:`~nespm_cli.data.plausibility.DataWarning` (once per track and sentence in a process: a command reads a
    track more than once), recorded in :data:`ACCEPTED`; returns that sentence."""
    found = judge(t, euler, v_n, dvl, imu, declared)
    if found is None:
        return None
    kind, why = found
    path = paths.get(kind) or paths["gt"]
    accept = declared.accept if accept is None else bool(accept)
    if not accept:
        raise NespmError(one_line(path, f"{why}; {ACCEPT_HINT}"))
    text = one_line(path, f"{why} (accepted: --accept-residual or {ACCEPT_KEY}; the numbers may be wrong)")
    key = (str(Path(paths["gt"]).parent), int(number))
    if ACCEPTED.get(key) != text:
        _warnings.warn(text, DataWarning, stacklevel=3)
    ACCEPTED[key] = text
    return text


def dvl_to_body(t: np.ndarray, v: np.ndarray, t_gt: np.ndarray, euler: np.ndarray, frame: str) -> np.ndarray:
    """A DVL logged in the earth frame ``frame`` (``"ned"``, or ``"enu"`` ``[v_e, v_n, v_u]``), ``v`` (K, 3) [m/s]
    at ``t`` (K,) [s], in the body frame: ``C_bn^T v_ned`` with the truth's attitude ``euler`` (N, 3) [rad] at
    ``t_gt`` (N,) interpolated to ``t`` (each angle linearly, unwrapped; clamped at the span's ends, where the
    stamps are checked afterwards). A NaN row stays NaN."""
    v = np.asarray(v, dtype=float)
    if frame == "enu":
        v = v @ ENU_OF_NED.T
    e = np.unwrap(np.asarray(euler, dtype=float), axis=0)
    at = np.column_stack([np.interp(t, t_gt, e[:, j]) for j in range(3)])
    return np.einsum("kji,kj->ki", euler_to_dcm(at), v)

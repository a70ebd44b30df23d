"""The DVL's part of a track's verdict: which DVL findings make the track inconsistent, and why.

Every rule is measured against one bound, derived from the DVL's own white noise ``sigma``
(:func:`dvl_frame.own_noise`, RMS over the axes) [m/s]:

    ``bound = max(RESID_SIGMAS * sigma, RESID_FLOOR)``

* **residual**: the RMS residual after the full :func:`dvl_gt.fit_dvl_to_gt` fit (lever arm, scale,
  misalignment, time offset) above the bound. On the 13 Snapir tracks it is 0.5-3.2 ``sigma``
  (0.004-0.036 m/s: the 1 Hz GT's own errors add to the DVL's noise); a DVL in the earth frame, or a
  GT attitude in another convention, leaves residuals of the order of the speed (44-260 ``sigma``).
  :data:`RESID_FLOOR` keeps a nearly noise-free DVL from being judged below what the GT resolves.
* **scale**: the scale factor's effect ``|s| U`` (``U`` the DVL's RMS speed) above the bound: a
  scale error the filters do not model biases every DVL update by that much (Snapir: at most
  0.017 m/s; an earth-frame DVL fits ``s`` of -43 to -127 %).
* **misalignment**: the fitted rotation's effect ``RMS |(R - I) dvl|`` above the bound, for the same
  reason (Snapir: below 0.4 deg, under 0.015 m/s; a DVL mounted 90 deg off in yaw fits ~77 deg).
* **time offset at the search edge**: the offset's grid minimum at ``+-max_offset``: no offset
  inside the search fits. Not counted only when the offset curve rises by less than
  :data:`FLAT_RISE` of its minimum over the whole search *and* the residual is within the bound
  (a track without the motion that times the DVL, e.g. a straight line at constant speed: the
  offset is undetermined, nothing is wrong).
* **frame**: the declared body frame's residual in the frame test (lever arm and offset fitted,
  no scale or misalignment: the full fit's misalignment can absorb a rotated mounting) is above
  the bound, and another reading of the truth (:func:`dvl_frame.frame_candidates`: earth NED or
  ENU, or permuted body axes) fits within the bound and at most :data:`FRAME_RATIO` times it:
  that reading is named as the likely cause, with the key to set.
"""
from __future__ import annotations

import math

import numpy as np

from nespm_cli.checks.dvl_frame import frame_candidates, own_noise
from nespm_cli.data.track import Track
from nespm_cli.nav.rotations import exp_so3

RESID_SIGMAS = 6.0  # the bound in DVL noise stds (Snapir: 3.2 at most on a correct track; 44 at least in the earth frame)
RESID_FLOOR = 0.05  # [m/s] the bound's floor: above the 1 Hz GT's own error (Snapir residuals 0.004-0.036 m/s)
FLAT_RISE = 0.1  # an offset curve rising by less than this fraction of its minimum over the search is flat
FRAME_RATIO = 0.5  # another frame is named when its residual is at most this fraction of the declared one's
DVL_FRAME_KEY = "dvl.frame"  # the track spec key declaring the DVL vector's frame (body, ned, enu): track_spec.schema.SCHEMA
DVL_AXES_KEY = "dvl.axes"  # the track spec key that maps the DVL file's axes onto the body axes
FRAME_NAMES = {"ned": "earth-frame NED", "enu": "earth-frame ENU"}


def _frame_finding(frame: dict, resid: float, bound: float) -> tuple[str, str] | None:
    """``(sentence, short reason)`` naming the frame that explains the DVL, or None. ``resid``: the full
    fit's residual [m/s] (quoted: its misalignment can absorb a rotated mounting, so the rule reads the
    frame test's own body residual)."""
    best = min(("ned", "enu", "axes"), key=lambda k: math.inf if frame[k]["rms"] is None else frame[k]["rms"])
    alt, body = frame[best]["rms"], frame["body"]["rms"]
    if alt is None or body is None or not (body > bound and alt <= bound and alt <= FRAME_RATIO * body):
        return None
    vs = f"vs {body:.2f} as body, {resid:.2f} with scale and misalignment fitted too"
    if best == "axes":
        axes = frame["axes"]["axes"]
        return (f"DVL axes look permuted (residual {alt:.3f} m/s with body = {axes} of the DVL {vs}): set "
                f"{DVL_AXES_KEY} = \"{axes}\" in nespm-data.toml (composed with any axes already set), or write the "
                "DVL in body FRD axes", f"DVL axes look like {axes}")
    return (f"DVL looks like {FRAME_NAMES[best]} velocity (residual {alt:.3f} m/s as {best.upper()} {vs}): set the "
            f"DVL frame key {DVL_FRAME_KEY} = \"{best}\" in nespm-data.toml, or write body-frame (FRD) velocity in "
            "the DVL file", f"DVL looks like {best.upper()} velocity")


def judge_dvl(track: Track, fit: dict) -> dict:
    """The DVL rules (module docstring) on a track and its :func:`dvl_gt.fit_dvl_to_gt` dict.

    Returns ``own_noise`` (3,) and ``noise`` [m/s], ``bound`` [m/s], ``speed_rms`` [m/s],
    ``frame`` (:func:`dvl_frame.frame_candidates`), ``findings`` (one sentence per rule broken,
    with the measured numbers and the likely cause; the frame first) and ``reasons`` (the same,
    short, for the verdict's line). The track is inconsistent when ``reasons`` is not empty.
    """
    dvl = np.asarray(track.dvl, dtype=float)
    nz = own_noise(dvl)
    sigma = float(np.sqrt(np.mean(nz**2))) if np.isfinite(nz).all() else 0.0
    bound = max(RESID_SIGMAS * sigma, RESID_FLOOR)
    good = np.isfinite(dvl).all(axis=1)
    speed = float(np.sqrt(np.mean((dvl[good] ** 2).sum(axis=1)))) if good.any() else 0.0
    frame = frame_candidates(track)
    resid = float(fit["resid_rms_after"])
    findings: list[str] = []
    reasons: list[str] = []
    cause = _frame_finding(frame, resid, bound)
    if cause is not None:
        findings.append(cause[0])
        reasons.append(cause[1])
    if resid > bound:
        tried = ", ".join(f"{k.upper()} {frame[k]['rms']:.3f}" for k in ("ned", "enu") if frame[k]["rms"] is not None)
        if frame["axes"]["rms"] is not None:
            tried += f", axes {frame['axes']['axes']} {frame['axes']['rms']:.3f}"
        why = ("the frame above explains it" if cause is not None else
               f"no other frame explains it ({tried} m/s): check the GT's attitude conventions (yaw zero and "
               "direction, pitch and roll signs, angle unit) and the DVL's unit")
        findings.append(f"DVL residual {resid:.3f} m/s RMS after lever arm, scale, misalignment and time offset is "
                        f"{resid / max(sigma, 1e-12):.0f}x the DVL's own noise {sigma:.4f} m/s (bound {bound:.3f} = "
                        f"max({RESID_SIGMAS:g}x noise, {RESID_FLOOR:g} m/s)): {why}")
        reasons.append(f"DVL residual {resid:.2f} m/s")
    s = float(fit["scale_factor"])
    if abs(s) * speed > bound:
        std = fit.get("scale_factor_std")
        findings.append(f"DVL scale factor {100 * s:+.1f}{'' if std is None else f' +- {100 * std:.1f}'} % moves the "
                        f"DVL by {abs(s) * speed:.3f} m/s at its {speed:.2f} m/s RMS speed, above the bound "
                        f"{bound:.3f} m/s; no correction exists (a wrong sound speed or speed unit, or the frame)")
        reasons.append(f"DVL scale {100 * s:+.1f} %")
    mis = np.radians(np.asarray(fit["misalignment_deg"], dtype=float))
    if good.any() and np.isfinite(mis).all():
        moved = dvl[good] @ (exp_so3(-mis) - np.eye(3))  # (R^T - I) v per row: how far the rotation moves the DVL
        effect = float(np.sqrt(np.mean((moved**2).sum(axis=1))))
        if effect > bound:
            findings.append(f"DVL misalignment ({', '.join(f'{x:+.1f}' for x in fit['misalignment_deg'])}) deg moves the "
                            f"DVL by {effect:.3f} m/s RMS, above the bound {bound:.3f} m/s; no correction exists "
                            f"(a rotated mounting: the DVL's axes, {DVL_AXES_KEY})")
            reasons.append(f"DVL misalignment {np.degrees(np.linalg.norm(mis)):.0f} deg")
    curve = np.asarray([np.nan if x is None else x for x in fit["offset_curve"]["rms"]], dtype=float)
    flat = bool(np.nanmax(curve) - np.nanmin(curve) < FLAT_RISE * np.nanmin(curve)) if np.isfinite(curve).any() else True
    if fit.get("time_offset_at_edge") and (not flat or resid > bound):
        taus = np.asarray(fit["offset_curve"]["tau_s"], dtype=float)
        at0 = float(curve[int(np.argmin(np.abs(taus)))])
        findings.append(f"DVL time offset {fit['time_offset_s']:+.2f} s at the edge of the +-{fit['max_offset_s']:g} s "
                        f"search: no offset inside it fits (RMS {np.nanmin(curve):.3f} m/s there, {at0:.3f} at 0 s): "
                        "a DVL clock off by more than that, or a DVL that does not describe the GT's motion")
        reasons.append(f"DVL offset at the {fit['time_offset_s']:+.0f} s edge")
    return {"own_noise": [float(x) for x in nz], "noise": sigma, "bound": bound, "speed_rms": speed,
            "frame": frame, "findings": findings, "reasons": reasons}
